"""Which shipped case fits which shipped plan: its scene builds there and, with the case's own settings, some
frame is a fair test of the detector (the search's rule: visible, tall enough, not cut off). Measured by
rendering ground truth (tests/test_cases.py checks every case on plan=small); docs/scenarios.md has the table.
A refusal or a job without a fair frame on a shipped plan names the plans where its case fits."""

from __future__ import annotations

CASES = ("1", "2", "3", "light", "pedestrian", "stepout", "pullout", "slots", "cpnco", "cpra", "crossing", "crouch",
         "oneshot")

FITS: dict[str, tuple[str, ...]] = {
    "small": CASES,  # the plan for tests and first steps
    "research": CASES,
    "realistic": CASES,
    "obstacles": CASES,
    # slots, crossing and crouch build there; their fair frames were not measured (the render ran out)
    "garage26x30": tuple(case for case in CASES if case not in ("slots", "crossing", "crouch")),
    "tiny": (),  # a test fixture: only case 1 builds, and its target is never fair with the case's own motion
}


# Shipped cases whose scene builds on a shipped plan they do not fit (no fair frame, or fair frames not measured):
# a refusal there is about something else (missing assets, an override), so it gets no hint.
BUILDS: dict[str, tuple[str, ...]] = {"tiny": ("1",), "garage26x30": ("slots", "crossing", "crouch")}


def fitting_plans(case: str) -> list[str]:
    return [plan for plan, cases in FITS.items() if case in cases]


def hint(case: str, plan_name: str, plan_file, refused: bool = False) -> str:
    """'' unless a shipped case is known not to fit the shipped plan it was given; then where it fits. `refused`:
    for a scene build's refusal, which a case that builds on that plan did not get for not fitting."""
    case = str(case)
    if plan_file or plan_name not in FITS or case not in CASES or case in FITS[plan_name]:
        return ""
    if refused and case in BUILDS.get(plan_name, ()):
        return ""
    return f"case={case} does not fit plan={plan_name}; it fits plan={', '.join(fitting_plans(case))} " \
           "(docs/scenarios.md)"
