"""Pixel work on rendered frames that every backend shares: the blank control's composite."""

from __future__ import annotations

from collections.abc import Iterable, Mapping

import numpy as np

from garage_exp.render.base import BLANK_GREY, Frame


def blank_composite(rgb: np.ndarray, frame: Frame, ids: Mapping[str, int], names: Iterable[str]) -> np.ndarray:
    """The named entities' pixels of `rgb` (a picture of `frame`) pasted on uniform BLANK_GREY; `ids` is the
    renderer's entity name -> id map (`Renderer.ids`).

    The blank control proper is a scene with `background=False`, which renders every vehicle whole on grey with
    the same lights. Compositing on top of that drops the other vehicles; on a full render it keeps the target
    as the occluders cut it (a different control: occlusion without background).
    """
    keep = np.isin(frame.ids, [ids[n] for n in names if n in ids])
    out = np.full_like(rgb, BLANK_GREY)
    out[keep] = rgb[keep]
    return out
