"""The kind of vehicle (car, van, pickup, suv, bus, truck) a model name says: the asset library sorts models
by it and the dataset export labels boxes by it, from the scene's entities alone."""

from __future__ import annotations

# Name fragments, most specific first (minibus before bus, pickup before the colour words).
_KIND_WORDS = (("minibus", "van"), ("motorhome", "van"), ("van", "van"), ("pickup", "pickup"),
               ("dodgeram", "pickup"), ("crv", "suv"), ("bus", "bus"), ("truck", "truck"),
               ("paramedic", "van"))


def kind_of(name: str) -> str:
    """The vehicle kind a model name says ('car' when it says none)."""
    lower = name.lower()
    return next((kind for word, kind in _KIND_WORDS if word in lower), "car")
