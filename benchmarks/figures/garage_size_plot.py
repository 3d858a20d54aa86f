"""The garage-size benchmark's table (benchmarks/results/garage_size.md, written by performance/garage_size.py) as a
plot, docs/img/scale.png: frame cost and peak memory against the garage's size.
Run: python -m benchmarks.figures.garage_size_plot"""

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import pandas as pd  # noqa: E402

from benchmarks.common import RESULTS, ROOT  # noqa: E402


def table(path: Path = RESULTS / "garage_size.md") -> pd.DataFrame:
    # the fenced table: lines not blank, not comments, not the page's own lines (heading, note, fences)
    text = path.read_text().split("```text\n", 1)[-1].split("```", 1)[0]
    lines = [ln for ln in text.splitlines() if ln.strip() and not ln.startswith("#")]
    rows = [ln.split() for ln in lines[1:]]
    cols = ["plan", "palette", "entities", "bodies", "hidden", "culled", "unculled", "gain", "x_research", "load",
            "peak_mb"]
    df = pd.DataFrame(rows, columns=cols)
    for c in ("entities", "bodies", "culled", "unculled", "x_research", "peak_mb"):
        df[c] = df[c].astype(float)
    return df


def main() -> Path:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "img" / "scale.png")
    args = parser.parse_args()
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
    fig.suptitle("Frame cost against garage size (case 1; 2 shared cores, see results/garage_size.md for the load)", fontsize=9)
    fig.tight_layout()
    fig.savefig(args.out)
    return args.out


if __name__ == "__main__":
    print(main())
