"""The verify entry point: check the config, the data and the detector, then score, track and report.

Bad input is one line on stderr and exit code 2 with nothing written: no MLflow run, no output dir (Hydra makes
one before the task starts; it is removed while it holds only Hydra's files).
"""

from __future__ import annotations

import json
from pathlib import Path

from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig

from garage_exp.core.plain import settings
from garage_exp.core import shell
from garage_exp.core.errors import GarageError
from garage_exp.verify import schema

COMMAND = shell.Command("garage_exp.verify", "verify", (schema.register,))


def check_verify(cfg: DictConfig) -> None:
    """The config's values (the schema checked the types; unknown keys are refused here), then the detector's."""
    from garage_exp.core.schema_check import refuse_unknown_keys
    from garage_exp.perception.detect.detector import check_detector

    refuse_unknown_keys(cfg, schema.VerifyConf)
    if str(cfg.split) not in ("train", "val", "test"):
        raise GarageError(f"{cfg.split!r} is not one of train, val, test", "split")
    check_detector(settings(cfg.detector))


def load_detector(cfg: DictConfig):
    """The configured detector through the one factory, every entry loaded and probed (missing weights, an
    unreachable server, a class map that matches nothing: GarageError naming the entry)."""
    from garage_exp.perception.detect import build_detector

    detector = build_detector(settings(cfg.detector))
    detector.check()
    return detector


def check_scored(data, groups: dict) -> None:
    """Some labelled object must be of a class the detector is scored on (after label_map)."""
    scored = set(groups["classes"]) | set(groups["person_classes"])
    labelled = sorted({c for im in data.images for c in im.classes})
    if not scored & set(labelled):
        shown = ", ".join(labelled[:8]) + (", ..." if len(labelled) > 8 else "")
        raise GarageError(f"data: no labelled object of the scored classes ({', '.join(sorted(scored))}); its labels "
                          f"are {shown}: rename them with label_map, e.g. '+label_map.{labelled[0]}=car'",
                          str(data.source))


def detector_title(group: str, models: list[str]) -> str:
    """What was run: the detector group's name with its models, or only the models when the command line replaced
    the group's (`detector.models=[...]`: the group's name would name models that were not run)."""
    task = HydraConfig.get().overrides.task if HydraConfig.initialized() else []
    replaced = any(o.lstrip("+~").split("=")[0] == "detector.models" for o in task)
    return ", ".join(models) if replaced else f"{group} ({', '.join(models)})"


def verify(cfg: DictConfig) -> dict:
    """Check, then score, log and report; returns what result.json holds."""
    from garage_exp.verify.data import read_set

    out = Path(HydraConfig.get().runtime.output_dir)
    check_verify(cfg)  # bad input: the shell removes the run dir and says it in one line
    data = read_set(str(cfg.data), dict(cfg.label_map), str(cfg.split), cfg.images)
    detector = load_detector(cfg)
    check_scored(data, detector.scoring())
    from garage_exp.tracking import runs as tracking
    from garage_exp.verify.report import verdict, write_report
    from garage_exp.verify.score import score, summary

    d = cfg.detector
    what = detector_title(str(d.name), list(detector.names))
    name = str(cfg.name) or f"{what} on {Path(str(data.source)).parent.name}/{Path(str(data.source)).name}"
    tags = {"kind": "verify", "data": str(data.source), "output_dir": str(out), "rendered": str(data.rendered).lower()}
    run = tracking.start_job_run(settings(cfg), name, tags, None)
    with tracking.tracked_run(run):  # ends FINISHED, or KILLED/FAILED with the error
        groups = detector.scoring()  # the listed classes plus detector.class_map's
        scored = score(lambda rgb: detector.detect([rgb])[0], list(detector.names), data, groups["classes"],
                       groups["person_classes"], float(d.iou), float(d.threshold))
        metrics = summary(scored, float(d.threshold))
        report = out / "report"
        report.mkdir(parents=True, exist_ok=True)
        write_report(report / "report.md", data, what, scored, metrics, float(d.threshold), float(d.iou))
        scored.objects.to_csv(report / "objects.csv", index=False)
        scored.images.to_csv(report / "images.csv", index=False)
        run.log_metrics({k: v for k, v in metrics.items() if v == v})  # NaN (an empty band) is left out
        tracking.log_report(run.mlc, run.run_id, report)
    summary_ = {"run_id": run.run_id, "report": str(report / "report.md"), "rendered": data.rendered,
                "metrics": metrics}
    (out / "result.json").write_text(json.dumps(summary_, indent=1))
    print(f"garage_exp.verify: {len(data.images)} images, {len(scored.objects)} labelled objects: recall "
          f"{metrics['recall']:.3f}, mAP50 {metrics['map50']:.3f}, {metrics['fp_per_image']:.2f} false positives "
          f"per image. {verdict(metrics, data.rendered)}")
    print(f"garage_exp.verify: report {report / 'report.md'}")
    return summary_


def cli(argv: list[str] | None = None) -> None:
    """`python -m garage_exp.verify overrides...`. Exit codes: 0 done; 2 bad input (one line, nothing written);
    1 a crash (traceback); 130 Ctrl-C, 143 SIGTERM (the run ends KILLED)."""
    COMMAND.run(verify, argv)
