"""Materials of the built garage. Colours are linear RGBA (glTF's and SAPIEN's convention), so a mid-grey
concrete is about 0.2, not 0.5."""

from __future__ import annotations

from garage_exp.scene.description import Material

# Floors: driveable asphalt is the darkest surface so lanes read apart from bays in a dim frame.
ASPHALT = Material("asphalt", (0.045, 0.045, 0.05, 1.0), roughness=0.9)
BAY_FLOOR = Material("bay_floor", (0.22, 0.21, 0.19, 1.0), roughness=0.85)
FREE_FLOOR = Material("free_floor", (0.15, 0.15, 0.14, 1.0), roughness=0.85)
OBSTACLE = Material("obstacle_concrete", (0.09, 0.09, 0.09, 1.0), roughness=0.9)

# Walls: light paint with a darker band up to bumper height, as most garages have.
WALL_PAINT = Material("wall_paint", (0.55, 0.55, 0.52, 1.0), roughness=0.8)
WALL_BAND = Material("wall_band", (0.07, 0.09, 0.13, 1.0), roughness=0.7)

# Pillars: white with a safety-yellow foot.
PILLAR_PAINT = Material("pillar_paint", (0.62, 0.62, 0.6, 1.0), roughness=0.75)
PILLAR_BAND = Material("pillar_band", (0.85, 0.52, 0.0, 1.0), roughness=0.6)

CEILING = Material("ceiling", (0.25, 0.25, 0.24, 1.0), roughness=0.95)
BEAM = Material("beam", (0.3, 0.3, 0.29, 1.0), roughness=0.95)

# Paint: centre lines yellow, bay and stop lines white.
LANE_YELLOW = Material("paint_yellow", (0.8, 0.55, 0.02, 1.0), roughness=0.6)
LANE_WHITE = Material("paint_white", (0.75, 0.75, 0.73, 1.0), roughness=0.6)

LAMP_OFF = Material("lamp_off", (0.3, 0.3, 0.3, 1.0), roughness=0.5)
LAMP_GLOW = 1.5  # emission per unit of light intensity: bright panels saturate the camera, as real ones do


def lamp_on(colour: tuple[float, float, float], intensity: float) -> Material:
    """An emissive panel; its emission follows the lamp's light intensity."""
    emission = tuple(float(c) * LAMP_GLOW * intensity for c in colour)
    return Material(f"lamp_on_{intensity:g}", (0.9, 0.9, 0.9, 1.0), roughness=0.3, emission=emission)


def faded(paint: Material, floor: Material, wear: float) -> Material:
    """Paint worn by `wear` (0 fresh .. 1 gone): its colour moves towards the floor's."""
    if wear <= 0.0:
        return paint
    color = tuple(p + (f - p) * wear for p, f in zip(paint.color[:3], floor.color[:3])) + (1.0,)
    return Material(f"{paint.name}_on_{floor.name}_worn{wear:.3f}", color,
                    roughness=paint.roughness + (floor.roughness - paint.roughness) * wear)
