"""What the user sees of a study (issue 10, §3): figures, tables and a report of the hardest scenarios.

`analyse(study, out_dir)` works on any Optuna study whose trials follow the sweeper's contract (values: the
search objective's, named by the study's user_attr direction_names: difficulty, lateness, ...; user_attrs:
overrides, visible_fraction, fair_frames, frames, recall, confidence, frame, and "infeasible" on a pruned
trial or "error" on a failed one). It writes, into out_dir: history.png, importances.png/.csv (fANOVA),
slices.png, pareto.png (multi-objective), sensitivity.png/.csv (Sobol', see sensitivity), trials.csv, hardest.csv,
frames/ (the hardest trials' frames) and search_report.md/.html. Only complete trials are ranked; pruned
(infeasible) and failed ones are counted and listed apart. `python -m garage_exp.report.search_analysis` writes the same for a study in a storage, finished or
still running.
"""

from __future__ import annotations

import argparse
import shlex
import shutil
import sys
import warnings
from pathlib import Path

import numpy as np
import optuna
import pandas as pd
from optuna.distributions import BaseDistribution, CategoricalDistribution
from optuna.trial import FrozenTrial, TrialState
from scipy.stats import ttest_ind

from garage_exp.core.errors import GarageError
from garage_exp.tracking.page import html_page
from garage_exp.core.paths import OUTPUTS_DIR
from garage_exp.report import sensitivity

FANOVA_SEED = 0  # the importances of one study are the same every time they are computed
ATTRS = ("visible_fraction", "fair_frames", "frames", "recall", "confidence")
# a moving ego's verdict, when the trials' case drives the ego (search.objective=late ranks by lateness)
LATE_ATTRS = ("late", "detection_distance", "ttc_at_detection")
THIRDS = ("low third", "middle third", "high third")
ALPHA = 0.05  # a side is called harder only when Welch's t-test tells it from the hardest other side


def first_value(trial: FrozenTrial) -> float:
    """The trial's first value, the one the study ranks by (difficulty, lateness, slot_miss: whatever the search's
    objective stored as `direction_names`), in single- and multi-objective studies alike."""
    return trial.values[0]


def objective_names(study: optuna.Study) -> list[str]:
    """The study's value names, as the search stored them (search/objectives.py); a study without them was
    made before the search stored names, when the only objectives were difficulty and pareto."""
    names = study.user_attrs.get("direction_names") or study.metric_names
    if names and len(names) == len(study.directions):
        return list(names)
    return ["difficulty", "visible_fraction"][:len(study.directions)] + [
        f"objective_{k}" for k in range(2, len(study.directions))]


def untestable(study: optuna.Study) -> str:
    """Why the study's objective prunes a trial as infeasible, as the search stored it."""
    return str(study.user_attrs.get("untestable") or "no fairly visible frame")


def overrides(trial: FrozenTrial) -> list[str]:
    """The trial's override list as the sweeper stored it; its parameters as overrides when it stored none."""
    return list(trial.user_attrs.get("overrides") or [f"{k}={v}" for k, v in trial.params.items()])


# The search settings a job reads itself: which frames are fair tests (its fair_* metrics and late verdict).
JOB_SEARCH_KEYS = ("search.min_visible=", "search.min_box=", "search.max_truncation=")


def rerun_overrides(trial: FrozenTrial) -> list[str]:
    """The overrides that rerun the scenario as a plain job: without the search's own settings and where it
    logged (`search.*` but the fairness rule the job applies, `tracking.*`), a quoted numeric level unquoted
    (the command line quotes it again)."""
    import re

    kept = [o for o in overrides(trial) if o.startswith(JOB_SEARCH_KEYS)
            or not o.startswith(("search.", "tracking.", "hydra."))]
    return [re.sub(r"^([\w.]+)='(\d+)'$", r"\1=\2", o) for o in kept]


def trial_table(study: optuna.Study) -> pd.DataFrame:
    """One row per trial: number, state, the first objective's value (complete trials) in a column named as the
    objective names it (difficulty, lateness, slot_miss: `objective_names`), the contract's user_attrs, each
    parameter in its own column, the overrides, and why a trial was pruned or failed."""
    multi = len(study.directions) > 1
    name = objective_names(study)[0]
    rows = []
    for t in study.get_trials(deepcopy=False):
        done = t.state == TrialState.COMPLETE
        row = {"trial": t.number, "state": t.state.name, name: first_value(t) if done else np.nan}
        for key in (*ATTRS, *LATE_ATTRS):
            row[key] = t.user_attrs.get(key, np.nan)
        if multi and done and pd.isna(row["visible_fraction"]):
            row["visible_fraction"] = t.values[1]
        row.update(t.params)
        row["overrides"] = " ".join(overrides(t))
        row["why"] = ("screened as easy by the pre-screen" if t.user_attrs.get("screened") == "easy"
                      else f"infeasible: {untestable(study)}" if t.user_attrs.get("infeasible")
                      else str(t.user_attrs.get("error", "")))
        row["run_id"] = t.user_attrs.get("run_id", "")
        row["frame"] = t.user_attrs.get("frame", "")
        rows.append(row)
    return pd.DataFrame(rows)


def hardest(study: optuna.Study, top: int) -> list[FrozenTrial]:
    """The top complete trials by the first value (the study's first direction says which end is hard)."""
    done = study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,))
    harder_is_higher = study.directions[0] == optuna.study.StudyDirection.MAXIMIZE
    return sorted(done, key=lambda t: (-first_value(t) if harder_is_higher else first_value(t), t.number))[:top]


def distributions(study: optuna.Study) -> dict[str, BaseDistribution]:
    """Each parameter's distribution, as the latest trial that used it declared it."""
    dists: dict[str, BaseDistribution] = {}
    for t in study.get_trials(deepcopy=False):
        dists.update(t.distributions)
    return dists


def position(value, dist: BaseDistribution) -> float:
    """Where a numeric value lies in its range, 0 (low end) to 1 (high end); on a log scale for log ranges."""
    return float(np.clip(sensitivity.to_unit(value, dist), 0, 1))


def side(value, dist: BaseDistribution) -> str:
    """The part of the range a value is in: a categorical level, or a third of a numeric range."""
    if isinstance(dist, CategoricalDistribution):
        return str(value)
    return THIRDS[min(int(position(value, dist) * 3), 2)]


def sides(table: pd.DataFrame, param: str, dist: BaseDistribution, name: str = "difficulty") -> dict[str, pd.Series]:
    """The complete trials' values of the objective `name` on each side (third or level) of a parameter."""
    done = table[(table.state == "COMPLETE") & table[param].notna()]
    labels = [side(v, dist) for v in done[param]]
    return {k: g for k, g in done[name].groupby(labels)}


def range_text(dist: BaseDistribution) -> str:
    if isinstance(dist, CategoricalDistribution):
        return "levels " + ", ".join(map(str, dist.choices))
    return f"{dist.low:g} to {dist.high:g}" + (" (log scale)" if getattr(dist, "log", False) else "")


def why_hard(trial: FrozenTrial, table: pd.DataFrame, dists: dict, importance: dict[str, float],
             higher_is_harder: bool = True, name: str = "difficulty") -> list[tuple[str, str, str]]:
    """(parameter, side, sentence) per parameter of the trial, most important first: where its value lies and
    whether the study's complete trials are harder on that side than on the hardest other side (Welch's
    t-test); the sentence says "the harder side" only when they are."""
    lines = []
    for param in sorted(trial.params, key=lambda p: (-importance.get(p, -1), p)):
        dist, value = dists[param], trial.params[param]
        where = side(value, dist)
        groups = sides(table, param, dist, name)
        shown = f"{value:.3g}" if isinstance(value, float) else str(value)
        head = f"`{param}` = {shown}"
        if not isinstance(dist, CategoricalDistribution):
            head += f", {position(value, dist):.0%} of the way from {range_text(dist)}, in the {where}"
        if param in importance:
            head += f" (importance {importance[param]:.2f})"
        mine = groups.get(where, pd.Series(dtype=float))
        others = {k: g for k, g in groups.items() if k != where and len(g) >= 2}
        if len(mine) < 2 or not others:
            lines.append((param, where, f"{head}: too few trials on each side to tell whether this side is harder."))
            continue
        pick = max if higher_is_harder else min
        best = pick(others, key=lambda k: others[k].mean())  # the hardest of the other sides
        rest = others[best]
        p = ttest_ind(mine, rest, equal_var=False).pvalue
        harder = mine.mean() >= rest.mean() if higher_is_harder else mine.mean() <= rest.mean()
        verdict = ("no clear harder side" if not p < ALPHA
                   else "the harder side" if harder else "not the harder side")
        there = f"with {param}={best}" if isinstance(dist, CategoricalDistribution) else f"in the {best}"
        lines.append((param, where, f"{head}: {verdict} (p = {p:.2g}): {name} {mine.mean():.2f} on average "
                                    f"there ({len(mine)} trials) against {rest.mean():.2f} {there} ({len(rest)})."))
    return lines


def importances(study: optuna.Study) -> tuple[dict[str, float], str]:
    """fANOVA importances of the parameters for the first value (seeded), or {} and the reason they are missing."""
    done = study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,))
    if len(done) < 2:
        return {}, f"Importances skipped: {len(done)} complete trial(s), fANOVA needs at least 2."
    evaluator = optuna.importance.FanovaImportanceEvaluator(seed=FANOVA_SEED)
    try:
        found = optuna.importance.get_param_importances(study, evaluator=evaluator, target=first_value)
    except RuntimeError as exc:  # fANOVA's "zero total variance": every trial equally hard
        return {}, f"Importances skipped: {exc}"
    if not found:
        return {}, "Importances skipped: no parameter was sampled in every complete trial."
    return {k: float(v) for k, v in found.items()}, ""


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


def copy_frame(trial: FrozenTrial, out_dir: Path) -> Path | None:
    """The trial's hardest fair frame, copied beside the report so the report (and its HTML) can show it."""
    src = trial.user_attrs.get("frame")
    if not src or not Path(src).is_file():
        return None
    dst = out_dir / "frames" / f"trial_{trial.number}{Path(src).suffix}"
    dst.parent.mkdir(exist_ok=True)
    shutil.copyfile(src, dst)
    return dst


def fmt(value, digits: int = 2) -> str:
    return "-" if value is None or pd.isna(value) else f"{value:.{digits}f}"


def md_table(df: pd.DataFrame) -> list[str]:
    """A small frame as a markdown table (floats to 2 decimals, pipes escaped)."""
    cells = df.map(lambda v: fmt(v) if isinstance(v, float) else str(v).replace("|", "\\|"))
    return ["| " + " | ".join(map(str, df.columns)) + " |", "|" + "---|" * len(df.columns),
            *("| " + " | ".join(row) + " |" for row in cells.itertuples(index=False))]


def sensitivity_section(study: optuna.Study, out_dir: Path, seed: int) -> tuple[list[str], list[Path]]:
    lines = ["## Global sensitivity (Sobol' indices)", ""]
    try:
        indices = sensitivity.sobol_indices(study, seed)
    except GarageError as exc:
        return [*lines, f"Sensitivity skipped: {exc}", ""], []
    csv = out_dir / "sensitivity.csv"
    indices.to_csv(csv, index=False)
    png = sensitivity.bar_plot(indices, out_dir / "sensitivity.png")
    categorical = sorted(k for k, d in distributions(study).items() if isinstance(d, CategoricalDistribution))
    lines += [sensitivity.method_text(indices)
              + (f" Categorical factors ({', '.join(categorical)}) are not in it: see the importances and slices."
                 if categorical else ""), "",
              *md_table(indices[["factor", "S1", "S1_conf", "ST", "ST_conf"]].rename(
                  columns={"S1_conf": "S1 ± (95 %)", "ST_conf": "ST ± (95 %)"})), "",
              "![Sobol' indices](sensitivity.png)", ""]
    return lines, [csv, png]


def summary(study: optuna.Study, table: pd.DataFrame, names: list[str]) -> list[str]:
    by_state = table.state.value_counts() if len(table) else pd.Series(dtype=int)
    count = {s: int(by_state.get(s, 0)) for s in ("COMPLETE", "PRUNED", "FAIL", "RUNNING", "WAITING")}
    objectives = ", ".join(f"{n} ({d.name.lower()})" for n, d in zip(names, study.directions))
    return [f"# Search report: {study.study_name}", "",
            f"{len(table)} trials: {count['COMPLETE']} complete, {count['PRUNED']} pruned as infeasible "
            f"({untestable(study)}), {count['FAIL']} failed"
            + (f", {count['RUNNING']} running" if count["RUNNING"] else "")
            + (f", {count['WAITING']} waiting" if count["WAITING"] else "")
            + f". Objectives: {objectives}. Only complete trials are ranked.", ""]


def hardest_section(study: optuna.Study, table: pd.DataFrame, out_dir: Path, top: int,
                    importance: dict[str, float]) -> tuple[list[str], list[Path]]:
    """The hardest scenarios: a table, then each one's command, reasons and frame; hardest.csv."""
    top_trials = hardest(study, top)
    name = objective_names(study)[0]
    by_number = table.set_index("trial")
    late = [c for c in LATE_ATTRS if by_number[c].notna().any()]
    hard = by_number.loc[[t.number for t in top_trials]].reset_index()[
        ["trial", name, *ATTRS, *late, "overrides", "run_id", "frame"]]
    hard.insert(0, "rank", range(1, len(hard) + 1))
    hard.to_csv(out_dir / "hardest.csv", index=False)
    written = [out_dir / "hardest.csv"]
    lines = [f"## The {len(top_trials)} hardest scenarios", ""]
    if not top_trials:
        return [*lines, "No complete trial: nothing to rank.", ""], written
    lines += [*md_table(hard[["rank", "trial", name, "visible_fraction", "fair_frames", "frames", *late]].rename(
        columns={"visible_fraction": "visible fraction", "fair_frames": "fair frames",
                 "detection_distance": "detection distance (m)", "ttc_at_detection": "TTC at detection (s)"})), ""]
    dists = distributions(study)
    higher_is_harder = study.directions[0] == optuna.study.StudyDirection.MAXIMIZE
    for rank, t in enumerate(top_trials, 1):
        command = " ".join(["python -m garage_exp", *map(shlex.quote, rerun_overrides(t))])
        lines += [f"### {rank}. trial {t.number}: {name} {first_value(t):.2f}, visible fraction "
                  f"{fmt(by_number.loc[t.number, 'visible_fraction'])}", "",
                  "Rerun it:", "", "```bash", command, "```", "",
                  *what_makes_it_hard(why_hard(t, table, dists, importance, higher_is_harder, name))]
        frame = copy_frame(t, out_dir)
        if frame:
            written.append(frame)
            lines += [f"![trial {t.number}: its hardest fair frame]({frame.relative_to(out_dir).as_posix()})", ""]
        else:
            lines += ["(no frame saved for this trial)", ""]
    return lines, written


def importance_section(importance: dict[str, float], skipped: str, name: str, out_dir: Path
                       ) -> tuple[list[str], list[Path]]:
    lines = ["## Parameter importances (fANOVA)", ""]
    if not importance:
        return [*lines, skipped, ""], []
    imp = pd.DataFrame({"parameter": list(importance), "importance": list(importance.values())})
    imp.to_csv(out_dir / "importances.csv", index=False)
    return [*lines, f"How much of the variance of {name} over the complete trials each parameter explains "
            f"(Optuna's fANOVA, seed {FANOVA_SEED}; they sum to 1).", "", *md_table(imp), "",
            "![importances](importances.png)", ""], [out_dir / "importances.csv"]


def pareto_section(study: optuna.Study, table: pd.DataFrame, names: list[str], drawn: bool) -> list[str]:
    """The trials on the Pareto front (two objectives), marked in the trial table too."""
    front = list(study.best_trials)
    table["on_front"] = table.trial.isin([t.number for t in front])
    lines = ["## Pareto front", "", f"{len(front)} trials that no other trial beats on both {names[0]} and "
             f"{names[1]}.", ""]
    if front:
        rows = pd.DataFrame([{"trial": t.number, **dict(zip(names, t.values)), "overrides": " ".join(overrides(t))}
                             for t in front])
        harder_first = study.directions[0] != optuna.study.StudyDirection.MAXIMIZE
        lines += [*md_table(rows.sort_values(names[0], ascending=harder_first)), ""]
    return lines + (["![Pareto front](pareto.png)", ""] if drawn else [])


def analyse(study: optuna.Study, out_dir: Path, top: int = 5, seed: int = 0) -> list[Path]:
    """Write the study's figures, tables and search_report.md/.html into out_dir; returns the files written.
    The report puts the hardest scenarios first, then how the search went and what the factors do."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    table = trial_table(study)
    names = objective_names(study)
    importance, skipped = importances(study)
    drawn = figures(study, out_dir, importance)
    written = list(drawn.values())

    lines = summary(study, table, names)
    section, files = hardest_section(study, table, out_dir, top, importance)
    lines += section
    written += files
    if "history" in drawn:
        lines += ["## Optimisation history", "", f"![history of {names[0]}](history.png)", ""]
    section, files = importance_section(importance, skipped, names[0], out_dir)
    lines += section
    written += files
    if "slices" in drawn:
        lines += ["## Slices", "", f"{names[0]} of each complete trial against each parameter.", "",
                  "![slices](slices.png)", ""]
    if len(study.directions) > 1:
        lines += pareto_section(study, table, names, "pareto" in drawn)
    section, files = sensitivity_section(study, out_dir, seed)
    lines += section + not_ranked(table)
    written += files

    table.to_csv(out_dir / "trials.csv", index=False)
    report = out_dir / "search_report.md"
    report.write_text("\n".join(lines))
    return [*written, out_dir / "trials.csv", report, html_page(report)]


def what_makes_it_hard(reasons: list[tuple[str, str, str]]) -> list[str]:
    """The report's lines for one scenario: a one-line summary, then one bullet per parameter."""
    harder = [f"`{param}` ({where})" for param, where, text in reasons if ": the harder side (" in text]
    summary = ("In short: hard through " + ", ".join(harder) + "." if harder else
               "In short: none of its parameters sits on a side that is clearly harder in this study's data.")
    return ["What makes it hard: " + summary.removeprefix("In short: "), "",
            *(f"- {text}" for _, _, text in reasons), ""]


def not_ranked(table: pd.DataFrame) -> list[str]:
    """The pruned (infeasible) and failed trials, each with its overrides and reason."""
    lines = []
    for state, title in (("PRUNED", "Pruned trials (infeasible: never fairly visible)"), ("FAIL", "Failed trials")):
        rows = table[table.state == state] if len(table) else table
        if len(rows):
            lines += [f"## {title}", "", *md_table(rows[["trial", "why", "overrides"]]), ""]
    return lines


STORAGE = f"sqlite:///{OUTPUTS_DIR / 'search' / 'optuna.db'}"  # `make dashboard`'s default too


def load(storage: str, name: str | None) -> optuna.Study:
    """The named study in the storage, or its latest one; GarageError when there is none by that name."""
    names = [s.study_name for s in optuna.get_all_study_summaries(storage, include_best_trial=False)]
    if not names:
        raise GarageError("no study in this storage", storage)
    if name is not None and name not in names:
        raise GarageError(f"no study named {name!r} (there are: {', '.join(names)})", storage)
    return optuna.load_study(study_name=name or names[-1], storage=storage)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m garage_exp.report.search_analysis",
                                 description="A search study's figures, importances, sensitivity and report.")
    ap.add_argument("--storage", default=STORAGE, help=f"Optuna storage URL (default: {STORAGE})")
    ap.add_argument("--study", default=None, help="the study's name (default: the storage's latest study)")
    ap.add_argument("-o", "--out", default=None, help="where to write (default: outputs/search/<study>)")
    ap.add_argument("--top", type=int, default=5, help="how many hardest scenarios the report lists")
    args = ap.parse_args(argv)
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    try:
        if args.storage.startswith("sqlite:///") and not Path(args.storage.removeprefix("sqlite:///")).is_file():
            raise GarageError("no such file", args.storage)  # sqlite would create an empty store
        study = load(args.storage, args.study)
    except GarageError as exc:
        print(exc, file=sys.stderr)
        return 2
    out = Path(args.out) if args.out else OUTPUTS_DIR / "search" / study.study_name
    analyse(study, out, top=args.top)
    print(f"written: {out / 'search_report.md'} (and .html)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
