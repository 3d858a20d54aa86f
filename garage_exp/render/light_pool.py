"""The renderer's fixed pool of point lights, handed each frame to the lamps that matter at the camera.

SAPIEN's default shader is compiled for a fixed number of point lights (at most 10), and changing the count
recompiles it. So every scene holds `max_lights` point lights, and before each frame they go to the lamps that
contribute most at the camera (intensity / distance^2); spare pool lights get zero colour. Every lamp fixture
is drawn as an emissive box whether or not it holds a pool light (the scene builder's job, not this module's).
Shadows (`shadows=True`) go to the 3 strongest pool lights (SAPIEN's limit): measured 0.144 s vs 0.047 s a
frame (3x; 2.6x with 128 px shadow maps), so they are off by default.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from garage_exp.scene.description import Scene

# SAPIEN's point light adds albedo * colour * cos / (pi * d^2): a description intensity of 1.0 (a ~40 W LED
# batten) becomes a colour of LAMP_POWER, which lights a grey (0.5) floor 2.5 m below one lamp to ~0.25
# linear (~140 of 255 after the shader's 1/2.2 gamma).
LAMP_POWER = 10.0
SHADOW_MAP_SIZE = 512  # per cube face; lavapipe renders all six faces of every shadowed light each frame
SHADOW_NEAR, SHADOW_FAR = 0.05, 30.0
MAX_SHADOWED = 3  # SAPIEN's default shader: "too many point lights that cast shadows" beyond this


class LightPool:
    """The lamps of the loaded scene (positions, colours, weights) and the pool of SAPIEN lights they share."""

    def __init__(self) -> None:
        self.lights: list[object] = []  # RenderPointLightComponents
        self.pos = np.zeros((0, 3))
        self.rgb = np.zeros((0, 3))
        self.weight = np.zeros(0)

    def set_lamps(self, scene: Scene) -> None:
        """The lamps the pool's lights go to, frame by frame (see choose); unlit lamps take none."""
        lamps = [light for light in scene.lights if light.intensity > 0]
        self.pos = np.array([light.position for light in lamps], dtype=float).reshape(-1, 3)
        self.rgb = np.array([np.asarray(light.color) * light.intensity * LAMP_POWER for light in lamps],
                            dtype=float).reshape(-1, 3)
        self.weight = np.array([light.intensity for light in lamps], dtype=float)

    def add_to(self, sapien_scene, count: int, shadows: bool) -> None:
        """Put `count` dark point lights into a new SAPIEN scene."""
        for k in range(count):
            # The pool is filled strongest first, so with shadows on the lamps nearest the camera cast them.
            self.lights.append(sapien_scene.add_point_light(
                [0.0, 0.0, -100.0], [0.0, 0.0, 0.0], shadow=shadows and k < MAX_SHADOWED,
                shadow_near=SHADOW_NEAR, shadow_far=SHADOW_FAR, shadow_map_size=SHADOW_MAP_SIZE))

    def choose(self, position: Sequence[float], count: int) -> np.ndarray:
        """Indices of the (at most `count`) lamps that get the pool's lights at this camera position (largest
        intensity/d^2), strongest first."""
        if len(self.pos) == 0:
            return np.zeros(0, dtype=int)
        d2 = np.sum((self.pos - np.asarray(position, dtype=float)) ** 2, axis=1)
        score = self.weight / np.maximum(d2, 1e-6)
        n = min(count, len(score))
        best = np.argpartition(-score, n - 1)[:n]
        return best[np.argsort(-score[best], kind="stable")]

    def place(self, position: Sequence[float], count: int) -> None:
        """Give the pool's lights to the lamps chosen for a camera at `position`; the spare ones go dark."""
        import sapien

        chosen = self.choose(position, count)
        for k, light in enumerate(self.lights):
            if k < len(chosen):
                light.pose = sapien.Pose(self.pos[chosen[k]].tolist())
                light.color = self.rgb[chosen[k]].tolist()
            else:
                light.color = [0.0, 0.0, 0.0]
