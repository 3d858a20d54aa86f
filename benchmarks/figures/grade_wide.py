"""Graded suites of four detectors on one figure (docs/img/grade_wide.png), from `python -m garage_exp.search.grade`'s
grade.csv of each: `python -m benchmarks.figures.grade_wide NAME=DIR/grade.csv ... [--out docs/img/grade_wide.png]`.
Each detector's failure rate of fresh draws per level with its 95 % Wilson interval (the csv's low and high),
Spearman's rho between level and rate in the legend, the detectors side by side a little apart on the level axis."""

from __future__ import annotations

import argparse
from pathlib import Path


def draw(tables: dict[str, Path], out: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import pandas as pd
    from scipy.stats import spearmanr

    fig, ax = plt.subplots(figsize=(6.0, 3.8))
    drawn = set()
    for k, (name, path) in enumerate(tables.items()):
        g = pd.read_csv(path)
        drawn |= set(int(n) for n in g.drawn)
        rho = spearmanr(g.level, g.failure_rate).statistic
        ax.errorbar(g.level + (k - (len(tables) - 1) / 2) * 0.06, g.failure_rate,
                    yerr=[g.failure_rate - g.low, g.high - g.failure_rate], fmt="o-", capsize=3,
                    label=f"{name} (rho {rho:.2f})")
    ax.set_xlabel("suite level (1 easiest)")
    ax.set_ylabel("failure rate of fresh draws")
    ax.set_ylim(-0.02, 1.02)
    ax.set_xticks([1, 2, 3, 4, 5])
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="upper left")
    per_level = "/".join(str(n) for n in sorted(drawn))  # from the tables: the figure says what it shows
    ax.set_title(f"space=wide: {per_level} fresh draws a level, sigma 0.05 (95 % Wilson intervals)", fontsize=9)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("tables", nargs="+", help="NAME=path/to/grade.csv, one per detector")
    parser.add_argument("--out", default="docs/img/grade_wide.png")
    args = parser.parse_args()
    tables = dict(t.split("=", 1) for t in args.tables)
    print(draw({k: Path(v) for k, v in tables.items()}, Path(args.out)))


if __name__ == "__main__":
    main()
