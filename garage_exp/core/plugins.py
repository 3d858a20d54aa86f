"""Components named by configs, and the one way they are built.

A config node names its component with `_target_` (the renderer, the sensor, the detector, a scene modifier,
a scenario's own site function); `build` makes it with `hydra.utils.instantiate`, the node's other keys as the
component's settings and the caller's arguments (the scene, the plan) beside them. Configs are data: they may
only name code under `garage_exp.` or under the module prefixes listed, comma-separated, in
$GARAGE_EXP_MODIFIER_MODULES; they cannot import arbitrary code.

Kinds that a config names by a plain word (a detector entry kind, an objective, a camera model or view, a sensor
kind, a slot detector kind) are registries filled by `@register_*` beside what they register. A module of the
user's that registers some is named in $GARAGE_EXP_PLUGINS (comma-separated module names): every command imports
them before its job starts (`import_plugins`), and code under them may be named by configs too.
"""

from __future__ import annotations

import importlib
import os
from collections.abc import Callable
from typing import Any

from garage_exp.core.errors import GarageError, did_you_mean

PROJECT_MODULES = ("garage_exp.",)


def allowed_modules() -> tuple[str, ...]:
    return PROJECT_MODULES + tuple(p.strip() for p in os.environ.get("GARAGE_EXP_MODIFIER_MODULES", "").split(",")
                                   if p.strip()) + tuple(f"{m}." for m in plugin_modules())


def plugin_modules() -> tuple[str, ...]:
    """The modules named in $GARAGE_EXP_PLUGINS."""
    return tuple(m.strip() for m in os.environ.get("GARAGE_EXP_PLUGINS", "").split(",") if m.strip())


def import_plugins() -> None:
    """Import the modules $GARAGE_EXP_PLUGINS names, so that their registrations take effect (each once: Python
    keeps an imported module); one GarageError naming the variable when one cannot be imported."""
    for module in plugin_modules():
        try:
            importlib.import_module(module)
        except Exception as exc:  # noqa: BLE001 - the user's module: which import failed and why, in one line
            raise GarageError(f"cannot import plugin {module!r}: {import_failure(module, exc)}",
                              "$GARAGE_EXP_PLUGINS") from None


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
        loaded = importlib.import_module(module)
    except Exception as exc:  # noqa: BLE001 - the user's module: which import failed and why, in one line
        raise GarageError(f"cannot import {what} {target!r}: {import_failure(module, exc)}", where) from None
    try:
        return getattr(loaded, attr)
    except AttributeError:
        names = [n for n in vars(loaded) if not n.startswith("_") and callable(getattr(loaded, n))]
        hint = did_you_mean(attr, names) if names else " (it defines no functions)"
        raise GarageError(f"cannot import {what} {target!r}: module {module!r} ({source_of(loaded)}) has no "
                          f"{attr!r}{hint}", where) from None


def import_failure(module: str, exc: Exception) -> str:
    """Why `import module` failed, said so that a user can act on it: a syntax error (file and line), the module
    itself not found (with the Python path it was looked for on), a dependency it imports not installed, or an
    error its code raised while being imported."""
    if isinstance(exc, SyntaxError):
        return f"its file {exc.filename}, line {exc.lineno}, has a syntax error: {exc.msg}"
    if isinstance(exc, ModuleNotFoundError) and exc.name and (module == exc.name or module.startswith(exc.name + ".")):
        top = module.split(".")[0]
        if exc.name != top:
            return f"package {exc.name.rpartition('.')[0]!r} has no module {exc.name!r}"
        path = os.environ.get("PYTHONPATH", "")
        return (f"no module {top!r} on the Python path (PYTHONPATH "
                + (f"is {path!r}" if path else "is not set") + f"; put the folder that holds {top}/ or {top}.py on it)")
    if isinstance(exc, ModuleNotFoundError):
        return f"its module imports {exc.name!r}, which is not installed"
    first = (str(exc).strip().splitlines() or [""])[0]
    return f"importing {module!r} raised {type(exc).__name__}: {first}"[:300]


def source_of(module) -> str:
    return getattr(module, "__file__", None) or "a namespace package"


def build(node: Any, what: str, where: str, *args: Any, **kwargs: Any) -> Any:
    """The component the config node names: `hydra.utils.instantiate(node, *args, **kwargs)`, so `_target_` is
    called with args, then the node's other keys and kwargs as keyword arguments. Only allowed modules; a
    target that cannot be imported or refuses its arguments is one GarageError naming `where`. The project's own
    code named by plain settings is called directly, as instantiate calls it (`direct`)."""
    from hydra.errors import InstantiationException
    from hydra.utils import instantiate
    from garage_exp.core.plain import plain, thawed

    settings = plain(node)
    target = str(settings.get("_target_") or "")
    made = resolve(target, what, where)  # checked and imported here, so that its errors name the config's place
    try:
        if target.startswith(PROJECT_MODULES) and direct(settings, kwargs):
            # instantiate's copy of the node into a config, its merge of kwargs and its checks cost ~2 ms a call: a
            # draw of the wide space builds a dozen (the sensor, the detector's settings, the scene's modifiers)
            fields = {key: thawed(value) for key, value in settings.items() if key != "_target_"}
            try:
                return made(*args, **{**fields, **kwargs})
            except Exception as exc:  # noqa: BLE001 - in instantiate's words, as it would have raised it
                name = f"{getattr(made, '__module__', '')}.{getattr(made, '__qualname__', target)}"
                raise InstantiationException(f"Error in call to target '{name}':\n{exc!r}") from exc
        return instantiate(settings, *args, _convert_="all", **kwargs)
    except InstantiationException as exc:
        cause = exc.__cause__
        if isinstance(cause, GarageError):
            raise cause from None
        if isinstance(cause, TypeError):  # wrong or missing settings for this target
            raise GarageError(f"{target}: {cause}", where) from None
        raise


INSTANTIATE_KEYS = ("_target_", "_args_", "_recursive_", "_convert_", "_partial_")


def direct(settings: dict, kwargs: dict) -> bool:
    """Whether `instantiate(settings, _convert_="all", **kwargs)` would call the target with the settings as they
    are (dicts and lists for tuples): no key of instantiate's but the top `_target_`, no text it would resolve
    (`${...}`) or refuse as missing (`???`), no caller's dict or list for it to copy."""
    def plain_value(value: Any) -> bool:
        if isinstance(value, dict):
            return all(isinstance(k, str) and k not in INSTANTIATE_KEYS and plain_value(v) for k, v in value.items())
        if isinstance(value, (list, tuple)):
            return all(plain_value(v) for v in value)
        if isinstance(value, str):
            return "${" not in value and value != "???"  # instantiate resolves the one, refuses the other
        return value is None or isinstance(value, (bool, int, float))

    return (all(isinstance(k, str) and (k == "_target_" or (not k.startswith("_") and plain_value(v)))
                for k, v in settings.items())
            and not any(isinstance(v, (dict, list, tuple)) or k.startswith("_") for k, v in kwargs.items()))
