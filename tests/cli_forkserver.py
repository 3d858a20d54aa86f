"""A fork server for the command line, so that dozens of bad-input runs do not each pay Python's and the
project's start-up (~1 s). It imports what `python -m garage_exp` imports, then, per request, forks a child
that does exactly what `python -m garage_exp ARGS` does - `garage_exp.cli.app.cli()` with that argv, in that
working dir and environment, its stdout and stderr in files - and answers with the child's exit code.

Protocol: one JSON object per line on stdin {"argv", "cwd", "env", "stdout", "stderr", optional "entry": another
command's cli as "module:function", e.g. "garage_exp.verify.app:cli"; optional "no_model": true, the entry must
be refused before any model loads: loading one raises in the child}, all before stdin
closes; one per line on stdout {"id" (the request's index), "rc", "s" and "cpu" (the child's wall and CPU
seconds)} as the children finish. Only for tests
(tests/test_reliability_inputs.py, which also runs a few entries as real subprocesses to compare).

The detectors' libraries (ultralytics and torch, OpenVINO, ONNX) are imported here too, for children that run
with GARAGE_EXP_DETECT_PROCESS=0: their detector checks then load in the child itself, forked with the libraries
in place, instead of in a detector process each that starts an interpreter and imports them anew (half the time
of an entry whose job reaches its detectors). Importing starts no thread in them, so the fork is safe.
"""

from __future__ import annotations

import json
import os
import sys
import time


def preload() -> None:
    """What most children import anyway (a job's preflight checks every config group; a sweep its jobs; a
    search its space and study), imported once here. Of garage_exp only modules the main command imports on its
    own path to a refusal: no other command's registrations, which would change what a child knows; of other
    commands only their third-party libraries."""
    import garage_exp.cli.app  # noqa: F401  hydra, omegaconf, the schema
    import garage_exp.assets.vehicles  # noqa: F401
    import garage_exp.cli.callbacks  # noqa: F401
    import garage_exp.run.frames  # noqa: F401  numpy, pandas, the scene description, the cases
    import garage_exp.plan  # noqa: F401
    import garage_exp.scene.lamps  # noqa: F401
    import garage_exp.perception.sensor  # noqa: F401
    import garage_exp.run.preflight  # noqa: F401
    import garage_exp.core.schema_check  # noqa: F401
    import garage_exp.scenario.assemble  # noqa: F401
    import garage_exp.slots.detector  # noqa: F401  the checks preflight.check_config imports
    import garage_exp.render.bev  # noqa: F401
    import garage_exp.scene.clutter  # noqa: F401
    import garage_exp.scene.look  # noqa: F401
    import garage_exp.scene.modifiers  # noqa: F401
    import garage_exp.scene.parking  # noqa: F401
    import garage_exp.scene.structure  # noqa: F401
    import garage_exp.search.sweep  # noqa: F401  optuna
    import garage_exp.tracking.store  # noqa: F401  sqlite3
    from hydra.core.plugins import Plugins

    Plugins.instance()  # plugin discovery scans site-packages once
    import onnx  # noqa: F401  the detector entries' loaders (see the module's docstring)
    import onnxruntime  # noqa: F401
    import openvino  # noqa: F401
    import torchvision  # noqa: F401
    import ultralytics  # noqa: F401
    import lxml.etree  # noqa: F401  the scenario import's entries (OpenSCENARIO and OpenDRIVE files)
    import scenariogeneration  # noqa: F401
    import scipy.optimize  # noqa: F401
    import xmlschema  # noqa: F401
    import gc

    # Everything imported so far is kept out of the children's garbage collections: a child's collection would
    # otherwise walk (and so copy, page by page) the parent's millions of objects, half of a short child's time.
    gc.collect()
    gc.freeze()


def call_cli(entry=None) -> int:
    """`garage_exp.cli.app.cli()` (or another entry point's, `entry`) on sys.argv, as `python -m garage_exp`
    runs it: its exit code, an uncaught exception printed as the interpreter would, with 1."""
    from garage_exp.cli.app import cli

    cli = entry or cli
    try:
        cli()
    except SystemExit as exc:
        if isinstance(exc.code, str):
            print(exc.code, file=sys.stderr)
        return exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    except Exception:
        import traceback

        traceback.print_exc()
        return 1
    return 0


def child(request: dict) -> int:
    os.chdir(request["cwd"])
    os.environ.update(request.get("env") or {})
    # as a fresh interpreter starts: the request's PYTHONPATH first on sys.path (a $GARAGE_EXP_PLUGINS module lies there)
    path = (request.get("env") or {}).get("PYTHONPATH", "")
    sys.path[:0] = [p for p in path.split(os.pathsep) if p and p not in sys.path]
    out = os.open(request["stdout"], os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
    err = os.open(request["stderr"], os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
    os.dup2(out, 1)
    os.dup2(err, 2)
    sys.stdout = os.fdopen(1, "w", buffering=1)
    sys.stderr = os.fdopen(2, "w", buffering=1)
    import garage_exp

    sys.argv = [os.path.join(os.path.dirname(garage_exp.__file__), "__main__.py"), *request["argv"]]
    if request.get("no_model"):  # every model a job loads goes through the preflight's check_loads
        import garage_exp.run.preflight

        def no_model(*args):
            raise AssertionError("a model was loaded before the refusal (a check that needs no model comes first)")

        garage_exp.run.preflight.check_loads = no_model
    entry = None
    if request.get("entry"):
        import importlib

        module, _, name = request["entry"].partition(":")
        entry = getattr(importlib.import_module(module), name)
    code = call_cli(entry)
    sys.stdout.flush()
    sys.stderr.flush()
    return code


def main() -> None:
    """Reads every request (until stdin closes), then runs them PARALLEL at a time; answers {"id", "rc"} as
    they finish."""
    preload()
    requests = [json.loads(line) for line in sys.stdin if line.strip()]
    parallel = int(os.environ.get("FORKSERVER_PARALLEL", "2"))
    running: dict[int, tuple[int, float]] = {}
    pending = list(enumerate(requests))
    while pending or running:
        while pending and len(running) < parallel:
            k, request = pending.pop(0)
            pid = os.fork()
            if pid == 0:
                code = 70
                try:
                    code = child(request)
                except BaseException:
                    import traceback

                    traceback.print_exc()
                finally:
                    os._exit(code)
            running[pid] = (k, time.monotonic())
        pid, status, usage = os.wait4(-1, 0)
        k, start = running.pop(pid)
        print(json.dumps({"id": k, "rc": os.waitstatus_to_exitcode(status), "s": round(time.monotonic() - start, 3),
                          "cpu": round(usage.ru_utime + usage.ru_stime, 3)}), flush=True)


if __name__ == "__main__":
    main()
