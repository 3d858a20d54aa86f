"""Pixel work on rendered frames that every backend shares: the blank control's composite."""

from __future__ import annotations

from collections.abc import Iterable, Mapping

from garage_exp.core import arrays
from garage_exp.render.base import BLANK_GREY, Frame


def blank_composite(rgb, frame: Frame, ids: Mapping[str, int], names: Iterable[str]):
    """The named entities' pixels of `rgb` (a picture of `frame`) pasted on uniform BLANK_GREY; `ids` is the
    renderer's entity name -> id map (`Renderer.ids`).

    The blank control proper is a scene with `background=False`, which renders every vehicle whole on grey with
    the same lights. Compositing on top of that drops the other vehicles; on a full render it keeps the target
    as the occluders cut it (a different control: occlusion without background).
    """
    keep = arrays.isin(frame.ids, [ids[n] for n in names if n in ids])  # numpy or torch, as the frame
    out = arrays.xp(rgb).full_like(rgb, BLANK_GREY)
    out[keep] = rgb[keep]
    return out
