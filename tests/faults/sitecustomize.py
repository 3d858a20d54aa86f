"""Test-only fault injection. Python imports this module at start-up when tests/faults is on PYTHONPATH; it
does nothing unless $GARAGE_EXP_FAULT is set, to one of:

    map:raise:JOB         job JOB (hydra.job.num) raises RuntimeError while drawing its plan map (after its
                          MLflow run started; works with dry_run=true)
    map:hang:JOB          job JOB sleeps there until it is killed (a sweep to kill -9 half-way)
    frame:raise:JOB:N     job JOB raises RuntimeError on its frame N+1 (N frames done: a partial frame table)

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


def _install(spec: str) -> None:
    where, action, job, *rest = spec.split(":")
    job = int(job)
    if where == "map":
        import garage_exp.plan.draw as draw

        real = draw.draw_map

        def draw_map(*args, **kwargs):
            if _job_num() == job:
                if action == "hang":
                    import time

                    print(f"FAULT: job {job} hangs", flush=True)
                    time.sleep(3600)
                raise RuntimeError(f"injected fault in job {job}")
            return real(*args, **kwargs)

        draw.draw_map = draw_map
    elif where == "frame":
        import garage_exp.sensor as sensor

        after = int(rest[0])
        real_make = sensor.make_sensor

        def make_sensor(conf):
            model = real_make(conf)
            if _job_num() != job:
                return model
            real_apply = model.apply
            done = [0]

            def apply(rgb, rng):
                if done[0] >= after:
                    raise RuntimeError(f"injected fault at frame {after} of job {job}")
                done[0] += 1
                return real_apply(rgb, rng)

            object.__setattr__(model, "apply", apply)
            return model

        sensor.make_sensor = make_sensor
    else:
        raise ValueError(f"GARAGE_EXP_FAULT: unknown fault {spec!r}")


if SPEC:
    _install(SPEC)
