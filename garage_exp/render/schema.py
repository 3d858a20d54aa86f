"""The `renderer` group's schema, beside the backends its `_target_` names (render/__init__.py checks it),
registered as a config node here (core/config_nodes.py).
"""

from __future__ import annotations

from dataclasses import dataclass

from garage_exp.core.config_nodes import register_node


@dataclass
class RendererConf:
    """The renderer: `backend` names a registered backend (render/registry.py), whose factory is called with the
    other keys it takes; `_target_`, kept for configs that name a factory there, wins when it is not SAPIEN's."""

    name: str = "sapien"
    backend: str = "sapien"
    _target_: str = "garage_exp.render.sapien_backend.make"
    max_lights: int = 8
    shadows: bool = False
    save_frames: str = "key"  # all | key | none
    device: str = "auto"  # the Vulkan device: auto (a GPU when present, else lavapipe) | cpu | cuda (render.device)
    scenes: int = 1  # sub-scenes of the render scene: the shots rendered as one batch (render/batch.py)
    # loaded garages the SAPIEN renderer keeps: a job on one of the last N garages replaces only its actors and
    # cameras (a search across a few plans switches garages without rebuilding them); 1: the last one, as before
    kept_garages: int = 1


register_node("renderer", RendererConf, group=True)
