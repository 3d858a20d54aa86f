"""Where config nodes register: each node's dataclass is declared beside the code that owns and checks it, in the
layer that owns it, and registered there with `register_node` when its module is imported. Core keeps only what
was registered, so it names no layer above it; the module that composes the experiment's config imports the
owners and assembles the schema from these registrations (core/schema.py: assemble).

As ManiSkill keeps `CameraConfig` beside `Camera`: one place for a node's keys, defaults and types.
"""

from __future__ import annotations

from dataclasses import dataclass

# OmegaConf's marker for a value a config must give (omegaconf.MISSING), spelled here so that a node below the job
# can use it without importing OmegaConf (the import contract keeps OmegaConf above the layers).
MISSING = "???"


@dataclass(frozen=True)
class Node:
    """A registered node: its top-level key, its dataclass and whether it is a config group (YAML levels in
    conf/<key>/, whose schema Hydra's ConfigStore also keeps as `<key>_schema`)."""

    key: str
    schema: type
    group: bool


# key -> Node, in the order of registration (which import order decides: the composer sets the config's order).
NODES: dict[str, Node] = {}


def register_node(key: str, schema: type, *, group: bool = False) -> type:
    """Register `schema` (a dataclass) as the top-level config node `key`; a group when it has YAML levels.
    Registering the same key again replaces it (a reloaded module); returns the schema."""
    NODES[key] = Node(key, schema, group)
    return schema


def group_keys() -> tuple[str, ...]:
    """The registered nodes that are config groups."""
    return tuple(key for key, node in NODES.items() if node.group)
