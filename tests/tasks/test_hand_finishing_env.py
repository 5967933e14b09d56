"""Tests of torchhrc.tasks.hand_finishing.env: the registered id makes the task's env, whose
model is the task's MOMDP with the study's generating hand model; and the deprecated aliases
left in torchhrc.envs. (Its frequencies and check_env: tests/envs/test_env_tasks.py.)"""

from __future__ import annotations

import warnings

import pytest
import torch

gym = pytest.importorskip("gymnasium", reason="the env needs the gym extra (gymnasium)")
pytest.importorskip("pytorch_kinematics")

import torchhrc.envs  # noqa: E402  (registers the ids)
from torchhrc.tasks.hand_finishing import env as hf_env  # noqa: E402
from torchhrc.tasks.hand_finishing.sensing import true_observation  # noqa: E402


def test_registered_id_makes_the_task_env_with_the_generating_hand_model():
    with warnings.catch_warnings():
        warnings.simplefilter("error", DeprecationWarning)  # the id names the new path
        env = gym.make("torchhrc/HandFinishing-v0", noise=0.3).unwrapped
    assert type(env) is hf_env.HandFinishingEnv
    assert env.task is hf_env.quick_hand_finishing_task()
    with torch.no_grad():
        expected = true_observation(env.task, 0.3).log_probs().double()  # (X, Y, O)
        got = env.person.log_probs().double()
    assert torch.allclose(got, expected, atol=1e-6)


@pytest.mark.parametrize("name", ["HandFinishingEnv", "quick_hand_finishing_task"])
def test_old_paths_warn_and_return_the_moved_object(name):
    import torchhrc.envs.hand_finishing as old_module

    new = getattr(hf_env, name)
    with pytest.warns(DeprecationWarning, match=f"torchhrc.tasks.hand_finishing.env.{name}"):
        assert getattr(torchhrc.envs, name) is new
    with pytest.warns(DeprecationWarning, match=f"torchhrc.tasks.hand_finishing.env.{name}"):
        assert getattr(old_module, name) is new
    with pytest.raises(AttributeError):
        old_module.no_such_name  # noqa: B018
