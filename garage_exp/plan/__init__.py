"""The garage plan: load, validate, classify, find features, draw."""

from garage_exp.plan.classify import Cell, Classified, classify
from garage_exp.plan.load import load_plan, plan_from_lists
from garage_exp.plan.model import Plan

__all__ = ["Cell", "Classified", "Plan", "classify", "load_plan", "plan_from_lists"]
