"""Components named by configs, and the one way they are built.

A config node names its component with `_target_` (the renderer, the sensor, the detector, a scene modifier,
a scenario's own site function); `build` makes it with `hydra.utils.instantiate`, the node's other keys as the
component's settings and the caller's arguments (the scene, the plan) beside them. Configs are data: they may
only name code under `garage_exp.` or under the module prefixes listed, comma-separated, in
$GARAGE_EXP_MODIFIER_MODULES; they cannot import arbitrary code.
"""

from __future__ import annotations

import importlib
import os
from collections.abc import Callable
from typing import Any

from garage_exp.core.errors import GarageError

PROJECT_MODULES = ("garage_exp.",)


def allowed_modules() -> tuple[str, ...]:
    return PROJECT_MODULES + tuple(p.strip() for p in os.environ.get("GARAGE_EXP_MODIFIER_MODULES", "").split(",")
                                   if p.strip())


def check_target(target: str, what: str, where: str) -> None:
    """GarageError naming `where` unless `target` lies under an allowed module."""
    allowed = allowed_modules()
    if not target:
        raise GarageError(f"{what} needs _target_ (the function or class to build it with)", where)
    if not target.startswith(allowed):
        raise GarageError(f"{target!r} is not {what} (allowed modules: {', '.join(allowed)}; "
                          "more via $GARAGE_EXP_MODIFIER_MODULES)", where)


def resolve(target: str, what: str, where: str) -> Callable:
    """The callable a dotted `_target_` names, if its module is allowed."""
    check_target(target, what, where)
    module, _, attr = target.rpartition(".")
    try:
        return getattr(importlib.import_module(module), attr)
    except (ImportError, AttributeError, ValueError):
        raise GarageError(f"cannot import {what} {target!r}", where) from None


def build(node: Any, what: str, where: str, *args: Any, **kwargs: Any) -> Any:
    """The component the config node names: `hydra.utils.instantiate(node, *args, **kwargs)`, so `_target_` is
    called with args, then the node's other keys and kwargs as keyword arguments. Only allowed modules; a
    target that cannot be imported or refuses its arguments is one GarageError naming `where`."""
    from hydra.errors import InstantiationException
    from hydra.utils import instantiate
    from omegaconf import DictConfig, OmegaConf

    settings = OmegaConf.to_container(node, resolve=True) if isinstance(node, DictConfig) else dict(node or {})
    target = str(settings.get("_target_") or "")
    resolve(target, what, where)  # checked and imported here, so that its errors name the config's place
    try:
        return instantiate(settings, *args, _convert_="all", **kwargs)
    except InstantiationException as exc:
        cause = exc.__cause__
        if isinstance(cause, GarageError):
            raise cause from None
        if isinstance(cause, TypeError):  # wrong or missing settings for this target
            raise GarageError(f"{target}: {cause}", where) from None
        raise
