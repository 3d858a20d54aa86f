"""The MLflow UI as a user sees it: a real browser (Debian's chromium, driven by Playwright) over `mlflow ui` on
a store holding a small real sweep (light x sensor, 2 x 2 jobs of 2 frames at 320 x 240, one detector). The
browser follows the link the sweep prints, expands the sweep, opens a child's `confidence` chart and
`confidence.png`, and the sweep's report. Screenshots: outputs/browser/ (look at them)."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import pytest
from conftest import ROOT, chromium, require, run_app
from mlflow_server import free_port

from garage_exp.tracking import runs as tracking

pytestmark = [pytest.mark.browser, pytest.mark.slow]

SWEEP = ["-m", "plan=tiny", "light=bright,dim", "sensor=ideal,noisy", "case.motion.start=5.5", "case.motion.end=5.0",
         "palette.target_colours=[black]", "detector.models=[yolov8n_int8_openvino_model]",
         "renderer.save_frames=none", "camera.width=320", "camera.height=240", "detector.imgsz=320"]
SHOTS = ROOT / "outputs" / "browser"
TIMEOUT_MS = 60_000  # a page of the UI on the busy 2-core machine (first load compiles the UI's JavaScript)


def wait_healthy(base: str, proc: subprocess.Popen, log: Path, timeout: float = 120) -> None:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if proc.poll() is not None:
            pytest.fail(f"mlflow ui exited with {proc.returncode}: {log.read_text()[-2000:]}")
        try:
            with urllib.request.urlopen(f"{base}/health", timeout=2) as r:
                if r.status == 200:
                    return
        except OSError:
            time.sleep(0.5)
    pytest.fail(f"mlflow ui not up after {timeout} s: {log.read_text()[-2000:]}")


@pytest.fixture(scope="module")
def ui(tmp_path_factory):
    """The sweep in a fresh store and `mlflow ui` serving it (started while the sweep runs: both are slow)."""
    require("vulkan", "vehicles", "models", "browser")
    tmp = tmp_path_factory.mktemp("ui")
    uri = f"sqlite:///{tmp / 'mlflow.db'}"
    tracking.client(uri)  # the schema, made once, before two processes open the store
    port, log = free_port(), tmp / "mlflow_ui.log"
    with open(log, "w") as fh:
        proc = subprocess.Popen([str(Path(sys.executable).parent / "mlflow"), "ui", "--backend-store-uri", uri,
                                 "--host", "127.0.0.1", "--port", str(port), "--workers", "1"],
                                cwd=tmp, stdout=fh, stderr=subprocess.STDOUT, start_new_session=True)
    try:
        t0 = time.monotonic()
        sweep = run_app([*SWEEP, f"tracking.uri={uri}"], tmp)
        assert sweep.returncode == 0, sweep.stderr[-3000:]
        base = f"http://127.0.0.1:{port}"
        wait_healthy(base, proc, log)
        print(f"sweep and UI up in {time.monotonic() - t0:.1f} s")
        mlc = tracking.client(uri)
        exp = mlc.get_experiment_by_name("garage_exp")
        runs = mlc.search_runs([exp.experiment_id])
        parent = next(r for r in runs if r.data.tags.get("sweep") == "parent")
        children = [r for r in runs if r.data.tags.get("mlflow.parentRunId") == parent.info.run_id]
        link = next(ln.split("MLflow UI: ", 1)[1].split()[0] for ln in sweep.stdout.splitlines()
                    if "MLflow UI: " in ln)
        yield {"base": base, "link": link, "exp": exp, "parent": parent, "children": children, "mlc": mlc}
    finally:
        os.killpg(proc.pid, signal.SIGTERM)  # the server and its worker: its own process group
        try:
            proc.wait(timeout=3)  # uvicorn waits for idle connections to close; a temp store has nothing to save
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()


@pytest.fixture(scope="module")
def browser(ui):
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=chromium(), args=["--no-sandbox"])
        yield b
        b.close()


@pytest.fixture
def page(browser):
    context = browser.new_context(viewport={"width": 1920, "height": 1080})
    pg = context.new_page()
    pg.set_default_timeout(TIMEOUT_MS)
    yield pg
    context.close()


ASSISTANT_CLOSE = 'button[data-component-id="mlflow.assistant.chat_panel.close"]'


def open_page(pg, url: str) -> None:
    """Go to url as a user would, and close the UI's chat assistant: on a local server MLflow opens it by itself
    on a fresh browser's first page (its `mlflow.assistant.fab.autoOpenedOnFirstLoad`), beside the page, hiding
    half the table. Tolerated: only that it did not open within 10 s (nothing to close then). A navigation error,
    two close buttons, a close button that cannot be clicked or a panel that stays open fail the test."""
    from playwright.sync_api import TimeoutError as PlaywrightTimeout

    pg.goto(url)
    close = pg.locator(ASSISTANT_CLOSE)
    try:
        close.wait_for(state="visible", timeout=10_000)
    except PlaywrightTimeout:
        return
    close.click(timeout=10_000)
    close.wait_for(state="hidden", timeout=10_000)


def shot(pg, name: str) -> None:
    SHOTS.mkdir(parents=True, exist_ok=True)
    pg.screenshot(path=str(SHOTS / f"{name}.png"))


def on_our_server(link: str, base: str) -> str:
    """The sweep prints the link for `make ui` (port 5000); the test's server has its own port."""
    assert link.startswith(tracking.UI_ADDRESS + "/#/experiments/"), link
    return base + link[len(tracking.UI_ADDRESS):]


def test_the_printed_link_opens_the_runs_table_with_factors_and_metrics(ui, page):
    assert ui["link"] == tracking.ui_link(None, ui["exp"].experiment_id)
    open_page(page, on_our_server(ui["link"], ui["base"]))
    rows = page.locator(".ag-center-cols-container .ag-row")
    rows.first.wait_for()

    def cell(row: str, column: str):  # a row is split over the grid's pinned and scrolling parts
        return page.locator(f".ag-row[row-index='{row}'] [col-id='{column}']")

    assert "workflowType=machine_learning" in page.url  # the model-training view, not the GenAI one
    assert page.get_by_text("Evaluation runs").count() == 0 and page.get_by_text("Overview").count() == 0
    headers = page.eval_on_selector_all(".ag-header-cell", "els => els.map(e => e.getAttribute('col-id'))")
    assert {"params.`light.name`", "params.`sensor.name`", "metrics.`confidence_mean`", "metrics.`recall`"} <= set(
        headers)
    parent_name = ui["parent"].data.tags["mlflow.runName"]
    assert parent_name.startswith("sweep plan=tiny light=bright,dim sensor=ideal,noisy")
    assert "tracking.uri" not in parent_name  # where a run is stored does not describe it
    assert rows.count() == 1  # only the sweep; its jobs are folded under it
    assert page.get_by_role("link", name=parent_name).count() == 1
    shot(page, "1_runs_table")

    cell("0", "attributes.`Run Name`").locator("button").first.click()  # expand the sweep
    page.wait_for_function("document.querySelectorAll('.ag-center-cols-container .ag-row').length == 5")
    table = {}
    for k in map(str, range(1, 5)):
        table[cell(k, "attributes.`Run Name`").locator("a").inner_text().strip()] = {
            c: cell(k, c).inner_text().strip()
            for c in ("params.`light.name`", "params.`sensor.name`", "metrics.`confidence_mean`")}
    for child in ui["children"]:
        name = child.data.tags["mlflow.runName"]
        cells = table[name]
        assert cells["params.`light.name`"] == child.data.params["light.name"]
        assert cells["params.`sensor.name`"] == child.data.params["sensor.name"]
        assert float(cells["metrics.`confidence_mean`"]) == pytest.approx(child.data.metrics["confidence_mean"],
                                                                          abs=0.006)
    assert {(c.data.params["light.name"], c.data.params["sensor.name"]) for c in ui["children"]} == {
        ("bright", "ideal"), ("bright", "noisy"), ("dim", "ideal"), ("dim", "noisy")}
    shot(page, "2_sweep_expanded")


def a_child(ui):
    return next(c for c in ui["children"] if c.data.params["light.name"] == "dim"
                and c.data.params["sensor.name"] == "ideal")


def test_a_child_shows_its_confidence_chart(ui, page):
    child = a_child(ui)
    open_page(page, tracking.ui_link(f"{ui['base']}", ui["exp"].experiment_id, child.info.run_id))
    page.get_by_role("tab", name="Model metrics").click()
    card = page.locator("[data-testid='experiment-view-compare-runs-card']").filter(
        has=page.get_by_role("heading", name="confidence", exact=True))
    line = card.locator("path.js-line").first
    line.wait_for()
    points = [tuple(map(float, xy.split(","))) for xy in re.findall(r"[\d.-]+,[\d.-]+", line.get_attribute("d"))]
    history = sorted(ui["mlc"].get_metric_history(child.info.run_id, "confidence"), key=lambda m: m.step)
    assert len(points) == len(history) == 2  # the two frames' values, one after the other along the x axis
    assert points[0][0] < points[1][0]
    if history[0].value != history[1].value:  # the line rises or falls as the values do (SVG's y points down)
        assert (points[1][1] < points[0][1]) == (history[1].value > history[0].value), (points, history)
    card.scroll_into_view_if_needed()
    shot(page, "3_confidence_chart")


def test_a_child_previews_confidence_png(ui, page):
    child = a_child(ui)
    open_page(page, tracking.ui_link(f"{ui['base']}", ui["exp"].experiment_id, child.info.run_id))
    page.get_by_role("tab", name="Artifacts").click()
    page.locator("[data-testid='artifact-tree-node'][artifact-name='confidence.png']").click()
    img = page.locator("img[alt='confidence.png']")
    img.wait_for()
    page.wait_for_function("document.querySelector(\"img[alt='confidence.png']\").naturalWidth > 0")
    size = img.evaluate("e => [e.naturalWidth, e.naturalHeight]")
    from PIL import Image

    on_disk = Path(child.data.tags["output_dir"]) / "confidence.png"
    assert tuple(size) == Image.open(on_disk).size  # the picture itself, decoded by the browser
    shot(page, "4_confidence_png")


def test_the_sweep_report_previews_with_its_figure(ui, page):
    parent = ui["parent"]
    arts = {a.path for a in ui["mlc"].list_artifacts(parent.info.run_id, "report")}
    assert {"report/report.md", "report/report.html", "report/heatmap.png"} <= arts
    open_page(page, tracking.ui_link(f"{ui['base']}", ui["exp"].experiment_id, parent.info.run_id))
    page.get_by_role("tab", name="Artifacts").click()
    page.locator("[data-testid='artifact-tree-node'][artifact-name='report']").click()
    page.locator("[data-testid='artifact-tree-node'][artifact-name='report.md']").click()
    page.get_by_role("heading", name="Sweep report").wait_for()  # the markdown, rendered
    assert page.get_by_role("heading", name="Main effects (mean over the other factors)").count() == 1
    shot(page, "5_report_md")

    page.locator("[data-testid='artifact-tree-node'][artifact-name='report.html']").click()
    page.frame_locator("iframe").first.locator("h1").wait_for()  # the UI shows an HTML artifact in a frame
    frame = page.locator("iframe").first.element_handle().content_frame()
    assert frame.locator("h1").inner_text() == "Sweep report"
    names = [a.path.split("/")[-1] for a in ui["mlc"].list_artifacts(parent.info.run_id, "report")
             if a.path.endswith(".png")]
    assert frame.locator("img").count() == len(names) >= 3  # main effects, interactions, heat map, ...
    figure = frame.locator("img[alt='heatmap.png']")
    figure.scroll_into_view_if_needed()
    frame.wait_for_function("[...document.images].every(i => i.complete && i.naturalWidth > 0)")
    from PIL import Image

    sweep_dir = Path(parent.data.tags["sweep_dir"])
    assert tuple(figure.evaluate("e => [e.naturalWidth, e.naturalHeight]")) == Image.open(
        sweep_dir / "report" / "heatmap.png").size
    assert re.search(r"light\s+x\s+sensor", frame.inner_text("body"))
    shot(page, "6_report_html")
