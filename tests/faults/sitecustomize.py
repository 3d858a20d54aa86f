"""Test-only fault injection. Python imports this module at start-up when tests/faults is on PYTHONPATH; it
does nothing unless $GARAGE_EXP_FAULT is set, to one of:

    map:raise:JOB         job JOB (hydra.job.num) raises RuntimeError while drawing its plan map (after its
                          MLflow run started; works with dry_run=true)
    map:hang:JOB          job JOB sleeps there until it is killed (a sweep to kill -9 half-way)
    map:wait:JOB          job JOB waits there until the file $GARAGE_EXP_FAULT_GO exists (the test acts meanwhile)
    frame:raise:JOB:N     job JOB raises RuntimeError on its frame N+1 (N frames done: a partial frame table)
    disk:fill:JOB         job JOB fills the filesystem of its output dir (a file `filler` in that dir, written
                          until the kernel says ENOSPC), then writes its plan map there: a real full disk
    disk:fill:JOB:N       the same when job JOB renders its frame N+1 (frames being written when the disk fills)
    disk:raise:JOB        job JOB's plan map write raises OSError ENOSPC (when no small filesystem can be mounted)
    detector:kill:JOB:N,M job JOB's detector process is killed (SIGKILL) right after frames N, M, ... (0-based)
                          are sent to it
    store:term:JOB        job JOB sends itself SIGTERM inside its first MLflow write's SQL session (the params of its
                          run: a scheduler's stop that lands mid-transaction)

Several faults: separate them with ";".

The production code has no test hooks; these wrap module attributes that garage_exp looks up at call time.
"""

import os

SPEC = os.environ.get("GARAGE_EXP_FAULT", "")


def _job_num() -> int:
    from hydra.core.hydra_config import HydraConfig

    try:
        return int(HydraConfig.get().job.num)
    except Exception:
        return 0


def _before_frames(job, hook):
    """Call hook(frames done so far) before each frame job `job`'s sensor model sees."""
    import garage_exp.perception.sensor as sensor

    real_make = sensor.make_sensor

    def make_sensor(**settings):
        model = real_make(**settings)
        if _job_num() != job:
            return model
        real_apply = model.apply
        done = [0]

        def apply(rgb, rng):
            hook(done[0])
            done[0] += 1
            return real_apply(rgb, rng)

        object.__setattr__(model, "apply", apply)
        return model

    sensor.make_sensor = make_sensor


def _install(spec: str) -> None:
    where, action, job, *rest = spec.split(":")
    job = int(job)
    if where == "map":
        def patch(module):
            real = module.plan_map  # where a job writes its plan map (drawn, or copied once drawn)

            def plan_map(classified, path, *args, **kwargs):
                if _job_num() == job:
                    if action == "hang":
                        import time

                        print(f"FAULT: job {job} hangs", flush=True)
                        time.sleep(3600)
                    if action == "wait":
                        import time

                        print(f"FAULT: job {job} waits", flush=True)
                        while not os.path.exists(os.environ["GARAGE_EXP_FAULT_GO"]):
                            time.sleep(0.1)
                        return real(classified, path, *args, **kwargs)
                    raise RuntimeError(f"injected fault in job {job}")
                return real(classified, path, *args, **kwargs)

            module.plan_map = plan_map

        after_import("garage_exp.run.job", patch)
    elif where == "frame":
        after = int(rest[0])

        def at_frame(done):
            if done >= after:
                raise RuntimeError(f"injected fault at frame {after} of job {job}")

        _before_frames(job, at_frame)
    elif where == "disk" and rest:
        after = int(rest[0])

        def at_frame(done):
            if done == after:
                from hydra.core.hydra_config import HydraConfig

                _fill(os.path.join(HydraConfig.get().runtime.output_dir, "filler"))

        _before_frames(job, at_frame)
    elif where == "disk":
        import errno

        def patch(module):
            real_map = module.plan_map  # where a job writes its plan map (drawn, or copied once drawn)

            def plan_map(classified, path, *args, **kwargs):
                if _job_num() == job:
                    if action == "raise":
                        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))
                    _fill(os.path.join(os.path.dirname(path), "filler"))
                return real_map(classified, path, *args, **kwargs)

            module.plan_map = plan_map

        after_import("garage_exp.run.job", patch)
    elif where == "detector":
        kills = {int(n) for n in rest[0].split(",")}
        sent = [0]

        def patch(module):
            real_submit = module.DetectorProcess.submit

            def submit(self, rgb, intrinsics=None):
                real_submit(self, rgb, intrinsics)
                if _job_num() == job:
                    if sent[0] in kills:
                        import signal

                        os.kill(self.pid, signal.SIGKILL)
                        print(f"FAULT: killed the detector process after frame {sent[0]}", flush=True)
                    sent[0] += 1

            module.DetectorProcess.submit = submit

        after_import("garage_exp.perception.detect.worker", patch)
    elif where == "store":
        sent = [False]

        def patch(module):
            real_get_run = module.SqlAlchemyStore._get_run  # read inside log_batch's session, before its writes

            def _get_run(self, *args, **kwargs):
                if _job_num() == job and not sent[0]:
                    import signal
                    import time

                    sent[0] = True
                    print(f"FAULT: job {job} gets SIGTERM inside a store session", flush=True)
                    os.kill(os.getpid(), signal.SIGTERM)
                    time.sleep(0.05)  # the handler runs here, inside the session
                return real_get_run(self, *args, **kwargs)

            module.SqlAlchemyStore._get_run = _get_run

        after_import("mlflow.store.tracking.sqlalchemy_store", patch)
    else:
        raise ValueError(f"GARAGE_EXP_FAULT: unknown fault {spec!r}")


def _fill(path: str) -> None:
    """Write zeros to path until the filesystem is full."""
    import errno

    with open(path, "wb", buffering=0) as fh:
        try:
            while True:
                fh.write(b"\0" * 65536)
        except OSError as exc:
            if exc.errno != errno.ENOSPC:
                raise
    print(f"FAULT: filled the disk ({path})", flush=True)


def after_import(name: str, patch) -> None:
    """Call patch(module) once `name` is imported as a module; not when it runs as a program (`python -m
    name`: the detector's own process), which importing it here would disturb."""
    import importlib.abc
    import importlib.util
    import sys

    class Finder(importlib.abc.MetaPathFinder):
        def find_spec(self, fullname, path, target=None):
            if fullname != name:
                return None
            sys.meta_path.remove(self)
            spec = importlib.util.find_spec(fullname)
            real_exec = spec.loader.exec_module

            def exec_module(module):
                real_exec(module)
                if module.__name__ == name:
                    patch(module)

            spec.loader.exec_module = exec_module
            return spec

    sys.meta_path.insert(0, Finder())


for _spec in filter(None, SPEC.split(";")):
    _install(_spec)

