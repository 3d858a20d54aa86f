"""The `search` node's schema (the sweeper's settings), beside its check (search/study.check_search), and the `space`
group's (search/space.py reads it), registered as config nodes here (core/config_nodes.py).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

from garage_exp.core.config_nodes import register_node


@dataclass
class SuiteConf:
    """Graded suites (`search.mode=suite`): K fairly visible scenarios per difficulty band."""

    per_band: int = 3  # K scenarios kept per band
    # band name -> [low, high) of the composite confidence (1 - difficulty) over the fair frames; empty: easy
    # >= 0.7, moderate 0.4-0.7, hard < 0.4 (garage_exp/search/suite.py). Empty by default so that
    # `+search.suite.bands.low=[0,0.5] +search.suite.bands.high=[0.5,1.01]` give exactly those (Hydra merges dicts).
    bands: dict[str, list[float]] = field(default_factory=dict)
    # N > 0 (and no bands): N levels of equal width on the composite confidence, level_1 the easiest to level_N
    # the hardest (garage_exp/search/grade.py, which measures them on fresh draws); 0: the bands above
    levels: int = 0
    dir: Optional[str] = None  # None: outputs/suites/<study>


@dataclass
class PrescreenConf:
    """A cheap first look at each trial before its full render (garage_exp/search/prescreen.py)."""

    level: str = "none"  # none | truth (ground truth at low resolution) | detector (and one detector on it)
    scale: float = 0.5  # of each camera's resolution and of the detector's input size
    easy: float = 0.25  # detector: a fair difficulty under this is screened as easy
    slack: float = 2.0  # detector, late objective: confirmed this many metres before the critical distance: easy
    slack_visible: float = 0.1  # the fairness rule's visible fraction loosened by this much


@dataclass
class SpaceRequireConf:
    """What a space asks of a draw before it is rendered (None: no condition): the target at least
    `min_visible` visible, its box at least `min_box` pixels tall, at most `max_distance` metres from the camera,
    at most `max_truncation` of its box outside the image."""

    min_visible: Optional[float] = None  # the target's estimated visible fraction (0-1)
    min_box: Optional[float] = None  # its projected box's height in the scored camera's image (px)
    max_distance: Optional[float] = None  # camera to the target's box centre (m)
    max_truncation: Optional[float] = None  # the share of its projected box outside the image (0-1)


@dataclass
class RequireConf(SpaceRequireConf):
    """A space's requirements on every draw, checked from the scene description before anything is rendered
    (garage_exp/search/require.py): a draw none of whose frames meets all of them is rejected and redrawn, as
    Scenic's `require` does. None: no such requirement."""

    max_draws: int = 1000  # draws rejected in a row before the search gives up on the space


@dataclass
class DescriptorConf:
    """One axis of the archive of failure kinds (garage_exp/search/archive.py): a quantity measured from each
    trial's own outputs (`source`, one registered in search/descriptors.py), binned by `values` (a categorical
    source: one cell per value) or `edges` (a numeric source: bins between increasing edges, values outside go
    to the end bins). merge: a categorical source's values that are not listed -> the listed value whose cell
    they join; a value neither listed nor merged leaves the trial without a cell (out of the archive)."""

    source: str = ""
    values: list[str] = field(default_factory=list)
    edges: list[float] = field(default_factory=list)
    merge: dict[str, str] = field(default_factory=dict)


def default_descriptors() -> list[DescriptorConf]:
    """The failure kinds of the shipped space (conf/loop.yaml: cases 1, 2, 3 and pedestrian, four lights, two
    plans): who the target is, what hides it, how far it is and how much of it is hidden when first fairly
    visible (3 x 3 x 3 x 3 = 81 cells). What hides it: a pillar, another vehicle, or nothing (under 2 % hidden);
    the building's other parts (walls, ceiling, beams) join the pillar's cell and a person the vehicle's (the
    other things in the way), so every fair trial has a cell. The edges come from a random pilot of 8 trials on
    that space (docs/search.md): the targets are first fair at about 6 m (case 2), 14 m (case 3) and 21 m
    (case 1), 1.0, 0.74 and 0.5 visible. The picture's luminance (`luminance`) replaced by `occluder`: the real
    look's camera exposes for the scene, so its mean luma spans only 0.41-0.46 over the four lights."""
    return [DescriptorConf("kind", values=["car", "adult", "child"]),
            DescriptorConf("occluder", values=["pillar", "vehicle", "none"],
                           merge={"structure": "pillar", "person": "vehicle"}),
            DescriptorConf("distance", edges=[0.0, 8.0, 16.0, 100.0]),
            DescriptorConf("visible", edges=[0.0, 0.6, 0.9, 1.0])]


def wide_descriptors() -> list[DescriptorConf]:
    """Cells for a wide space (issue 49: every site, many target kinds, continuous light and camera factors),
    each measured from ground truth at the first fair frame: what the target is by its kind and 3D height (4),
    what hides it (4: a pillar, with the building's other parts; a vehicle; a person; nothing), how far (3), how
    much of it shows (3), how lit it is (3: the lamps' direct light, edges between the shipped presets' values)
    and the camera's height (2: a bumper or grille camera under 1.2 m, a roof camera above): 4 x 4 x 3 x 3 x 3 x 2
    = 864 cells (docs/search.md). Name it in a space or on the command line as search.descriptors."""
    return [DescriptorConf("target_class", values=["small_person", "person", "car", "tall_vehicle"]),
            DescriptorConf("occluder", values=["pillar", "vehicle", "person", "none"], merge={"structure": "pillar"}),
            DescriptorConf("distance", edges=[0.0, 8.0, 16.0, 100.0]),
            DescriptorConf("visible", edges=[0.0, 0.75, 0.95, 1.0]),
            DescriptorConf("light", edges=[0.0, 0.2, 0.6, 100.0]),
            DescriptorConf("camera_height", edges=[0.0, 1.2, 10.0])]


# Named sets of descriptors, for a space to name (conf/space/NAME.yaml: `descriptors: wide`).
DESCRIPTOR_SETS = {"default": default_descriptors, "wide": wide_descriptors}


@dataclass
class ArchiveConf:
    """The quality-diversity search (`search.sampler=archive`, garage_exp/search/archive.py)."""

    # gaussian (MAP-Elites) | iso_line (MAP-Elites with the Iso+LineDD operator) | sparse (an elite with 1-3 of
    # its factors redrawn, the rest kept) | directed (an elite moved along one descriptor: the factors that drive
    # it, learnt from the study, redrawn, the rest kept) | surrogate (the candidate a forest fit on the study expects
    # to add the most failure cells not yet found: search/surrogate.py)
    emitter: str = "gaussian"
    # which elite is mutated: uniform (MAP-Elites) | curiosity (in proportion to how often its offspring entered the
    # archive: Cully & Demiris 2018), mutated by any emitter (iso_line's other elite drawn uniformly)
    parents: str = "uniform"
    sigma: float = 0.15  # the mutation's spread in the space normalised to [0, 1] per parameter
    failure: float = 0.6  # a cell holds a hard-and-fair failure when its elite's difficulty is at least this
    # (the gym's HARD and the loop's hard_below 0.4 on the confidence)


@dataclass
class SearchConf:
    """The search for hard scenarios (`hydra/sweeper=search`, garage_exp/search); read by the sweeper."""

    mode: str = "search"  # search: the hardest fair scenarios | suite: K scenarios per difficulty band
    trials: int = 20  # trials of the study in all (a resumed or shared study counts the ones it has)
    # A budget of rendered frames (0: none): the study asks no more trials once those it ran rendered this many
    # frames in all (each trial's job count), `trials` staying its cap. The trial (batch) that crosses it finishes,
    # so a study spends at least `frames` and less than one trial's (batch's) frames more. Generators compared at
    # equal cost (the loop's arms) get the same frames, not the same trials: a trial's frames vary with its case.
    frames: int = 0
    # trials asked at once and handed to the launcher as one batch (ask K, run K, tell K): a GPU worker renders a
    # batch's trials together; on the CPU they run one after another, as with 1. TPE then lies constantly about
    # the trials still running (Optuna's constant_liar), so a batch does not sample one point K times.
    batch: int = 1
    sampler: str = "tpe"  # tpe | cmaes | gp | random | qmc | nsga2 | saltelli | grid | archive
    objective: str = "difficulty"  # difficulty | pareto (difficulty against visible fraction) | late (lateness) |
    # slots (1 - recall of the fair slots on the BEV: case=slots camera=fisheye4, docs/slots.md)
    seed: Optional[int] = None  # the sampler's seed; None: the config's seed
    startup: int = 10  # tpe, gp, cmaes: random trials before the model guides (Optuna's n_startup_trials)
    study: str = ""  # the study's name; empty: from the command's overrides (the same command continues it)
    storage: Optional[str] = None  # an Optuna RDB URL; None: sqlite under outputs/search/optuna.db
    # A frame is a fair test when the target is at least this visible, its box at least this tall and at most
    # this much of it outside the image (KITTI's "hard" level: 25 px, truncation 0.5).
    min_visible: float = 0.5
    min_box: int = 25
    max_truncation: float = 0.5
    top: int = 5  # the hardest N scenarios the report lists and shows
    saltelli_n: int = 16  # sampler=saltelli: N of the Saltelli design (N x (D + 2) trials)
    grid_levels: int = 3  # sampler=grid: each interval at this many evenly spaced values (ends included)
    suite: SuiteConf = field(default_factory=SuiteConf)
    prescreen: PrescreenConf = field(default_factory=PrescreenConf)
    require: RequireConf = field(default_factory=RequireConf)
    # the archive of failure kinds: each complete trial's descriptors (difficulty objective), its cells and
    # elites (archive.csv, archive.png), and `sampler=archive`'s quality-diversity search over them
    descriptors: list[DescriptorConf] = field(default_factory=default_descriptors)
    archive: ArchiveConf = field(default_factory=ArchiveConf)
    # per_trial: each trial's job has its MLflow run (a child of the search's); per_search: one run per search, the
    # parent, which holds every trial's frame rows (search/scenarios.csv) and the study's analysis: a one-shot
    # trial's own run cost about as much as rendering it (docs/performance.md, "One-shot scenarios")
    runs: str = "per_trial"
    # the CPUs this worker (its Python thread, renderer threads and detector process) is kept on: "0", "0-1",
    # "0,2"; null: wherever the scheduler puts it. Two workers of one study on two cores: cpus=0 and cpus=1
    # (garage_exp/search/cpus.py)
    cpus: Optional[str] = None
    trial: Optional[int] = None  # set by the sweeper on each trial's job: a lean job that returns its summary


@dataclass
class SpaceConf:
    """A search space shipped as a file (conf/space/NAME.yaml; `space=NAME`): `params` are overrides in the
    search's grammar (`key=interval(a,b)`, `key=choice(a,b)`, fixed `key=value`), taken as if written on the
    command line before the command's own (which win for the same key: garage_exp/search/space.py: expand);
    `require` its conditions on a draw. These, its cells and its archive emitter are the search's
    (`search.require`, `search.descriptors`, `search.archive.emitter`) unless the command sets those itself
    (garage_exp/search/space.py: settle)."""

    name: str = "none"
    params: list[str] = field(default_factory=list)
    require: SpaceRequireConf = field(default_factory=SpaceRequireConf)
    # the archive's cells for this space: a named set of descriptors (search/schema.py: DESCRIPTOR_SETS);
    # None: the search's own (`search.descriptors`)
    descriptors: Optional[str] = None
    # the archive's emitter for this space (ArchiveConf.emitter's names); None: the search's own
    # (`search.archive.emitter`). The wide space names the surrogate, which found 1.8x random's failure cells there
    emitter: Optional[str] = None


register_node("search", SearchConf)
register_node("space", SpaceConf, group=True)
