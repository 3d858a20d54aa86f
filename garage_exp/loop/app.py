"""`python -m garage_exp.loop`: the closed-loop experiment in rounds (garage_exp/loop/__init__.py says which).

Every step's result stays under `dir`; rerunning the command skips the steps already done (a study that holds its
trials, a training with its result.json, a detector's scores), so an interrupted loop goes on where it stopped; a
step made or begun from other inputs (its command, the files it reads) is refused in one line, never reused.
"""

from __future__ import annotations

import json
import re
import time
from pathlib import Path

from omegaconf import DictConfig, open_dict

from garage_exp.core import shell
from garage_exp.core.errors import GarageError, JobFault, check_range
from garage_exp.loop import budget, garages, replay, schema, steps
from garage_exp.loop.budget import arm_budget

COMMAND = shell.Command("garage_exp.loop", "loop", (schema.register,),
                        resume_hint="rerun the same command to go on where it stopped")


def check_budgets(cfg: DictConfig) -> None:
    """Every arm spends the same per round: generator trials, training frames, epochs, image size and replay."""
    arms = list(cfg.arms)
    first = arm_budget(cfg, arms[0])
    for arm in arms[1:]:
        mine = arm_budget(cfg, arm)
        for key in schema.BUDGET_KEYS:
            if mine[key] != first[key]:
                raise GarageError(f"unequal budgets: arm {arm} has {key}={mine[key]}, arm {arms[0]} {first[key]} "
                                  "(every arm gets the same generator frames and trials, training frames, "
                                  "epochs, image size and replay per round)", f"arms.{arm}.{key}")


def check_loop(cfg: DictConfig) -> None:
    from garage_exp.search.study import SAMPLERS

    check_range(cfg.startup, 0, 100_000, "startup")
    for key in ("base_trials", "trials", "train_frames", "heldout_trials", "epochs", "base_epochs", "batch",
                "rounds"):
        check_range(cfg[key], 1, 100_000, key)
    check_range(cfg.frames, 0, 10_000_000, "frames")
    check_range(cfg.bn_calibrate, 0, 100_000, "bn_calibrate")
    check_range(cfg.replay_fraction, 0, 10, "replay_fraction")
    check_range(cfg.hard_below, 0, 1, "hard_below")
    if cfg.variant and not str(cfg.variant).replace("_", "").replace("-", "").isalnum():
        raise GarageError(f"{cfg.variant!r}: letters, digits, - and _ only (it names folders and studies)", "variant")
    if not cfg.arms:
        raise GarageError("no arms", "arms")
    for arm, conf in cfg.arms.items():
        if not str(arm).isalnum():
            raise GarageError(f"{arm!r}: an arm's name is letters and digits (it names studies)", "arms")
        if conf.sampler not in SAMPLERS:
            raise GarageError(f"{conf.sampler!r} is not a sampler of the search ({' | '.join(SAMPLERS)})",
                              f"arms.{arm}.sampler")
        if conf.keep not in ("failures", "all"):
            raise GarageError(f"{conf.keep!r}: failures | all", f"arms.{arm}.keep")
        if conf.get("overrides") and conf.sampler != "archive":
            raise GarageError(f"arm {arm}'s sampler is {conf.sampler}: its overrides (search.archive.*) would change "
                              "nothing", f"arms.{arm}.overrides")
        for k, line in enumerate(conf.get("overrides") or []):
            if not re.fullmatch(r"search\.archive\.[a-z_]+=[^\s=]+", str(line)):
                raise GarageError(f"{line!r}: an arm sets only its sampler's method (search.archive.KEY=VALUE); the "
                                  f"space and the budgets are every arm's", f"arms.{arm}.overrides[{k}]")
    check_budgets(cfg)
    if not cfg.seeds or len(set(cfg.seeds)) != len(cfg.seeds):
        raise GarageError("give distinct training seeds", "seeds")
    if cfg.heldout_method not in ("sobol", "halton"):
        raise GarageError(f"{cfg.heldout_method!r}: sobol | halton", "heldout_method")
    if not 0 <= int(cfg.freeze) <= 1000:
        raise GarageError(f"{cfg.freeze} layers: 0 (none frozen) to 1000", "freeze")
    check_range(cfg.wise, 0.0, 1.0, "wise", f"{cfg.wise} (the fine-tuned weights' share: 0 D0, 1 as trained)")
    if abs(100 * float(cfg.wise) - round(100 * float(cfg.wise))) > 1e-9:  # it names the mix's files and results
        raise GarageError(f"{cfg.wise}: a whole percentage (0.5, 0.25, ...)", "wise")
    if int(cfg.imgsz) % 32:
        raise GarageError(f"{cfg.imgsz} is not a multiple of 32", "imgsz")
    garages.check(cfg)  # the held-out garages share no plan, generator seed or layout family with training's
    if str(cfg.base).endswith(".pt") and not Path(str(cfg.base)).expanduser().is_file():
        raise GarageError("base .pt not found", str(cfg.base))
    if cfg.photos and not cfg.estimate:  # fetched at set-up (`make data`): missing, said before any step
        from garage_exp.assets.photos import street_photos

        street_photos()


# Steps every variant shares: a change to them needs another dir, not a variant.
SHARED_STEPS = ("base", "D0", "heldout") + tuple(f"protocol_{k}" for k in ("cpnco", "cpra", "crossing", "crouch"))


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
                    "give this run another dir or the pool another name" if name.startswith("replay_") else
                    "give this run its own variant=NAME (its rounds and results apart) or another dir")
            raise GarageError(f"{self.dir} holds step {name!r} made from other inputs ({steps.changes(known, key)}); "
                              f"{hint}", "dir")
        self.commands[name] = key
        self.commands_file.parent.mkdir(parents=True, exist_ok=True)
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

    def study(self, name: str, garage: list[str], trials: int, sampler: str, seed: int, models=None, before=None,
              startup=None, frames: int = 0, extra=()):
        """A search on the garages `garage` says (loop/garages.py; `before`: called once its inputs passed the
        check and before it runs, e.g. to enqueue); `frames`: its budget of rendered frames, `trials` then its cap;
        `extra`: an arm's own overrides of its sampler's method."""
        cmd = steps.search_command(self.cfg, name, list(garage), trials, sampler, seed, models, startup, frames,
                                   list(extra))
        done = steps.study_done(self.cfg, name, trials, frames)
        if not self.reuse(name, cmd, done, [Path(m) for m in models or ()]):
            if before is not None:
                before()
            self._run(cmd)
        return steps.trials(self.cfg, name)

    def sweep(self, name: str, overrides: list[str]) -> list[steps.Trial]:
        """A plain sweep of the main command (a protocol's jobs), each job with its dataset."""
        out = self.dir / "studies" / name
        cmd = steps.sweep_command(self.cfg, out, overrides)
        if not self.reuse(name, cmd, (out / "done").is_file()):
            self._run(cmd)
            (out / "done").write_text("")
        return steps.jobs(name, out)

    def train(self, name: str, **kw) -> dict:
        out = self.dir / "train" / name
        cmd = steps.train_command(self.cfg, name, out, **kw)
        inputs = [Path(p) for key in ("data", "val", "replay") for p in kw.get(key, ())] + [Path(str(kw["base"]))]
        if not self.reuse(name, cmd, (out / "result.json").is_file(), inputs):
            self._run(cmd)
        return json.loads((out / "result.json").read_text())

    def wise(self, name: str, base: str, tuned: str, imgsz: int) -> dict:
        """The fine-tuning `name`'s weights mixed with the base's (train/wise.py) and the mix's validation on the
        fine-tuning's own validation split (its curves describe the tuned weights, not the mix): made once, again
        only when either input is newer than the mix."""
        from garage_exp.train import wise

        out = self.dir / "train" / name / f"{wise_suffix(self.cfg).lstrip('_')}.pt"
        scored = out.with_suffix(".json")
        if not scored.is_file() or scored.stat().st_mtime < max(Path(p).stat().st_mtime for p in (base, tuned)):
            self.ran = True
            wise.interpolate(Path(base), Path(tuned), float(self.cfg.wise), out)
            metrics = wise.validate(out, self.dir / "train" / name / "data" / "data.yaml", imgsz)
            scored.write_text(json.dumps({"weights": str(out), "alpha": float(self.cfg.wise), **metrics}))
        return json.loads(scored.read_text())

    def verify(self, name: str, data: str, weights: list[str]) -> dict:
        out = self.dir / "verify" / name
        cmd = steps.verify_command(self.cfg, out, data, weights)
        if not self.reuse(f"verify_{name}", cmd, (out / "result.json").is_file(), [Path(w) for w in weights]):
            self._run(cmd)
        return json.loads((out / "result.json").read_text())


def run_loop(cfg: DictConfig) -> dict:
    from garage_exp.loop import cost, evaluate, heldout, report
    from garage_exp.results.labels import coco_names
    from garage_exp.train.data import split_scenarios

    loop = Loop(cfg)
    loop.dir.mkdir(parents=True, exist_ok=True)
    print(f"garage_exp.loop: the cost model's estimate on a fresh dir: {cost.describe(cost.estimate(cfg))}",
          flush=True)
    names = coco_names()
    data = loop.dir / "data"
    plans = garages.train(cfg)  # the training garages: the train_plans, or generated ones of the training seeds
    base_pt = str(Path(str(cfg.base)).expanduser().absolute()) if str(cfg.base).endswith(".pt") else None
    # 1. Base data: a QMC sample of the space on the training plans: the replay pool and the validation scenarios.
    base = loop.step("base data", lambda: loop.study("base", plans, cfg.base_trials, "qmc", 0,
                                                     [base_pt] if base_pt else None))
    base_sets = [t.dataset for t in base if t.dataset is not None]
    train_s, val_s = split_scenarios([str(d) for d in base_sets], float(cfg.val_fraction), 0)
    base_train = budget.write_dirs(data / "base_train.yaml", [Path(d) for d in train_s], names)
    base_val = budget.write_dirs(data / "base_val.yaml", [Path(d) for d in val_s], names)
    # 1b. Replay pools beyond the base data (replay_pool): their scenarios join every fine-tuning's replay alone.
    replay_dirs, replay_lists = [Path(d) for d in train_s], [base_train]
    for pool in replay.pools(cfg, plans):
        drawn = loop.step(pool.step, lambda p=pool: loop.study(p.study, p.overrides, p.trials, "qmc", p.seed,
                                                                 [base_pt] if base_pt else None))
        dirs = [Path(t.dataset) for t in drawn if t.dataset is not None]
        replay_dirs += dirs
        replay_lists.append(budget.write_dirs(data / f"{pool.study}.yaml", dirs, names))
    # 2. D0: the COCO-pretrained detector as given (its BatchNorms are calibrated by each fine-tuning), or trained
    # from scratch on the base data.
    if base_pt:
        d0 = {"model": base_pt, "weights": base_pt}
    else:
        d0 = loop.step("D0", lambda: loop.train("D0", data=[base_train], val=[base_val], base=str(cfg.base),
                                                epochs=int(cfg.base_epochs), seed=0, lr0=float(cfg.base_lr0),
                                                study="base", calibrate=False))
    # 3. The held-out suites, rendered once: the failure-rate sample (a fixed QMC sample of the space on eval_plan),
    # the protocol cases, and (scored later) the real photos.
    held_space = steps.with_garage(cfg, garages.heldout(cfg))
    points = heldout.draws(held_space, int(cfg.heldout_trials), int(cfg.heldout_seed), str(cfg.heldout_method),
                           heldout.requires(cfg))
    held = loop.step("held-out sample", lambda: loop.study(
        "heldout", garages.heldout(cfg), cfg.heldout_trials, "random", 0, [d0["model"]],
        before=lambda: heldout.enqueue(steps.storage(cfg), "heldout", points)))
    protocol = {name: loop.step(f"protocol {name}", lambda name=name, o=overrides: loop.sweep(
        f"protocol_{name}", [*o, *cfg.protocol_fixed])) for name, overrides in cfg.protocol.items()}
    # 4. Rounds: each arm's generator searches the arm's detector of the round before; its failures join the arm's
    # suite; that detector is fine-tuned on as many of the suite's frames as every other arm's, with replay.
    suffix = f"_{cfg.variant}" if cfg.variant else ""
    detectors: dict[str, dict] = {"D0": {"arm": "D0", "round": 0, "seed": -1, **d0}}
    book = []  # the rounds' bookkeeping: per arm, round and seed, what the generator found and what was trained
    suites: dict[tuple[str, int], list] = {}
    for k in range(1, int(cfg.rounds) + 1):
        for seed in cfg.seeds:
            seed = int(seed)
            trained, generated = {}, {}
            for arm in cfg.arms:
                b = arm_budget(cfg, arm)
                prev = detectors["D0"] if k == 1 else detectors[f"{arm}_r{k - 1}_s{seed}{suffix}"]
                name = f"{arm}_r{k}_s{seed}{suffix}"
                label = f"round {k} arm {arm} seed {seed}{suffix}"
                found = loop.step(f"{label}: search", lambda name=name, arm=arm, b=b, p=prev:
                                  loop.study(f"gen_{name}", plans, int(b["trials"]), cfg.arms[arm].sampler,
                                             1000 * k + seed, [p["weights"]], startup=int(cfg.startup),
                                             frames=int(b["frames"]), extra=cfg.arms[arm].get("overrides") or ()))
                generated[arm] = found
                # Short of its frame budget at its cap of trials: stop before its fine-tuning (exit 1, kept).
                budget.check_spent(arm, found, int(b["frames"]), f"round {k}, seed {seed}{suffix}", str(loop.dir))
                budget.check_replay(cfg, replay_dirs, str(loop.dir))  # before its fine-tuning
                new = budget.joining(found, cfg.arms[arm].keep, float(cfg.hard_below))
                suites[(arm, seed)] = suite = suites.get((arm, seed), []) + new
                try:
                    frames, topped = budget.round_frames(suite, found, int(b["train_frames"]), seed * 100 + k)
                except ValueError as exc:  # the budget asks for more frames than the generator rendered
                    raise JobFault(f"round {k}, arm {arm}, seed {seed}: {exc} (in another dir or with variant=NAME); "
                                   f"the steps done so far are kept under {loop.dir}") from None
                listing = budget.write_list(data / f"{name}.yaml", frames, names)
                trained[arm] = loop.step(f"{label}: fine-tune", lambda name=name, b=b, p=prev,
                                         listing=listing, arm=arm: loop.train(
                    name, data=[listing], val=[base_val], base=p["weights"], epochs=int(b["epochs"]), seed=seed,
                    lr0=float(cfg.lr0), replay=replay_lists, study=f"gen_{name}", imgsz=int(b["imgsz"]),
                    replay_fraction=float(b["replay_fraction"]), calibrate=bool(base_pt), freeze=int(cfg.freeze)))
                detectors[name] = {"arm": arm, "round": k, "seed": seed, **trained[arm]}
                book.append({"arm": arm, "round": k, "seed": seed, "sampler": cfg.arms[arm].sampler,
                             "trials": sum(t.ran for t in found), "rejected": sum(t.rejected for t in found),
                             "rendered_frames": budget.rendered(found),
                             "failures": budget.failures(found, float(cfg.hard_below))[0],
                             "joined": len(new), "suite_scenarios": len(suite),
                             "train_frames": trained[arm]["train_frames"], "topped_up_frames": topped,
                             "failure_frames": budget.failure_frames(frames, suite + found, float(cfg.hard_below)),
                             "replay_frames": trained[arm]["replay_frames"], "epochs": trained[arm]["epochs"],
                             "imgsz": trained[arm]["imgsz"]})
            budget.assert_equal_budget(trained)
            budget.assert_equal_frames(generated, int(b["frames"]), f"round {k}, seed {seed}{suffix}", str(loop.dir))
    # 4b. WiSE-FT (`wise` < 1): each round's detector delivered as its weights mixed with D0's; the evaluation, its
    # results and report take the mix's name (results_VARIANT_wise50), so they sit beside the variant's own.
    if float(cfg.wise) < 1.0:
        suffix += wise_suffix(cfg)
        for name, d in detectors.items():
            if d["round"] >= 1:
                mixed = loop.step(f"{wise_suffix(cfg).lstrip('_')} {name}", lambda d=d, name=name: loop.wise(
                    name, d0["weights"], d["weights"], int(d.get("imgsz", cfg.imgsz))))
                d.update(weights=mixed["weights"], mixed_validation={k: mixed[k] for k in ("alpha", "map50", "recall")})
    # 5. Evaluation: every detector on the failure-rate sample (and its easy third), D0 and the last round on the
    # protocol suite and the real photos.
    last = {n: d for n, d in detectors.items() if d["round"] in (0, int(cfg.rounds))}
    easy = loop.step("easy suite", lambda: evaluate.easy_suite(loop.dir / "eval", held, d0, cfg))
    parts = heldout.parts(held, list(cfg.garages.heldout_families))  # new seeds / new family, on generated garages
    # The mixes' scores apart from the tuned weights' (kept per detector name): switching `wise` re-scores neither.
    scores = loop.step(f"evaluation{suffix}", lambda: evaluate.score_all(loop.dir / f"eval{wise_suffix(cfg)}", cfg,
                                                                         detectors, held, easy,
                                                               protocol, last, parts), always=True)
    photos = loop.step(f"real photos{suffix}", lambda: real_photos(loop, last), always=True)
    loop.times["total"] = sum(v for k, v in loop.times.items() if k != "total")
    from omegaconf import OmegaConf

    from garage_exp.loop.cells import cells_of
    from garage_exp.search.schema import SearchConf

    search = OmegaConf.structured(SearchConf)  # the generators' searches' descriptors: the search's, or the space's
    if schema.space_descriptors(cfg):
        search.descriptors = OmegaConf.structured(schema.space_descriptors(cfg))
    sample = {"garages": garages.label(cfg, "heldout"), "points": len(points), **heldout.acceptance(held, len(points))}
    from garage_exp.loop import curves

    return report.write(cfg, loop.dir / f"results{suffix}", scores, photos, book, detectors, loop.times,
                        cells=cells_of(held, search), search=search, sample=sample,
                        curves=curves.read(loop.dir / "train", detectors))


def wise_suffix(cfg) -> str:
    """What names the steps and results of detectors mixed with D0 (`wise` < 1): '_wise50' for 0.5; '' for none."""
    return f"_wise{round(100 * float(cfg.wise)):02d}" if float(cfg.wise) < 1.0 else ""


def verify_suffix(cfg) -> str:
    """What names a real-photo check: one per last round, variant, training seeds and mix, so that `rounds=K+1` or
    `'seeds=[0,1]'` in the same dir scores its own detectors instead of being refused as a step made from other
    inputs (adding a seed twice met that refusal, and the one-seed checks had to be moved aside by hand). The
    seeds are named only when they are not the default [0], so a one-seed dir keeps its steps."""
    seeds = [int(s) for s in cfg.seeds]
    return (f"_r{cfg.rounds}" + (f"_{cfg.variant}" if cfg.variant else "")
            + ("" if seeds == [0] else "_seeds" + "-".join(map(str, seeds))) + wise_suffix(cfg))


def real_photos(loop: Loop, detectors: dict) -> list[dict]:
    """The detectors through one `python -m garage_exp.verify` per real-photo set (every detector one of its
    models, linked under its loop name, so each gets its own recall and mAP50): D0 and the last round's."""
    import os

    from garage_exp.results.photos import write_photos, write_street_photos

    sets = []
    if loop.cfg.photos:  # the two photos ultralytics ships, and the street set fetched at set-up
        for label, write in (("photos", write_photos), ("street", write_street_photos)):
            root = loop.dir / label
            if not (root / "coco.json").is_file():
                write(root)
            sets.append((label, str(root / "coco.json")))
    sets += [(f"real{k}", str(p)) for k, p in enumerate(loop.cfg.real_sets)]
    models = loop.dir / "verify" / "models"
    models.mkdir(parents=True, exist_ok=True)
    linked = {}
    for name, d in detectors.items():
        link = models / f"{name}.pt"  # the detector's name in verify's metrics is its file's stem
        if link.is_symlink() and os.readlink(link) != str(Path(d["weights"]).absolute()):
            link.unlink()
        if not link.exists():
            link.symlink_to(Path(d["weights"]).absolute())
        linked[name] = link
    rows = []
    suffix = verify_suffix(loop.cfg)
    for label, data in sets:
        m = loop.verify(f"{label}{suffix}", data, [str(p) for p in linked.values()])["metrics"]
        for name, d in detectors.items():
            rows.append({"detector": name, "arm": d["arm"], "round": d["round"], "seed": d["seed"], "set": label,
                         "recall": m[f"recall/{name}"], "map50": m[f"map50/{name}"], "objects": m.get("targets")})
    return rows


def main(cfg: DictConfig) -> dict:
    from garage_exp.tracking.runs import tracking_uri

    from garage_exp.loop.check import check_steps

    check_loop(cfg)  # bad input: the shell removes Hydra's log dir (and `dir` if it made it) and says it in one line
    check_steps(cfg)  # what the steps would refuse, before the first (an estimate too: it is of a loop that can run)
    if cfg.estimate:
        from garage_exp.loop.cost import describe, estimate, power_line

        parts = estimate(cfg)
        print(f"garage_exp.loop: estimate: {describe(parts)}")
        print(f"garage_exp.loop: {power_line(cfg)}")
        return parts
    with open_dict(cfg):
        cfg.tracking.uri = tracking_uri(cfg.tracking.uri)  # every step's store, also for models:/ entries
        cfg.dir = str(Path(str(cfg.dir)).absolute())
    return run_loop(cfg)


def cli(argv: list[str] | None = None) -> None:
    """`python -m garage_exp.loop overrides...`. Exit codes: 0 done; 2 bad input (one line, nothing written);
    1 a failed step or a crash (traceback); 130 Ctrl-C, 143 SIGTERM (the running step is stopped the same way,
    its run ends KILLED; rerunning the command goes on where it stopped). `estimate=true` writes nothing: Hydra's
    run dir (its log) is then a temporary folder, removed after."""
    import shutil
    import sys
    import tempfile

    argv = schema.space_by_name(schema.space_config(list(sys.argv[1:] if argv is None else argv)))
    if not estimating(argv):
        COMMAND.run(main, argv)
        return
    scratch = tempfile.mkdtemp(prefix="garage_exp_loop_estimate_")
    try:
        COMMAND.run(main, [*argv, f"hydra.run.dir={scratch}"])
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


def estimating(argv: list[str]) -> bool:
    """Whether the command line asks for the estimate alone (`estimate=true`, as Hydra reads a bool)."""
    from hydra.core.override_parser.overrides_parser import OverridesParser

    try:
        overrides = OverridesParser.create().parse_overrides([a for a in argv if "=" in a and not a.startswith("-")])
    except Exception:  # noqa: BLE001 - a bad override: the command itself says it in one line
        return False
    values = [o.value() for o in overrides if o.key_or_group == "estimate" and not o.is_delete()]
    return bool(values) and str(values[-1]).lower() in ("true", "1", "yes", "on")
