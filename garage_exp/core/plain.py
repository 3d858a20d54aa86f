"""Config nodes as plain data: the one place below the job (`run`) where a DictConfig is turned into dicts and
dataclasses, so that the stages under it (plan, scene, render, perception, results) import no OmegaConf
(pyproject.toml's import-linter contract) and take a node, a dict or a dataclass alike."""

from __future__ import annotations

from dataclasses import is_dataclass
from typing import Any


def plain(node: Any) -> dict:
    """A node's settings as a plain dict (interpolations resolved; nested nodes as dicts and lists)."""
    from omegaconf import DictConfig, OmegaConf

    if isinstance(node, DictConfig):
        return OmegaConf.to_container(node, resolve=True)
    if is_dataclass(node) and not isinstance(node, type):
        from dataclasses import asdict

        return asdict(node)
    return dict(node or {})


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
