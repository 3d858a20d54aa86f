"""A user's detector module that imports a package that is not installed: tests/bad_inputs/cases.yaml."""

import garage_exp_no_such_dependency  # noqa: F401


def detect(frames, intrinsics):
    return []
