"""Rendering: a Frame (picture, entity ids, camera), the Renderer interface, and the registry of backends.

Importing this package does not import a backend: `Frame` is plain data that ground truth and tests use without
a Vulkan device. The backend is the one registered under `renderer.backend` (render/registry.py; `sapien` by
default), so a second backend is one module plus its registration. `render.open.open_renderer` is how every
caller (the job, the search's pre-screen, the gym, the benchmarks) gets its render scene (render/batch.py: N
sub-scenes behind one `render_batch`), batched by the backend.
"""

from __future__ import annotations

from garage_exp.render.base import BLANK_GREY, Frame, Renderer
from garage_exp.render.registry import register_backend

__all__ = ["BLANK_GREY", "Frame", "Renderer", "register_backend"]
