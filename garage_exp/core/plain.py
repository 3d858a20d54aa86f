"""Config nodes as plain data: the one place where a DictConfig is turned into dicts, `Settings` and dataclasses.
The job (`run`) and the commands above it hand the stages under it (plan, scene, scenario, render, perception,
results, tracking, exports) `Settings`, never a config node: those stages import no OmegaConf (pyproject.toml's
import-linter contract), and tests/test_spec.py watches every call into them during a job, a search and an
adversary's episode for a node among the arguments."""

from __future__ import annotations

import types
import typing
from dataclasses import is_dataclass
from typing import Any

from garage_exp.core.state import STATE


class Settings(dict):
    """A config group's values as plain, read-only data: a dict whose keys read as attributes too (`garage.width`
    as a node reads), nested groups `Settings`, lists tuples, interpolations resolved. Read-only because the
    layers below the job are told the job's settings; none of them may change what the next one reads."""

    __slots__ = ()

    def __getattr__(self, name: str) -> Any:
        try:
            return self[name]
        except KeyError:
            raise AttributeError(name) from None

    def _refuse(self, *args: Any, **kwargs: Any):
        raise TypeError("a job's settings are read-only (core.plain.Settings)")

    __setattr__ = __setitem__ = __delitem__ = __delattr__ = _refuse
    pop = popitem = clear = update = setdefault = _refuse

    def __copy__(self) -> "Settings":
        return self

    def __deepcopy__(self, memo: dict) -> "Settings":
        return self

    def __reduce__(self):  # a pickle (a Ray task's arguments) builds it back through the constructor
        return (Settings, (dict(self),))


def frozen(value: Any) -> Any:
    """A container's values as Settings and tuples (leaves as they are)."""
    if isinstance(value, dict):
        return Settings({k: frozen(v) for k, v in value.items()})
    if isinstance(value, (list, tuple)):
        return tuple(frozen(v) for v in value)
    return value


def settings(node: Any) -> Any:
    """A config node (or a dict, a dataclass, a list) as read-only plain data: `Settings` and tuples; None as None."""
    from omegaconf import DictConfig, ListConfig, OmegaConf

    if isinstance(node, Settings):
        return node
    if isinstance(node, DictConfig) and holds(node, "hydra"):  # composed with Hydra's own node (tests): not a setting,
        # and its sweep keys resolve only inside a sweep; the other keys resolve against the whole config as before
        return Settings({k: settings(child) if isinstance(child := node._get_node(k), (DictConfig, ListConfig))
                         else frozen(node[k]) for k in node if k != "hydra"})
    if isinstance(node, (DictConfig, ListConfig)):
        return frozen(resolved(node))
    if is_dataclass(node) and not isinstance(node, type):
        from dataclasses import asdict

        return frozen(asdict(node))
    return frozen(node)


def holds(node, key: str) -> bool:
    """`key in node` for a DictConfig, without asking the node where its own keys say no: on a struct node (each
    group of a composed config) OmegaConf answers a missing key by raising and catching a ConfigAttributeError, its
    message formatted (~57 us), and the exception's traceback is garbage in a cycle. `settings` asked it of every
    group of every draw a search checks (~13 a draw), and those cycles were a large share of what the collector
    found in a one-shot search."""
    content = node.__dict__["_content"]
    return (not isinstance(content, dict) or key in content) and key in node


def resolved(node: Any, resolve: bool = True) -> Any:
    """`OmegaConf.to_container(node, resolve=resolve)`, read from the nodes: a value that is no interpolation is
    taken as it is held, the rest resolved as to_container resolves it (or kept as written, resolve=False). A job
    and each draw a search checks convert their config (~630 nodes on the wide space: 3.6 ms by to_container, most
    of it spent per node on values that need no resolving; 2.0 ms here), and the schema check reads it unresolved.
    Anything that raises is converted again by to_container, which raises it in its words; tests/test_job_spec.py
    pins the two equal."""
    from omegaconf import OmegaConf

    try:
        return _content(node, resolve)
    except Exception:  # noqa: BLE001 - to_container says what is wrong, as it did
        return OmegaConf.to_container(node, resolve=resolve)


def _content(conf: Any, resolve: bool) -> Any:
    """omegaconf's BaseContainer._to_content(conf, resolve, throw_on_missing=False), values read directly."""
    from omegaconf import MISSING, Container, DictConfig

    if conf._is_none():
        return None
    if conf._is_missing():
        return MISSING
    if conf._is_interpolation():
        if not resolve:
            return conf._value()
        conf = conf._dereference_node()
    items = conf.__dict__["_content"]
    keys = items.keys() if isinstance(conf, DictConfig) else range(len(items))
    out = {} if isinstance(conf, DictConfig) else []
    for key in keys:
        node = items[key]
        if isinstance(node, Container):
            value = _content(node, resolve)
        else:
            value = node.__dict__["_val"]
            if resolve and isinstance(value, str) and "${" in value:  # resolved as to_container resolves it
                node = node._dereference_node()
                value = _content(node, resolve) if isinstance(node, Container) else node._value()
        if isinstance(out, dict):
            out[key] = value
        else:
            out.append(value)
    return out


def thawed(value: Any) -> Any:
    """Settings and tuples back as dicts and lists (to write them, or to merge them into a node)."""
    if isinstance(value, dict):
        return {k: thawed(v) for k, v in value.items()}
    if isinstance(value, tuple):
        return [thawed(v) for v in value]
    return value


def plain(node: Any) -> dict:
    """A node's settings as a plain dict (interpolations resolved; nested nodes as dicts and lists)."""
    from omegaconf import DictConfig

    if isinstance(node, DictConfig):
        return resolved(node)
    if is_dataclass(node) and not isinstance(node, type):
        from dataclasses import asdict

        return asdict(node)
    return thawed(dict(node or {}))


def as_object(node: Any) -> Any:
    """A node as the dataclass its schema names (a dict where it has none); a dataclass or dict as it is."""
    from omegaconf import DictConfig, OmegaConf

    if not isinstance(node, DictConfig):
        return node
    return OmegaConf.to_object(node) if OmegaConf.get_type(node) is not dict else OmegaConf.to_container(node)


def structured(schema: type, *nodes: Any):
    """A config node of `schema` (a dataclass) with `nodes` (nodes, dicts, or YAML files as paths) merged over its
    defaults: how a command outside Hydra (the scenario importer) makes the node a job would have."""
    from pathlib import Path

    from omegaconf import OmegaConf

    return OmegaConf.merge(OmegaConf.structured(schema),
                           *(OmegaConf.load(n) if isinstance(n, Path) else n for n in nodes))


def typed(schema: type, values: Any, where: str = "") -> Any:
    """A group's values (`Settings` or a dict, as `settings` makes them) as the dataclass its schema is, nested
    groups as theirs (a field's dataclass, list, tuple, dict or Optional of them): what a layer below the job is
    handed, so that a misspelt key is an AttributeError, not a dict's silent None. Values the schema types `Any`
    (a `_target_` spec) stay `Settings`. A key the schema lacks (forced past it: `+case.actors.x.bumper=1`) is a
    GarageError at `where.key`, as the schema check (core/schema_check.py) words it."""
    if values is None or isinstance(values, schema):
        return values
    from garage_exp.core.errors import GarageError

    hints = _hints(schema)
    for key in values:
        if key not in hints:
            raise GarageError(f"unknown key {key!r} (not in {schema.__name__})", f"{where}.{key}".lstrip("."))
    return schema(**{key: _typed(hints[key], value, f"{where}.{key}") for key, value in values.items()})


@STATE.memo("process", maxsize=256)  # a schema's hints: the same for the process's life
def _hints(schema: type) -> dict:
    return typing.get_type_hints(schema)


def _typed(hint: Any, value: Any, where: str) -> Any:
    """One value as its field's type hint says (typed's doc)."""
    if value is None:
        return None
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):  # Optional[X]: X
        hint = next(a for a in args if a is not type(None))
        origin, args = typing.get_origin(hint), typing.get_args(hint)
    if is_dataclass(hint):
        return typed(hint, value, where)
    if origin is list:
        return [_typed(args[0] if args else Any, v, f"{where}.{k}") for k, v in enumerate(value)]
    if origin is tuple:  # tuple[X, Y] or tuple[X, ...]
        inner = args if args and Ellipsis not in args else (args[:1] or (Any,)) * len(value)
        return tuple(_typed(a, v, f"{where}.{k}") for k, (a, v) in enumerate(zip(inner, value)))
    if origin is dict:
        return {k: _typed(args[1] if args else Any, v, f"{where}.{k}") for k, v in value.items()}
    return value
