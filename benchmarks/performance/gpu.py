"""The GPU path against the CPU one (issue 24, part 4): `python -m benchmarks.performance.gpu`.

Measures on this machine, in one run:
  render    frames/s of the render stage (lit picture, silhouettes, ground truth, sensor) at 640x480, on the tiny
            and the research (default) plan, case 1, renderer.device=auto (the GPU's Vulkan driver where there is
            one, else lavapipe); the first frame (shader compilation) left out;
  detect    images/s of each detector on the research plan's frames: the three OpenVINO INT8 exports (CPU always)
            and a yolo11n .pt of random weights (from ultralytics' yolo11n.yaml: speed does not depend on the
            weights) on the CPU and, where torch sees CUDA, on cuda:0;
  sweep     wall seconds of `make run`'s sweep (RUN_ARGS: 12 jobs), as its own process;
  search    trials/hour of a search (benchmarks/studies/search.py's case-1 scenario and space), as its own process;
  train     images/s of one training epoch (--epochs: more, each epoch's rate from the run's MLflow metrics) (`python -m garage_exp.train`, yolo11n.yaml from scratch, imgsz 640,
            device=auto) on the frames of a `dataset=true` sweep of cases 1-3.
Parts that need a GPU are skipped with a message on a CPU-only machine. The numbers go to --out (JSON, written
after each part, so a run stopped early keeps what it measured); `--against OTHER.json` (another machine's run)
prints this run's numbers over the other's.

Run: .venv/bin/python -m benchmarks.performance.gpu [--only render,detect,sweep,search,train] [--trials 200]
     [--frames 60] [--epochs 1] [--out FILE] [--against FILE|none]
The GPU machine's numbers are kept in benchmarks/results/gpu_cuda.md, this CPU machine's in results/gpu_cpu.md: a run
on either prints its numbers over the other's.
"""

from __future__ import annotations

import argparse
import glob
import json
import os
import platform
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks.common import RESULTS, read_json_page, write_json_page
PARTS = ("render", "detect", "sweep", "search", "train")
RUN_ARGS = ["-m", "light=bright,dim", "case=1,2,3", "replicates=2"]  # the Makefile's RUN_ARGS
RATES = ("render_fps", "detect_ips", "sweep_s", "search_trials_per_hour", "train_ips")  # compared between machines


def machine() -> dict:
    info = {"cpu": platform.processor() or platform.machine(), "cores": os.cpu_count(), "python": platform.python_version()}
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                info["cpu"] = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    try:
        import torch

        info["torch"] = torch.__version__
        info["cuda"] = torch.cuda.get_device_name(0) if torch.cuda.is_available() else None
    except Exception as exc:  # noqa: BLE001 - only a description
        info["cuda"] = f"torch failed: {exc}"
    return info


def cuda() -> bool:
    from garage_exp.perception.detect.detector import cuda_available

    return cuda_available()


def measure_render(frames: int) -> dict:
    from benchmarks import jobkit

    from garage_exp.render.device import ensure_device

    out = {"vulkan_device": ensure_device()}
    for plan in ("tiny", "research"):
        job = jobkit.build_job([f"plan={plan}", "case=1", "light=bright"])  # first frame rendered (shaders)
        shots = len(job.setup.shots)
        done, start = 0, time.perf_counter()
        while done < frames:
            for _ in job.frames(min(shots, frames - done)):
                done += 1
        wall = time.perf_counter() - start
        out[f"render_fps_{plan}"] = done / wall
        print(f"render {plan}: {done} frames at 640x480 in {wall:.2f} s = {done / wall:.1f} frames/s", flush=True)
        if plan == "research":
            measure_render.rgb = [item.rgb for item in job.frames(min(shots, 20))]
    return out


def random_pt(folder: Path) -> Path:
    """yolo11n with random weights, saved as a .pt (no official weights are downloaded)."""
    import yaml
    from ultralytics import YOLO
    from ultralytics.utils import ROOT as ULTRALYTICS

    path = folder / "yolo11n_random.pt"
    if not path.exists():
        model = YOLO("yolo11n.yaml")
        # The COCO class names, so that the detector's car/truck/bus classes exist (the YAML numbers them only).
        model.model.names = yaml.safe_load((ULTRALYTICS / "cfg/datasets/coco.yaml").read_text())["names"]
        model.save(str(path))
    return path


def measure_detect(frames: int, work: Path) -> dict:
    from garage_exp.assets.locate import models_dir
    from garage_exp.perception.detect.detector import Detector

    rgb = getattr(measure_render, "rgb", None)
    if rgb is None:
        from benchmarks import jobkit

        job = jobkit.build_job(["plan=research", "case=1", "light=bright"])
        rgb = [item.rgb for item in job.frames(min(len(job.setup.shots), 20))]
    out = {}
    pt = random_pt(work)
    runs = [(p.name.replace("_openvino_model", ""), p, "cpu") for p in sorted(models_dir().glob("*_openvino_model"))]
    runs.append(("yolo11n_random.pt cpu", pt, "cpu"))
    if cuda():
        runs.append(("yolo11n_random.pt cuda", pt, "cuda"))
    else:
        print("detect: skipping the .pt on CUDA: torch sees no CUDA GPU here", flush=True)
    for label, path, device in runs:
        det = Detector(models=[path], device=device)
        det.detect(rgb[0])  # warm-up (CUDA kernels, OpenVINO's first infer)
        start, done = time.perf_counter(), 0
        while done < frames:
            det.detect(rgb[done % len(rgb)])
            done += 1
        wall = time.perf_counter() - start
        key = "detect_ips_" + re.sub(r"[^a-z0-9]+", "_", label.lower()).strip("_")
        out[key] = done / wall
        print(f"detect {label} on {det.devices[0]}: {done} images in {wall:.2f} s = {done / wall:.1f} images/s",
              flush=True)
    return out


def app(args: list[str], work: Path, timeout: float, module: str = "garage_exp") -> tuple[float, str]:
    """Run `python -m module args` in its own process; its wall seconds and its output."""
    env = {**os.environ, "YOLO_OFFLINE": "1", "PYTHONUNBUFFERED": "1"}
    start = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", module, *args], cwd=work, env=env, text=True,
                          stdout=subprocess.PIPE, stderr=subprocess.STDOUT, timeout=timeout)
    wall = time.perf_counter() - start
    if proc.returncode:
        raise RuntimeError(f"{module} {' '.join(args)} exited {proc.returncode}: {proc.stdout[-2000:]}")
    return wall, proc.stdout


def measure_sweep(work: Path, timeout: float) -> dict:
    sweep = work / "sweep"
    wall, _ = app([*RUN_ARGS, f"tracking.uri=sqlite:///{work}/mlflow.db", f"hydra.sweep.dir={sweep}"], work, timeout)
    jobs = len(glob.glob(str(sweep / "*" / ".hydra")))
    print(f"sweep ({' '.join(RUN_ARGS)}): {jobs} jobs in {wall:.1f} s (process start included)", flush=True)
    return {"sweep_s": wall, "sweep_jobs": jobs}


def measure_search(work: Path, trials: int, timeout: float) -> dict:
    from bench_search import SCENARIO, SPACE

    args = ["-m", "hydra/sweeper=search", *SCENARIO, *SPACE, f"search.trials={trials}", "search.sampler=random",
            f"search.storage=sqlite:///{work}/optuna.db", f"tracking.uri=sqlite:///{work}/mlflow_search.db",
            f"hydra.sweep.dir={work}/search"]
    wall, _ = app(args, work, timeout)
    print(f"search: {trials} trials in {wall:.1f} s = {3600 * trials / wall:.0f} trials/hour (process start "
          "included)", flush=True)
    return {"search_s": wall, "search_trials": trials, "search_trials_per_hour": 3600 * trials / wall}


def epoch_rates(uri: str) -> list[float]:
    """train_images_per_s of each epoch (the app prints their mean; the first epoch carries the warm-up)."""
    import mlflow

    client = mlflow.MlflowClient(tracking_uri=uri)
    rates = []
    for exp in client.search_experiments():
        for run in client.search_runs([exp.experiment_id]):
            history = client.get_metric_history(run.info.run_id, "train_images_per_s")
            rates += [m.value for m in sorted(history, key=lambda m: m.step) if m.step > 0]
    return rates


def measure_train(work: Path, timeout: float, epochs: int) -> dict:
    data = work / "data"
    wall, _ = app(["-m", "case=1,2,3", "dataset=true", f"tracking.uri=sqlite:///{work}/mlflow_data.db",
                   f"hydra.sweep.dir={data}"], work, timeout)
    jobs = sorted(str(Path(p).parent.parent) for p in glob.glob(str(data / "*" / "dataset" / "data.yaml")))
    images = len(glob.glob(str(data / "*" / "dataset" / "images" / "*")))
    print(f"train data: {len(jobs)} jobs, {images} images in {wall:.1f} s", flush=True)
    uri = f"sqlite:///{work}/mlflow_train.db"
    wall, text = app([f"data=[{','.join(jobs)}]", "base=yolo11n.yaml", f"epochs={epochs}", "imgsz=640",
                      f"tracking.uri={uri}"], work, timeout, module="garage_exp.train")
    found = re.findall(r"([0-9.]+) images/s on (\S+)", text)
    if not found:
        raise RuntimeError(f"no 'images/s on' line in the training's output: {text[-1500:]}")
    ips, device = float(found[-1][0]), found[-1][1]
    rates = epoch_rates(uri)
    print(f"train: {epochs} epoch(s), {images} images, {ips:.1f} images/s on {device} (per epoch: "
          f"{', '.join(f'{r:.1f}' for r in rates)}; {wall:.1f} s with start-up)", flush=True)
    out = {"train_ips": ips, "train_device": device, "train_images": images, "train_s": wall,
           "train_epoch_ips": rates}
    if len(rates) > 1:
        out["train_ips_after_first_epoch"] = sum(rates[1:]) / len(rates[1:])
    return out


def compare(mine: dict, other: dict) -> None:
    print(f"\nthis run ({mine['machine'].get('cuda') or mine['machine']['cpu']}) over the other "
          f"({other['machine'].get('cuda') or other['machine']['cpu']}):")
    # The .pt detector on CUDA against the same .pt on the CPU of the machine that has no CUDA.
    for gpu, cpu in ((mine, other), (other, mine)):
        if "detect_ips_yolo11n_random_pt_cuda" in gpu and "detect_ips_yolo11n_random_pt_cpu" in cpu:
            print(f"  .pt detector, CUDA over the CPU-only machine's CPU: "
                  f"{gpu['detect_ips_yolo11n_random_pt_cuda'] / cpu['detect_ips_yolo11n_random_pt_cpu']:.2f}x")
    for key, value in mine.items():
        if not key.startswith(RATES):
            continue
        if key in other and isinstance(value, float) and isinstance(other[key], float) and other[key]:
            lower_is_better = key.endswith("_s")
            ratio = other[key] / value if lower_is_better else value / other[key]
            print(f"  {key}: {value:.2f} vs {other[key]:.2f} -> {ratio:.2f}x {'faster' if ratio >= 1 else 'slower'}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", default=",".join(PARTS))
    parser.add_argument("--frames", type=int, default=60, help="frames rendered, and images detected, per setting")
    parser.add_argument("--trials", type=int, default=200)
    parser.add_argument("--epochs", type=int, default=1, help="training epochs (the first one carries the warm-up)")
    parser.add_argument("--timeout", type=float, default=1800, help="seconds for each child process")
    parser.add_argument("--out", help="default: benchmarks/results/gpu_cuda.md where torch sees CUDA, else "
                        "benchmarks/results/gpu_cpu.md")
    parser.add_argument("--against", help="another machine's --out, to print ratios (default: the other of those "
                        "two files, when it exists; 'none': no ratios)")
    opts = parser.parse_args()
    parts = [p for p in opts.only.split(",") if p]
    unknown = set(parts) - set(PARTS)
    if unknown:
        parser.error(f"unknown parts {sorted(unknown)} (of {', '.join(PARTS)})")
    os.environ.setdefault("YOLO_OFFLINE", "1")
    from garage_exp.render.device import nvidia_icd

    mine, other = ("cuda", "cpu") if cuda() else ("cpu", "cuda")
    out = Path(opts.out or RESULTS / f"gpu_{mine}.md")
    against = opts.against or str(RESULTS / f"gpu_{other}.md")

    result = {"machine": machine(), "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
              "load_before": os.getloadavg()[0]}
    if nvidia_icd() is None:
        print("render: no NVIDIA GPU with a Vulkan ICD here: rendering runs on the CPU (lavapipe)", flush=True)
    if not cuda():
        print("cuda: torch sees no CUDA GPU here: the .pt detector and the training run on the CPU", flush=True)
    print(json.dumps(result["machine"]), flush=True)
    work = Path(tempfile.mkdtemp(prefix="bench_gpu_"))
    for part in parts:
        try:
            if part == "render":
                result.update(measure_render(opts.frames))
            elif part == "detect":
                result.update(measure_detect(opts.frames, work))
            elif part == "sweep":
                result.update(measure_sweep(work, opts.timeout))
            elif part == "search":
                result.update(measure_search(work, opts.trials, opts.timeout))
            else:
                result.update(measure_train(work, opts.timeout, opts.epochs))
        except Exception as exc:  # noqa: BLE001 - report and go on with the other parts
            print(f"{part}: FAILED {type(exc).__name__}: {str(exc)[-1500:]}", flush=True)
            result[f"{part}_failed"] = str(exc)[-500:]
        result["load_after"] = os.getloadavg()[0]
        write_json_page(out, f"bench_gpu on {result['machine'].get('cuda') or result['machine']['cpu']}", result)
    print(json.dumps(result, indent=1))
    if against != "none" and Path(against).is_file():
        compare(result, read_json_page(Path(against)))
    elif against != "none":
        print(f"no {against}: no ratios (run this on the other machine first)")


if __name__ == "__main__":
    main()
