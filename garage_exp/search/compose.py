"""One config composition per combination of group levels, the rest of a point's overrides set on a copy.

Hydra composes a job's config from the files (about 0.3-0.9 s here). Points of a search differ from one another by
a few values, so a point is composed once per combination of its structural overrides (a group's level, `+`/`~`,
Hydra's node), and its other overrides are set on a copy as Hydra's composition sets them on the composed defaults
(`OmegaConf.update(..., merge=True)`). `test_search.py` pins that the result equals Hydra's own composition. Used by
the search's launcher for every trial (launch.CachedLaunch) and by the search's check for every probed point of the
space (sweep.check: 300 points on the wide space, each a full composition before)."""

from __future__ import annotations

import copy
import re
from collections import defaultdict

from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.core.override_parser.types import Override, OverrideType, ValueType
from omegaconf import Container, DictConfig, OmegaConf, open_dict


class Compositions:
    def __init__(self, loader, config: DictConfig, groups):
        self.loader, self.config, self.groups = loader, config, set(groups)
        self.parser = OverridesParser.create()
        # Each point gets a copy of its composition (`copied`: ~2 ms on the wide space's config, where deepcopy
        # took 8-14 ms and unpickling 7 ms, but the package keeps no pickle module: test_reliability_inputs.py).
        self.cache: dict[tuple[str, ...], DictConfig] = {}
        self.parses: dict = {}  # override line -> its parsed Override

    def structural(self, override) -> bool:
        """Overrides that change the defaults list (a group's level, +/~) or Hydra's node: composed by Hydra."""
        key = override.key_or_group
        return (key in self.groups or "/" in key or key.startswith("hydra") or override.is_add()
                or override.is_delete() or override.is_force_add())

    def parsed(self, line: str):
        """An override parsed once: a search's fixed overrides recur in every point, its values often (a choice's
        levels). A drawn number (`key=12`, `key=-0.25`: most of a draw's lines, each new) is made as Hydra's parser
        makes it without its grammar (~0.1 ms a line, 3 ms a draw of the wide space; test_search.py pins that the
        two agree)."""
        if line not in self.parses:
            self.parses[line] = number_override(line) or self.parser.parse_overrides([line])[0]
        return self.parses[line]

    def compose(self, overrides: list[str], job: bool = True) -> DictConfig:
        """The config Hydra would compose for the command's config and `overrides` (a sweep's job), a copy of
        its own. job=False leaves Hydra's node as composed for the group levels (the overrides and dirname of a
        job are set by `as_job`): a search's check of a draw reads none of it, and setting its ~50 overrides as
        a typed list cost ~3 ms a draw, most of them rejected."""
        parsed = [self.parsed(line) for line in overrides]
        fixed = tuple(o.input_line for o in parsed if self.structural(o))
        if fixed not in self.cache:
            self.cache[fixed] = self.loader.load_sweep_config(self.config, list(fixed))
        cfg = copied(self.cache[fixed])
        for o in parsed:
            if not self.structural(o):
                OmegaConf.update(cfg, o.key_or_group, o.value(), merge=True)  # as Hydra applies an override
        return self.as_job(cfg, overrides) if job else cfg

    def as_job(self, cfg: DictConfig, overrides: list[str]) -> DictConfig:
        """`cfg`, composed for `overrides`, with Hydra's node as a sweep's job of them has it: its overrides and
        the dirname made of them."""
        from hydra._internal.config_loader_impl import get_overrides_dirname

        with open_dict(cfg):
            cfg.hydra.overrides.task = list(overrides)
            job = cfg.hydra.job
            cfg.hydra.job.override_dirname = get_overrides_dirname(
                overrides=[self.parsed(line) for line in overrides], kv_sep=job.config.override_dirname.kv_sep,
                item_sep=job.config.override_dirname.item_sep,
                exclude_keys=list(job.config.override_dirname.exclude_keys))
        return cfg


def copied(node, parent=None):
    """What `copy.deepcopy(node)` makes of an OmegaConf config, made directly (its nodes' `__deepcopy__`, without
    deepcopy's dispatch and memo: ~25 deepcopy calls a node, ~630 nodes in the wide space's config). As OmegaConf
    2.3's own copy: each node's metadata copied (its flags and resolver cache its own), a value shared (OmegaConf
    keeps a value as is: a str, a number, an enum), the content's nodes parented to the copy, a container's
    flag cache copied and a value node's emptied, the root's parent kept. test_search.py pins it against
    deepcopy node for node on the wide space's config."""
    new = object.__new__(type(node))
    state = dict(node.__dict__)
    meta = copy.copy(state["_metadata"])
    meta.flags = dict(meta.flags) if meta.flags is not None else None
    meta.resolver_cache = copy.deepcopy(meta.resolver_cache) if meta.resolver_cache else defaultdict(dict)
    state["_metadata"] = meta
    state["_parent"] = node.__dict__["_parent"] if parent is None else parent
    if isinstance(node, Container):
        cache = state["_flags_cache"]
        state["_flags_cache"] = dict(cache) if cache is not None else None
        content = state["_content"]
        if isinstance(content, dict):
            state["_content"] = {key: copied(child, new) for key, child in content.items()}
        elif isinstance(content, list):
            state["_content"] = [copied(child, new) for child in content]
    else:
        state["_flags_cache"] = None
    new.__dict__.update(state)
    return new


# `key=value` with a number Hydra's grammar reads the same way as Python does: a decimal integer without leading
# zeros, with or without a fraction (no exponent, no underscores, no inf or nan: those go to the grammar; Hydra
# reads `00.5` as a string).
NUMBER = re.compile(r"([A-Za-z_][A-Za-z0-9_]*(?:\.[A-Za-z_][A-Za-z0-9_]*)*)=(-?(?:0|[1-9][0-9]*)(?:\.[0-9]+)?)")


def number_override(line: str):
    """The Override Hydra's parser makes of a `key=number` line, or None for any other line."""
    match = NUMBER.fullmatch(line)
    if match is None:
        return None
    key, text = match.groups()
    value = float(text) if "." in text else int(text)
    return Override(type=OverrideType.CHANGE, key_or_group=key, value_type=ValueType.ELEMENT, _value=value,
                    input_line=line)
