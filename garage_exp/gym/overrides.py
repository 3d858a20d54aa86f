"""The command line's overrides as `python -m garage_exp` reads them (gym sits below cli, so it has its own)."""

from __future__ import annotations

from garage_exp.core.paths import PROJECT_ROOT


def quote_numeric_choices(argv: list[str]) -> list[str]:
    """Hydra parses `case=1` as an int and rejects it as a group choice: quote bare integer choices of config
    groups (`case=1` -> `case='1'`), as garage_exp.cli.app does."""
    groups = {p.name for p in (PROJECT_ROOT / "conf").iterdir() if p.is_dir()}
    out = []
    for arg in argv:
        key, eq, value = arg.partition("=")
        if eq and key.lstrip("+~") in groups and any(v.strip().isdigit() for v in value.split(",")):
            arg = key + "=" + ",".join(f"'{v.strip()}'" if v.strip().isdigit() else v for v in value.split(","))
        out.append(arg)
    return out
