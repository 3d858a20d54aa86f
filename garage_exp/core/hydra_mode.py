"""Hydra's mode without composing the config twice.

Before it composes a command's config, Hydra (1.3, `_run_hydra`) composes it once more, whole, only to read
`hydra.mode` (`Hydra.get_mode`: RUN or MULTIRUN when a config sets it; None, then `-m` decides, when none does).
That is a quarter of a refused command's time (0.09 s of a bad-input entry's 0.35 s CPU). Here
`get_mode` answers None at once when no config source can set `hydra.mode` - which is what composing would
find - and composes as before otherwise: when an override names a mode, a search path or a package (`@`),
when the search path holds more than the project's conf/, Hydra's own configs and the ConfigStore, or when one
of their configs sets `hydra.mode` (a `hydra:` node with `mode`, a `# @package hydra` file with `mode`, a
defaults entry placed `@hydra`).
"""

from __future__ import annotations

import re
from pathlib import Path

MODE_KEY = re.compile(r"\bmode['\"]?\s*:")  # a YAML key `mode` (block or flow style)
AT_HYDRA = re.compile(r"@hydra\s*:")  # a defaults entry placing a config at the package `hydra`
PACKAGE = re.compile(r"^#\s*@package\s+(\S+)", re.MULTILINE)


def install() -> None:
    """Hydra's `get_mode` asks `mode_unset` first (once per process; idempotent)."""
    from hydra._internal.hydra import Hydra

    if getattr(Hydra.get_mode, "asks_mode_unset", False):
        return
    compose_for_mode = Hydra.get_mode

    def get_mode(self, config_name, overrides):
        if mode_unset(self.config_loader, overrides):
            return None
        return compose_for_mode(self, config_name, overrides)

    get_mode.asks_mode_unset = True
    Hydra.get_mode = get_mode


def mode_unset(loader, overrides) -> bool:
    """Whether no config source of `loader` (its search path) nor any of `overrides` can set `hydra.mode`."""
    import hydra

    from garage_exp.core.paths import PROJECT_ROOT

    if any(word in o for o in overrides for word in ("mode", "searchpath", "@")):
        return False
    own = {("hydra", "pkg://hydra.conf"): Path(hydra.__file__).parent / "conf",
           ("main", str(PROJECT_ROOT / "conf")): PROJECT_ROOT / "conf"}
    dirs = []
    for element in loader.get_search_path().get_path():
        if (element.provider, element.path) == ("schema", "structured://"):
            continue
        if (element.provider, element.path) not in own:
            return False
        dirs.append(own[(element.provider, element.path)])
    return not any(file_sets_mode(path) for d in dirs for path in sorted(d.rglob("*.yaml"))) and \
        not store_sets_mode()


def file_sets_mode(path: Path) -> bool:
    """Whether the YAML config file can set `hydra.mode`, wherever the defaults place it."""
    import yaml

    text = path.read_text(errors="replace")
    if AT_HYDRA.search(text):
        return True
    if not MODE_KEY.search(text):
        return False
    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError:
        return True  # composing will say what is wrong with it
    if not isinstance(doc, dict):
        return False
    package = PACKAGE.search(text)
    node = doc.get("hydra")
    return (isinstance(node, dict) and node.get("mode") is not None) or \
        (package is not None and package.group(1) == "hydra" and doc.get("mode") is not None)


def store_sets_mode() -> bool:
    """Whether a config in Hydra's ConfigStore (the schemas, Hydra's own) sets `hydra.mode`."""
    from hydra.core.config_store import ConfigNode, ConfigStore
    from omegaconf import OmegaConf

    def sets(tree: dict, group: str) -> bool:
        for name, entry in tree.items():
            if isinstance(entry, dict):
                if sets(entry, f"{group}/{name}" if group else name):
                    return True
                continue
            if not isinstance(entry, ConfigNode):
                continue
            package = entry.package or (group.replace("/", ".") if group else "_global_")
            key = {"_global_": "hydra.mode", "hydra": "mode"}.get(package)
            if key is None:
                continue
            try:
                if OmegaConf.select(entry.node, key, default=None) is not None:
                    return True
            except Exception:  # noqa: BLE001 - a node we cannot read: let Hydra compose
                return True
        return False

    return sets(ConfigStore.instance().repo, "")
