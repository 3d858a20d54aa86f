"""The MLflow UI: links to an experiment's runs, the saved view of its runs table, and how to serve a store.

`python -m garage_exp.tracking.ui [--uri URI]` prints where each experiment of a store opens (`make ui`).
"""

from __future__ import annotations

import json
import time

from garage_exp.core.paths import OUTPUTS_DIR
from garage_exp.tracking.client import client, retry, tracking_uri

# MLflow 3 opens an experiment without this tag in its GenAI view (traces, "evaluation runs"); ours are classic
# model experiments: runs with params, metrics and artifacts. The UI's own switch sets the same tag.
EXPERIMENT_KIND = ("mlflow.experimentKind", "custom_model_development")
# What decides the view of a link whatever the tag or the browser's last choice (kept in its local storage).
UI_VIEW = "workflowType=machine_learning"
UI_ADDRESS = "http://127.0.0.1:5000"  # where `make ui` serves the project's store
# A saved view of the runs table (the UI's "Views" menu; a link opens it with viewStateShareKey): the factors
# and the key metrics as columns, a run name wide enough to read the overrides. Without it the table shows
# only names, dates and durations.
VIEW_KEY = "factors"
VIEW_PARAMS = ("plan.name", "case.name", "light.name", "occluder.name", "sensor.name", "camera.name")
VIEW_METRICS = ("confidence_mean", "recall", "difficulty")


def saved_view() -> tuple[str, str]:
    """The experiment tag of the saved view: MLflow's envelope {name, createdAt, state}, state a JSON string
    of the runs table's UI state (column keys as the UI writes them: params.`KEY`, metrics.`KEY`)."""
    columns = [f"metrics.`{k}`" for k in VIEW_METRICS] + [f"params.`{k}`" for k in VIEW_PARAMS]
    # The UI applies widths only to the columns of columnOrder (its own ids: run name, created, duration).
    order = ["attributes.`Run Name`", "runDateAndNestInfo", "duration", *columns]
    state = {"selectedColumns": columns, "columnOrder": order, "columnWidths": {"attributes.`Run Name`": 340}}
    envelope = {"name": "factors and key metrics", "createdAt": int(time.time() * 1000), "state": json.dumps(state)}
    return f"mlflow.sharedViewState.{VIEW_KEY}", json.dumps(envelope)


def experiment_tags() -> dict[str, str]:
    """The tags every experiment of ours carries: the classic runs view and the saved view of its table."""
    return dict([EXPERIMENT_KIND, saved_view()])


def ui_link(uri: str | None, experiment: str, run_id: str | None = None, view: bool = True) -> str:
    """The MLflow UI's page of an experiment (in the runs view, with the saved view when `view`) or of one of
    its runs. A tracking server serves its own UI; a local store is served by `make ui` or `ui_command`."""
    uri = tracking_uri(uri)
    base = uri.rstrip("/") if uri.startswith(("http://", "https://")) else UI_ADDRESS
    if run_id:
        return f"{base}/#/experiments/{experiment}/runs/{run_id}?{UI_VIEW}"
    return f"{base}/#/experiments/{experiment}/runs?{UI_VIEW}" + (f"&viewStateShareKey={VIEW_KEY}" if view else "")


def ui_command(uri: str | None) -> str | None:
    """The command that serves a local store's UI at UI_ADDRESS (None for a tracking server: it has its UI)."""
    uri = tracking_uri(uri)
    if uri.startswith(("http://", "https://")):
        return None
    if uri == f"sqlite:///{OUTPUTS_DIR / 'mlflow.db'}":
        return "make ui"
    return f"make ui UI_STORE={uri}"  # the Makefile's UI over that store (it was `mlflow ui`, without the links)


def links(uri: str | None = None) -> str:
    """Where each experiment of a store opens in the UI (`make ui` prints this before it starts the UI)."""
    mlc = client(uri)
    exps = [e for e in retry(mlc.search_experiments)  # MLflow's own empty "Default" is noise
            if e.name != "Default" or retry(lambda e=e: mlc.search_runs([e.experiment_id], max_results=1))]
    if not exps:
        return f"garage_exp: no experiment in {tracking_uri(uri)} yet (make run, or python -m garage_exp ...)"
    lines = [f"garage_exp: the MLflow UI of {tracking_uri(uri)}; each experiment in the runs view:"]
    lines += [f"  {e.name}: {ui_link(uri, e.experiment_id, view=saved_view()[0] in e.tags)}"
              for e in sorted(exps, key=lambda e: e.name)]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """`python -m garage_exp.tracking.ui [--uri URI]`, in the one shell (garage_exp.core.shell): a store that is
    not MLflow's is one line and exit 2, Ctrl-C 130, SIGTERM 143."""
    import argparse

    from garage_exp.core import shell

    def run(args) -> int:
        print(links(args.uri))  # a store that is not there yet is made, as `make ui` makes it
        return 0

    ap = argparse.ArgumentParser(prog="python -m garage_exp.tracking.ui", description=links.__doc__)
    ap.add_argument("--uri", default=None, help="the MLflow store (default: $MLFLOW_TRACKING_URI or outputs/mlflow.db)")
    return shell.Command("garage_exp.tracking.ui").run_args(ap, run, argv)


if __name__ == "__main__":
    import sys

    sys.exit(main())
