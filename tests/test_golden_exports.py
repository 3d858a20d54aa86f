"""Golden exported bytes (issue 48): the files the OpenSCENARIO and slot code write, pinned as sha256 digests of
today's code before its modules moved into packages of their own, and compared after.

Pinned: every shipped case's `export.openscenario=true` files (garage.xodr and each variant's .xosc) on the
research plan and on garage26x30, crossing and cpnco as OpenSCENARIO 1.0 too, the cpnco export imported back as a
case YAML (`python -m garage_exp.scenario.import`), and the slot outputs: the `slots/` export of a slot case's
ground truth on the tiny plan (PS2.0-like labels, truth, COCO keypoints), the `lines` slot detector's records
and scores on synthetic bird's-eye views, and the sweep report's slot section on a made-up table. No rendering.

What the writers stamp with the clock (the OpenDRIVE and OpenSCENARIO headers' date, the COCO file's
date_created) and the temporary folder in the import's comment line are set to fixed text before hashing; the
OpenDRIVE objects' ids, which scenariogeneration counts per process, restart as in a fresh process.
`python tests/test_golden_exports.py` prints the digests as tests/golden/exports.json holds them (it wrote that
file on 7a6a6a4, on an AVX-512 machine); a failing test names the file and leaves the normalised bytes under its
tmp_path to diff. The slot truth's bird's-eye JSON (floats written to the last digit) comes out with other bytes on
a machine without AVX-512: tests/golden/avx2/exports.json holds those two files' digests as the pinned code
(ea4ec2d) writes them on an AVX2 machine (a Zen 3, where today's code writes the same), and replaces the pinned
ones there.
"""

from __future__ import annotations

import hashlib
import json
import re
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import instruction_set

GOLDEN = Path(__file__).parent / "golden" / "exports.json"
NUMERIC_SET = "avx512" if instruction_set() in ("avx512", "amx") else "avx2"  # AVX-512 or not
ON_THIS_MACHINE = Path(__file__).parent / "golden" / NUMERIC_SET / "exports.json"
CASES = ["1", "2", "3", "cpnco", "cpra", "crossing", "crouch", "light", "pedestrian", "pullout", "slots", "stepout"]
PLANS = ["research", "garage26x30"]
SLOTS = ("plan=tiny", "camera=fisheye4", "case=slots", "case.motion.start=3.0", "case.motion.end=4.0",
         "case.motion.step=1.0")
CLOCK = [(re.compile(rb'(<header [^>]*date=")[^"]*(")'), rb"\g<1>DATE\g<2>"),  # OpenDRIVE
         (re.compile(rb'(<FileHeader [^>]*date=")[^"]*(")'), rb"\g<1>DATE\g<2>"),  # OpenSCENARIO
         (re.compile(rb'("date_created": ")[^"]*(")'), rb"\g<1>DATE\g<2>")]  # COCO


def normalised(data: bytes, folder: Path | None = None) -> bytes:
    for pattern, fixed in CLOCK:
        data = pattern.sub(fixed, data)
    return data.replace(str(folder).encode(), b"TMP") if folder is not None else data


def digests(root: Path, folder: Path | None = None) -> dict[str, bytes]:
    """Every file under `root`, by its path relative to it: its normalised bytes."""
    return {p.relative_to(root).as_posix(): normalised(p.read_bytes(), folder)
            for p in sorted(root.rglob("*")) if p.is_file()}


def openscenario_files(library, out: Path) -> dict[str, bytes]:
    """Each pinned export's files, keyed "osc/<plan>/<case>/<version>/<file>", and the cpnco import's YAML."""
    from test_cases import case_setup

    from garage_exp.core.paths import PLANS_DIR
    from garage_exp.run.openscenario import export
    from garage_exp.run.preflight import PreparedJob

    from scenariogeneration.xodr.signals_objects import _SignalObjectBase

    # scenariogeneration numbers a road file's objects from counters on the class, shared by every file the
    # process writes: start them as in the fresh process the digests were recorded in, whatever exported before
    _SignalObjectBase._usedIDs.clear()
    _SignalObjectBase._IDCounter.clear()
    jobs = [(plan, case, "1.2") for plan in PLANS for case in CASES]
    jobs += [("research", case, "1.0") for case in ("crossing", "cpnco")]
    files = {}
    for plan, case, version in jobs:
        cfg, classified, setup = case_setup(library, f"case={case}", f"plan={plan}",
                                            f"export.openscenario_version={version}")
        folder = out / plan / case / version
        export(cfg, folder, PreparedJob(PLANS_DIR / f"{plan}.yaml", classified, setup=setup))
        files.update({f"osc/{plan}/{case}/{version}/{k}": v for k, v in digests(folder).items()})
    from conftest import run_module

    xosc = out / "research" / "cpnco" / "1.2" / "scenario.xosc"
    result = run_module("garage_exp.scenario.import", [str(xosc), "--name", "rt", "-o", str(out / "rt.yaml")], out)
    assert result.returncode == 0, result.stderr
    files["import/cpnco/rt.yaml"] = normalised((out / "rt.yaml").read_bytes(), out)
    return files


def slot_files(out: Path) -> dict[str, bytes]:
    """A slot case's truth exported, the lines detector on synthetic views, and the report's slot section."""
    import pandas as pd
    from conftest import compose_cfg
    from omegaconf import OmegaConf

    from garage_exp.scene.schema import BevSpec
    from garage_exp.slots.export import SlotExports, ps2_record
    from garage_exp.slots.detector import load
    from garage_exp.slots.schema import SlotDetectorConf
    from garage_exp.slots.synthetic import bev_row
    from garage_exp.slots.truth import obstacles, slot_truth, world_bays
    from garage_exp.render.bev import bev_maps, spec_of
    from garage_exp.report import slots as slot_report
    from garage_exp.report.tables import markdown_table, with_ci
    from garage_exp.slots.results import pool, score
    from garage_exp.run.preflight import preflight

    cfg = compose_cfg(*SLOTS)
    prepared = preflight(cfg, check_space=False, load=False)
    scene = prepared.scene
    spec = spec_of(BevSpec())
    ego = next(v for v in scene.vehicles() if v.role == "ego")
    maps = bev_maps(scene.cameras, spec, ego.extent)
    world = world_bays(prepared.classified, cfg.garage, 0.3)
    exports = SlotExports(out / "slots")
    for shot in prepared.setup.shots:
        truth = slot_truth(world, spec, shot.ego, scene.cameras, maps, obstacles(scene, shot.poses))
        w, h = truth.frame.size
        exports.add(f"{shot.index:04d}_bev", np.full((h, w, 3), 90, np.uint8), truth)
    files = {f"slots/truth/{k}": v for k, v in digests(exports.finish()).items()}
    conf = OmegaConf.structured(SlotDetectorConf)
    detect = load(conf)
    scores = []
    for seed in range(4):
        image, truth = bev_row(seed, wear=0.3 * seed)
        found = detect(image, truth.meters_per_pixel)
        scored = score(truth, found, None, conf.metrics)
        scores.append(scored)
        files[f"slots/found/{seed}.json"] = json.dumps(ps2_record(found)).encode()
        files[f"slots/score/{seed}.json"] = json.dumps(scored, sort_keys=True).encode()
    files["slots/pool.json"] = json.dumps(pool(scores), sort_keys=True).encode()
    runs = pd.DataFrame({"run_id": ["a", "b", "c", "d"], "factor.wear": ["fresh", "fresh", "worn", "worn"]})
    frames = pd.DataFrame([{"run_id": r, "replicate": k, **s} for r, s in zip("abcd", scores) for k in (0, 1)])
    units = slot_report.slot_units(runs, frames, ["factor.wear"])
    effects = slot_report.slot_effects(units, ["factor.wear"])
    files["slots/report.md"] = "\n".join(slot_report.section(effects, markdown_table, with_ci)).encode()
    return files


def sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def check(files: dict[str, bytes], prefix: str, tmp_path: Path) -> None:
    pinned = json.loads(GOLDEN.read_text())
    if ON_THIS_MACHINE.is_file():
        pinned.update(json.loads(ON_THIS_MACHINE.read_text()))
    pinned = {k: v for k, v in pinned.items() if k.startswith(prefix)}
    got = {k: sha(v) for k, v in files.items()}
    changed = sorted(k for k in pinned.keys() & got.keys() if pinned[k] != got[k])
    for name in changed:  # the bytes to diff against the pinned code's
        (tmp_path / "changed" / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / "changed" / name).write_bytes(files[name])
    assert sorted(got) == sorted(pinned), f"files written {sorted(got.keys() ^ pinned.keys())} not as pinned"
    assert not changed, f"bytes changed in {changed} (written under {tmp_path / 'changed'})"


def test_the_openscenario_exports_and_import_are_byte_for_byte_as_pinned(library, tmp_path):
    files = openscenario_files(library, tmp_path / "osc")
    check({k: v for k, v in files.items() if k.startswith("osc/")}, "osc/", tmp_path)
    check({k: v for k, v in files.items() if k.startswith("import/")}, "import/", tmp_path)


def test_the_slot_outputs_are_byte_for_byte_as_pinned(tmp_path):
    check(slot_files(tmp_path), "slots/", tmp_path)


@pytest.fixture(scope="module")
def library():
    from conftest import require

    require("vehicles")
    from garage_exp.assets.vehicles import VehicleLibrary

    return VehicleLibrary()


if __name__ == "__main__":  # the digests of this checkout's code, as GOLDEN holds them
    import tempfile

    sys.path.insert(0, str(Path(__file__).parent))
    from garage_exp.assets.vehicles import VehicleLibrary

    with tempfile.TemporaryDirectory() as tmp:
        files = {**openscenario_files(VehicleLibrary(), Path(tmp) / "osc"), **slot_files(Path(tmp))}
    print(json.dumps({k: sha(v) for k, v in sorted(files.items())}, indent=1))
