"""A search study's figures: the optimisation history, the slices, the importances and (two objectives) the
Pareto front, as PNGs drawn with optuna.visualization.matplotlib."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import optuna
from optuna.trial import TrialState

from garage_exp.report.trials import first_value, objective_names


def _plots():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from optuna.visualization import matplotlib as vis

    return plt, vis


def save_plot(draw, path: Path, size: tuple[float, float] | None = None) -> Path:
    """Save the figure an optuna.visualization.matplotlib function drew (it returns one axes or an array)."""
    plt, _ = _plots()
    # optuna's plots switch the global style to ggplot: rc_context gives the caller's style back afterwards
    with warnings.catch_warnings(), plt.rc_context():
        warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
        axes = draw()
    fig = np.ravel(axes)[0].figure
    if size:
        fig.set_size_inches(*size)
    fig.savefig(path, dpi=110, bbox_inches="tight")  # optuna's colour bar axes defeat tight_layout
    plt.close(fig)
    return path


def figures(study: optuna.Study, out_dir: Path, importance: dict[str, float]) -> dict[str, Path]:
    """The history, the importances, the slices and (two objectives) the Pareto front, as PNGs."""
    _, vis = _plots()
    done = study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,))
    names = objective_names(study)
    if not done:
        return {}
    # one objective: no target, so optuna also draws the best-so-far line; two: the difficulty alone
    target = first_value if len(study.directions) > 1 else None
    out = {"history": save_plot(lambda: vis.plot_optimization_history(
        study, target=target, target_name=names[0]), out_dir / "history.png", (7, 4))}
    params = sorted({p for t in done for p in t.params})
    if params:
        out["slices"] = save_plot(lambda: vis.plot_slice(study, target=first_value, target_name=names[0]),
                                  out_dir / "slices.png")  # optuna sizes it to the parameters
    if importance:
        plt, _ = _plots()
        fig, ax = plt.subplots(figsize=(6, 0.5 * len(importance) + 1.2), dpi=110)
        order = sorted(importance, key=importance.get)
        ax.barh(order, [importance[p] for p in order], color="tab:blue")
        ax.set_xlabel(f"fANOVA importance for {names[0]} (sums to 1)")
        fig.tight_layout()
        fig.savefig(out_dir / "importances.png")
        plt.close(fig)
        out["importances"] = out_dir / "importances.png"
    if len(study.directions) == 2:
        out["pareto"] = save_plot(lambda: vis.plot_pareto_front(study, target_names=names),
                                  out_dir / "pareto.png", (6, 4.5))
    return out
