"""The one way to open a renderer, whoever calls it (the job's frames, the search's pre-screen, the gym, the
benchmarks): `open_renderer` gives the backend the `renderer` group names (render/registry.py:
`renderer.backend`, `sapien` by default) as a render scene (render/batch.py: N sub-scenes behind one
`render_batch`), batched by the backend; `check_renderer` checks the group. Apart from the package's `__init__`,
which plain data (`Frame`) is imported through, so that importing it never imports a backend.
"""

from __future__ import annotations

from garage_exp.core.errors import GarageError, check_range
from garage_exp.core.plugins import resolve
from garage_exp.render.registry import Backend, backend

SAVE_FRAMES = ("all", "key", "none")
MAX_SCENES = 256  # sub-scenes of one render scene: what one GPU's group held in the measured recipe (FACTS.md)
# What `renderer._target_` says when a config leaves it alone: SAPIEN's factory. Another factory there is how
# configs named a backend before `renderer.backend`, and still does (`chosen`).
DEFAULT_TARGET = "garage_exp.render.sapien_backend.make"
NOT_SETTINGS = ("_target_", "backend", "scenes")  # the choice of backend and the render scene's size


def chosen(conf) -> Backend:
    """The backend the `renderer` group names: `renderer.backend`'s; a `renderer._target_` other than SAPIEN's
    factory (the older way) is a backend of its own, that factory with the generic batch."""
    import garage_exp.render.sapien_backend  # noqa: F401 - registers the shipped backend, `sapien`

    target = str(conf.get("_target_") or "")
    if target and target != DEFAULT_TARGET:
        return Backend(target, resolve(target, "a renderer", "renderer._target_"))
    return backend(str(conf.get("backend") or "sapien"))


def check_renderer(conf) -> None:
    """The `renderer` group: a registered backend (or an allowed factory), 1 to MAX_SCENES sub-scenes, a known
    save_frames, then the backend's own keys (SAPIEN's: its light pool, kept garages and Vulkan device)."""
    chosen_backend = chosen(conf)
    check_range(conf.get("scenes", 1), 1, MAX_SCENES, "renderer.scenes")
    if conf.save_frames not in SAVE_FRAMES:
        raise GarageError(f"unknown save_frames {conf.save_frames!r} (all | key | none)", "renderer.save_frames")
    if chosen_backend.check is not None:
        chosen_backend.check(conf)


def open_renderer(conf, hidden, scenes: int | None = None):
    """The one way to open a renderer: the `renderer` group's backend as a render scene (`render.batch.RenderScene`)
    of `scenes` sub-scenes (default `renderer.scenes`, 1 when unset), batched as the backend batches (SAPIEN:
    one RenderSystemGroup under `renderer.device=cuda`), else one sub-scene after another. hidden: where an actor
    absent from a shot waits. Sub-scene 0 is the process's warm renderer where the backend keeps one."""
    from garage_exp.core.plain import plain
    from garage_exp.render.batch import RenderScene

    settings = plain(conf)
    n = int(scenes if scenes is not None else settings.get("scenes", 1) or 1)
    chosen_backend = chosen(conf)
    kept = chosen_backend.settings({k: v for k, v in settings.items() if k not in NOT_SETTINGS})

    def first():
        return chosen_backend.make(**kept)

    if chosen_backend.scene is not None:
        return chosen_backend.scene(first, n, hidden, **kept)
    return RenderScene.of(first(), n, hidden)
