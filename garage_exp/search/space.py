"""The search space, written in Hydra's override grammar as with the official Optuna sweeper.

`key=interval(a,b)` is a float range (`tag(log, interval(a,b))` on a log scale, `int(interval(a,b))` an integer
range), `key=choice(a,b,c)` or `key=a,b,c` a categorical choice (a config group's levels, or values),
`key=range(a,b[,step])` integers (or floats with a float step). Every other override is fixed for all trials.

Bad spaces fail before the first trial, with one line naming the override: a key the composed config does not
have, an empty interval, a level its group lacks, or a value a job would refuse (each interval's two ends and
each choice are composed and checked like a job, without rendering).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import optuna.distributions as od
from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.core.override_parser.types import (ChoiceSweep, IntervalSweep, Override, RangeSweep, Transformer)
from omegaconf import DictConfig, OmegaConf

from garage_exp.core.errors import GarageError

# Keys the sweeper owns: a search over them would make no sense (or would search the search).
RESERVED = ("search.", "hydra.", "resume", "dry_run", "tracking.")


@dataclass
class Space:
    """What the study samples (name -> Optuna distribution, in the order given) and what every trial fixes."""

    params: dict[str, od.BaseDistribution]
    fixed: list[str]  # overrides as written (key=value), passed to every trial
    written: dict[str, str] = field(default_factory=dict)  # each searched key's override as written
    # The fewest and the most frames a trial of the space renders, as far as the check saw: the shot counts of the
    # points it composed (every choice, each interval's ends and middle); 0 before the check. Whether a cap of
    # trials reaches a frame budget (the loop's generators) is then known before any rendering.
    fewest_frames: int = 0
    most_frames: int = 0

    def overrides(self, values: dict) -> list[str]:
        """A trial's override list: the fixed ones, then each sampled value."""
        return [*self.fixed, *(f"{name}={format_value(values[name])}" for name in self.params)]


def format_value(value) -> str:
    """A sampled value as an override's right-hand side: floats rounded to what a scenario file would say
    (1e-6), strings quoted when Hydra would parse them as something else (a level named `1` stays a string)."""
    if isinstance(value, bool) or value is None:
        return {True: "true", False: "false", None: "null"}[value]
    if isinstance(value, float):
        return repr(round(value, 6))
    if isinstance(value, int):
        return str(value)
    text = str(value)
    if text.lstrip("-").replace(".", "", 1).isdigit() or text.lower() in ("true", "false", "null"):
        return f"'{text}'"
    return text


def expand(config: DictConfig, arguments: list[str]) -> list[str]:
    """The command's overrides after its space's (`space=NAME`: conf/space/NAME.yaml's `params`), as if those were
    written first on the command line; a key the command sets itself keeps the command's value. A space entry
    that is no override, or sets a key twice, is one line naming the file and the entry."""
    if not OmegaConf.select(config, "space.params", default=None):
        return list(arguments)
    return merged(origins(config), arguments)


def settle(config: DictConfig, arguments: list[str]) -> None:
    """A shipped space's own search settings onto `config.search`, each unless the command sets it itself: each
    bound of its `require` (search.require.*), its named `descriptors` (search.descriptors) and its archive
    `emitter` (search.archive.emitter). In place; the same config settles the same way again."""
    from omegaconf import open_dict, read_write

    from garage_exp.search.schema import DESCRIPTOR_SETS

    space = OmegaConf.select(config, "space", default=None)
    if space is None or not space.get("params"):
        return
    given = {a.split("=", 1)[0].lstrip("+~") for a in arguments}
    with read_write(config), open_dict(config):
        for key, value in (space.get("require") or {}).items():
            if value is not None and f"search.require.{key}" not in given:
                config.search.require[key] = value
        name = space.get("descriptors")
        if name and not any(k == "search.descriptors" or k.startswith("search.descriptors.") for k in given):
            if name not in DESCRIPTOR_SETS:
                raise GarageError(f"unknown descriptor set {name!r} ({' | '.join(DESCRIPTOR_SETS)})",
                                  "space.descriptors")
            config.search.descriptors = OmegaConf.structured(DESCRIPTOR_SETS[name]())
        emitter = space.get("emitter")
        if emitter and not given & {"search.archive", "search.archive.emitter"}:
            config.search.archive.emitter = emitter  # checked with the search's own (search/archive.py: EMITTERS)


def with_shipped(arguments: list[str], folder=None) -> list[str]:
    """A list of overrides with each `space=NAME` entry replaced by its file's (conf/space/NAME.yaml, or
    `folder`/NAME.yaml) `params` before the rest, a key given in the list winning, as `expand` does for a composed
    config: for a command that reads a space without composing it (the loop's held-out sample)."""
    from pathlib import Path

    from garage_exp.core.paths import PROJECT_ROOT

    folder = Path(folder) if folder else PROJECT_ROOT / "conf" / "space"
    entries = {}
    for name in [a.split("=", 1)[1] for a in arguments if a.startswith("space=")]:
        path = folder / f"{name}.yaml"
        if not path.is_file():
            raise GarageError(f"no space {name!r} ({path} does not exist)", f"space={name}")
        for index, entry in enumerate(OmegaConf.load(path).get("params") or []):
            entries[str(entry)] = f"{path}: space.params[{index}]"
    return [a for a in merged(entries, arguments) if not a.startswith("space=")]


def merged(entries: dict[str, str], arguments: list[str]) -> list[str]:
    """A space's entries (each -> where it was written) before the arguments, less those whose key an argument
    sets; an entry that is no override, names a space or sets a key twice is refused where it was written."""
    given = {o.key_or_group for o in parse(arguments)}
    kept, seen = [], set()
    for entry, place in entries.items():
        try:
            (override,) = OverridesParser.create().parse_overrides([entry])
        except Exception as exc:  # Hydra's OverrideParseException
            raise GarageError(f"{entry!r} is not an override ({str(exc).splitlines()[0]})", place) from None
        key = override.key_or_group
        if key == "space" or key in seen:
            raise GarageError(f"{entry!r}: " + ("a space cannot name a space" if key == "space" else
                                                f"{key} is set twice in the space"), place)
        seen.add(key)
        if key not in given:
            kept.append(entry)
    return [*kept, *arguments]


def origins(config: DictConfig) -> dict[str, str]:
    """Each entry of the config's space (`space.params`) -> where it was written (the space's file and the
    entry's index), for messages. An entry that is not text is refused there."""
    from garage_exp.core.schema_check import level_file

    entries = OmegaConf.select(config, "space.params", default=None) or []
    source = level_file(config, "space")
    out = {}
    for index, entry in enumerate(entries):
        place = f"{source}: space.params[{index}]"
        if not isinstance(entry, str) or "=" not in entry:
            raise GarageError(f"{entry!r} is not an override (key=value, key=interval(a,b), key=choice(a,b))", place)
        out[str(entry)] = place
    return out


def in_space_file(exc: GarageError, config: DictConfig) -> GarageError:
    """A refusal of a search override said at the space file's entry it came from (else as it was)."""
    for entry, place in origins(config).items():
        if exc.where == f"search space {entry}":
            return exc.again(str(exc)[len(exc.where) + 2:], f"{place} {entry}")
    return exc


def parse(arguments: list[str]) -> list[Override]:
    try:
        return OverridesParser.create().parse_overrides(list(arguments))
    except Exception as exc:  # Hydra's OverrideParseException: one line, naming the override
        raise GarageError(str(exc).split("\n")[0], "search space") from None


def distribution(override: Override) -> od.BaseDistribution:
    """The Optuna distribution of one sweep override."""
    where = f"search space {override.input_line}"
    value = override.value()
    if override.is_interval_sweep():
        assert isinstance(value, IntervalSweep)
        lo, hi = value.start, value.end
        if lo is None or hi is None or not lo < hi:
            raise GarageError(f"the interval is empty ({lo} to {hi}): the low end must be below the high end", where)
        log = "log" in value.tags
        if log and lo <= 0:
            raise GarageError(f"a log interval needs a positive low end, not {lo}", where)
        if isinstance(lo, int) and isinstance(hi, int):
            return od.IntDistribution(lo, hi, log=log)
        return od.FloatDistribution(float(lo), float(hi), log=log)
    if override.is_range_sweep():
        assert isinstance(value, RangeSweep)
        choices = list(override.sweep_iterator(transformer=Transformer.encode))
        if not choices:
            raise GarageError(f"the range is empty ({value.start} to {value.stop})", where)
        if value.shuffle or any(isinstance(v, float) for v in (value.start, value.stop, value.step)):
            return od.CategoricalDistribution(choices)
        return od.IntDistribution(int(value.start), int(choices[-1]), step=int(value.step))
    if override.is_choice_sweep():
        assert isinstance(value, ChoiceSweep)
        choices = list(dict.fromkeys(override.sweep_iterator(transformer=Transformer.encode)))
        if not choices:
            raise GarageError("the choice is empty", where)
        return od.CategoricalDistribution(choices)
    raise GarageError("this kind of sweep cannot be searched (use interval, choice or range)", where)


def build(arguments: list[str], config: DictConfig, groups: dict[str, list[str]]) -> Space:
    """The space of a command's overrides. `groups`: each config group's levels (the loader's view, so a
    user's --config-dir counts). Checks keys and levels; values are checked by `check_values`."""
    params: dict[str, od.BaseDistribution] = {}
    fixed: list[str] = []
    written: dict[str, str] = {}
    for override in parse(arguments):
        if not override.is_sweep_override():
            fixed.append(override.input_line)
            continue
        key = override.key_or_group
        where = f"search space {override.input_line}"
        if override.is_hydra_override() or key.startswith(RESERVED) or key in RESERVED:
            raise GarageError(f"{key} cannot be searched", where)
        if override.is_add() or override.is_delete():
            raise GarageError("a searched key must be in the config already (no + or ~)", where)
        dist = distribution(override)
        if key in groups:
            if not isinstance(dist, od.CategoricalDistribution):
                raise GarageError(f"{key} is a config group: choose its levels with choice(...)", where)
            unknown = [str(c) for c in dist.choices if str(c) not in groups[key]]
            if unknown:
                raise GarageError(f"{key} has no level {unknown[0]!r} (levels: {', '.join(groups[key])})", where)
            dist = od.CategoricalDistribution([str(c) for c in dist.choices])
        elif OmegaConf.select(config, key, default=_ABSENT) is _ABSENT:
            raise GarageError(f"the config has no key {key}", where)
        params[key] = dist
        written[key] = override.input_line
    if not params:
        raise GarageError("nothing to search: give at least one key=interval(a,b) or key=choice(a,b)",
                          "search space")
    return Space(params, fixed, written)


_ABSENT = object()


def probe_points(space: Space) -> list[tuple[str, object]]:
    """The values each parameter's check composes: an interval's two ends and its middle, every choice."""
    points = []
    for name, dist in space.params.items():
        if isinstance(dist, od.CategoricalDistribution):
            points.extend((name, c) for c in dist.choices)
        else:
            points.extend([(name, dist.low), (name, dist.high), (name, middle(dist))])
    return points


def middle(dist: od.BaseDistribution):
    """An interval's middle (an integer one's, rounded down to its step; a log one's, geometric)."""
    if isinstance(dist, od.IntDistribution):
        step = dist.step or 1
        return dist.low + (dist.high - dist.low) // (2 * step) * step
    if getattr(dist, "log", False):
        return float((dist.low * dist.high) ** 0.5)
    return (dist.low + dist.high) / 2


def default_point(space: Space) -> dict:
    """A valid point of the space (each interval's low end, each choice's first), to fill in the others."""
    return {name: (d.choices[0] if isinstance(d, od.CategoricalDistribution) else d.low)
            for name, d in space.params.items()}


def middle_point(space: Space) -> dict:
    """The space's middle (each interval's middle, each choice's first): one more point a check probes."""
    return {name: (d.choices[0] if isinstance(d, od.CategoricalDistribution) else middle(d))
            for name, d in space.params.items()}


def at_fault(lines: list[str], actors) -> list[str]:
    """Of these overrides, those that place the given actors, most specific first: their own keys
    (`case.actors.child.offset`); else the case's motion, bays, variants or site; else the case, plan, garage or
    occluder themselves. What to name when those actors stand in one another."""
    names = {str(a) for a in actors} | {str(a).rpartition("_")[0] for a in actors}

    def tier(line: str) -> int:
        parts = line.split("=", 1)[0].lstrip("+~").split(".")
        if len(parts) > 2 and parts[0] in ("case", "occluder") and parts[1] == "actors" and parts[2] in names:
            return 1
        if parts[0] == "case" and len(parts) > 1 and parts[1] in ("motion", "bays", "variants", "site"):
            return 2
        return 3 if parts[0] in ("case", "occluder", "plan", "garage") and (len(parts) == 1 or parts[0] in
                                                                             ("plan", "garage")) else 0

    for level in (1, 2, 3):
        found = [line for line in lines if tier(line) == level]
        if found:
            return found
    return []
