"""The deprecated paths left behind when place-and-drill's env, workbench, replay and baselines
moved into torchhrc.tasks.place_and_drill (issue 32): each old name warns, naming its new place,
and is the moved object; the registered gym id makes the moved env without a warning."""

from __future__ import annotations

import importlib
import warnings

import pytest

_NEW = "torchhrc.tasks.place_and_drill"

# (old module, name, new module): one row per shim (old module path or package __init__)
ALIASES = [
    ("torchhrc.envs.place_and_drill", "PlaceAndDrillEnv", f"{_NEW}.env"),
    ("torchhrc.envs.place_and_drill", "PlaceAndDrillHuman", f"{_NEW}.env"),
    ("torchhrc.envs.vector", "PlaceAndDrillVectorEnv", f"{_NEW}.vector_env"),
    ("torchhrc.envs", "PlaceAndDrillEnv", f"{_NEW}.env"),
    ("torchhrc.envs", "PlaceAndDrillVectorEnv", f"{_NEW}.vector_env"),
    ("torchhrc.sim.workbench", "PlaceAndDrillScene", f"{_NEW}.workbench"),
    ("torchhrc.sim.workbench", "robot_urdf", f"{_NEW}.workbench"),
    ("torchhrc.sim", "WorkbenchLayout", f"{_NEW}.workbench"),
    ("torchhrc.sim.drill_replay", "execution_steps", f"{_NEW}.replay"),
    ("torchhrc.sim", "replay_execution", f"{_NEW}.replay"),
    ("torchhrc.baselines.hand_coded", "load_expert_model", f"{_NEW}.hand_coded"),
    ("torchhrc.baselines.cross_training", "fit_cross_training", f"{_NEW}.cross_training"),
    ("torchhrc.baselines", "DEFAULT_EXPERT_PATH", f"{_NEW}.hand_coded"),
    ("torchhrc.baselines", "CrossTrainingPolicy", f"{_NEW}.cross_training"),
]


@pytest.mark.parametrize(("old", "name", "new"), ALIASES)
def test_old_path_warns_and_returns_the_moved_object(old, name, new):
    if old.startswith("torchhrc.envs"):
        pytest.importorskip("gymnasium", reason="torchhrc.envs needs the gym extra")
    old_module = importlib.import_module(old)
    expected = getattr(importlib.import_module(new), name)
    with pytest.warns(DeprecationWarning, match=f"{old}.{name} is deprecated; use {new}.{name}"):
        assert getattr(old_module, name) is expected
    with pytest.raises(AttributeError):
        old_module.no_such_name  # noqa: B018


def test_registered_ids_make_the_moved_envs_without_a_warning():
    gym = pytest.importorskip("gymnasium", reason="torchhrc.envs needs the gym extra")
    import torchhrc.envs  # noqa: F401  (registers the ids)
    from torchhrc.tasks.place_and_drill.env import PlaceAndDrillEnv
    from torchhrc.tasks.place_and_drill.vector_env import PlaceAndDrillVectorEnv

    with warnings.catch_warnings():
        warnings.simplefilter("error", DeprecationWarning)  # the ids name the new paths
        env = gym.make("torchhrc/PlaceAndDrill-v0")
        envs = gym.make_vec(
            "torchhrc/PlaceAndDrill-v0", num_envs=2, vectorization_mode="vector_entry_point"
        )
    assert type(env.unwrapped) is PlaceAndDrillEnv
    assert type(envs) is PlaceAndDrillVectorEnv
