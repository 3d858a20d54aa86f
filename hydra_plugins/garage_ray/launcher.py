"""`hydra/launcher=ray`: a Hydra launcher on Ray's current API (garage_exp.cluster); settings in
conf/hydra/launcher/ray.yaml. Hydra only instantiates launchers from the `hydra_plugins` package, so this shell
lives here."""

from __future__ import annotations

from typing import Any, Sequence

from hydra.core.utils import JobReturn
from hydra.plugins.launcher import Launcher
from hydra.types import HydraContext, TaskFunction
from omegaconf import DictConfig


class RayLauncher(Launcher):
    def __init__(self, **settings: Any) -> None:
        from garage_exp.cluster.ray_jobs import settings as parse

        self.settings = parse(settings)
        self.config: DictConfig | None = None
        self.hydra_context: HydraContext | None = None
        self.task_function: TaskFunction | None = None

    def setup(self, *, hydra_context: HydraContext, task_function: TaskFunction, config: DictConfig) -> None:
        self.config, self.hydra_context, self.task_function = config, hydra_context, task_function

    def launch(self, job_overrides: Sequence[Sequence[str]], initial_job_idx: int) -> Sequence[JobReturn]:
        from garage_exp.cluster.ray_jobs import launch

        return launch(self.settings, self.hydra_context, self.task_function, self.config, job_overrides,
                      initial_job_idx)

    def search(self) -> dict:
        """A search's workers as Ray tasks (hydra_plugins/garage_search asks for this)."""
        from garage_exp.cluster.ray_search import run

        return run(self.settings, self.hydra_context, self.task_function, self.config)
