"""The descriptors of the archive of failure kinds (search/archive.py): each a quantity measured from a trial's own
outputs, registered by name beside its function (`@register_descriptor`), as the project's other kinds are; a
user's module of descriptors is named in $GARAGE_EXP_PLUGINS.

A descriptor is `measure(first, out_dir, frame) -> value`: `first` is the trial's frame-table row at its first
fairly visible frame of the scored camera (a pandas Series), `out_dir` its job directory, `frame` the path of its
saved hardest fair frame (or None). A `category` returns a word, a `number` a float (NaN: not measured, and the
trial has no cell). `search.descriptors` names them (`source`) and bins them (`values` or `edges`).

The frame table's columns they read come from ground truth and the scene's geometry (perception/groundtruth.py):
what hides the target (`occluder`, from the frame's id picture), its distance, visible fraction, box height and 3D
height (`target_height`), the lamps' direct light at it (`target_light`) and the camera's height
(`camera_height`); a table written before a column existed leaves the descriptor NaN (no cell).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from garage_exp.core.errors import GarageError

CATEGORY, NUMBER = "category", "number"
SMALL_PERSON = 1.4  # m: a person whose 3D box is lower than this is child-sized (a child, or an adult crouching)
TALL_VEHICLE = 1.7  # m: a vehicle this tall or taller is an SUV, a van, a minibus or a truck, not a car


@dataclass(frozen=True)
class Descriptor:
    name: str
    kind: str  # category | number
    says: str  # what it measures (the docs' and the error messages' words)
    measure: Callable[[pd.Series, Path, object], object]


DESCRIPTORS: dict[str, Descriptor] = {}


def register_descriptor(name: str, kind: str, says: str):
    """Register the decorated `measure(first, out_dir, frame)` as the descriptor `name` (a category or a number)."""
    if kind not in (CATEGORY, NUMBER):
        raise ValueError(f"a descriptor is a {CATEGORY} or a {NUMBER}, not {kind!r}")

    def register(measure):
        DESCRIPTORS[name] = Descriptor(name, kind, says, measure)
        return measure

    return register


def descriptor(name: str, where: str) -> Descriptor:
    try:
        return DESCRIPTORS[name]
    except KeyError:
        raise GarageError(f"unknown descriptor source {name!r} ({' | '.join(DESCRIPTORS)})", where) from None


def number(first: pd.Series, column: str) -> float:
    """A frame-table number at the first fair frame; NaN when the table has no such column (an older table)."""
    value = first.get(column)
    try:
        return float(value)
    except (TypeError, ValueError):
        return math.nan


# --- what the target is --------------------------------------------------------------------------------------------

@register_descriptor("kind", CATEGORY, "the target: car, adult or child")
def kind(first: pd.Series, _out: Path, _frame) -> str:
    """car for a vehicle target; a person is a child when the scene's target actor is one (the shipped cases
    name their child targets child, child_walking), else an adult. Read from the frame table's target_kind and
    target columns at the first fair frame (a vehicle-only table has no target_kind: a car)."""
    if str(first.get("target_kind", "vehicle")) != "person":
        return "car"
    return "child" if str(first.get("target", "")).startswith("child") else "adult"


@register_descriptor("target_class", CATEGORY,
                     "the target by its kind and 3D height: small_person (under 1.4 m: a child or a crouching "
                     "adult), person, car, tall_vehicle (1.7 m or more: SUV, van, minibus, truck)")
def target_class(first: pd.Series, _out: Path, _frame) -> str:
    """Measured from ground truth (the target's 3D box height, `target_height`), not from an actor's name, so a
    search that draws any of the library's vehicles or any person finds its class; "" when the table has no
    height (written before the column)."""
    height = number(first, "target_height")
    if not height > 0:
        return ""
    if str(first.get("target_kind", "vehicle")) == "person":
        return "small_person" if height < SMALL_PERSON else "person"
    return "tall_vehicle" if height >= TALL_VEHICLE else "car"


@register_descriptor("target", CATEGORY, "the target actor's name")
def target(first: pd.Series, _out: Path, _frame) -> str:
    return str(first.get("target", ""))


@register_descriptor("camera", CATEGORY, "the camera of the first fair frame")
def camera(first: pd.Series, _out: Path, _frame) -> str:
    return str(first.get("camera"))


# --- what hides it, how far, how much of it -----------------------------------------------------------------------

@register_descriptor("occluder", CATEGORY, "what hid most of the target's hidden pixels at its first fair frame: "
                     "pillar, vehicle, person, structure or none (under 2 % of it hidden)")
def occluder(first: pd.Series, _out: Path, _frame) -> str:
    """The frame table's `occluder` column (perception/groundtruth.py: the category covering most of the target's
    hidden pixels in the frame's id picture); "" in a table written before it."""
    value = first.get("occluder")
    return "" if value is None or (isinstance(value, float) and math.isnan(value)) else str(value)


@register_descriptor("distance", NUMBER, "the target's distance (m) at its first fair frame")
def distance(first: pd.Series, _out: Path, _frame) -> float:
    return float(first["distance"])


@register_descriptor("visible", NUMBER,
                     "the target's visible fraction at its first fair frame (below 1: something hid part)")
def visible(first: pd.Series, _out: Path, _frame) -> float:
    return float(first["visible_fraction"])


@register_descriptor("box", NUMBER, "the height (px) of the target's full box at its first fair frame")
def box(first: pd.Series, _out: Path, _frame) -> float:
    return number(first, "box_height")


# --- the light on it, the camera that saw it ----------------------------------------------------------------------

@register_descriptor("light", NUMBER, "the lamps' direct light at the target's centre at its first fair frame "
                     "(sum of intensity / d^2; about 0.05-0.3 dim, 0.2-0.7 clear, 0.45-1.45 bright)")
def light(first: pd.Series, _out: Path, _frame) -> float:
    """The frame table's `target_light` (perception/groundtruth.direct_light): how lit the target is where it
    stands, whatever the preset, intensity or failed lamps that made it so."""
    return number(first, "target_light")


@register_descriptor("camera_height", NUMBER, "the height (m) of the camera that first saw the target fairly")
def camera_height(first: pd.Series, _out: Path, _frame) -> float:
    return number(first, "camera_height")


@register_descriptor("luminance", NUMBER, "the mean luma (0-1) of the hardest fair frame")
def luminance(_first: pd.Series, _out: Path, frame) -> float:
    """The mean luma (Rec. 601, 0-1) of the trial's saved hardest fair frame: how dark the scene looks to the
    camera (its light, lamps and materials together), its drawn boxes a few pixels of it."""
    from PIL import Image

    if not frame or not Path(frame).exists():
        return math.nan
    rgb = np.asarray(Image.open(frame).convert("RGB"), dtype=float) / 255.0
    return float((rgb @ np.array([0.299, 0.587, 0.114])).mean())
