"""The composed config against the schema (garage_exp/core/schema.py), once per job, before anything is written.

Hydra's `+key=value` and `++key=value` open the struct flag to add a key, so a typo such as
`+case.bumper_gapp=1` or `+case.actors.target.offsett=1` would be added and silently ignored. Here every key of
the composed config is looked up in its dataclass, down every nested dataclass, every list of them
(`camera.cameras`) and every dict of them (`case.actors.<name>`, `occluder.actors.<name>`); a field typed
`dict[str, Any]` or a dict of plain values (`modifiers`, `sensor.params`, `case.bays`, `search.suite.bands`)
is open by design. The first unknown key is one GarageError naming the override that brought it (or the config
file), the key and the nearest valid one.
"""

from __future__ import annotations

import dataclasses
import typing
from pathlib import Path
from typing import Any, Iterator

from omegaconf import DictConfig, OmegaConf

from garage_exp.core.plain import holds
from garage_exp.core.state import STATE
from garage_exp.core.schema import config_schema
from garage_exp.core.errors import GarageError, did_you_mean

NOT_IN_SCHEMA = ("hydra",)  # top-level nodes that are not the task's config (a sweep job's config carries hydra)


@STATE.memo("process", maxsize=None)
def _fields(schema: type) -> dict[str, Any]:
    return typing.get_type_hints(schema)


def unknown_keys(value: Any, schema: Any, path: tuple[str, ...] = ()) -> Iterator[tuple[tuple[str, ...], str, type]]:
    """(parent path, key, dataclass) for every key of `value` (plain dicts and lists, as
    `OmegaConf.to_container` gives them) that its dataclass in `schema` does not have, in the config's order."""
    origin, args = typing.get_origin(schema), typing.get_args(schema)
    if origin is typing.Union:  # Optional[X]: X's keys, when the value is not None
        for arg in args:
            if arg is not type(None):
                yield from unknown_keys(value, arg, path)
        return
    if dataclasses.is_dataclass(schema) and isinstance(schema, type):
        if not isinstance(value, dict):
            return
        fields = _fields(schema)
        for key, item in value.items():
            if not path and key in NOT_IN_SCHEMA and schema is config_schema():
                continue
            if key not in fields:
                yield path, str(key), schema
            else:
                yield from unknown_keys(item, fields[key], (*path, str(key)))
    elif origin is dict and len(args) == 2 and isinstance(value, dict):  # dict[str, ActorConf]: each value
        for key, item in value.items():
            yield from unknown_keys(item, args[1], (*path, str(key)))
    elif origin in (list, tuple) and args and isinstance(value, list):
        for k, item in enumerate(value):
            yield from unknown_keys(item, args[0], (*path, str(k)))
    # Any, plain values, dicts of plain values: open


def task_overrides(cfg: DictConfig) -> list[str]:
    """The job's command-line overrides: a sweep job's config composed for the sweep's check carries its own
    (`hydra.overrides.task`); a running job's are Hydra's."""
    if isinstance(cfg, DictConfig) and holds(cfg, "hydra"):
        task = OmegaConf.select(cfg, "hydra.overrides.task", default=None)
        if task is not None:
            return [str(o) for o in task]
    from hydra.core.hydra_config import HydraConfig

    return [str(o) for o in HydraConfig.get().overrides.task] if HydraConfig.initialized() else []


def override_of(key: str, overrides: list[str]) -> str | None:
    """The override that set `key` (dotted path) or a node above or below it; one that adds (`+`, `++`)
    first."""
    found = []
    for o in overrides:
        if o.startswith("~"):
            continue
        name = o.split("=", 1)[0].lstrip("+")
        if name == key or key.startswith(name + ".") or name.startswith(key + "."):
            found.append(o)
    found.sort(key=lambda o: not o.startswith("+"))
    return found[0] if found else None


def level_file(cfg: DictConfig, group: str) -> str:
    """The YAML file a group's level came from (Hydra's choices and config sources), else the primary config."""
    try:
        from hydra.core.hydra_config import HydraConfig

        hc = cfg.hydra if isinstance(cfg, DictConfig) and holds(cfg, "hydra") else HydraConfig.get()
        level = hc.runtime.choices.get(group)
        sources = [s.path for s in hc.runtime.config_sources if s.schema == "file"]
    except (ValueError, AttributeError):  # composed outside a Hydra app
        return "the composed config"
    for folder in sources:
        path = Path(folder) / (f"{group}/{level}.yaml" if level else f"{hc.job.config_name}.yaml")
        if path.is_file():
            return str(path)
    return f"{group}={level}" if level else "the composed config"


def _task_values(cfg: DictConfig) -> dict:
    """The config as plain data, but Hydra's own node (a sweep job's config carries it; a fifth of the config),
    which unknown_keys skips: not converted."""
    from garage_exp.core.plain import resolved

    if not (isinstance(cfg, DictConfig) and any(holds(cfg, k) for k in NOT_IN_SCHEMA)):
        return resolved(cfg, resolve=False)
    out = {}
    for key in cfg:
        if key not in NOT_IN_SCHEMA:
            node = cfg._get_node(key)
            plain = OmegaConf.is_config(node) and not node._is_none() and not node._is_missing()
            out[key] = resolved(node, resolve=False) if plain else node._value()
    return out


def check_schema(cfg: DictConfig, overrides: list[str] | None = None) -> None:
    """Every key of the composed config is in the schema; else GarageError naming the override (or the file),
    the key and the nearest valid key: `+case.bumper_gapp=1: case has no key 'bumper_gapp' (did you mean
    'bumper_gap'?)`."""
    values = _task_values(cfg)
    for parent, key, schema in unknown_keys(values, config_schema()):
        full = ".".join((*parent, key))
        given = override_of(full, task_overrides(cfg) if overrides is None else overrides)
        where = given or level_file(cfg, parent[0] if parent else "")
        owner = ".".join(parent) or "the config"
        raise GarageError(f"{owner} has no key {key!r}{did_you_mean(key, _fields(schema))}", where)


def refuse_unknown_keys(cfg: DictConfig, schema: type) -> None:
    """A command's config (`python -m garage_exp.train`, `.verify`) holds only its schema's keys (Hydra's own
    `hydra` node aside); else GarageError naming the first unknown key and the dataclass that lacks it."""
    for path, key, owner in unknown_keys(OmegaConf.to_container(cfg, resolve=False), schema):
        if path == () and key == "hydra":
            continue
        raise GarageError(f"unknown key {key!r} (not in {owner.__name__})", ".".join((*path, key)))
