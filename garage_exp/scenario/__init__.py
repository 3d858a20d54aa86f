"""Scenarios as data: a `case` YAML names a site of the plan, its actors, a motion and variants; this package
turns it into the shot list a job renders."""

from garage_exp.scenario.build import EGO, CaseSetup, Shot, make_case, steps

__all__ = ["EGO", "CaseSetup", "Shot", "make_case", "steps"]
