"""Renderer backends by name (`renderer.backend`): a registry filled by `@register_backend` beside each backend's
factory, as the other kinds a config names by a word (core/plugins.py). A backend is its factory (the `renderer`
group's settings -> the process's `Renderer`, sub-scene 0) and, optionally, its own check of the group and its
own batch (a render scene of its making: SAPIEN's CUDA group); without one it gets the generic batch
(render/batch.py, sub-scenes rendered one after another through the `Renderer` interface).

`render.open.open_renderer` is the one way to open one; `render.open.check_renderer` checks the group. The
shipped backend (`sapien`, render/sapien_backend.py) registers itself when imported (`render.open` imports it);
a module of the user's is named in $GARAGE_EXP_PLUGINS.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from garage_exp.core.errors import GarageError, did_you_mean


@dataclass(frozen=True)
class Backend:
    """A registered renderer backend. make(**settings) -> `Renderer`: called with the group's keys it names (all
    of them when it takes **kwargs). scene(first, n, hidden, **settings) -> `render.batch.RenderScene`: the
    backend's own batch of n sub-scenes (`first()` makes the process's renderer), None: the generic one.
    check(conf): the backend's own keys (light count, device), beside the group's common check."""

    name: str
    make: Callable[..., Any]
    scene: Callable[..., Any] | None = None
    check: Callable[[Any], None] | None = None
    says: str = ""

    def settings(self, settings: dict) -> dict:
        """The group's keys this backend's factory takes."""
        params = inspect.signature(self.make).parameters
        if any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values()):
            return dict(settings)
        return {k: v for k, v in settings.items() if k in params}


BACKENDS: dict[str, Backend] = {}


def register_backend(name: str, *, scene: Callable[..., Any] | None = None,
                     check: Callable[[Any], None] | None = None, says: str = ""):
    """Decorator on a backend's factory: `renderer.backend=name` opens it (`render.open.open_renderer`)."""
    def register(make: Callable[..., Any]) -> Callable[..., Any]:
        BACKENDS[name] = Backend(name, make, scene, check, says)
        return make
    return register


def backend(name: str) -> Backend:
    """The backend registered as `name`; one GarageError naming `renderer.backend` (and the registered ones)
    otherwise."""
    if name not in BACKENDS:
        raise GarageError(f"unknown renderer backend {name!r}{did_you_mean(name, sorted(BACKENDS))}; a module "
                          "of your own registers one with @register_backend and is named in $GARAGE_EXP_PLUGINS",
                          "renderer.backend")
    return BACKENDS[name]
