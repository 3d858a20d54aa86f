"""`hydra/sweeper=search`: a Hydra sweeper that searches with Optuna's ask/tell (garage_exp.search).

Hydra only instantiates sweepers from the `hydra_plugins` package, so this shell lives here; the search itself
is garage_exp.search.sweep. Settings are the task config's `search` node (search.trials, search.sampler, ...),
the space is the command's sweep overrides in Hydra's grammar (interval, choice, range).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from hydra.core.plugins import Plugins
from hydra.plugins.sweeper import Sweeper
from hydra.types import HydraContext, TaskFunction
from omegaconf import DictConfig, OmegaConf


BASIC_LAUNCHER = "hydra._internal.core_plugins.basic_launcher.BasicLauncher"


class SearchSweeper(Sweeper):
    def __init__(self) -> None:
        self.config: DictConfig | None = None
        self.hydra_context: HydraContext | None = None
        self.launcher = None

    def setup(self, *, hydra_context: HydraContext, task_function: TaskFunction, config: DictConfig) -> None:
        self.config = config
        self.hydra_context = hydra_context
        self.task_function = task_function
        self.launcher = Plugins.instance().instantiate_launcher(
            config=config, hydra_context=hydra_context, task_function=task_function)

    def launch_function(self):
        """Trials in this process compose their config once per combination of group levels (Hydra's basic
        launcher, made cheaper: garage_exp.search.launch); other launchers (joblib, submitit) get the batch."""
        from garage_exp.search.launch import CachedLaunch, launch_in_runs
        from garage_exp.search.sweep import group_levels

        if OmegaConf.select(self.config, "hydra.launcher._target_") == BASIC_LAUNCHER:
            groups = set(group_levels(self.hydra_context.config_loader))
            return CachedLaunch(self.hydra_context, self.task_function, self.config, groups)
        return lambda batch, first: launch_in_runs(self.launcher, batch, first)

    def sweep(self, arguments: list[str]) -> Any:
        from garage_exp.tracking import runs as tracking
        from garage_exp.search import sweep

        assert self.config is not None and self.hydra_context is not None
        sweep_dir = Path(self.config.hydra.sweep.dir)
        sweep_dir.mkdir(parents=True, exist_ok=True)
        OmegaConf.save(self.config, sweep_dir / "multirun.yaml")
        loader = self.hydra_context.config_loader
        launch = self.launch_function()
        if hasattr(self.launcher, "search"):  # hydra/launcher=ray: its workers run the trial loops
            result = self.launcher.search()
        else:
            result = sweep.run(self.config, loader, launch)
        paths = sweep.finish(self.config, result, sweep_dir / "search", loader, launch)
        parent = tracking.read_parent(sweep_dir)
        if parent:
            sweep.log_on_parent(self.config, parent, result, paths, sweep_dir / "search")
        sweep.count_others_apart(self.config, result, sweep_dir)
        print(sweep.summary(result, sweep_dir / "search"))
        if OmegaConf.select(self.config, "search.runs") == "per_search":
            from garage_exp.core.state import STATE

            if STATE.sweep is not None:  # the sweep's callback: its trials have no runs to count
                STATE.sweep.trials_summary = sweep.trials_summary(result)
        return result["ran"]
