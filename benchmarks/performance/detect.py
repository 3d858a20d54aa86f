"""Cheaper detection per frame, measured: `python -m benchmarks.performance.detect [--frames 24] [--repeat 3]`.

The three INT8 OpenVINO detectors on the frames of a case-1 job (research plan), 1 OpenVINO thread per model
as in the job's detector child. Variants, all through ultralytics' own pre- and post-processing functions, so
that only the named change differs:
  today      `Detector.detect`: `model.predict` per model (letterbox 640 x 640 each time), batch 1, LATENCY
  shared     one letterbox per frame for the three models, then each model's `inference` + `postprocess`
  rect       as shared, with each network reshaped to 1 x 3 x 480 x 640: the 640 x 480 frame needs no padding
  batch4     as shared, networks reshaped to batch 4, four consecutive frames per call
  async3     as shared, the three networks started together (OpenVINO infer requests), then waited for
rect and batch4 run only where OpenVINO can reshape every network; otherwise the reason is printed (the shipped
static exports fix shapes inside the graph). Columns: wall and CPU seconds per frame (median over repeats; this process, all threads), CPU against
today's, and the largest change of any frame's composite confidence (the job's `score_target` with the job's
ground truth) against today's. Adopt only a variant that moves no composite by more than 1e-3 (issue 13).
"""

from __future__ import annotations

import argparse
import os
import statistics

from benchmarks import jobkit
import numpy as np

TOLERANCE = 1e-3


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=24)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    import openvino as ov

    from garage_exp.perception.detect import score_target
    from garage_exp.core.plugins import build
    from garage_exp.perception.detect.detector import Detector, ModelDetections

    print(f"# detection, case 1, {args.frames} frames, {args.repeat} repeats; {jobkit.machine()}")
    print(f"# before: {jobkit.load()}")
    job = jobkit.build_job(["case=1", "light=bright"])
    cfg = job.cfg
    frames = list(job.frames(args.frames))
    detector = Detector(**build(cfg.detector, "a detector", "detector._target_"), threads=1)
    models = detector._models
    predictors = [m.predictor for m in models]
    core = ov.Core()
    config = {"PERFORMANCE_HINT": "LATENCY", "INFERENCE_NUM_THREADS": 1}

    refused = {}

    original = [p.model.backend.ov_compiled_model for p in predictors]

    def compiled(variant, shape):
        """Each network reshaped to `shape`; a network that cannot be keeps its own shape (reason kept), and
        the variant then runs on the others only when shapes still agree (batch), else it is dropped."""
        nets = []
        for path, orig in zip(detector.paths, original):
            net = core.read_model(str(next(path.glob("*.xml"))))
            try:
                net.reshape(shape)
                nets.append(core.compile_model(net, "CPU", config))
            except RuntimeError as exc:  # static exports fix shapes inside the graph (attention views)
                why = next((ln for ln in str(exc).splitlines() if "While" in ln), str(exc))
                refused.setdefault(variant, []).append(f"{path.name}: {why[:160]}")
                nets.append(None)
        return nets

    rect = compiled("rect", [1, 3, 480, 640])
    batch4 = compiled("batch4", [4, 3, 640, 640])

    def to_dets(name, result, ms=0.0):
        boxes = result.boxes
        return ModelDetections(name, boxes.xyxy.cpu().numpy().astype(np.float32).reshape(-1, 4),
                               boxes.conf.cpu().numpy().astype(np.float32).reshape(-1),
                               [result.names[int(k)] for k in boxes.cls.cpu().numpy()], ms)

    def run_shared(bgrs, nets, imgsz=(640, 640)):
        first = predictors[0]
        first.imgsz = imgsz
        try:
            im = first.preprocess(bgrs)  # the letterbox every model of the frame shares
        finally:
            first.imgsz = (640, 640)
        out = [[] for _ in bgrs]
        for name, p, net, orig in zip(detector.names, predictors, nets, original):
            p.model.backend.ov_compiled_model = net
            p.batch = [[f"frame{k}" for k in range(len(bgrs))]]
            try:
                results = p.postprocess(p.inference(im), im, bgrs)
            finally:
                p.model.backend.ov_compiled_model = orig
            for k, r in enumerate(results):
                out[k].append(to_dets(name, r))
        return out

    def variant_today():
        return [detector.detect(f.rgb) for f in frames]

    def variant_shared():
        out = []
        for f in frames:
            out += run_shared([np.ascontiguousarray(f.rgb[..., ::-1])], original)
        return out

    def variant_rect():
        out = []
        for f in frames:
            out += run_shared([np.ascontiguousarray(f.rgb[..., ::-1])], rect, (480, 640))
        return out

    def variant_batch4():
        out = []
        for k in range(0, len(frames), 4):
            bgrs = [np.ascontiguousarray(f.rgb[..., ::-1]) for f in frames[k:k + 4]]
            bgrs += [bgrs[-1]] * (4 - len(bgrs))  # pad the last batch
            out += run_shared(bgrs, batch4)[: len(frames[k:k + 4])]
        return out

    def variant_async3():
        import torch

        out = []
        requests = [net.create_infer_request() for net in original]
        for f in frames:
            bgr = np.ascontiguousarray(f.rgb[..., ::-1])
            im = predictors[0].preprocess([bgr])
            array = im.cpu().numpy().astype(np.float32, copy=False)
            for req in requests:
                req.start_async({0: array})
            dets = []
            for name, p, req in zip(detector.names, predictors, requests):
                req.wait()
                preds = [torch.from_numpy(req.get_output_tensor(i).data.copy()) for i in range(len(req.model_outputs))]
                preds = preds[0] if len(preds) == 1 else preds
                p.batch = [["frame0"]]
                dets.append(to_dets(name, p.postprocess(preds, im, [bgr])[0]))
            out.append(dets)
        return out

    variants = {"today": variant_today, "shared": variant_shared, "async3": variant_async3}
    if all(n is not None for n in rect):
        variants["rect"] = variant_rect
    if all(n is not None for n in batch4):
        variants["batch4"] = variant_batch4

    def composites(all_dets):
        out = []
        for f, dets in zip(frames, all_dets):
            s = score_target(dets, f.target, f.truth, iou_threshold=cfg.detector.iou, match=cfg.detector.match,
                             threshold=cfg.detector.threshold, classes=tuple(cfg.detector.classes),
                             person_classes=tuple(cfg.detector.person_classes))
            out.append(s.composite)
        return np.array(out)

    def raw_inference():
        """Per reshapable network: CPU s per frame of inference alone at 640 x 640 (batch 1), 480 x 640, and
        640 x 640 in batches of 4; and the largest change of its best car/truck/bus confidence per frame."""
        import torch

        rows = []
        for name, p, orig, r, b in zip(detector.names, predictors, original, rect, batch4):
            ims = [p.preprocess([np.ascontiguousarray(f.rgb[..., ::-1])]).numpy() for f in frames]
            first = predictors[0]
            first.imgsz = (480, 640)
            ims_rect = [first.preprocess([np.ascontiguousarray(f.rgb[..., ::-1])]).numpy() for f in frames]
            first.imgsz = (640, 640)
            out = {"model": name}
            for label, net, batch in (("640", orig, ims), ("rect", r, ims_rect)):
                if net is None:
                    continue
                t0 = jobkit.cpu_seconds()
                preds = [net(x)[0] for x in batch]
                out[label] = (jobkit.cpu_seconds() - t0) / len(frames)
                out[f"{label}_preds"] = preds
            if b is not None:
                t0 = jobkit.cpu_seconds()
                for k in range(0, len(ims) - 3, 4):
                    b(np.concatenate(ims[k:k + 4]))
                out["batch4"] = (jobkit.cpu_seconds() - t0) / (4 * (len(ims) // 4))
            if "rect_preds" in out:
                vehicle = [k for k, v in p.model.names.items() if v in tuple(cfg.detector.classes)]
                best = lambda pr: torch.from_numpy(pr)[0, 4:][vehicle].max().item()  # noqa: E731
                out["rect_dconf"] = max(abs(best(a) - best(c)) for a, c in zip(out["640_preds"],
                                                                                 out["rect_preds"]))
            rows.append(out)
        return rows

    times = {v: [] for v in variants}
    scores = {}
    me = [os.getpid()]
    for _ in range(args.repeat):
        for name, fn in variants.items():
            result = []
            wall, cores = jobkit.timed(lambda: result.extend(fn()), me)
            times[name].append((wall / len(frames), wall * cores / len(frames)))
            scores.setdefault(name, composites(result))
    base_cpu = statistics.median(c for _, c in times["today"])
    print(f"{'variant':>8} {'wall s':>7} {'cpu s':>6} {'cpu vs today':>12} {'max |d composite|':>17} {'within 1e-3':>11}")
    for name in variants:
        wall = statistics.median(w for w, _ in times[name])
        cpu = statistics.median(c for _, c in times[name])
        diff = float(np.abs(scores[name] - scores["today"]).max())
        print(f"{name:>8} {wall:>7.4f} {cpu:>6.4f} {cpu / base_cpu:>12.2f} {diff:>17.2e} "
              f"{'yes' if diff <= TOLERANCE else 'NO':>11}")
    for name, why in refused.items():
        print(f"# {name}: these networks cannot be reshaped: {'; '.join(why)}")
    print("# inference alone, reshapable networks (CPU s per frame; largest change of the best vehicle score):")
    for row in raw_inference():
        print(f"#   {row['model']}: 640x640 {row['640']:.4f}"
              + (f", 480x640 {row['rect']:.4f} ({row['rect'] / row['640']:.2f}x, max |d| "
                 f"{row['rect_dconf']:.3f})" if "rect" in row else ", 480x640 refused")
              + (f", batch 4 {row['batch4']:.4f} ({row['batch4'] / row['640']:.2f}x)" if "batch4" in row
                 else ", batch 4 refused"))
    print(f"# composite today: mean {scores['today'].mean():.4f} over {len(frames)} frames")
    print(f"# after: {jobkit.load()}")


if __name__ == "__main__":
    main()
