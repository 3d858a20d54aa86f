"""A new factor of the wide space is one module plus its registration (issue 48, "Done when"): a user's module
defines a scene modifier, a YAML level names it (`_target_`: the registration), and a space of the user's own,
the shipped wide space plus that factor as a continuous interval, is searched by the real command. The drawn
value reaches the scene the job builds. Frames are left out (test_readme_commands.built: each job stops after its
preflight built its scene), so the search costs two scene builds."""

from __future__ import annotations

import textwrap

import optuna
import pytest
from conftest import ROOT, run_app
from omegaconf import OmegaConf
from test_readme_commands import built  # noqa: F401  (each job stops after its preflight: its prepared jobs)

MODULE = """
    from garage_exp.scene.description import Box, Entity, Material, Pose

    def barrier(scene, classified, garage, height=1.0):
        '''Factor `barrier`: a red post `height` metres tall in the middle of the garage.'''
        x0, y0, x1, y1 = scene.bounds
        scene.entities.append(Entity("barrier", "structure", Pose((x0 + x1) / 2, (y0 + y1) / 2, 0.0),
                                     [Box((0.2, 0.2, height), Material("barrier", (0.8, 0.1, 0.1, 1.0)),
                                          Pose(0.0, 0.0, height / 2))]))
    """


def user_files(tmp_path):
    """The user's module, its registration (a level of the `barrier` group naming it) and their space: the
    shipped wide space with the barrier's level in its defaults and its height among its params."""
    (tmp_path / "user_mods.py").write_text(textwrap.dedent(MODULE))
    conf = tmp_path / "conf"
    (conf / "barrier").mkdir(parents=True)
    (conf / "barrier" / "mid.yaml").write_text(
        "# @package modifiers.barrier\n_target_: user_mods.barrier\nheight: 1.0\n")
    space = OmegaConf.load(ROOT / "conf" / "space" / "wide.yaml")
    space.name = "wide_barrier"
    space.defaults.insert(0, {"/barrier@_global_.modifiers.barrier": "mid"})  # (overrides come last in a list)
    space.params.append("modifiers.barrier.height=interval(0.5,2.0)")
    (conf / "space").mkdir()
    OmegaConf.save(space, conf / "space" / "wide_barrier.yaml")
    return conf


def test_a_factor_of_the_users_own_is_drawn_by_the_wide_spaces_search_into_the_scene(tmp_path, built):  # noqa: F811
    conf = user_files(tmp_path)
    storage = f"sqlite:///{tmp_path}/optuna.db"
    r = run_app(["-m", "--config-dir", str(conf), "hydra/sweeper=search", "space=wide_barrier", "search.trials=2",
                 "search.sampler=random", f"search.storage={storage}", f"tracking.uri=sqlite:///{tmp_path}/mlflow.db"],
                tmp_path, env={"PYTHONPATH": str(tmp_path), "GARAGE_EXP_MODIFIER_MODULES": "user_mods"})
    assert r.returncode == 0, r.stderr[-3000:]
    (name,) = optuna.get_all_study_names(storage)
    drawn = {t.number: t.params["modifiers.barrier.height"] for t in optuna.load_study(study_name=name,
                                                                                       storage=storage).trials}
    assert len(drawn) == 2 and all(0.5 <= v <= 2.0 for v in drawn.values()), drawn
    # a draw the requirements refuse is pruned before its job: at least one of the two ran
    assert built, r.stdout[-3000:]
    for prepared in built:
        value = drawn[int(prepared.config.search.trial)]
        assert prepared.spec.scene.modifiers["barrier"]["height"] == pytest.approx(value, abs=1e-6)
        (post,) = [e for e in prepared.scene.entities if e.name == "barrier"]
        assert post.shapes[0].size[2] == pytest.approx(value, abs=1e-6)  # the drawn height stands in the scene
