"""A draw's first look from plain data: its settings made from its values without composing its config (issue 49,
item 6).

A search checks every draw against the space's requirements before rendering it (search/require.py), and on the
wide space most draws go no further than the case's placed actors: their actors collide (told infeasible) or the
first look rejects them (the target too small, too far or cut by the image's edge). Composing each draw's config
(a copy of ~630 nodes, its values set through OmegaConf) and converting it to plain data cost ~18 ms of the ~45 ms
such a draw took, for the ~30 values that change from one draw to the next.

Here the plain settings of a combination of fixed overrides (the composition's groups and any list or dict value)
are made once, and a draw's values are set on them as its composition would set them: each converted by the
config node it replaces (its schema type: an int drawn for a float key is a float), the interpolations that read
a changed key read its new value, the plan's garage handed on (run/preflight.py `hand_on`). Anything this cannot
make exactly (a key the composition lacks, an interpolation that is not a plain reference to a changed key) is
None, and the full check decides. tests/test_plain_draw.py pins the settings equal to the composed config's on
drawn points of the wide space, and the loop's verdicts equal to the full check's.

`first_look` then builds the case from them as the job's scene build does (scenario/assemble.py `make_case`)
and looks at the placed actors: Infeasible when they collide, the rejection when the first look rejects, None
when only the built garage can decide (the full check, composing the draw, follows).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from omegaconf import Container, DictConfig

from garage_exp.core.plain import Settings, frozen, settings

MAX_BASES = 32  # combinations of fixed overrides kept (a search has one or a few: its group levels)
# An interpolation that is one reference to another key: absolute (`${garage.ceiling_height}`) or relative to its
# node's parent (`${.length}`, `${..size}`).
REFERENCE = re.compile(r"\$\{(\.*)([A-Za-z_][\w]*(?:\.[A-Za-z_][\w]*)*)\}")


@dataclass
class Base:
    """The plain settings of one combination of fixed overrides, the config node they came from (for each key's
    type) and its interpolations ((path, text) of each, the `hydra` node left out as `settings` leaves it)."""

    config: DictConfig
    plain: Settings
    interpolations: list[tuple[tuple[str, ...], str]]

    @classmethod
    def of(cls, config: DictConfig) -> "Base":
        found: list[tuple[tuple[str, ...], str]] = []
        for key in config:
            if key != "hydra":
                _interpolations(config._get_node(key), (str(key),), found)
        return cls(config, settings(config), found)

    def node(self, path: tuple[str, ...]):
        """The value node at `path`, or None where the config has no such value (a container, a list's item)."""
        node = self.config
        for part in path:
            if not isinstance(node, DictConfig) or part not in node.__dict__["_content"]:
                return None
            node = node._get_node(part)
        return None if isinstance(node, Container) else node

    def read_by_resolvers(self, values) -> list[tuple[str, ...]]:
        """The paths among `values` that an interpolation other than a plain reference may read."""
        texts = [text for _, text in self.interpolations if REFERENCE.fullmatch(text) is None]
        return [p for p in values if any(_reads(text, p) for text in texts)]

    def with_values(self, values: dict[tuple[str, ...], object]) -> Settings | None:
        """These settings with `values` set (path -> the override's value), or None where that cannot be made
        exactly here."""
        converted = {}
        for path, value in values.items():
            node = self.node(path)
            if node is None:
                return None
            converted[path] = frozen(node.validate_and_convert(value))
        plain = self.plain
        for path, value in converted.items():
            plain = _set(plain, path, value)
        for path, text in self.interpolations:
            if path in converted:
                continue  # a drawn value replaced the interpolation
            match = REFERENCE.fullmatch(text)
            target = None if match is None else _target(path, match)
            touched = [p for p in converted if target is not None and _overlap(p, target)]
            if target is None:
                if any(_reads(text, p) for p in converted):
                    return None  # a resolver or a concatenation that may read a changed key
                continue
            if any(_overlap(target, other) for other, _ in self.interpolations):
                return None  # a reference to another interpolation (which may have changed): left to OmegaConf
            if not touched:
                continue
            if not isinstance(_get(plain, path[:-1]), dict):
                return None  # an interpolation in a list's item
            value = _get(plain, target)
            if isinstance(value, (dict, tuple)):
                return None
            plain = _set(plain, path, frozen(self.node(path).validate_and_convert(value)))
        return plain


class PlainDraws:
    """Draws' plain settings on one search's compositions (search/compose.py `Compositions`), each combination of
    fixed overrides made once."""

    def __init__(self, compositions):
        self.compositions = compositions
        self.bases: dict[tuple[str, ...], Base] = {}

    def settings(self, overrides: list[str]) -> Settings | None:
        """The plain settings of the config `overrides` compose to, before the plan's garage is handed on (the
        job's `settings(cfg)` of `Compositions.compose(overrides, job=False)`), or None."""
        split = self.split(overrides)
        if split is None:
            return None
        fixed, values = split
        return self.base(fixed).with_values(values)

    def split(self, overrides: list[str]):
        """(the fixed overrides, {path: value} of the drawn ones), or None for an override this cannot set. A
        value that a resolver or a concatenation reads (`detector.registry: ${oc.select:tracking.uri,null}` reads
        a search's `tracking.uri`) goes with the fixed ones, into the composition: OmegaConf resolves it."""
        comp = self.compositions
        fixed, values, lines = [], {}, {}
        for line in overrides:
            o = comp.parsed(line)
            value = None if comp.structural(o) else o.value()
            if comp.structural(o) or isinstance(value, (dict, list)):
                fixed.append(o.input_line)
                continue
            path = tuple(o.key_or_group.split("."))
            if path in values:
                return None  # set twice: Hydra's order decides
            values[path], lines[path] = value, o.input_line
        if any(tuple(comp.parsed(line).key_or_group.split(".")) in values for line in fixed):
            return None
        read = self.base(tuple(fixed)).read_by_resolvers(values)
        if read:
            fixed = [line for line in overrides if line in fixed or any(lines[p] == line for p in read)]
            values = {p: v for p, v in values.items() if p not in read}
        return tuple(fixed), values

    def base(self, fixed: tuple[str, ...]) -> Base:
        if fixed not in self.bases:
            if len(self.bases) >= MAX_BASES:  # a drawn value a resolver reads makes a base a draw: keep the last
                self.bases.pop(next(iter(self.bases)))
            self.bases[fixed] = Base.of(self.compositions.compose(list(fixed), job=False))
        return self.bases[fixed]

    def handed_on(self, overrides: list[str], plan) -> Settings | None:
        """The draw's settings with the plan's garage handed on as the job's preflight hands it on (run/preflight.py
        `hand_on`: the generated plan's pillar size, bay width, ceiling height, and the pillar group's size)."""
        split = self.split(overrides)
        if split is None:
            return None
        base = self.base(split[0])
        return _handed_on(base, split[1], plan)


def _handed_on(base: Base, values: dict, plan) -> Settings | None:
    from garage_exp.run.preflight import handed_values

    return base.with_values({**values, **handed_values(base.config, plan)})


def first_look(draws: PlainDraws, overrides: list[str], rule):
    """The requirements' first look at a draw from plain data (require.first_look): its rejection (a Verdict),
    or None when the full check must decide (the look passed, or the draw's settings or plan could not be made
    here). Raises Infeasible when its actors collide, in the words its job's preflight would use."""
    import numpy as np

    from garage_exp.run.preflight import _library, check_config, classified_plan, resolve_plan_path
    from garage_exp.scenario.assemble import cameras
    from garage_exp.scenario.build import make_case
    from garage_exp.scenario.fits import hint
    from garage_exp.scene.camera import scored_camera
    from garage_exp.search import require

    split = draws.split(overrides)
    if split is None:
        return None
    base, values = draws.base(split[0]), split[1]
    drawn = base.with_values(values)  # its plan's settings, to read the plan
    if drawn is None:
        return None
    classified = classified_plan(resolve_plan_path(drawn.plan))
    config = _handed_on(base, values, classified.plan)
    if config is None or hint(config.case.name, config.plan.name, config.plan.file, refused=True):
        return None  # a shipped case on a plan it does not fit: the preflight's words say where it fits
    job = check_config(config)
    setup = make_case(job, classified, _library(), np.random.default_rng(job.seed))
    return require.first_look(rule, setup, cameras(job, setup), scored_camera(job.camera, str(job.case.camera or "")))


def _interpolations(node, path: tuple[str, ...], found: list) -> None:
    if node._is_interpolation():
        found.append((path, str(node._value())))
        return
    if isinstance(node, DictConfig):
        for key in node.__dict__["_content"]:
            _interpolations(node._get_node(key), (*path, str(key)), found)
    elif isinstance(node, Container):  # a list: its items' interpolations too
        for k in range(len(node)):
            _interpolations(node._get_node(k), (*path, str(k)), found)


def _reads(text: str, path: tuple[str, ...]) -> bool:
    """Whether an interpolation's text may read `path` (its full key, or its last part in a relative key)."""
    return ".".join(path) in text or path[-1] in text


def _target(path: tuple[str, ...], match: re.Match) -> tuple[str, ...]:
    dots, key = match.groups()
    if not dots:
        return tuple(key.split("."))
    parent = path[:len(path) - len(dots)]
    return (*parent, *key.split("."))


def _overlap(a: tuple[str, ...], b: tuple[str, ...]) -> bool:
    """Whether one path is the other or holds it."""
    n = min(len(a), len(b))
    return a[:n] == b[:n]


def _get(plain, path: tuple[str, ...]):
    for part in path:
        plain = plain[part] if isinstance(plain, dict) else plain[int(part)]
    return plain


def _set(plain: Settings, path: tuple[str, ...], value) -> Settings:
    """A copy of `plain` with `path` set, sharing every untouched branch."""
    head, rest = path[0], path[1:]
    return Settings({**plain, head: _set(plain[head], rest, value) if rest else value})
