"""`python -m garage_exp.loop`: the closed-loop experiment, step by step (garage_exp/loop/__init__.py says which).

Every step's result stays under `dir`; rerunning the command skips the steps already done (a study that holds its
trials, a training with its result.json), so an interrupted loop goes on where it stopped; a step made or begun
from other inputs (its command, the files it reads) is refused in one line, never reused.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

from omegaconf import DictConfig, open_dict

from garage_exp.core import shell
from garage_exp.core.errors import GarageError, check_range
from garage_exp.loop import budget, schema, steps

COMMAND = shell.Command("garage_exp.loop", "loop", (schema.register,),
                        resume_hint="rerun the same command to go on where it stopped")


def check_loop(cfg: DictConfig) -> None:
    for key in ("base_trials", "failure_trials", "hard_scenarios", "random_trials", "eval_trials", "epochs",
                "base_epochs", "batch"):
        check_range(cfg[key], 1, 100_000, key)
    check_range(cfg.replay_fraction, 0, 10, "replay_fraction")
    check_range(cfg.hard_below, 0, 1, "hard_below")
    if cfg.heldout_graded_by not in ("d0", "shipped"):
        raise GarageError(f"{cfg.heldout_graded_by!r}: d0 | shipped", "heldout_graded_by")
    if cfg.variant and not str(cfg.variant).replace("_", "").replace("-", "").isalnum():
        raise GarageError(f"{cfg.variant!r}: letters, digits, - and _ only (it names folders and studies)", "variant")
    if not cfg.seeds:
        raise GarageError("no training seeds", "seeds")
    if int(cfg.imgsz) % 32:
        raise GarageError(f"{cfg.imgsz} is not a multiple of 32", "imgsz")
    if cfg.eval_plan in cfg.train_plans:
        raise GarageError(f"{cfg.eval_plan!r} is also a training plan: held-out data must come from another plan",
                          "eval_plan")
    if str(cfg.base).endswith(".pt") and not Path(str(cfg.base)).expanduser().is_file():
        raise GarageError("base .pt not found", str(cfg.base))


# Steps every variant shares: a change to them needs another dir, not a variant.
SHARED_STEPS = ("base", "D0", "failures_D0", "random", "heldout")


class Loop:
    def __init__(self, cfg: DictConfig):
        self.cfg = cfg
        self.dir = Path(cfg.dir)
        self.log = self.dir / "loop.log"
        # Each step's wall time when it last ran (a step skipped because its result is on disk keeps its time).
        self.times_file = self.dir / "times.json"
        self.times: dict[str, float] = json.loads(self.times_file.read_text()) if self.times_file.is_file() else {}
        self.ran = False
        self.name = ""  # the step under way
        # Each step's full inputs (its command and the digests of the files it reads): a step, finished or not, is
        # reused or resumed only for the same inputs, never silently for other settings.
        self.commands_file = self.dir / "commands.json"
        self.commands: dict[str, list[str]] = (json.loads(self.commands_file.read_text())
                                               if self.commands_file.is_file() else {})

    def reuse(self, name: str, cmd: list[str], done: bool, inputs: list[Path] = ()) -> bool:
        """Whether step `name`'s result on disk is reused; GarageError when the step (finished or begun) was
        made from other inputs: another command, or files it reads (a data list, weights) that changed since."""
        key = [*cmd, *steps.digests(inputs)]
        known = self.commands.get(name)
        if known is not None and known != key:
            hint = ("give this run another dir" if name in SHARED_STEPS else
                    "give this run its own variant=NAME (its arms and second round apart) or another dir")
            raise GarageError(f"{self.dir} holds step {name!r} made from other inputs ({steps.changes(known, key)}); "
                              f"{hint}", "dir")
        self.commands[name] = key
        self.commands_file.write_text(json.dumps(self.commands, indent=1))
        return done

    def step(self, name: str, fn, always: bool = False):
        start = time.perf_counter()
        self.ran = always
        self.name = name
        if always:
            print(f"garage_exp.loop: {name} ...", flush=True)
        result = fn()
        if self.ran:
            self.times[name] = time.perf_counter() - start
        elif name not in self.times and isinstance(result, dict) and "wall_s" in result:
            self.times[name] = float(result["wall_s"])  # a training that finished outside this loop's process
        self.times_file.write_text(json.dumps(self.times, indent=1))
        print(f"garage_exp.loop: {name}: {time.perf_counter() - start:.0f} s"
              + ("" if self.ran else " (done before)"), flush=True)
        return result

    def _run(self, cmd: list[str]) -> None:
        self.ran = True
        print(f"garage_exp.loop: {self.name} ...", flush=True)  # said once its inputs passed the check
        steps.run(cmd, self.log)

    def study(self, name: str, plans, trials: int, sampler: str, seed: int, models=None):
        cmd = steps.search_command(self.cfg, name, list(plans), trials, sampler, seed, models)
        if not self.reuse(name, cmd, steps.study_done(self.cfg, name, trials), [Path(m) for m in models or ()]):
            self._run(cmd)
        return steps.trials(self.cfg, name)

    def train(self, name: str, **kw) -> dict:
        out = self.dir / "train" / name
        cmd = steps.train_command(self.cfg, name, out, **kw)
        inputs = [Path(p) for key in ("data", "val", "replay") for p in kw.get(key, ())] + [Path(str(kw["base"]))]
        if not self.reuse(name, cmd, (out / "result.json").is_file(), inputs):
            self._run(cmd)
        return json.loads((out / "result.json").read_text())


def run_loop(cfg: DictConfig) -> dict:
    from garage_exp.loop import report
    from garage_exp.results.labels import coco_names
    from garage_exp.train.data import split_scenarios

    loop = Loop(cfg)
    loop.dir.mkdir(parents=True, exist_ok=True)
    names = coco_names()
    data = loop.dir / "data"
    plans = list(cfg.train_plans)
    # 1. Base data: a QMC sample of the space on the training plans, each scenario with its dataset.
    base = loop.step("base data", lambda: loop.study("base", plans, cfg.base_trials, "qmc", 0))
    base_sets = [t.dataset for t in base if t.dataset is not None]
    train_s, val_s = split_scenarios([str(d) for d in base_sets], float(cfg.val_fraction), 0)
    base_train = budget.write_dirs(data / "base_train.yaml", [Path(d) for d in train_s], names)
    base_val = budget.write_dirs(data / "base_val.yaml", [Path(d) for d in val_s], names)
    # 2. D0: from scratch on the base data, or the user's .pt.
    if str(cfg.base).endswith(".pt"):
        d0 = {"model": str(Path(str(cfg.base)).expanduser().absolute()), "weights": str(cfg.base)}
    else:
        d0 = loop.step("D0", lambda: loop.train("D0", data=[base_train], val=[base_val], base=str(cfg.base),
                                                epochs=int(cfg.base_epochs), seed=0, lr0=float(cfg.base_lr0),
                                                study="base"))
    # 3. D0's failures: a search against D0 itself; its hardest fair scenarios are H's training data.
    round1 = loop.step("D0's failures", lambda: loop.study("failures_D0", plans, cfg.failure_trials, "tpe", 1,
                                                           [d0["model"]]))
    hard = budget.hardest(round1, int(cfg.hard_scenarios))
    hard_yaml = budget.write_dirs(data / "hard.yaml", [t.dataset for t in hard], names)
    n_hard = len(budget.images([t.dataset for t in hard]))
    # 4. R's pool: random scenarios of the same space; exactly as many frames as H's, drawn at random.
    pool = loop.step("random pool", lambda: loop.study("random", plans, cfg.random_trials, "random", 2,
                                                       [d0["model"]]))
    random_frames = budget.draw_frames(budget.images([t.dataset for t in pool if t.dataset is not None]), n_hard, 0)
    random_yaml = budget.write_list(data / "random.yaml", random_frames, names)
    suffix = f"_{cfg.variant}" if cfg.variant else ""  # a variant's arms, second round and results stand apart
    arms: dict[str, dict[int, dict]] = {"H": {}, "R": {}}
    for seed in cfg.seeds:
        for arm, arm_data in (("H", hard_yaml), ("R", random_yaml)):
            arms[arm][int(seed)] = loop.step(
                f"arm {arm} seed {seed}{suffix}", lambda arm=arm, arm_data=arm_data, seed=seed: loop.train(
                    f"{arm}_seed{seed}{suffix}", data=[arm_data], val=[base_val], base=d0["model"],
                    epochs=int(cfg.epochs),
                    seed=int(seed), lr0=float(cfg.lr0), replay=[base_train],
                    study="failures_D0" if arm == "H" else "random"))
        budget.assert_equal_budget(arms["H"][int(seed)], arms["R"][int(seed)])
    # 5. Held-out: scenarios of a plan no training frame came from (scored in the study by the shipped detectors);
    # the hardest and the easiest third, graded by D0 itself (heldout_graded_by=d0) or by the shipped detectors.
    held = loop.step("held-out suites", lambda: loop.study("heldout", [cfg.eval_plan], cfg.eval_trials, "qmc", 3))
    suites = report.heldout_suites(cfg, held, d0)
    # 6. A second round: search the fine-tuned detectors again (seed 0 of each arm), as D0 was searched.
    first = int(cfg.seeds[0])
    round2 = {arm: loop.step(f"{arm}'s failures{suffix}", lambda arm=arm: loop.study(
        f"failures_{arm}{suffix}", plans, cfg.failure_trials, "tpe", 1, [arms[arm][first]["model"]]))
        for arm in ("H", "R")}
    models = {"D0": {0: d0}, **arms}
    result = loop.step(f"evaluation{suffix}", lambda: report.evaluate_all(cfg, models, suites), always=True)
    loop.times["total"] = sum(v for k, v in loop.times.items() if k != "total")
    return report.write(cfg, loop.dir / f"results{suffix}", result, {"D0": round1, **round2}, suites, hard, loop.times)


def main(cfg: DictConfig) -> dict:
    from garage_exp.tracking.runs import tracking_uri

    check_loop(cfg)  # bad input: the shell removes Hydra's log dir (and `dir` if it made it) and says it in one line
    with open_dict(cfg):
        cfg.tracking.uri = tracking_uri(cfg.tracking.uri)  # every step's store, also for models:/ entries
        cfg.dir = str(Path(str(cfg.dir)).absolute())
    return run_loop(cfg)


def cli(argv: list[str] | None = None) -> None:
    """`python -m garage_exp.loop overrides...`. Exit codes: 0 done; 2 bad input (one line, nothing written);
    1 a failed step or a crash (traceback); 130 Ctrl-C, 143 SIGTERM (the running step is stopped the same way,
    its run ends KILLED; rerunning the command goes on where it stopped)."""
    COMMAND.run(main, argv)
