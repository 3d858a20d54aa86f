"""`make dashboard`: optuna-dashboard on a search's storage, bound to 127.0.0.1. The Makefile's own command line
(`make -n`) is started on a small sqlite study built with the sweeper's trial contract (no rendering); the study
comes back over the dashboard's JSON API, then once in a real browser (screenshot: outputs/browser/)."""

from __future__ import annotations

import json
import os
import shlex
import signal
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import optuna
import pytest
from conftest import ROOT, chromium, require
from mlflow_server import free_port
from optuna.distributions import CategoricalDistribution, FloatDistribution
from optuna.trial import TrialState, create_trial

SPACE = {"light.intensity": FloatDistribution(0.1, 1.0), "occluder": CategoricalDistribution(["none", "pillar"])}
STUDY = "garage_search_test"


def make_study(storage: str) -> None:
    study = optuna.create_study(storage=storage, study_name=STUDY, direction="maximize")
    study.set_user_attr("direction_names", ["difficulty"])
    study.set_metric_names(["difficulty"])  # what the dashboard labels its axes with (else "Objective 0")
    for k, (light, occluder) in enumerate([(0.2, "pillar"), (0.9, "none"), (0.5, "pillar")]):
        p = {"light.intensity": light, "occluder": occluder}
        study.add_trial(create_trial(params=p, distributions=SPACE, values=[1 - light], user_attrs={
            "overrides": [f"light.intensity={light}", f"occluder={occluder}"], "visible_fraction": 0.8}))
    study.add_trial(create_trial(params={"light.intensity": 0.3, "occluder": "pillar"}, distributions=SPACE,
                                 state=TrialState.PRUNED, user_attrs={"infeasible": True}))


def make_command(storage: str, port: int) -> list[str]:
    """The recipe of `make dashboard`, as make would run it, with this venv's bin and the test's store."""
    out = subprocess.run(["make", "-n", "--no-print-directory", "dashboard", f"BIN={Path(sys.executable).parent}",
                          f"DASHBOARD_STORAGE={storage}", f"DASHBOARD_PORT={port}"],
                         cwd=ROOT, capture_output=True, text=True, check=True).stdout
    line = next(ln for ln in out.splitlines() if "optuna-dashboard" in ln)
    return shlex.split(line)


def get_json(url: str):
    with urllib.request.urlopen(url, timeout=5) as r:
        return json.loads(r.read())


@pytest.fixture(scope="module")
def dashboard(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("dashboard")
    storage = f"sqlite:///{tmp / 'optuna.db'}"
    make_study(storage)
    port = free_port()
    cmd = make_command(storage, port)
    assert cmd[cmd.index("--host") + 1] == "127.0.0.1"  # never on the network
    log = tmp / "dashboard.log"
    with open(log, "w") as fh:
        proc = subprocess.Popen(cmd, cwd=tmp, stdout=fh, stderr=subprocess.STDOUT, start_new_session=True)
    base = f"http://127.0.0.1:{port}"
    try:
        end = time.monotonic() + 60
        while True:
            if proc.poll() is not None:
                pytest.fail(f"optuna-dashboard exited with {proc.returncode}: {log.read_text()[-2000:]}")
            try:
                studies = get_json(f"{base}/api/studies")["study_summaries"]
                break
            except OSError:
                if time.monotonic() > end:
                    pytest.fail(f"optuna-dashboard not up after 60 s: {log.read_text()[-2000:]}")
                time.sleep(0.3)
        yield {"base": base, "studies": studies, "storage": storage}
    finally:
        os.killpg(proc.pid, signal.SIGTERM)
        proc.wait(timeout=10)


def test_make_dashboard_serves_the_study_over_its_json_api(dashboard):
    summary = next(s for s in dashboard["studies"] if s["study_name"] == STUDY)
    detail = get_json(f"{dashboard['base']}/api/studies/{summary['study_id']}")
    assert detail["name"] == STUDY and detail["directions"] == ["maximize"]
    states = [t["state"] for t in detail["trials"]]
    assert states == ["Complete", "Complete", "Complete", "Pruned"]
    best = detail["best_trials"][0]
    assert best["number"] == 0 and best["values"] == [pytest.approx(0.8)]
    attrs = {a["key"]: a["value"] for a in best["user_attrs"]}
    assert json.loads(attrs["overrides"]) == ["light.intensity=0.2", "occluder=pillar"]


@pytest.mark.browser
def test_the_dashboard_shows_the_study_in_a_browser(dashboard):
    require("browser")
    from playwright.sync_api import sync_playwright

    summary = next(s for s in dashboard["studies"] if s["study_name"] == STUDY)
    shots = ROOT / "outputs" / "browser"
    shots.mkdir(parents=True, exist_ok=True)
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=chromium(), args=["--no-sandbox"])
        try:
            page = browser.new_page(viewport={"width": 1400, "height": 900})
            page.set_default_timeout(60_000)
            page.goto(f"{dashboard['base']}/dashboard/studies/{summary['study_id']}")
            page.get_by_text(STUDY).first.wait_for()
            page.get_by_text("difficulty").first.wait_for()  # the history's y axis, named by the study
            page.wait_for_timeout(1500)  # the history chart draws after the page's first paint
            page.screenshot(path=str(shots / "dashboard_study.png"))
            body = page.inner_text("body")
        finally:
            browser.close()
    assert "garage_search_test" in body and "Objective 0" not in body  # the axes say "difficulty"


def test_the_report_names_its_importances_and_shows_the_dashboard_s(dashboard, tmp_path):
    """The report's importances are fANOVA's, optuna-dashboard's PED-ANOVA's (issue 47, item 11: the two ranked
    different parameters first for one study, and the report did not say by what method): the report names both
    methods and says how they differ, and importances.csv's `dashboard_ped_anova` is what the dashboard serves for
    the same study (40 trials, two parameters)."""
    import numpy as np
    import pandas as pd

    from garage_exp.report.search_analysis import analyse

    rng = np.random.default_rng(0)
    space = {"light.intensity": FloatDistribution(0.1, 1.0), "case.actors.target.distance": FloatDistribution(2, 10)}
    study = optuna.create_study(storage=dashboard["storage"], study_name="importances", direction="maximize")
    study.set_user_attr("direction_names", ["difficulty"])
    for _ in range(40):
        light, distance = rng.uniform(0.1, 1.0), rng.uniform(2, 10)
        value = 0.8 - 0.5 * light + (0.2 if distance > 9.2 else 0.0)
        study.add_trial(create_trial(params={"light.intensity": light, "case.actors.target.distance": distance},
                                     distributions=space, values=[value],
                                     user_attrs={"overrides": [], "visible_fraction": 0.8}))
    analyse(study, tmp_path)
    table = pd.read_csv(tmp_path / "importances.csv").set_index("parameter")
    served = get_json(f"{dashboard['base']}/api/studies/{study._study_id}/param_importances")["param_importances"][0]
    assert {p["name"]: p["importance"] for p in served} == pytest.approx(table.dashboard_ped_anova.to_dict())
    assert table.importance.sum() == pytest.approx(1.0) and table.index.tolist() == ["light.intensity",
                                                                                     "case.actors.target.distance"]
    report = (tmp_path / "search_report.md").read_text()
    assert "Optuna's fANOVA evaluator" in report and "optuna-dashboard shows" in report
    assert "PED-ANOVA evaluator, which measures how much each parameter matters to reach the hardest 10 %" in report
