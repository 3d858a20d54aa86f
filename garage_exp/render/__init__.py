"""Rendering: a Frame (picture, entity ids, camera), the Renderer interface, and the backend the config names.

Importing this package does not import a backend: `Frame` is plain data that ground truth and tests use without
a Vulkan device. The backend is the factory named by `renderer._target_` (conf/renderer/*.yaml), called with
the group's keys, so a second backend is one module plus one YAML.
"""

from __future__ import annotations

from garage_exp.core.errors import GarageError, check_range
from garage_exp.render.base import BLANK_GREY, Frame, Renderer
from garage_exp.render.icd import check_available
from garage_exp.core.plugins import build, check_target

SAVE_FRAMES = ("all", "key", "none")
MAX_KEPT = 16  # loaded garages kept (renderer.kept_garages): each holds its SAPIEN scene's memory
MAX_SCENES = 256  # sub-scenes of one render scene: what one GPU's group held in the measured recipe (FACTS.md)


def check_renderer(conf) -> None:
    """The `renderer` group: an allowed factory, a light pool SAPIEN's default shader can compile (1-10),
    a known save_frames and device (auto | cpu | cuda), 1 to MAX_SCENES sub-scenes, 1 to MAX_KEPT kept garages."""
    check_target(str(conf._target_), "a renderer", "renderer._target_")
    check_range(conf.max_lights, 1, 10, "renderer.max_lights")
    check_range(conf.get("scenes", 1), 1, MAX_SCENES, "renderer.scenes")
    check_range(conf.get("kept_garages", 1), 1, MAX_KEPT, "renderer.kept_garages")
    if conf.save_frames not in SAVE_FRAMES:
        raise GarageError(f"unknown save_frames {conf.save_frames!r} (all | key | none)", "renderer.save_frames")
    # File globs only: whether Vulkan really finds the device shows when the first scene loads (ensure_device).
    check_available(conf.device)


def open_renderer(conf) -> Renderer:
    """The process's renderer of the backend `conf._target_` names, set up from the `renderer` group. `scenes` is
    the render scene's (render/batch.py), not the backend's: a user's backend is not handed a key it never asked
    for."""
    from garage_exp.core.plain import plain

    settings = plain(conf)
    settings.pop("scenes", None)
    kept = settings.pop("kept_garages", None)  # the SAPIEN renderer's, set on it: a user's backend never asked
    renderer = build(settings, "a renderer", "renderer._target_")
    if kept is not None and hasattr(renderer, "kept_garages"):
        renderer.kept_garages = int(kept)
    return renderer


__all__ = ["BLANK_GREY", "Frame", "Renderer", "check_renderer", "open_renderer"]
