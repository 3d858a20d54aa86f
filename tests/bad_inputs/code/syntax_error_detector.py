"""A user's detector module with a syntax error (a missing colon): tests/bad_inputs/cases.yaml."""


def detect(frames, intrinsics)
    return []
