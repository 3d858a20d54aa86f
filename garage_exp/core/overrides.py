"""The command line's overrides as the entry points read them (`python -m garage_exp`, `garage_exp.gym`)."""

from __future__ import annotations

from garage_exp.core.paths import PROJECT_ROOT


def quote_numeric_choices(argv: list[str]) -> list[str]:
    """Hydra parses `case=1` as an int and rejects it as a group choice; the research names its cases
    1, 2, 3, so quote bare integer choices of config groups (`case=1,2` -> `case='1','2'`)."""
    groups = {p.name for p in (PROJECT_ROOT / "conf").iterdir() if p.is_dir()}
    out = []
    for arg in argv:
        key, eq, value = arg.partition("=")
        if eq and key.lstrip("+~") in groups and any(v.strip().isdigit() for v in value.split(",")):
            arg = key + "=" + ",".join(f"'{v.strip()}'" if v.strip().isdigit() else v for v in value.split(","))
        out.append(arg)
    return out
