"""Bad input (issue 5): the corpus in tests/bad_inputs/cases.yaml, and config and plan files as data.

Every corpus entry runs the command line (`garage_exp.cli.app.cli`, in a child forked from a warm interpreter, see
tests/cli_forkserver.py) and must give exit code 2, one line on stderr naming what is wrong and where, no
traceback, and leave nothing behind: no MLflow store, no Hydra run or sweep dir, no file in its working dir.
Weights that exist but do not load are no exception: the job's preflight loads every detector entry first.
"""

from __future__ import annotations

import ast
import json
import os
import re
import subprocess
from pathlib import Path

import pytest
import yaml
from conftest import PYTHON, ROOT, run_app

CORPUS = Path(__file__).resolve().parent / "bad_inputs"
CASES = yaml.safe_load((CORPUS / "cases.yaml").read_text())
BY_ID = {c["id"]: c for c in CASES}
# `command`: which command an entry runs (default the main one), as its cli's "module:function" ("" = garage_exp's).
COMMANDS = {"garage_exp": "", **{c: f"garage_exp.{c}.app:cli" for c in ("gym", "train", "loop", "verify")},
            "scenario.import": "garage_exp.openscenario.xosc_import:cli"}
NOT_HYDRA = {"scenario.import"}  # commands of plain arguments: no hydra.run.dir or tracking.uri appended
# Entries refused by a check that needs no model, so before any model loads (the preflight's order: a user waits
# a second for the one line, not the detectors' loading): their children crash if one loads.
NO_MODEL = {"late-objective-static-ego", "placement-search-space-never-feasible", "ray-batch-zero",
            "ray-address-not-answering"}
NO_MODEL |= {"plan-generator-lane-too-narrow-for-its-bays", "plan-generator-bay-below-the-ordinance",
             "plan-generator-unknown-family", "plan-generator-range-backwards", "plan-generator-not-an-integer",
             "plan-generator-negative-seed"}  # refused as the job's plan is drawn, its first step


def test_corpus_is_large_and_well_formed():
    assert len(CASES) >= 30
    assert len(BY_ID) == len(CASES), "duplicate ids"
    for case in CASES:
        assert set(case) <= {"id", "args", "expect", "env", "generate", "absent", "command", "server"}, case["id"]
        assert case.get("command", "garage_exp") in COMMANDS, case["id"]
        assert case["expect"], case["id"]
        for arg in case["args"]:
            for path in re.findall(r"\{corpus\}/(\S+?)(?:\]|$)", arg):
                assert (CORPUS / path).exists(), f"{case['id']}: {path} is not in the corpus"
    kinds = {c["id"].split("-")[0] for c in CASES}
    assert {"plan", "override", "sweep", "missing", "config"} <= kinds


def generate(kind: str, work: Path) -> None:
    """Big inputs are written at test time, not kept in git."""
    if kind == "big_file":  # just over the 4 MB limit: refused before it is read
        from garage_exp.plan.load import MAX_FILE_BYTES

        with open(work / "big.yaml", "w") as f:
            f.write("S: [[2, 1, 3]]\nR: [6]\nC: [3, 3, 3]\n# ")
            f.write("x" * MAX_FILE_BYTES)
    elif kind == "alias_rows":  # 400 kB that YAML expands to 100001 rows of 500 cells (50 M values)
        row = "[" + ", ".join(["1"] * 500) + "]"
        (work / "alias.yaml").write_text("S: [&r " + row + ", " + ", ".join(["*r"] * 100_000)
                                         + "]\nR: [6]\nC: [3]\n")
    elif kind == "onnx_truncated":  # the graph below cut in half, as a download that stopped
        generate("onnx_not_detections", work)
        whole = (work / "not_detections.onnx").read_bytes()
        (work / "not_detections.onnx").unlink()
        (work / "truncated.onnx").write_bytes(whole[:len(whole) // 2])
    elif kind == "onnx_not_detections":  # a valid ONNX graph, with class names, whose output is an image
        import onnx
        from onnx import TensorProto, helper

        image = helper.make_tensor_value_info("images", TensorProto.FLOAT, [1, 3, "H", "W"])
        features = helper.make_tensor_value_info("features", TensorProto.FLOAT, [1, 3, "H", "W"])
        graph = helper.make_graph([helper.make_node("Identity", ["images"], ["features"])], "g", [image], [features])
        model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)], ir_version=8)
        helper.set_model_props(model, {"names": json.dumps(["__background__", "car", "person"])})
        onnx.save(model, str(work / "not_detections.onnx"))
    else:
        raise ValueError(kind)


def files_under(path: Path) -> set[str]:
    return {str(p.relative_to(path)) for p in path.rglob("*")}


def start_forkserver(scratch: Path) -> subprocess.Popen:
    """tests/cli_forkserver.py, started: it imports the project and the detectors' libraries while the caller
    prepares the requests (generated inputs, model servers)."""
    # GARAGE_EXP_DETECT_PROCESS=0: a job's detector checks load in the child, forked with the detectors' libraries
    # imported, not in a new detector process per entry (the same one line: test_fork_server_answers_as_the_real_
    # command_line compares model entries with the command line's default, a detector process)
    return subprocess.Popen([PYTHON, str(Path(__file__).with_name("cli_forkserver.py"))], cwd=scratch,
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "OPENBLAS_NUM_THREADS": "1", "GARAGE_EXP_DETECT_PROCESS": "0"})


def forked_cli(server: subprocess.Popen, scratch: Path, batch: list[tuple[list[str], Path, dict]],
               entries: list[str], no_model: list[bool]) -> list[subprocess.CompletedProcess]:
    """`python -m garage_exp ARGS` (or the command of `entries`, one per request: COMMANDS' values) for each
    (args, cwd, env) of the batch, through the fork server `server` started in `scratch` (two at a time, without
    paying the interpreter's start-up each time); where `no_model` is true, loading a model crashes the child."""
    requests, results = [], []
    for k, (args, cwd, env) in enumerate(batch):
        argv = [*args, f"hydra.run.dir={cwd}/run", f"hydra.sweep.dir={cwd}/sweep"]  # as conftest.run_app
        if entries[k] in {COMMANDS[c] for c in NOT_HYDRA}:
            argv = list(args)
        requests.append({"argv": argv, "cwd": str(cwd), "env": env, "stdout": str(scratch / f"{k}.out"),
                         "stderr": str(scratch / f"{k}.err"), "entry": entries[k], "no_model": no_model[k]})
    out, err = server.communicate("".join(json.dumps(r) + "\n" for r in requests), timeout=600)
    assert server.returncode == 0, err
    answers = [json.loads(line) for line in out.splitlines()]
    codes = {a["id"]: a["rc"] for a in answers}
    if os.environ.get("FORKSERVER_TIMES"):  # each entry's seconds, for finding the slow ones (docs/testing.md)
        with open(os.environ["FORKSERVER_TIMES"], "a") as f:
            f.writelines(f"{a['cpu']:8.2f} {a['s']:8.2f} {Path(batch[a['id']][1]).name} {' '.join(batch[a['id']][0])}\n"
                         for a in answers)
    for k, r in enumerate(requests):
        results.append(subprocess.CompletedProcess(r["argv"], codes[k], Path(r["stdout"]).read_text(),
                                                   Path(r["stderr"]).read_text()))
    return results


def prepare(case: dict, work: Path, server: str = "") -> tuple[list[str], dict, list[str]]:
    """The entry's arguments, environment and expected strings, with {corpus}, {work} and {server} (the URL of
    the model the entry's `server` serves) filled in."""
    fill = lambda s: s.replace("{corpus}", str(CORPUS)).replace("{work}", str(work)).replace(  # noqa: E731
        "{server}", server)
    if case.get("generate"):
        generate(case["generate"], work)
    args = [fill(a) for a in case["args"]]
    if case.get("command") not in NOT_HYDRA:
        args.append(f"tracking.uri=sqlite:///{work}/mlflow.db")
    env = {k: fill(v) for k, v in (case.get("env") or {}).items()}
    if "PYTHONPATH" in env and os.environ.get("PYTHONPATH"):  # the case's code first, then the test's own
        env["PYTHONPATH"] += os.pathsep + os.environ["PYTHONPATH"]
    return args, env, [fill(e) for e in case["expect"]]


def real_run(case: dict, work: Path) -> dict:
    args, env, expect = prepare(case, work)
    before = files_under(work)
    proc = run_app(args, work, env=env, timeout=300)
    return {"proc": proc, "before": before, "after": files_under(work), "work": work, "expect": expect}


@pytest.fixture(scope="module")
def corpus_results(request, tmp_path_factory):
    """Runs the selected corpus entries through the fork server."""
    selected = [item.callspec.params["case_id"] for item in request.session.items
                if item.module is request.module and hasattr(item, "callspec") and "case_id" in item.callspec.params]
    selected += [cid for cid in COMPARED if cid not in selected]  # one fork server for the comparison test too
    scratch = tmp_path_factory.mktemp("forkserver")
    forkserver = start_forkserver(scratch)
    results, batch, servers = {}, [], {}
    try:
        for cid in selected:
            work = tmp_path_factory.mktemp(cid)
            url = serve(BY_ID[cid], servers, tmp_path_factory) if BY_ID[cid].get("server") else ""
            args, env, expect = prepare(BY_ID[cid], work, url)
            results[cid] = {"before": files_under(work), "work": work, "expect": expect}
            batch.append((args, work, env))
        entries = [COMMANDS[BY_ID[cid].get("command", "garage_exp")] for cid in selected]
        no_model = [cid in NO_MODEL for cid in selected]
        for cid, proc in zip(selected, forked_cli(forkserver, scratch, batch, entries, no_model)):
            results[cid].update(proc=proc, after=files_under(results[cid]["work"]))
    finally:
        if forkserver.poll() is None:  # the preparation failed: the server's stdin never closes
            forkserver.kill()
            forkserver.communicate()
        for server in servers.values():
            server.stop()
    return results


def serve(case: dict, servers: dict, tmp_path_factory) -> str:
    """A model server (tests/kserve_server.py, serving the small ONNX graph) with the entry's fault, started once
    per fault for the module's run; the URL of its model. The caller stops every server by its pid."""
    from kserve_server import Server, brightness_onnx

    fault = case["server"]
    if fault not in servers:
        model = brightness_onnx(tmp_path_factory.mktemp("served") / "bright.onnx")
        servers[fault] = Server({"bright": model}, fault=fault)
        servers[fault].start()
    return servers[fault].url("bright")


# The entries test_fork_server_answers_as_the_real_command_line runs both ways.
COMPARED = ("plan-unreachable-lane", "sweep-bad-fov-in-2nd-job", "model-onnx-truncated")


def test_fork_server_answers_as_the_real_command_line(corpus_results, tmp_path_factory):
    """The fork server is a shortcut, not a different program: a few entries give the same exit code and the
    same stderr either way, a model entry too (loaded in the forked child there, in the detector process as the
    command line does by default here). The forked answers are the module's run's (corpus_results)."""
    for cid in COMPARED:
        fork = corpus_results[cid]["proc"]
        real = real_run(BY_ID[cid], tmp_path_factory.mktemp(cid))["proc"]
        strip = lambda text: re.sub(r"/\S*/" + re.escape(cid) + r"\d*", "<work>", text)  # noqa: E731
        assert (fork.returncode, strip(fork.stderr)) == (real.returncode, strip(real.stderr)), cid


@pytest.mark.parametrize("case_id", list(BY_ID))
def test_bad_input(case_id, corpus_results):
    case = BY_ID[case_id]
    result = corpus_results[case_id]
    proc, work = result["proc"], result["work"]
    assert proc.returncode == 2, f"exit {proc.returncode}\nstdout:\n{proc.stdout[-3000:]}\nstderr:\n{proc.stderr}"
    assert "Traceback" not in proc.stderr and "Traceback" not in proc.stdout, proc.stderr
    lines = [ln.strip() for ln in re.split(r"[\r\n]+", proc.stderr) if ln.strip()]
    command = case.get("command", "garage_exp")
    ours = [ln for ln in lines if ln.startswith(f"{command if command == 'garage_exp' else 'garage_exp.' + command}: ")]
    assert len(ours) == 1, proc.stderr
    line = ours[0]
    for text in result["expect"]:
        assert text in line, f"{text!r} not in {line!r}"
    for name in case.get("absent") or []:
        assert not (work / name).exists(), f"{name} was created: the input ran code"
    assert lines == [line], "stderr must hold the one line and nothing else"
    # Nothing written: no MLflow store (not even an empty one), no run/sweep dir, no stray file.
    assert result["after"] == result["before"], sorted(result["after"] - result["before"])


# ------------------------------------------------------------------------ config and plan files are data

UNSAFE_ATTRS = {("yaml", "unsafe_load"), ("yaml", "full_load"), ("yaml", "load_all"), ("yaml", "Loader"),
                ("yaml", "UnsafeLoader"), ("yaml", "FullLoader"), ("yaml", "CLoader"), ("yaml", "CUnsafeLoader"),
                ("yaml", "CFullLoader"), ("torch", "load"), ("pd", "read_pickle"), ("pandas", "read_pickle")}
UNSAFE_MODULES = {"pickle", "cPickle", "dill", "cloudpickle", "marshal", "shelve", "jsonpickle"}


def test_source_has_no_eval_pickle_or_unsafe_yaml():
    """Static guard: no eval/exec, no pickle-family module, YAML only through safe loaders, torch.load only with
    weights_only=True (its restricted unpickler: tensors and plain containers, no code)."""
    problems = []
    for path in sorted((ROOT / "garage_exp").rglob("*.py")):
        rel = path.relative_to(ROOT)
        safe = set()  # the callee of each call with weights_only=True (ast.walk meets a call before its callee)
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Call) and any(k.arg == "weights_only" and isinstance(k.value, ast.Constant)
                                                  and k.value.value is True for k in node.keywords):
                safe.add(id(node.func))
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in (
                    "eval", "exec", "compile", "__import__"):
                problems.append(f"{rel}:{node.lineno}: {node.func.id}()")
            if isinstance(node, ast.Import):
                problems += [f"{rel}:{node.lineno}: import {a.name}" for a in node.names
                             if a.name.split(".")[0] in UNSAFE_MODULES]
            if isinstance(node, ast.ImportFrom) and (node.module or "").split(".")[0] in UNSAFE_MODULES:
                problems.append(f"{rel}:{node.lineno}: from {node.module} import")
            if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and (
                    node.value.id, node.attr) in UNSAFE_ATTRS and not (
                    (node.value.id, node.attr) == ("torch", "load") and id(node) in safe):
                problems.append(f"{rel}:{node.lineno}: {node.value.id}.{node.attr}")
            if isinstance(node, ast.Call) and any(k.arg == "allow_pickle" and not (
                    isinstance(k.value, ast.Constant) and k.value.value is False) for k in node.keywords):
                problems.append(f"{rel}:{node.lineno}: allow_pickle")
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == "load" \
                    and isinstance(node.func.value, ast.Name) and node.func.value.id == "yaml":
                loader = next((k.value for k in node.keywords if k.arg == "Loader"), None)
                if loader is None or "SafeLoader" not in ast.unparse(loader):
                    problems.append(f"{rel}:{node.lineno}: yaml.load without a SafeLoader")
    assert not problems, problems


def test_no_evaluating_resolver():
    """Interpolations in configs can read values (${oc.env:...}), never evaluate code."""
    from omegaconf import OmegaConf

    import garage_exp.cli.app  # noqa: F401  registers the project's resolvers

    for name in ("eval", "exec", "python", "py", "lambda"):
        assert not OmegaConf.has_resolver(name)


def test_override_value_is_never_evaluated(tmp_path):
    """An override that looks like Python is a string to Hydra: a type error, not a call."""
    r = run_app(['seed=__import__("os").system("touch pwned")', "dry_run=true", "plan=tiny"], tmp_path)
    assert r.returncode == 2 and "seed" in r.stderr and "Traceback" not in r.stderr
    assert not (tmp_path / "pwned").exists()


def test_bad_input_in_a_single_run_leaves_no_run_dir(tmp_path):
    """Hydra makes the run dir before the job starts; a job refused for bad input removes it again (only
    when it holds nothing but Hydra's own files)."""
    from garage_exp.core.shell import remove_untouched

    hydra_only = tmp_path / "a"
    (hydra_only / ".hydra").mkdir(parents=True)
    (hydra_only / ".hydra" / "config.yaml").write_text("x: 1\n")
    (hydra_only / "app.log").write_text("")
    remove_untouched(hydra_only)
    assert not hydra_only.exists()
    used = tmp_path / "b"
    (used / ".hydra").mkdir(parents=True)
    (used / "config.yaml").write_text("x: 1\n")
    remove_untouched(used)
    assert (used / "config.yaml").exists()


def test_hydra_full_error_still_gives_the_traceback(tmp_path):
    """HYDRA_FULL_ERROR=1 (Hydra's documented debugging switch) bypasses the one-line report."""
    r = run_app(["light=dusk"], tmp_path, env={"HYDRA_FULL_ERROR": "1"})
    assert r.returncode != 0 and "Traceback" in r.stderr
