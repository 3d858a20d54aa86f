"""The loop's extra replay pools (`replay_pool` in its config): studies on the training garages whose scenarios only
ever join the fine-tunings' replay, never the validation split. The base data holds the replay a short fine-tuning
needs; a run of hundreds of training frames, or one that must not forget people, draws more from these."""

from __future__ import annotations

import zlib
from dataclasses import dataclass

from omegaconf import DictConfig


@dataclass(frozen=True)
class Pool:
    step: str  # the loop's step ("replay pool people")
    study: str  # its study in the loop's storage ("replay_people")
    overrides: list[str]  # the training garages' overrides, then the pool's own params (they win over the space's)
    trials: int
    seed: int  # its QMC seed: not the base data's 0, else the pool would draw the base's own points again


def seed(name: str) -> int:
    """A pool's QMC seed, from its name alone (adding a pool does not move another's draws)."""
    return 1 + zlib.crc32(name.encode()) % 9999


def pools(cfg: DictConfig, plans: list[str]) -> list[Pool]:
    """The pools as run_loop and the loop's check ask for them, in the config's order; one of 0 trials is none."""
    out = []
    for name, pool in (cfg.get("replay_pool") or {}).items():
        if int(pool.trials) > 0:
            out.append(Pool(f"replay pool {name}", f"replay_{name}", [*plans, *map(str, pool.params)],
                            int(pool.trials), seed(str(name))))
    return out
