"""Hydra callbacks: the MLflow parent run of a sweep and the report at its end."""

from __future__ import annotations

import logging
from typing import Any

from hydra.experimental.callback import Callback
from omegaconf import DictConfig

from garage_exp import tracking

log = logging.getLogger(__name__)


class MlflowSweepCallback(Callback):
    """Opens a parent run when a multirun starts; every job (in any process) reads its id from the sweep dir
    and becomes its child. At the end of the sweep the report is logged on the parent."""

    def __init__(self) -> None:
        self.parent_run_id: str | None = None

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        from mlflow.utils.mlflow_tags import MLFLOW_RUN_NAME

        mlc = tracking.client(config.tracking.uri)
        exp_id = tracking.experiment_id(mlc, config.tracking.experiment)
        overrides = " ".join(config.hydra.overrides.task)
        tags = {MLFLOW_RUN_NAME: f"sweep {overrides}".strip(), "sweep": "parent", "overrides": overrides,
                "git_commit": tracking.git_commit(), "sweep_dir": str(config.hydra.sweep.dir)}
        run = tracking.retry(lambda: mlc.create_run(exp_id, tags=tags))
        self.parent_run_id = run.info.run_id
        tracking.write_parent(config.hydra.sweep.dir, self.parent_run_id)

    def on_multirun_end(self, config: DictConfig, **kwargs: Any) -> None:
        if not self.parent_run_id:
            return
        mlc = tracking.client(config.tracking.uri)
        status = "FINISHED"
        try:
            from garage_exp.report import sweep_report

            sweep_report(mlc, self.parent_run_id, config.hydra.sweep.dir,
                         resumed=tracking.read_resumed(config.hydra.sweep.dir))
        except Exception as exc:  # the sweep's runs are safe; a failed summary must not hide them
            log.error("sweep report failed: %s", exc)
            tracking.retry(lambda: mlc.set_tag(self.parent_run_id, "report_error", str(exc)[:5000]))
            status = "FAILED"
        tracking.retry(lambda: mlc.set_terminated(self.parent_run_id, status))
