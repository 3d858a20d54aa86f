"""The search's check of a space (search/sweep.py `check`): every choice and each interval's ends probed, composed
and preflighted as a trial's job would be. Every search and the loop's check of its steps run it before their
first trial; on the wide space it probes about 300 points.

    python -m benchmarks.performance.space_check [--space wide] [--rounds 2]

Two arms in one process, alternating (`--rounds`), so that another process's load falls on both:

  hydra     each probe composed by Hydra from the files (the check before search/compose.py)
  cached    each probe composed as the launcher composes a trial: Hydra once per combination of group levels,
            the other values set on a copy (search/compose.py)

Printed: each arm's seconds, Hydra's compositions and the ratio. Models are not loaded (the same in both arms).
The page: benchmarks/results/space_check.md.
"""

from __future__ import annotations

import argparse
import time

from benchmarks.common import RESULTS, write_json_page


def run_arm(arm: str, space: str) -> dict:
    from hydra import initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra
    from hydra.types import RunMode
    from omegaconf import open_dict

    from garage_exp.core import shell
    from garage_exp.core.state import STATE
    from garage_exp.run import preflight as preflight_mod
    from garage_exp.search import sweep

    import garage_exp.config  # noqa: F401 - the experiment's Config assembled, as the main command does on import

    shell.register()
    GlobalHydra.instance().clear()
    with initialize_config_dir(config_dir=str(shell.CONF_DIR), version_base="1.3"):
        loader = GlobalHydra.instance().config_loader()
        task = ["hydra/sweeper=search", f"space={space}"]
        master = loader.load_configuration("config", task, RunMode.MULTIRUN)
        with open_dict(master):
            master.hydra.overrides.task = task
        composed = []
        real = type(loader).load_sweep_config

        def counting(self, cfg, overrides):
            composed.append(1)
            return real(self, cfg, overrides)

        saved = (type(loader).load_sweep_config, preflight_mod.load_models, sweep._probe)
        type(loader).load_sweep_config = counting
        preflight_mod.load_models = lambda job: None
        if arm == "hydra":
            sweep._probe = lambda compositions, point, where: sweep._probe_error(
                lambda: preflight_mod.preflight(loader.load_sweep_config(master, point), check_space=False,
                                                load=False), where)
        try:
            STATE.begin()
            start = time.perf_counter()
            checked = sweep.check(master, loader)
            seconds = time.perf_counter() - start
        finally:
            type(loader).load_sweep_config, preflight_mod.load_models, sweep._probe = saved
    return {"arm": arm, "seconds": seconds, "hydra_compositions": len(composed), "params": len(checked.params)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--space", default="wide")
    ap.add_argument("--rounds", type=int, default=2)
    args = ap.parse_args()
    rows = []
    for r in range(args.rounds):
        for arm in ("hydra", "cached"):
            rows.append({"round": r, **run_arm(arm, args.space)})
            print(rows[-1], flush=True)
    mean = {a: sum(x["seconds"] for x in rows if x["arm"] == a) / args.rounds for a in ("hydra", "cached")}
    ratio = mean["hydra"] / mean["cached"]
    print(f"check of space={args.space}: Hydra per probe {mean['hydra']:.1f} s, cached {mean['cached']:.1f} s: "
          f"{ratio:.1f}x faster")
    write_json_page(RESULTS / "space_check.md", f"The search's check of space={args.space}",
                    {"rows": rows, "mean_seconds": mean, "ratio": ratio})


if __name__ == "__main__":
    main()
