"""Which garages the loop's searches run on: the training garages (the base data and every generator) and the
held-out ones (the failure-rate sample), kept apart so that no held-out scenario stands in a garage a training
frame came from.

Two kinds of space (the loop's `space`):
- a space on the shipped plans (`space=loop`): the training plans (`train_plans`) and another, `eval_plan`;
- a space of generated garages (`plan=generated` among its params, `space=wide`): the garages are drawn from
  `plan.seed`, so the training searches draw their seeds from `garages.train_seeds` and their layout families
  from the space's own list, the held-out sample its seeds from `garages.heldout_seeds` (a disjoint range) and
  its family from those families and `garages.heldout_families` (a family no training garage has: `spine`), each
  a Sobol' coordinate, so the sample holds both kinds in known shares and the report gives each its own rate.
"""

from __future__ import annotations

from omegaconf import DictConfig

from garage_exp.core.errors import GarageError
from garage_exp.loop.schema import searched

# `plan=generated` on the search's command line itself, not only as the space's entry: the search composes the
# command's own overrides before it reads its space, and a searched plan.generator.* key must be there then.
PLAN = "plan=generated"
SEED = "plan.seed"
FAMILY = "plan.generator.family"


def space_entries(cfg: DictConfig) -> list[str]:
    """The loop's space as its params (a shipped space's file read), whatever searched() hands the search."""
    from garage_exp.search.space import with_shipped

    return with_shipped(searched(cfg))


def generated(cfg: DictConfig) -> bool:
    """Whether the loop's space draws generated garages (`plan=generated` among its params)."""
    return any(e.replace(" ", "") == "plan=generated" for e in space_entries(cfg))


def _entry(cfg: DictConfig, key: str) -> str | None:
    return next((e.split("=", 1)[1] for e in space_entries(cfg) if e.split("=", 1)[0] == key), None)


def train_families(cfg: DictConfig) -> list[str]:
    """The layout families the space's own garages are drawn from (its `plan.generator.family=[...]`, else
    the generator's default)."""
    value = _entry(cfg, FAMILY)
    if value is None:
        return ["loop"]  # conf/plan/generated.yaml's family
    return [v.strip() for v in value.strip("[]").replace("choice(", "").rstrip(")").split(",") if v.strip()]


def seeds(pair, where: str) -> tuple[int, int]:
    lo, hi = (int(v) for v in pair)
    if not 0 <= lo <= hi:
        raise GarageError(f"[{lo}, {hi}]: a range of generator seeds is [low, high], 0 <= low <= high", where)
    return lo, hi


def check(cfg: DictConfig) -> None:
    """The held-out garages share no seed and no plan with the training ones (one line, exit 2, else)."""
    if not generated(cfg):
        if cfg.eval_plan in cfg.train_plans:
            raise GarageError(f"{cfg.eval_plan!r} is also a training plan: held-out data must come from another "
                              "plan", "eval_plan")
        return
    train = seeds(cfg.garages.train_seeds, "garages.train_seeds")
    held = seeds(cfg.garages.heldout_seeds, "garages.heldout_seeds")
    if train[0] <= held[1] and held[0] <= train[1]:
        raise GarageError(f"the held-out seeds {list(held)} overlap the training seeds {list(train)}: held-out "
                          "garages must be ones no training frame came from", "garages.heldout_seeds")
    shared = set(cfg.garages.heldout_families) & set(train_families(cfg))
    if shared:
        raise GarageError(f"{sorted(shared)}: a held-out family is also a training family", "garages.heldout_families")


def train(cfg: DictConfig) -> list[str]:
    """The overrides that put a training search (base data, generators) on the training garages."""
    if not generated(cfg):
        plans = list(cfg.train_plans)
        return [f"plan=choice({','.join(plans)})" if len(plans) > 1 else f"plan={plans[0]}"]
    lo, hi = seeds(cfg.garages.train_seeds, "garages.train_seeds")
    return [PLAN, f"{SEED}=int(interval({lo},{hi}))"]


def heldout(cfg: DictConfig) -> list[str]:
    """The overrides that put the held-out sample on garages no training frame came from."""
    if not generated(cfg):
        return [f"plan={cfg.eval_plan}"]
    lo, hi = seeds(cfg.garages.heldout_seeds, "garages.heldout_seeds")
    families = [*train_families(cfg), *cfg.garages.heldout_families]
    return [PLAN, f"{SEED}=int(interval({lo},{hi}))",
            f"{FAMILY}=choice({','.join(families)})" if len(families) > 1 else f"{FAMILY}={families[0]}"]


def label(cfg: DictConfig, role: str) -> str:
    """The garages in words, for the report and the check's messages."""
    if not generated(cfg):
        return ", ".join(cfg.train_plans) if role == "train" else str(cfg.eval_plan)
    pair = cfg.garages.train_seeds if role == "train" else cfg.garages.heldout_seeds
    fams = train_families(cfg) + ([] if role == "train" else list(cfg.garages.heldout_families))
    return f"generated garages, seeds {pair[0]}-{pair[1]}, families {'/'.join(fams)}"
