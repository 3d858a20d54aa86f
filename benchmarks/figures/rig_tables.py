"""The rig tables and figure of docs/results.md from two sweeps' job dirs (each job's frames.csv and
.hydra/overrides.yaml):

    python -m garage_exp -m case=2 camera=fisheye camera.view=raw,perspective,cylindrical case.motion.step=1
    python -m garage_exp -m case=1,3 camera.mount=roof,mirror,bumper camera.fovy=30,60,90,120 case.motion.step=2
    python -m benchmarks.figures.rig_tables --views VIEWS_SWEEP_DIR --mounts MOUNTS_SWEEP_DIR [--out docs/img]

--views: composite confidence against the target's angle from the optical axis (15-degree bins), per view, as a
markdown table and docs/img/rigs_off_axis.png. --mounts: mean composite confidence by mount and FOV, per case.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import pandas as pd
import yaml

BINS = list(range(0, 105, 15))


def jobs(sweep: Path) -> pd.DataFrame:
    """Every job's frame table with its overrides as columns."""
    parts = []
    for table in sorted(sweep.glob("*/frames.csv")):
        overrides = yaml.safe_load((table.parent / ".hydra" / "overrides.yaml").read_text())
        cols = dict(o.split("=", 1) for o in overrides if "=" in o)
        parts.append(pd.read_csv(table).assign(**{k.split(".")[-1]: v for k, v in cols.items()}))
    return pd.concat(parts, ignore_index=True)


def markdown(df: pd.DataFrame) -> str:
    head = "| " + " | ".join(map(str, df.columns)) + " |"
    rule = "|" + "|".join("---" for _ in df.columns) + "|"
    rows = ["| " + " | ".join(f"{v:.3f}" if isinstance(v, float) else str(v) for v in r) + " |"
            for r in df.itertuples(index=False)]
    return "\n".join([head, rule, *rows])


def views(sweep: Path, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = jobs(sweep)
    t["angle"] = pd.cut(t.off_axis, BINS)
    # frames the view does not hold count as misses (0): the car is there, the view cannot show it
    keys = ["label", "position", *(["replicate"] if "replicate" in t else [])]
    raw = t[t.view == "raw"][[*keys, "off_axis"]]
    t = t.drop(columns="off_axis").merge(raw, on=keys)
    t["angle"] = pd.cut(t.off_axis, BINS)
    table = t.pivot_table(index="angle", columns="view", values="composite", aggfunc="mean", observed=False)
    counts = t[t.view == "raw"].groupby("angle", observed=False).size()
    table = table[["raw", "perspective", "cylindrical"]].assign(frames=counts).reset_index()
    table["angle"] = table.angle.astype(str).str.replace(", ", "-").str.strip("(]") + " deg"
    print(markdown(table.dropna()))
    print()
    print(markdown(t.groupby("view").agg(confidence=("composite", "mean"),
                                         in_view=("kitti", lambda k: float((k != "out_of_view").mean())),
                                         frames=("composite", "size")).reset_index()))
    fig, ax = plt.subplots(figsize=(7, 4), dpi=110)
    for view, style, colour in (("raw", "-o", "C0"), ("perspective", "-s", "C3"), ("cylindrical", "-^", "C2")):
        g = t[t.view == view].sort_values("off_axis")
        ax.plot(g.off_axis, g.composite, style[1], ms=3, alpha=0.3, color=colour)
        binned = g.groupby("angle", observed=False).agg(a=("off_axis", "mean"), c=("composite", "mean")).dropna()
        ax.plot(binned.a, binned.c, style, color=colour, label=f"{view} (mean per 15-degree bin; dots: frames)")
    ax.set_xlabel("target's angle from the fisheye's optical axis (degrees)")
    ax.set_ylabel("composite confidence")
    ax.set_ylim(-0.02, 1.02)
    ax.set_title("case 2, camera=fisheye (front bumper, 190 deg): raw vs undistorted views")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "rigs_off_axis.png")


def mounts(sweep: Path) -> None:
    t = jobs(sweep)
    for case, g in t.groupby("case", sort=True):
        table = g.pivot_table(index="mount", columns="fovy", values="composite", aggfunc="mean")
        table = table.reindex(["roof", "mirror", "bumper"])[sorted(table.columns, key=float)]
        table.columns = [f"fovy {c}" for c in table.columns]
        vis = g.pivot_table(index="mount", columns="fovy", values="visible_fraction", aggfunc="mean")
        print(f"case {case}: mean composite confidence ({len(g) // len(table.columns) // len(table)} frames a cell)")
        print(markdown(table.reset_index()))
        print(f"case {case}: mean visible fraction")
        vis = vis.reindex(["roof", "mirror", "bumper"])[sorted(vis.columns, key=float)]
        vis.columns = [f"fovy {c}" for c in vis.columns]
        print(markdown(vis.reset_index()))
        print()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--views", type=Path)
    parser.add_argument("--mounts", type=Path)
    parser.add_argument("--out", type=Path, default=Path("docs/img"))
    args = parser.parse_args()
    if args.views:
        views(args.views, args.out)
    if args.mounts:
        mounts(args.mounts)


if __name__ == "__main__":
    main()
