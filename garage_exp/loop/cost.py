"""The loop's cost model: how long a config takes, from rates measured on the machine (`cost` in conf/loop.yaml;
docs/loop.md says how they were measured). `python -m garage_exp.loop estimate=true` prints it and stops; the
loop prints it before it starts. Steps already done cost nothing when a loop resumes (not counted here).

The wide space's rates (conf/loop_wide.yaml's `cost`) were refitted on the measured run of 2026-12-06 (docs/loop.md,
"The measured run on the wide space"; commits 489c8de and f2d8a00, the shared 2-core CPU at load 2-5), from its
steps' times (times.json) and its studies' trials (Optuna's start and end of each):
  generators: 48 rendered scenarios in 51-73 trials, 62-80 s a search of which 22-23 s its start, check and
  analysis (search_s 30); a trial 0.74 s rendered or not (trial_overhead_s 0.45 + frames_per_trial 0.62 x
  render_s_per_frame 0.5); a rejected draw 0.16 s (reject_s), 1,024 of 1,353 held-out draws accepted (acceptance 0.76);
  the held-out study: 1,024 trials in 2,172 s, with its start (about 60 s) and analysis (150 s, fANOVA on a sample of
  300) 2,380 s: heldout_trial_s 2.33;
  fine-tunings of 96 images x 10 epochs with 22 validation scenarios: 61-65 s (train_s_per_image_epoch 0.05,
  val_s_per_image 0.05); the protocol's 14 jobs 113 s (protocol_job_s 5.2 with command_s 10); evaluation 102 s;
  the loop's check of its steps 35 s (check_s).
The estimate: 1.06 h; the run's steps: 1.0 h. D0 failed 313 of the 631 held-out scenarios: power.pilot_rate 0.50.
"""

from __future__ import annotations


def detectors(cfg) -> int:
    """D0 and one fine-tuned detector per arm, round and training seed."""
    return 1 + len(cfg.arms) * int(cfg.rounds) * len(cfg.seeds)


def estimate(cfg) -> dict[str, float]:
    """Seconds per part of the loop, and `total`."""
    c = cfg.cost
    # A space with requirements redraws what they reject: every trial costs its rejected draws too.
    redraw = (1.0 / float(c.acceptance) - 1.0) * float(c.reject_s)
    per_trial = c.trial_overhead_s + c.frames_per_trial * c.render_s_per_frame + redraw

    def study(trials: int) -> float:
        return c.search_s + trials * per_trial

    runs = len(cfg.arms) * int(cfg.rounds) * len(cfg.seeds)  # searches, and as many fine-tunings
    if int(cfg.get("frames") or 0) > 0:  # a frame budget: crossed, on average, by half a trial's frames
        spent = int(cfg.frames) + c.frames_per_trial / 2
        generator = c.search_s + spent * c.render_s_per_frame + spent / c.frames_per_trial * (c.trial_overhead_s
                                                                                            + redraw)
    else:
        generator = study(int(cfg.trials))
    images = int(cfg.train_frames) * (1.0 + float(cfg.replay_fraction))
    val_frames = float(cfg.val_fraction) * int(cfg.base_trials) * c.frames_per_trial
    epochs = int(cfg.epochs)
    training = c.command_s + epochs * images * c.train_s_per_image_epoch + (epochs + 1) * val_frames * c.val_s_per_image
    protocol_jobs = sum(_jobs(overrides) for overrides in cfg.protocol.values())
    job_s = per_trial if c.get("protocol_job_s") is None else float(c.protocol_job_s)
    job_frames = c.frames_per_trial if c.get("protocol_frames_per_job") is None else float(c.protocol_frames_per_job)
    last = 1 + len(cfg.arms) * len(cfg.seeds)  # D0 and the last round's detectors: every suite
    held_frames = int(cfg.heldout_trials) * c.frames_per_trial
    out = {"base data": study(int(cfg.base_trials)),
           "held-out sample": study(int(cfg.heldout_trials)) if c.get("heldout_trial_s") is None
           else c.search_s + int(cfg.heldout_trials) * float(c.heldout_trial_s),
           "protocol suite": len(cfg.protocol) * c.command_s + protocol_jobs * job_s,
           "generators": runs * generator,
           "fine-tunings": runs * training,
           "evaluation": detectors(cfg) * (c.load_s + held_frames * c.detect_s_per_frame)
           + last * protocol_jobs * job_frames * c.detect_s_per_frame,
           "real photos": (2 * int(bool(cfg.photos)) + len(cfg.real_sets)) * (c.command_s + last * c.verify_s)}
    pools = [int(p.trials) for p in (cfg.get("replay_pool") or {}).values() if int(p.trials) > 0]
    if pools:
        out["replay pools"] = sum(study(n) for n in pools)
    if float(c.get("check_s") or 0) > 0:
        out["checks"] = float(c.check_s)
    if not str(cfg.base).endswith(".pt"):
        out["D0"] = c.command_s + int(cfg.base_epochs) * (1 - float(cfg.val_fraction)) * int(cfg.base_trials) \
            * c.frames_per_trial * c.train_s_per_image_epoch
    out["total"] = sum(out.values())
    return out


def _jobs(overrides) -> int:
    """Jobs of a sweep's overrides: the product of comma lists (an experiment's own sweep: CPNCO's 6 and CPRA's 4
    jobs in the shipped ones, 4 for a user's)."""
    n = 1
    for o in overrides:
        if o.startswith("+experiment="):
            n *= {"cpnco": 6, "cpra": 4}.get(o.split("=", 1)[1], 4)
        elif "=" in o and "," in o.split("=", 1)[1] and "(" not in o:
            n *= len(o.split("=", 1)[1].split(","))
    return n


def describe(parts: dict[str, float]) -> str:
    return ", ".join(f"{k} {v / 60:.0f} min" for k, v in parts.items() if k != "total") + \
        f"; total {parts['total'] / 3600:.2f} h"


def comparisons(cfg) -> int:
    """The comparisons the report corrects as one Holm family (report.comparisons): every pair of arms and each
    arm against D0 on the failure rate, and each arm against D0 on the protocol and the real photos' recall."""
    arms = len(cfg.arms)
    per_arm = 1 + int(bool(cfg.protocol)) + int(bool(cfg.photos) or bool(cfg.real_sets))
    return arms * (arms - 1) // 2 + arms * per_arm


def power_line(cfg) -> str:
    """The power estimate in words (loop/stats.py, scenarios_for), from the config's pilot failure rate."""
    from garage_exp.loop.stats import scenarios_for

    p, m = cfg.power, comparisons(cfg)
    n = scenarios_for(float(p.pilot_rate), float(p.relative), m, float(p.alpha), float(p.power))
    scenarios = int(int(cfg.heldout_trials) * float(p.scenario_share))  # less the infeasible draws
    paired = paired_power(cfg, m)
    # the verdict uses the paired test when the loop has one seed: a measured discordant share sizes it
    need = paired[1] if paired else n
    enough = "enough" if scenarios >= need else "too few"
    test = " for the paired test" if paired else ""
    return (f"power: at a pilot failure rate of {float(p.pilot_rate):.2f}, {n} held-out scenarios per detector "
            f"detect {100 * float(p.relative):.0f} % fewer failures ({float(p.pilot_rate):.3f} -> "
            f"{float(p.pilot_rate) * (1 - float(p.relative)):.3f}) at alpha {float(p.alpha):g} (Holm over {m} "
            f"comparisons), power {float(p.power):g}" + (paired[0] if paired else "") + f"; this config's "
            f"heldout_trials={int(cfg.heldout_trials)} hold about {scenarios} scenarios: {enough}{test}")


def paired_power(cfg, m: int) -> tuple[str, int] | None:
    """McNemar's scenarios for the same difference when every detector scores the same scenarios, from the
    pilot's discordant share (power.pilot_discordant), in words and as a number; None when none was measured."""
    from garage_exp.loop.stats import scenarios_for_paired

    p = cfg.power
    if p.get("pilot_discordant") is None:
        return None
    share = max(float(p.pilot_discordant), float(p.pilot_rate) * float(p.relative))  # below the difference: impossible
    n = scenarios_for_paired(float(p.pilot_rate), share, float(p.relative), m, float(p.alpha), float(p.power))
    return f"; paired by scenario (McNemar, a pilot's discordant share {share:.2f}): {n}", n
