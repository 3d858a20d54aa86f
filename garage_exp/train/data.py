"""The training data: gathered from suites, `dataset=true` job outputs and YOLO data.yaml files, checked, and split
into train and val by scenario, never by frame (the frames of one trajectory are not independent).

A scenario is the folder that holds an `images/` folder and its `labels/` twin: one job's dataset, or one scenario
of a suite's dataset. Everything is checked before anything is written (`plan_data`); `write_data` then writes
the lists ultralytics reads (train.txt, val.txt, data.yaml) and the manifest (which scenarios, how many frames).
"""

from __future__ import annotations

import math
import os
import random
import shutil
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from garage_exp.core.errors import GarageError

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp")
BOX_SLACK = 1e-3  # labels are written with 6 decimals: a box on the image edge may round a hair outside


@dataclass
class Frame:
    image: Path
    label: Path
    scenario: str  # the folder holding images/ and labels/


@dataclass
class Source:
    """One input, as given (`where`: its config key and index, e.g. data[1])."""

    where: str
    path: Path
    data_yaml: Path
    names: dict[int, str]
    frames: list[Frame]


@dataclass
class DataPlan:
    """What a training will read: its frames by split, each a list of Frames, and the class names."""

    names: dict[int, str]
    train: list[Frame]
    val: list[Frame]
    replay: list[Frame]
    sources: list[Source] = field(default_factory=list)

    def scenarios(self, split: str) -> list[str]:
        return sorted({f.scenario for f in getattr(self, split)})

    @property
    def fit_frames(self) -> list[Frame]:
        """The frames the trainer learns from: the new data's train split and the replay."""
        return self.train + self.replay


def label_of(image: Path) -> Path:
    """ultralytics' rule: the last /images/ of the path becomes /labels/, the suffix .txt."""
    parts = list(image.parts)
    for k in range(len(parts) - 2, -1, -1):
        if parts[k] == "images":
            parts[k] = "labels"
            break
    return Path(*parts).with_suffix(".txt")


def data_yaml_of(path: Path, where: str) -> Path:
    """The data.yaml of an input: the file itself, a dataset folder's, a job output's dataset/, a suite's
    dataset/."""
    if not path.exists():
        raise GarageError(f"{where}: not found (a suite, a dataset=true job output or a data.yaml)", str(path))
    if path.is_file():
        if path.suffix not in (".yaml", ".yml"):
            raise GarageError(f"{where}: not a YOLO data.yaml, a suite or a dataset folder", str(path))
        return path
    for candidate in (path / "data.yaml", path / "dataset" / "data.yaml"):
        if candidate.is_file():
            return candidate
    if (path / "manifest.csv").is_file():
        raise GarageError(f"{where}: the suite has no dataset (run it with dataset=true)", str(path))
    raise GarageError(f"{where}: no data.yaml here or in dataset/ (a suite, a dataset=true job output or a "
                      "data.yaml)", str(path))


def read_names(raw, where: str, path: Path) -> dict[int, str]:
    if isinstance(raw, list):
        return {k: str(v) for k, v in enumerate(raw)}
    if isinstance(raw, dict) and raw:
        try:
            return {int(k): str(v) for k, v in raw.items()}
        except (TypeError, ValueError):
            pass
    raise GarageError(f"{where}: `names` must be a list or a mapping of class ids to names", str(path))


def images_of(entry: Path, where: str, data_yaml: Path) -> list[Path]:
    """The images of one train/val entry of a data.yaml: a folder (searched recursively), a .txt list or one image."""
    if entry.is_dir():
        return sorted(p for p in entry.rglob("*") if p.suffix.lower() in IMAGE_SUFFIXES)
    if entry.suffix == ".txt" and entry.is_file():
        out = []
        for line in entry.read_text().splitlines():
            line = line.strip()
            if line:
                p = Path(line)
                out.append(p if p.is_absolute() else (entry.parent / p).resolve())
        return out
    if entry.suffix.lower() in IMAGE_SUFFIXES and entry.is_file():
        return [entry]
    raise GarageError(f"{where}: its image entry {str(entry)!r} is neither a folder, a .txt list nor an image",
                      str(data_yaml))


def read_source(entry: str, where: str) -> Source:
    path = Path(entry).expanduser().absolute()
    data_yaml = data_yaml_of(path, where)
    try:
        spec = yaml.safe_load(data_yaml.read_text())
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise GarageError(f"{where}: unreadable YAML ({str(exc).splitlines()[0]})", str(data_yaml)) from None
    if not isinstance(spec, dict) or "names" not in spec or "train" not in spec:
        raise GarageError(f"{where}: a data.yaml needs `train` and `names`", str(data_yaml))
    names = read_names(spec["names"], where, data_yaml)
    root = Path(str(spec.get("path") or data_yaml.parent)).expanduser()
    root = root if root.is_absolute() else data_yaml.parent / root
    images: dict[Path, None] = {}  # train and val both: the split is made here, by scenario
    for key in ("train", "val"):
        entries = spec.get(key) or []
        for item in [entries] if isinstance(entries, str) else entries:
            p = Path(str(item))
            for image in images_of(p if p.is_absolute() else root / p, where, data_yaml):
                images[image] = None
    frames = []
    for image in images:
        if not image.is_file():
            raise GarageError(f"{where}: image listed but missing", str(image))
        frames.append(Frame(image, label_of(image), str(image.parent.parent)))
    if not frames:
        raise GarageError(f"{where}: no images (an empty suite or dataset)", str(data_yaml))
    return Source(where, path, data_yaml, names, frames)


def check_labels(frame: Frame, names: dict[int, str]) -> int:
    """The label file's boxes: a known class and a box inside the image; GarageError naming the file and line.
    Returns the number of boxes (a missing label file is an image with none, as ultralytics reads it)."""
    if not frame.label.is_file():
        return 0
    lines = frame.label.read_text().splitlines()
    count = 0
    for k, line in enumerate(lines, start=1):
        if not line.strip():
            continue
        fields = line.split()
        where = f"{frame.label}: line {k}"
        try:
            cls, cx, cy, w, h = int(fields[0]), *(float(v) for v in fields[1:])
            if len(fields) != 5:
                raise ValueError
        except (ValueError, TypeError, IndexError):
            raise GarageError("expected `class x_centre y_centre width height`", where) from None
        if cls not in names:
            raise GarageError(f"class {cls} is not in the data's names (0-{max(names)})", where)
        if not all(math.isfinite(v) for v in (cx, cy, w, h)) or w <= 0 or h <= 0:
            raise GarageError("the box has no area or is not finite", where)
        x1, x2, y1, y2 = cx - w / 2, cx + w / 2, cy - h / 2, cy + h / 2
        if min(x1, y1) < -BOX_SLACK or max(x2, y2) > 1 + BOX_SLACK:
            raise GarageError(f"box outside the image (x {x1:.3f}-{x2:.3f}, y {y1:.3f}-{y2:.3f}; normalised "
                              "coordinates lie in 0-1)", where)
        count += 1
    return count


def same_names(sources: list[Source]) -> dict[int, str]:
    first = sources[0]
    for source in sources[1:]:
        if source.names != first.names:
            raise GarageError(f"{source.where}: its class map ({_short(source.names)}) does not match "
                              f"{first.where}'s ({_short(first.names)})", str(source.data_yaml))
    return first.names


def _short(names: dict[int, str]) -> str:
    items = [f"{k}: {v}" for k, v in sorted(names.items())]
    return ", ".join(items[:4]) + (f", ... {len(items)} classes" if len(items) > 4 else "")


def split_scenarios(scenarios: list[str], val_fraction: float, seed: int) -> tuple[list[str], list[str]]:
    """(train, val) scenarios: a seeded shuffle, then ceil(val_fraction x n) (at least one) held out."""
    if len(scenarios) < 2:
        raise GarageError(f"{len(scenarios)} scenario: a split by scenario needs at least 2 (or give val=[...])",
                          "data")
    order = sorted(scenarios)
    random.Random(seed).shuffle(order)
    n_val = min(len(order) - 1, max(1, math.ceil(val_fraction * len(order))))
    return sorted(order[n_val:]), sorted(order[:n_val])


def plan_data(cfg) -> DataPlan:
    """Read and check every input; split `data` by scenario (or take `val` as given); draw the replay."""
    if not cfg.data:
        raise GarageError("no training data given (data=[suite dir, dataset dir or data.yaml, ...])", "data")
    if not 0.0 <= float(cfg.val_fraction) < 1.0:
        raise GarageError(f"{cfg.val_fraction} is outside [0, 1)", "val_fraction")
    if not 0.0 <= float(cfg.replay_fraction) <= 10.0:
        raise GarageError(f"{cfg.replay_fraction} is outside 0-10 (replay frames per new frame)", "replay_fraction")
    if float(cfg.replay_fraction) > 0 and not cfg.replay:
        raise GarageError("replay_fraction > 0 needs replay=[base data]", "replay")
    data = [read_source(e, f"data[{k}]") for k, e in enumerate(cfg.data)]
    val = [read_source(e, f"val[{k}]") for k, e in enumerate(cfg.val)]
    replay = [read_source(e, f"replay[{k}]") for k, e in enumerate(cfg.replay)] if cfg.replay_fraction else []
    sources = data + val + replay
    names = same_names(sources)
    for source in sources:
        for frame in source.frames:
            check_labels(frame, names)
    new = [f for s in data for f in s.frames]
    if val:
        val_frames = [f for s in val for f in s.frames]
        held = {f.scenario for f in val_frames}
        train = [f for f in new if f.scenario not in held]
        if not train:
            raise GarageError("every scenario of `data` is also in `val`: nothing left to train on", "val")
    else:
        train_s, val_s = split_scenarios(sorted({f.scenario for f in new}), float(cfg.val_fraction), int(cfg.seed))
        held = set(val_s)
        train = [f for f in new if f.scenario not in held]
        val_frames = [f for f in new if f.scenario in held]
    drawn = draw_replay([f for s in replay for f in s.frames if f.scenario not in held],
                        round(float(cfg.replay_fraction) * len(train)), int(cfg.seed))
    plan = DataPlan(names, train, val_frames, drawn, sources)
    assert_split(plan)
    return plan


def draw_replay(pool: list[Frame], n: int, seed: int) -> list[Frame]:
    """n frames of the replay pool, drawn at random (seeded; the same seed and pool give the same draw)."""
    if n <= 0:
        return []
    if n > len(pool):
        raise GarageError(f"the replay holds {len(pool)} frame(s) outside the validation scenarios, fewer than the "
                          f"{n} asked (replay_fraction x training frames)", "replay")
    return random.Random(seed).sample(pool, n)


def assert_split(plan: DataPlan) -> None:
    """No scenario on both sides: a frame's neighbours in its trajectory would leak into validation."""
    both = set(plan.scenarios("val")) & (set(plan.scenarios("train")) | set(plan.scenarios("replay")))
    if both:
        raise GarageError(f"scenario(s) {sorted(both)[:3]} on both sides of the split", "val")


def write_data(plan: DataPlan, out: Path) -> Path:
    """train.txt, val.txt, data.yaml and manifest.csv under out/; returns the data.yaml. The lists name links
    under out/frames/, not the inputs: ultralytics writes its labels.cache beside the labels it reads, and the
    inputs stay untouched (read-only inputs work)."""
    out.mkdir(parents=True, exist_ok=True)
    shutil.rmtree(out / "frames", ignore_errors=True)  # a rerun's links (rmtree removes links, not targets)
    (out / "train.txt").write_text("".join(f"{p}\n" for p in link_frames(plan.fit_frames, out / "frames" / "train")))
    (out / "val.txt").write_text("".join(f"{p}\n" for p in link_frames(plan.val, out / "frames" / "val")))
    data_yaml = out / "data.yaml"
    data_yaml.write_text(yaml.safe_dump({"path": str(out), "train": "train.txt", "val": "val.txt",
                                         "names": plan.names}, sort_keys=False))
    manifest(plan).to_csv(out / "manifest.csv", index=False)
    return data_yaml


def link_frames(frames: list[Frame], root: Path) -> list[Path]:
    """Each frame's image and label linked (copied where links cannot be made) under root/sNNN/images and
    root/sNNN/labels, one sNNN folder per scenario (the split stays visible by folder); returns the images."""
    scenario_dirs: dict[str, Path] = {}
    images = []
    for n, frame in enumerate(frames):
        folder = scenario_dirs.setdefault(frame.scenario, root / f"s{len(scenario_dirs):03d}")
        image = folder / "images" / f"{n:06d}_{frame.image.name}"  # numbered: two inputs may share a name
        _link(frame.image, image)
        if frame.label.is_file():
            _link(frame.label, label_of(image))
        images.append(image)
    return images


def _link(source: Path, target: Path) -> None:
    target.parent.mkdir(parents=True, exist_ok=True)
    try:
        os.symlink(source.absolute(), target)
    except OSError:  # a file system without symbolic links
        shutil.copyfile(source, target)


def manifest(plan: DataPlan):
    """One row per scenario and split: how many frames of it the training read."""
    import pandas as pd

    rows: dict[tuple[str, str], int] = {}
    for split in ("train", "replay", "val"):
        for f in getattr(plan, split):
            rows[(f.scenario, split)] = rows.get((f.scenario, split), 0) + 1
    return pd.DataFrame([{"scenario": s, "split": split, "frames": n} for (s, split), n in rows.items()],
                        columns=["scenario", "split", "frames"])
