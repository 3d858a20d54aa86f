"""The scale benchmark's table (benchmarks/scale_run.txt, written by bench_scale.py) as a plot: frame cost and
peak memory against the garage's size. Run: python benchmarks/plot_scale.py"""

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import pandas as pd  # noqa: E402

HERE = Path(__file__).parent


def table(path: Path = HERE / "scale_run.txt") -> pd.DataFrame:
    lines = [ln for ln in path.read_text().splitlines() if ln.strip() and not ln.startswith("#")]
    rows = [ln.split() for ln in lines[1:]]
    cols = ["plan", "palette", "entities", "bodies", "hidden", "culled", "unculled", "gain", "x_research", "load",
            "peak_mb"]
    df = pd.DataFrame(rows, columns=cols)
    for c in ("entities", "bodies", "culled", "unculled", "x_research", "peak_mb"):
        df[c] = df[c].astype(float)
    return df


def main() -> Path:
    df = table()
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 3.8), dpi=110)
    for palette, g in df.groupby("palette", sort=False):
        a.plot(g.entities, g.culled, "o-", label=f"{palette}, culled (now)")
        a.plot(g.entities, g.unculled, "x--", label=f"{palette}, not culled")
        b.plot(g.entities, g.peak_mb, "o-", label=palette)
        for _, r in g.iterrows():
            a.annotate(r.plan, (r.entities, r.culled), fontsize=7, xytext=(3, 3), textcoords="offset points")
    a.set_xscale("log")
    b.set_xscale("log")
    a.set_xlabel("scene entities (log)")
    a.set_ylabel("render-stage seconds per frame")
    b.set_xlabel("scene entities (log)")
    b.set_ylabel("peak memory (MB)")
    a.legend(fontsize=7)
    b.legend(fontsize=7)
    a.grid(alpha=0.3)
    b.grid(alpha=0.3)
    fig.suptitle("Frame cost against garage size (case 1; 2 shared cores, see scale_run.txt for the load)", fontsize=9)
    fig.tight_layout()
    out = HERE.parent / "docs" / "img" / "scale.png"
    fig.savefig(out)
    return out


if __name__ == "__main__":
    print(main())
