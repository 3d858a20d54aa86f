"""The schema of `python -m garage_exp.loop`'s config (conf/loop.yaml), registered in Hydra's ConfigStore."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

from hydra.core.config_store import ConfigStore

from garage_exp.core.schema import TrackingConf


@dataclass
class LoopConf:
    dir: str = "outputs/loop/default"  # every study, dataset, training and result of the loop
    # A name for a run of the arms with other settings (replay_fraction=1, epochs=10, ...) in the same dir: its
    # trainings, second round and results/ get this suffix; base data, D0, its failures and the held-out suites
    # are shared. Empty: the first run's names. A step is never reused for another command.
    variant: str = ""
    # The declared scenario space, in the search's override grammar (docs/search.md), shared by every study.
    space: list[str] = field(default_factory=lambda: ["case=choice('1','2','3',pedestrian)",
                                                      "light=choice(bright,clear,moderate,dim)",
                                                      "seed=int(interval(0,9999))"])
    fixed: list[str] = field(default_factory=lambda: ["case.motion.step=2.0"])  # set on every job
    train_plans: list[str] = field(default_factory=lambda: ["research", "realistic"])
    eval_plan: str = "obstacles"  # no training frame comes from it
    base: str = "yolov8n.yaml"  # a model YAML: D0 trained from scratch; a .pt: D0 is that detector
    base_trials: int = 32  # QMC scenarios of base data
    base_epochs: int = 25
    optimizer: str = "AdamW"  # for D0 and the arms (ultralytics' auto would pick lr 0.00012: see TrainConf)
    base_lr0: float = 0.002
    lr0: float = 0.001  # the arms' fine-tuning
    failure_trials: int = 30  # each search for failures (D0's, then the fine-tuned detectors')
    hard_scenarios: int = 8  # D0's hardest fair scenarios: arm H's training data
    random_trials: int = 16  # random scenarios from the same space: arm R's pool
    eval_trials: int = 24  # QMC scenarios on eval_plan; the hardest and the easiest third are the held-out suites
    heldout_graded_by: str = "d0"  # d0 | shipped: who grades the held-out scenarios into the hard and easy third
    epochs: int = 6  # each arm's fine-tuning
    imgsz: int = 320
    batch: int = 16
    replay_fraction: float = 0.5
    seeds: list[int] = field(default_factory=lambda: [0, 1, 2])
    val_fraction: float = 0.2  # of the base scenarios, held out to validate every training
    hard_below: float = 0.4  # a failure: a fair trial whose confidence is below this (the suites' hard band)
    threshold: float = 0.5  # composite confidence counted as detected
    tracking: TrackingConf = field(default_factory=lambda: TrackingConf(experiment="garage_loop"))


def register() -> None:
    ConfigStore.instance().store(name="loop_schema", node=LoopConf)
