"""Functions named by configs (`_target_`: a scene modifier, a scenario's own site, a renderer factory). Configs are data: they may
only name functions under `garage_exp.` or under the module prefixes listed, comma-separated, in
$GARAGE_EXP_MODIFIER_MODULES; they cannot import arbitrary code."""

from __future__ import annotations

import importlib
import os
from collections.abc import Callable

from garage_exp.core.errors import GarageError

PROJECT_MODULES = ("garage_exp.",)


def allowed_modules() -> tuple[str, ...]:
    return PROJECT_MODULES + tuple(p.strip() for p in os.environ.get("GARAGE_EXP_MODIFIER_MODULES", "").split(",")
                                   if p.strip())


def check_target(target: str, what: str, where: str) -> None:
    """GarageError naming `where` unless `target` lies under an allowed module."""
    allowed = allowed_modules()
    if target and not target.startswith(allowed):
        raise GarageError(f"_target_ {target!r} is not {what} (allowed modules: {', '.join(allowed)}; "
                          "more via $GARAGE_EXP_MODIFIER_MODULES)", where)


def resolve_allowed(target: str, where: str, what: str = "scene modifier") -> Callable:
    """The function `target` names, if its module is allowed."""
    allowed = allowed_modules()
    if not target.startswith(allowed):
        raise GarageError(f"{target!r} is not a {what} (allowed modules: {', '.join(allowed)}; more via "
                          "$GARAGE_EXP_MODIFIER_MODULES)", where)
    return resolve(target)


def resolve(target: str, what: str = "scene modifier", where: str = "_target_") -> Callable:
    """The function a dotted `_target_` names."""
    module, _, attr = target.rpartition(".")
    try:
        return getattr(importlib.import_module(module), attr)
    except (ImportError, AttributeError, ValueError):
        raise GarageError(f"cannot import {what} {target!r}", where) from None
