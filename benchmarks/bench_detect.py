"""Cheaper detection per frame, measured: `python benchmarks/bench_detect.py [--frames 24] [--repeat 3]`.

The three INT8 OpenVINO detectors on the frames of a case-1 job (research plan), 1 OpenVINO thread per model
as in the job's detector child. Variants, all through ultralytics' own pre- and post-processing functions, so
that only the named change differs:
  today      `Detector.detect`: `model.predict` per model (letterbox 640 x 640 each time), batch 1, LATENCY
  shared     one letterbox per frame for the three models, then each model's `inference` + `postprocess`
  rect       as shared, with each network reshaped to 1 x 3 x 480 x 640: the 640 x 480 frame needs no padding
  batch4     as shared, networks reshaped to batch 4, four consecutive frames per call
  async3     as shared, the three networks started together (OpenVINO infer requests), then waited for
Columns: wall and CPU seconds per frame (median over repeats; this process, all threads), CPU against
today's, and the largest change of any frame's composite confidence (the job's `score_target` with the job's
ground truth) against today's. Adopt only a variant that moves no composite by more than 1e-3 (issue 13).
"""

from __future__ import annotations

import argparse
import os
import statistics

import jobkit
import numpy as np

TOLERANCE = 1e-3


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=24)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    import openvino as ov

    from garage_exp.detect import score_target
    from garage_exp.detect.detector import Detector, ModelDetections, spec_from_config

    print(f"# detection, case 1, {args.frames} frames, {args.repeat} repeats; {jobkit.machine()}")
    print(f"# before: {jobkit.load()}")
    job = jobkit.build_job(["case=1", "light=bright"])
    cfg = job.cfg
    frames = list(job.frames(args.frames))
    detector = Detector(**spec_from_config(cfg.detector), threads=1)
    models = detector._models
    predictors = [m.predictor for m in models]
    core = ov.Core()
    config = {"PERFORMANCE_HINT": "LATENCY", "INFERENCE_NUM_THREADS": 1}

    def compiled(path, shape):
        xml = next(path.glob("*.xml"))
        net = core.read_model(str(xml))
        net.reshape(shape)
        return core.compile_model(net, "CPU", config)

    original = [p.model.backend.ov_compiled_model for p in predictors]
    rect = [compiled(path, [1, 3, 480, 640]) for path in detector.paths]
    batch4 = [compiled(path, [4, 3, 640, 640]) for path in detector.paths]

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
                preds = [torch.from_numpy(req.get_output_tensor(i).data.copy()) for i in range(len(req.outputs))]
                preds = preds[0] if len(preds) == 1 else preds
                p.batch = [["frame0"]]
                dets.append(to_dets(name, p.postprocess(preds, im, [bgr])[0]))
            out.append(dets)
        return out

    variants = {"today": variant_today, "shared": variant_shared, "rect": variant_rect,
                "batch4": variant_batch4, "async3": variant_async3}

    def composites(all_dets):
        out = []
        for f, dets in zip(frames, all_dets):
            s = score_target(dets, f.target, f.truth, iou_threshold=cfg.detector.iou, match=cfg.detector.match,
                             threshold=cfg.detector.threshold, classes=tuple(cfg.detector.classes),
                             person_classes=tuple(cfg.detector.person_classes))
            out.append(s.composite)
        return np.array(out)

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
    print(f"# composite today: mean {scores['today'].mean():.4f} over {len(frames)} frames")
    print(f"# after: {jobkit.load()}")


if __name__ == "__main__":
    main()
