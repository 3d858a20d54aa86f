"""The views a lens camera's detector gets (`camera.view`): the raw image, or a view undistorted from it. A
registry: each view is registered beside its function with `@register_view(NAME)`, so adding a view is one module
with its function (or a lens class with `for_spec(spec)`) and that line (imported before the config is checked;
docs/architecture.md, "Extension points").

A view is a function spec -> lens (scene/lenses: a `Pinhole`, a `Cylindrical`, ...), or None for the raw image,
at the spec's size; render/fisheye.py remaps the fisheye image into it, and ground truth and the detector see its
lens (`picture_lens`). Plain numpy: no SAPIEN, no OpenCV.
"""

from __future__ import annotations

from collections.abc import Callable

from garage_exp.scene.lenses import Cylindrical, Lens, Pinhole, lens_of

# View name -> fn(CameraSpec) -> lens, or None for the raw image.
VIEWS: dict[str, Callable] = {}


def register_view(name: str) -> Callable:
    """Register a view under `name`: a class with `for_spec(spec)` (or a function spec -> lens | None)."""
    def register(obj):
        VIEWS[name] = getattr(obj, "for_spec", obj)
        return obj
    return register


register_view("raw")(lambda spec: None)  # the lens's own image


@register_view("perspective")
def perspective(spec) -> Pinhole:
    """A perspective view cannot hold 190 degrees: it keeps the central 120 degrees across."""
    return Pinhole.from_fovx(spec.width, spec.height, 120.0)


@register_view("cylindrical")
def cylindrical(spec) -> Cylindrical:
    """The lens's whole width (up to 180 degrees)."""
    return Cylindrical.from_fovx(spec.width, spec.height, min(spec.fov, 180.0))


def view_lens(spec) -> Lens | None:
    """The view a lens camera's detector gets (`spec.view`), None for the raw image."""
    return VIEWS[spec.view](spec)


def picture_lens(spec) -> Lens:
    """The lens of the picture a camera delivers (its frames, its detector's input, its ground truth): a
    perspective camera's own lens; a lens camera's view, or its own lens for the raw image."""
    view = view_lens(spec) if spec.fisheye else None
    return lens_of(spec) if view is None else view
