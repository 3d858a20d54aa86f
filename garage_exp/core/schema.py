"""The experiment's config schema, assembled from the nodes each layer registers beside the code that owns it
(core/config_nodes.py: register_node), and its registration in Hydra's ConfigStore.

A YAML level of a group is validated against its dataclass (typos and wrong types fail at compose time). Core
declares no node and names no layer above it: the module that composes the experiment's config imports the
owners (their registrations run on import), calls `assemble` with the config's order and its own plain values
and registers the dataclass that makes, `Config` (register_config, config_schema).
"""

from __future__ import annotations

import dataclasses
import typing
from collections.abc import Sequence
from dataclasses import field

from hydra.core.config_store import ConfigStore

from garage_exp.core.config_nodes import NODES
from garage_exp.core.state import STATE

_ASSEMBLED: list[type] = []  # the experiment's Config, once its composer has registered it (register_config)


def assemble(order: Sequence[str], values: type, module: str) -> type:
    """The top-level config's dataclass (`Config`): each key of `order` is a registered node (its dataclass,
    defaults from it) or a field of `values` (the composer's own plain values, with their defaults); a registered
    node that `order` does not place comes after them, so that a new node is its module and its registration.
    `module` is the composer's, where `Config` can be imported from (a pickled config names its class there)."""
    plain = {f.name: f for f in dataclasses.fields(values)}
    unknown = [k for k in order if k not in NODES and k not in plain]
    if unknown:
        raise LookupError(f"config keys {unknown} are neither registered nodes nor values of {values.__name__}")
    spec = []
    for key in [*order, *(k for k in NODES if k not in order)]:
        if key in NODES:
            schema = NODES[key].schema
            spec.append((key, schema, field(default_factory=schema)))
        else:
            f = plain[key]
            spec.append((key, f.type, field(default=f.default, default_factory=f.default_factory)))
    config = dataclasses.make_dataclass("Config", spec)
    config.__module__ = module
    return config


def register_config(config: type) -> type:
    """`config` (assemble's) as the experiment's Config: the schema check's and the ConfigStore's; returns it."""
    _ASSEMBLED[:] = [config]
    return config


def config_schema() -> type:
    """The experiment's `Config`, as its composer registered it."""
    if not _ASSEMBLED:
        raise LookupError("the experiment's config schema is not assembled: the command that composes the "
                          "experiment's config imports its composer first")
    return _ASSEMBLED[0]


def schema_named(name: str) -> type | None:
    """A registered node's dataclass, or one nested in it, by its class name (`BevSpec`, `SlotLinesConf`)."""
    seen: set[type] = set()
    todo = [node.schema for node in NODES.values()]
    while todo:
        schema = todo.pop(0)
        if schema in seen:
            continue
        seen.add(schema)
        if schema.__name__ == name:
            return schema
        for hint in typing.get_type_hints(schema).values():
            todo += [t for t in _types_in(hint) if isinstance(t, type) and dataclasses.is_dataclass(t)]
    return None


def _types_in(hint) -> list:
    """A type hint and every type inside it (Optional[X], list[X], dict[str, X])."""
    return [hint, *(t for arg in typing.get_args(hint) for t in _types_in(arg))]


def __getattr__(name: str):
    """`Config` and, for code written when every node was declared here, each registered node's dataclass by its
    name (its owner's module imported first, as the composer does)."""
    if name == "Config" and _ASSEMBLED:
        return _ASSEMBLED[0]
    found = schema_named(name) if not name.startswith("_") else None
    if found is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r} (a node's dataclass lives beside its "
                             "owner; import it from there)")
    return found


# What register() last stored: (group, name, dataclass) -> the ConfigStore entry it made.
_STORED = STATE.cache("core.schema.stored", "process")


def register() -> None:
    """Store the config schema and each group's schema in Hydra's ConfigStore. Every command calls it (and every
    composition outside one); storing converts each dataclass (OmegaConf.structured, 0.1-0.2 s in all), so a
    dataclass whose entry is still in the store is not stored again: a process running many commands (a test
    session, a notebook) pays it once."""
    cs = ConfigStore.instance()
    # A group, so that a command whose config composes the experiment's (conf/gym.yaml) types it with its own
    # subclass of Config: `override config_schema: gym`.
    nodes = [("config_schema", "experiment", config, "_global_") for config in _ASSEMBLED]
    nodes += [(key, f"{key}_schema", node.schema, None) for key, node in NODES.items() if node.group]
    for group, name, node, package in nodes:
        entries = cs.repo.get(group, {})
        if _STORED.get((group, name, node)) is None or entries.get(f"{name}.yaml") is not _STORED[group, name, node]:
            cs.store(group=group, name=name, node=node, package=package)
            _STORED[group, name, node] = cs.repo[group][f"{name}.yaml"]
