"""What the user sees of a study (issue 10, §3): figures, tables and a report of the hardest scenarios.

`analyse(study, out_dir)` works on any Optuna study whose trials follow the sweeper's contract (values: the search
objective's, named by the study's user_attr direction_names: difficulty, lateness, ...; user_attrs: overrides,
visible_fraction, fair_frames, frames, recall, confidence, frame, and "infeasible" on a pruned trial or "error" on
a failed one). It writes, into out_dir: history.png, importances.png/.csv (fANOVA), slices.png, pareto.png (multi-
objective), sensitivity.png/.csv (Sobol', see sensitivity), trials.csv, hardest.csv, frames/ (the hardest trials'
frames) and search_report.md/.html. Only complete trials are ranked; pruned (infeasible) and failed ones are
counted and listed apart. `python -m garage_exp.report.search_analysis` writes the same for a study in a storage,
finished or still running.

This module writes the report's sections; what it shows comes from `trials.py` (the sweeper's contract: the
trial table, the hardest trials, rerun commands), `why_hard.py` (importances, and which side of each parameter
is harder), `study_figures.py` (the PNGs) and `sensitivity.py` (Sobol' indices).
"""

from __future__ import annotations

import argparse
import shlex
import shutil
import sys
from pathlib import Path

import optuna
import pandas as pd
from optuna.distributions import CategoricalDistribution
from optuna.trial import FrozenTrial

from garage_exp.core import shell
from garage_exp.core.errors import GarageError
from garage_exp.core.paths import OUTPUTS_DIR
from garage_exp.report import archive_cells, sensitivity
from garage_exp.report.study_figures import figures
from garage_exp.report.trials import (ATTRS, attr_headings, distributions, first_value, hardest, objective_names,
                                      overrides, rerun_overrides, trial_table, untestable)
from garage_exp.report.why_hard import (FANOVA_SEED, dashboard_importances, importances, what_makes_it_hard,
                                       why_hard)
from garage_exp.tracking.page import html_page


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
    headings = attr_headings(study)
    late = [c for c in headings if by_number[c].notna().any()]
    hard = by_number.loc[[t.number for t in top_trials]].reset_index()[
        ["trial", name, *ATTRS, *late, "overrides", "run_id", "frame"]]
    hard.insert(0, "rank", range(1, len(hard) + 1))
    hard.to_csv(out_dir / "hardest.csv", index=False)
    written = [out_dir / "hardest.csv"]
    lines = [f"## The {len(top_trials)} hardest scenarios", ""]
    if not top_trials:
        return [*lines, "No complete trial: nothing to rank.", ""], written
    lines += [*md_table(hard[["rank", "trial", name, "visible_fraction", "fair_frames", "frames", *late]].rename(
        columns={"visible_fraction": "visible fraction", "fair_frames": "fair frames", **headings})), ""]
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


def importance_section(study: optuna.Study, importance: dict[str, float], skipped: str, name: str, out_dir: Path
                       ) -> tuple[list[str], list[Path]]:
    # skipped: why there are no importances, or (with importances) how they were computed: from a sample
    """The fANOVA importances the report ranks by, beside optuna-dashboard's PED-ANOVA ones, and why they may
    rank the parameters differently (issue 47, item 11: the dashboard put one parameter first, the report another,
    for the same study, and neither said by what method)."""
    lines = ["## Parameter importances (fANOVA)", ""]
    if not importance:
        return [*lines, skipped, ""], []
    dashboard = dashboard_importances(study)
    imp = pd.DataFrame({"parameter": list(importance), "importance": list(importance.values()),
                        "dashboard_ped_anova": [dashboard.get(p, float("nan")) for p in importance]})
    imp.to_csv(out_dir / "importances.csv", index=False)
    return [*lines, f"How much of the variance of {name} over the complete trials each parameter explains: "
            f"`importance`, Optuna's fANOVA evaluator (`FanovaImportanceEvaluator`, seed {FANOVA_SEED}; they sum "
            "to 1), which the report ranks the parameters by. `dashboard_ped_anova` is what optuna-dashboard shows "
            f"for the same study: Optuna's PED-ANOVA evaluator, which measures how much each parameter matters to "
            f"reach the hardest 10 % of the trials, not how much of the variance of {name} over all of them it "
            "explains; the two may rank the parameters differently, and neither is wrong.", "",
            *([skipped, ""] if skipped else []), *md_table(imp), "",
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
    section, files, _ = archive_cells.section(study, out_dir)  # a difficulty search's cells (its archive)
    lines += section
    written += files
    if "history" in drawn:
        lines += ["## Optimisation history", "", f"![history of {names[0]}](history.png)", ""]
    section, files = importance_section(study, importance, skipped, names[0], out_dir)
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


COMMAND = shell.Command("garage_exp.report.search_analysis")


def run(args: argparse.Namespace) -> int:
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    if args.storage.startswith("sqlite:///") and not Path(args.storage.removeprefix("sqlite:///")).is_file():
        raise GarageError("no such file", args.storage)  # sqlite would create an empty store
    study = load(args.storage, args.study)
    out = Path(args.out) if args.out else OUTPUTS_DIR / "search" / study.study_name
    analyse(study, out, top=args.top)
    print(f"written: {out / 'search_report.md'} (and .html)")
    return 0


def main(argv: list[str] | None = None) -> int:
    """The command in the one shell (garage_exp.core.shell): bad input one line and 2, Ctrl-C 130, SIGTERM 143."""
    ap = argparse.ArgumentParser(prog="python -m garage_exp.report.search_analysis",
                                 description="A search study's figures, importances, sensitivity and report.")
    ap.add_argument("--storage", default=STORAGE, help=f"Optuna storage URL (default: {STORAGE})")
    ap.add_argument("--study", default=None, help="the study's name (default: the storage's latest study)")
    ap.add_argument("-o", "--out", default=None, help="where to write (default: outputs/search/<study>)")
    ap.add_argument("--top", type=int, default=5, help="how many hardest scenarios the report lists")
    return COMMAND.run_args(ap, run, argv)


if __name__ == "__main__":
    sys.exit(main())
