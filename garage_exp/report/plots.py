"""The report's figures: a heat map per factor pair, each main effect with its 95 % intervals, an interaction
plot per pair, and recall against visible fraction with the fitted curves."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pandas as pd


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _err(df: pd.DataFrame, col: str) -> np.ndarray:
    """Error bar lengths below and above each mean (0 where a mean has no interval)."""
    low = (df[col] - df[f"{col}_low"]).fillna(0).clip(lower=0)
    high = (df[f"{col}_high"] - df[col]).fillna(0).clip(lower=0)
    return np.vstack([low.to_numpy(dtype=float), high.to_numpy(dtype=float)])


def heatmaps(obs: pd.DataFrame, factors: list[str], path: Path) -> Path | None:
    plt = _plt()
    pairs = list(itertools.combinations(factors, 2))
    if not pairs or obs.empty:  # a dry-run sweep has no confidences to map
        return None
    fig, axes = plt.subplots(1, len(pairs), figsize=(4.8 * len(pairs), 4), dpi=110, squeeze=False)
    for ax, (a, b) in zip(axes[0], pairs):
        table = obs.pivot_table(index=a, columns=b, values="confidence_mean", aggfunc="mean", sort=False)
        im = ax.imshow(table.to_numpy(dtype=float), vmin=0, vmax=1, cmap="viridis")
        ax.set_xticks(range(len(table.columns)), table.columns)
        ax.set_yticks(range(len(table.index)), table.index)
        ax.set_xlabel(b.removeprefix("factor."))
        ax.set_ylabel(a.removeprefix("factor."))
        for (y, x), v in pd.DataFrame(table.to_numpy()).stack().items():
            ax.text(x, y, f"{v:.2f}", ha="center", va="center", color="white" if v < 0.6 else "black", fontsize=8)
        fig.colorbar(im, ax=ax, shrink=0.8, label="mean composite confidence")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path


def main_effects(effects: pd.DataFrame, path: Path) -> Path | None:
    """One panel per factor: mean composite confidence and recall per level, with 95 % intervals."""
    if effects.empty:
        return None
    plt = _plt()
    factors = list(dict.fromkeys(effects.factor))
    fig, axes = plt.subplots(1, len(factors), figsize=(3.6 * len(factors) + 0.6, 3.4), dpi=110, squeeze=False,
                             sharey=True)
    for ax, factor in zip(axes[0], factors):
        e = effects[effects.factor == factor]
        x = np.arange(len(e))
        for col, dx, colour in (("confidence_mean", -0.08, "tab:blue"), ("recall", 0.08, "tab:orange")):
            ax.errorbar(x + dx, e[col], yerr=_err(e, col), fmt="o", capsize=4, color=colour,
                        label="mean composite confidence" if col == "confidence_mean" else "recall")
        ax.set_xticks(x, e.level.astype(str))
        ax.set_xlim(-0.5, len(e) - 0.5)
        ax.set_xlabel(factor)
        ax.set_ylim(0, 1.02)
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel("mean over units, 95 % CI")
    handles, labels = axes[0][0].get_legend_handles_labels()
    fig.legend(handles, labels, fontsize=8, loc="upper center", ncol=2, frameon=False)
    fig.tight_layout(rect=(0, 0, 1, 0.92))
    fig.savefig(path)
    plt.close(fig)
    return path


def interactions(pairs: pd.DataFrame, path: Path) -> Path | None:
    """One panel per factor pair: composite confidence against the first factor's levels, a line per level of
    the second, with 95 % intervals (parallel lines: no interaction)."""
    if pairs.empty:
        return None
    plt = _plt()
    names = list(dict.fromkeys(pairs.pair))
    fig, axes = plt.subplots(1, len(names), figsize=(4.2 * len(names) + 0.6, 3.4), dpi=110, squeeze=False)
    for ax, name in zip(axes[0], names):
        p = pairs[pairs.pair == name]
        xs = list(dict.fromkeys(p.level_a.astype(str)))
        for k, (level, g) in enumerate(p.groupby("level_b", sort=False)):
            g = g.set_index(g.level_a.astype(str)).reindex(xs)
            ax.errorbar(np.arange(len(xs)) + 0.04 * k, g.confidence_mean, yerr=_err(g, "confidence_mean"),
                        marker="o", capsize=3, label=str(level))
        a, b = name.split(" x ")
        ax.set_xticks(range(len(xs)), xs)
        ax.set_xlim(-0.4, len(xs) - 0.6)
        ax.set_xlabel(a)
        ax.set_ylabel("mean composite confidence")
        ax.set_ylim(0, 1.02)
        ax.legend(title=b, fontsize=8)
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path


def visibility(frames: pd.DataFrame, curves: pd.DataFrame, path: Path) -> Path | None:
    """Recall against visible fraction: binned recall per score (tenths of visibility) and the fitted logistic
    curve, with each curve's 50 % crossing marked."""
    if frames.empty or curves.empty:
        return None
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7, 4.2), dpi=110)
    edges = np.linspace(0, 1, 11)
    grid = np.linspace(0, 1, 101)
    bins = pd.cut(frames.visible_fraction, edges, include_lowest=True)
    for k, row in curves.reset_index(drop=True).iterrows():
        col = "composite" if row.model == "composite" else f"conf_{row.model}"
        colour = f"C{k}"
        hit = (frames[col] >= frames.threshold).astype(float)
        binned = hit.groupby(bins, observed=True).mean()
        mids = [iv.mid for iv in binned.index]
        width = 2.2 if row.model == "composite" else 1.2
        ax.plot(mids, binned.to_numpy(), "o", color=colour, alpha=0.6)
        label = row.model
        if isinstance(row.fit, tuple):
            b0, b1 = row.fit
            ax.plot(grid, 1 / (1 + np.exp(-(b0 + b1 * grid))), color=colour, lw=width)
            if 0 <= row.v50 <= 1:
                ax.axvline(row.v50, color=colour, ls=":", lw=1)
                label += f" (recall 0.5 at {row.v50:.2f})"
        ax.plot([], [], color=colour, lw=width, marker="o", label=label)
    for edge in (0.2, 0.65):  # CityPersons' bins
        ax.axvline(edge, color="grey", lw=0.8, ls="--")
    ax.set_xlabel("visible fraction of the target (CityPersons bins: < 0.2 | heavy | reasonable)")
    ax.set_ylabel("recall (frames with confidence >= threshold)")
    ax.set_xlim(0, 1)
    ax.set_ylim(-0.02, 1.02)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="upper left")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path
