"""The validation curves (issue 50, item 1: "enough epochs to converge: show the validation curve"): every
fine-tuning's per-epoch metrics on the loop's validation split (the base data's validation scenarios, never the
held-out sample), read from the training's own log (`train/<name>/ultralytics/results.csv`, ultralytics' columns),
one table and one figure for the run.

`converged` says whether the last epochs still gained: the validation mAP50's best lies in the last epoch and
rose by more than `rise` over the epochs before it; a curve still climbing at its end asks for more epochs.
"""

from __future__ import annotations

from pathlib import Path

import pandas as pd

# ultralytics' results.csv columns -> ours
COLUMNS = {"epoch": "epoch", "metrics/mAP50(B)": "map50", "metrics/recall(B)": "recall",
           "metrics/precision(B)": "precision", "val/box_loss": "val_box_loss", "val/cls_loss": "val_cls_loss",
           "val/dfl_loss": "val_dfl_loss", "train/box_loss": "train_box_loss", "train/cls_loss": "train_cls_loss"}


def read(train_dir: Path, detectors: dict) -> pd.DataFrame:
    """Every trained detector's curve (D0 as given has none): one row per detector and epoch."""
    tables = []
    for name, d in detectors.items():
        path = Path(train_dir) / name / "ultralytics" / "results.csv"
        if d.get("round", 0) == 0 or not path.is_file():
            continue
        raw = pd.read_csv(path)
        raw.columns = [c.strip() for c in raw.columns]  # older ultralytics pads its headers with spaces
        table = raw[[c for c in COLUMNS if c in raw.columns]].rename(columns=COLUMNS)
        if "val_box_loss" in table:
            table["val_loss"] = table[[c for c in ("val_box_loss", "val_cls_loss", "val_dfl_loss") if c in table]
                                      ].sum(axis=1)
        tables.append(table.assign(detector=name, arm=d["arm"], round=int(d["round"]), seed=int(d["seed"])))
    if not tables:
        return pd.DataFrame(columns=["detector", "arm", "round", "seed", "epoch", "map50", "val_loss"])
    out = pd.concat(tables, ignore_index=True)
    return out[["detector", "arm", "round", "seed", *[c for c in out.columns
                                                       if c not in ("detector", "arm", "round", "seed")]]]


def converged(curves: pd.DataFrame, rise: float = 0.01) -> dict[str, dict]:
    """Per detector: its epochs, best epoch and mAP50, last mAP50, and whether the curve had flattened (not still
    rising by more than `rise` into its last epoch)."""
    out = {}
    for name, g in curves.groupby("detector", sort=False):
        g = g.sort_values("epoch")
        best = g.loc[g.map50.idxmax()]
        last = float(g.map50.iloc[-1])
        before = float(g.map50.iloc[:-1].max()) if len(g) > 1 else float("nan")
        rising = len(g) < 2 or (int(best.epoch) == int(g.epoch.iloc[-1]) and last - before > rise)
        out[str(name)] = {"epochs": int(len(g)), "best_epoch": int(best.epoch), "best_map50": float(best.map50),
                          "last_map50": last, "converged": not rising}
    return out


def draw(curves: pd.DataFrame, path: Path) -> Path | None:
    """validation.png: mAP50 and the validation loss per epoch, a line per fine-tuning (colour: arm; dashes:
    round)."""
    if not len(curves):
        return None
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from garage_exp.loop.figure import COLOURS

    fig, (ax, bx) = plt.subplots(1, 2, figsize=(11, 4))
    styles = ["-", "--", ":", "-."]
    for (arm, k, seed), g in curves.groupby(["arm", "round", "seed"], sort=True):
        g = g.sort_values("epoch")
        kw = {"color": COLOURS.get(arm), "linestyle": styles[(int(k) - 1) % len(styles)], "marker": ".",
              "label": f"{arm} round {k}" + (f" seed {seed}" if curves.seed.nunique() > 1 else "")}
        ax.plot(g.epoch, g.map50, **kw)
        if "val_loss" in g:
            bx.plot(g.epoch, g.val_loss, **kw)
    ax.set_xlabel("epoch")
    ax.set_ylabel("mAP50 on the validation split")
    ax.set_title("Validation mAP50 per epoch")
    bx.set_xlabel("epoch")
    bx.set_ylabel("validation loss (box + cls + dfl)")
    bx.set_title("Validation loss per epoch")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path
