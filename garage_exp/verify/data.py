"""A labelled image set for `python -m garage_exp.verify`: a COCO JSON file or a YOLO data.yaml (or a folder
holding one: a dataset, a `dataset=true` job output, a suite), read and checked before anything is written.

Each image's labels become boxes in pixels (x1, y1, x2, y2) with the label's class name; `label_map` renames
label classes first (`{Car: car, pedestrian: person}`), so that a set labelled in its own words is scored by the
project's classes. COCO's crowd regions (iscrowd 1) are left out, as COCO's own evaluation does for recall.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from garage_exp.core.errors import GarageError
from garage_exp.train.data import check_labels, data_yaml_of, images_of, label_of, read_names, Frame

KINDS_HINT = "a COCO JSON file, a YOLO data.yaml, a dataset folder, a dataset=true job output or a suite"
RENDERED = "garage_exp ground truth"  # the `info.description` of the COCO files this project writes


@dataclass
class Labelled:
    """One image and its labelled objects."""

    image: Path
    width: int
    height: int
    boxes: np.ndarray  # (M, 4) float x1, y1, x2, y2 in pixels
    classes: list[str]  # M class names (after label_map)


@dataclass
class LabelledSet:
    source: Path  # the COCO JSON or the data.yaml read
    format: str  # "coco" | "yolo"
    images: list[Labelled] = field(default_factory=list)
    rendered: bool = False  # written by this project (a dataset=true job, a suite): synthetic, not real images

    @property
    def objects(self) -> int:
        return sum(len(im.classes) for im in self.images)


def read_set(data: str, label_map: dict[str, str], split: str = "val", images: str | None = None) -> LabelledSet:
    """The labelled set at `data` (see the module's doc); GarageError naming the file for anything unusable."""
    if not str(data).strip():
        raise GarageError(f"no data given: data=PATH ({KINDS_HINT})", "data")
    path = Path(str(data)).expanduser().absolute()
    if not path.exists():
        raise GarageError(f"data: not found ({KINDS_HINT})", str(path))
    if path.suffix == ".json":
        found = read_coco(path, label_map, images)
    elif path.is_dir() and not (path / "data.yaml").is_file() and not (path / "dataset" / "data.yaml").is_file() \
            and (path / "coco.json").is_file():
        found = read_coco(path / "coco.json", label_map, images)
    else:
        found = read_yolo(data_yaml_of(path, "data"), label_map, split)
    if not found.images:
        raise GarageError("data: no images", str(found.source))
    if not found.objects:
        raise GarageError(f"data: no labels on any of its {len(found.images)} images (nothing to score a detector "
                          "against)", str(found.source))
    return found


def read_coco(path: Path, label_map: dict[str, str], images: str | None) -> LabelledSet:
    """A COCO instances file; images at `images`/file_name, else beside the file or in its images/ folder."""
    try:
        coco = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise GarageError(f"data: unreadable COCO JSON ({str(exc).splitlines()[0]})", str(path)) from None
    if not isinstance(coco, dict) or not isinstance(coco.get("images"), list) or not isinstance(
            coco.get("categories"), list):
        raise GarageError("data: a COCO file needs `images` and `categories` lists", str(path))
    try:
        categories = {int(c["id"]): str(c["name"]) for c in coco["categories"]}
        check_label_map(label_map, categories.values(), path)
        image_ids = {int(im["id"]) for im in coco["images"]}
        by_image: dict[int, list[dict]] = {}
        for ann in coco.get("annotations") or []:
            if int(ann["image_id"]) not in image_ids:  # its object would silently go unscored
                raise GarageError(f"data: annotation {ann.get('id')} has image_id {ann['image_id']}, not among "
                                  "`images`", str(path))
            by_image.setdefault(int(ann["image_id"]), []).append(ann)
        roots = [Path(images).expanduser()] if images else [path.parent, path.parent / "images"]
        out = LabelledSet(path, "coco", rendered=is_rendered(coco))
        for im in coco["images"]:
            file = next((r / im["file_name"] for r in roots if (r / im["file_name"]).is_file()), None)
            if file is None:
                raise GarageError(f"data: image {im['file_name']!r} not found in {', '.join(map(str, roots))}",
                                  str(path))
            boxes, classes = [], []
            for ann in by_image.get(int(im["id"]), []):
                if ann.get("iscrowd", 0):
                    continue
                if int(ann["category_id"]) not in categories:
                    raise GarageError(f"data: annotation {ann.get('id')} has category {ann['category_id']}, "
                                      "not among `categories`", str(path))
                x, y, w, h = (float(v) for v in ann["bbox"])
                check_box(ann.get("id"), (x, y, w, h), int(im["width"]), int(im["height"]), path)
                boxes.append((x, y, x + w, y + h))
                name = categories[int(ann["category_id"])]
                classes.append(label_map.get(name, name))
            out.images.append(Labelled(file, int(im["width"]), int(im["height"]),
                                       np.asarray(boxes, dtype=float).reshape(-1, 4), classes))
    except (KeyError, TypeError, ValueError) as exc:
        raise GarageError(f"data: not a COCO instances file ({type(exc).__name__}: {exc})", str(path)) from None
    return out


def read_yolo(data_yaml: Path, label_map: dict[str, str], split: str) -> LabelledSet:
    """A YOLO data.yaml's `split` images (`train` when it has no such split), their labels/ twins."""
    from PIL import Image

    try:
        spec = yaml.safe_load(data_yaml.read_text())
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise GarageError(f"data: unreadable YAML ({str(exc).splitlines()[0]})", str(data_yaml)) from None
    if not isinstance(spec, dict) or "names" not in spec or not (spec.get(split) or spec.get("train")):
        raise GarageError(f"data: a data.yaml needs `names` and `{split}` (or `train`)", str(data_yaml))
    names = read_names(spec["names"], "data", data_yaml)
    check_label_map(label_map, names.values(), data_yaml)
    root = Path(str(spec.get("path") or data_yaml.parent)).expanduser()
    root = root if root.is_absolute() else data_yaml.parent / root
    entries = spec.get(split) or spec["train"]
    files: dict[Path, None] = {}
    for item in [entries] if isinstance(entries, str) else entries:
        p = Path(str(item))
        files.update(dict.fromkeys(images_of(p if p.is_absolute() else root / p, "data", data_yaml)))
    beside = data_yaml.parent / "coco.json"  # the project's datasets write one beside their data.yaml
    try:
        rendered = beside.is_file() and is_rendered(json.loads(beside.read_text()))
    except (OSError, ValueError):
        rendered = False
    out = LabelledSet(data_yaml, "yolo", rendered=rendered)
    check_orphan_labels(files)
    for image in files:
        if not image.is_file():
            raise GarageError("data: image listed but missing", str(image))
        label = label_of(image)
        check_labels(Frame(image, label, ""), names)  # one line naming the file and line of a bad label
        with Image.open(image) as im:
            width, height = im.size
        rows = [ln.split() for ln in label.read_text().splitlines() if ln.strip()] if label.is_file() else []
        boxes = [((float(cx) - float(w) / 2) * width, (float(cy) - float(h) / 2) * height,
                  (float(cx) + float(w) / 2) * width, (float(cy) + float(h) / 2) * height) for _, cx, cy, w, h in rows]
        classes = [label_map.get(names[int(c)], names[int(c)]) for c, *_ in rows]
        out.images.append(Labelled(image, width, height, np.asarray(boxes, dtype=float).reshape(-1, 4), classes))
    return out


def check_label_map(label_map: dict[str, str], classes, source: Path) -> None:
    """Every label_map key is a class of the data: a misspelt key would rename nothing, silently."""
    known = sorted(set(classes))
    for key in label_map:
        if key not in known:
            shown = ", ".join(known[:12]) + (", ..." if len(known) > 12 else "")
            raise GarageError(f"{key!r} is not a class of the data (its classes: {shown}; {source})",
                              f"label_map.{key}")


def check_box(ann_id, xywh: tuple[float, float, float, float], width: int, height: int, source: Path) -> None:
    """A COCO box that has an area and overlaps its image: one wholly outside would be a target nobody can
    detect (scored as a miss), one with no area is a typo."""
    x, y, w, h = xywh
    if not all(np.isfinite(xywh)) or w <= 0 or h <= 0:
        raise GarageError(f"data: annotation {ann_id}'s bbox {list(xywh)} has no area or is not finite", str(source))
    if x >= width or y >= height or x + w <= 0 or y + h <= 0:
        raise GarageError(f"data: annotation {ann_id}'s bbox [x {x:g}-{x + w:g}, y {y:g}-{y + h:g}] lies wholly "
                          f"outside its {width}x{height} image", str(source))


def check_orphan_labels(images) -> None:
    """A YOLO label file beside the scored images whose image is missing: its objects would go unscored."""
    from garage_exp.train.data import IMAGE_SUFFIXES

    folders = {label_of(image).parent: image.parent for image in images}
    for labels, pictures in sorted(folders.items()):
        if not labels.is_dir():
            continue
        for label in sorted(labels.glob("*.txt")):
            if not any((pictures / (label.stem + s)).is_file() for s in (*IMAGE_SUFFIXES, *(
                    x.upper() for x in IMAGE_SUFFIXES))):
                raise GarageError(f"data: label file without its image (no {label.stem}.* in {pictures})", str(label))


def is_rendered(coco: dict) -> bool:
    info = coco.get("info") if isinstance(coco, dict) else None
    return isinstance(info, dict) and info.get("description") == RENDERED
