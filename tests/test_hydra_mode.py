"""A command composes its config once (core/hydra_mode.py): Hydra's second composition, only to read
`hydra.mode`, is skipped where no config source can set it, and kept where one does."""

from __future__ import annotations

from conftest import run_app


def count_compositions(monkeypatch) -> list:
    from hydra._internal.hydra import Hydra

    calls, compose = [], Hydra.compose_config

    def counted(self, *args, **kwargs):
        calls.append(kwargs.get("run_mode"))
        return compose(self, *args, **kwargs)

    monkeypatch.setattr(Hydra, "compose_config", counted)
    return calls


def test_a_command_composes_its_config_once(tmp_path, monkeypatch):
    calls = count_compositions(monkeypatch)
    r = run_app(["dry_run=true", "plan=tiny"], tmp_path)
    assert r.returncode == 0, r.stderr
    assert len(calls) == 1, calls  # Hydra alone: twice (Hydra.get_mode, then the run)


def test_hydra_mode_set_by_an_override_still_decides(tmp_path, monkeypatch):
    """`hydra.mode=MULTIRUN` without -m runs a sweep, as Hydra does (it composes for the mode then)."""
    calls = count_compositions(monkeypatch)
    r = run_app(["dry_run=true", "plan=tiny", "hydra.mode=MULTIRUN"], tmp_path)
    assert r.returncode == 0, r.stderr
    assert len(calls) == 2 and (tmp_path / "sweep").is_dir() and not (tmp_path / "run").exists()


def test_a_config_that_sets_hydra_mode_is_seen(tmp_path):
    from garage_exp.core.hydra_mode import file_sets_mode, store_sets_mode

    cases = {"global.yaml": ("# @package _global_\nhydra:\n  mode: MULTIRUN\n", True),
             "flow.yaml": ("hydra: {mode: RUN}\n", True),
             "package.yaml": ("# @package hydra\nmode: MULTIRUN\n", True),
             "placed.yaml": ("defaults:\n  - sweep@hydra: many\n", True),
             "gym_like.yaml": ("mode: train\nhydra:\n  run:\n    dir: x\n", False),
             "unset.yaml": ("hydra:\n  mode: null\n", False),
             "other.yaml": ("# @package hydra.launcher\nmode: fast\n", False)}
    for name, (text, sets) in cases.items():
        (tmp_path / name).write_text(text)
        assert file_sets_mode(tmp_path / name) is sets, name
    from hydra.core.config_store import ConfigStore

    store = ConfigStore.instance()
    assert not store_sets_mode()
    store.store(name="mode_test", node={"mode": "MULTIRUN"}, package="hydra")
    try:
        assert store_sets_mode()
    finally:
        del store.repo["mode_test.yaml"]
