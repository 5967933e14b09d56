"""POMDPEnv and MOMDPEnv sample what the model's tensors say (chi-square), check_env passes,
and reset(seed) fixes the episode."""

from __future__ import annotations

import numpy as np
import pytest
import torch

gym = pytest.importorskip("gymnasium", reason="torchhrc.envs needs the gym extra (gymnasium)")
pytest.importorskip("scipy", reason="the frequency tests use scipy.stats")

ALPHA = 1e-3  # significance level: a correct sampler fails one fixed seed in a thousand

from gymnasium.utils.env_checker import check_env  # noqa: E402

from torchhrc.envs import MOMDPEnv, POMDPEnv  # noqa: E402
from torchhrc.pomdp import MOMDP, POMDP  # noqa: E402
from torchhrc.pomdp.sparse import SparsePOMDP  # noqa: E402
from torchhrc.tasks.classic import tiger  # noqa: E402
from torchhrc.testing import random_momdp, random_pomdp  # noqa: E402


def _flat_samples(env, steps: int, seed: int):
    """``(s, a, s2, o, r)`` arrays of one long episode under uniformly random actions."""
    rng = np.random.default_rng(seed)
    _, info = env.reset(seed=seed)
    s = info["state"]
    out = np.zeros((steps, 5))
    for t, a in enumerate(rng.integers(env.action_space.n, size=steps)):
        o, r, _, _, info = env.step(int(a))
        out[t] = (s, a, info["state"], o, r)
        s = info["state"]
    s, a, s2, o = (out[:, i].astype(np.int64) for i in range(4))
    return s, a, s2, o, out[:, 4]


def _model(form: str) -> POMDP | SparsePOMDP:
    m = random_pomdp(4, 3, 3, sparsity=0.3, seed=1)
    return SparsePOMDP.from_dense(m) if form == "sparse" else m


@pytest.mark.parametrize("form", ["dense", "sparse"])
def test_pomdp_env_frequencies_match_model(chi_square, form):
    model = _model(form)
    dense = model.to_dense() if form == "sparse" else model
    S = dense.num_states
    T, Z, R = (t.numpy() for t in (dense.T, dense.Z, dense.R))
    s, a, s2, o, r = _flat_samples(POMDPEnv(model), 40_000, seed=0)
    assert chi_square(a * S + s, s2, T.reshape(-1, S)) > ALPHA
    assert chi_square(a * S + s2, o, Z.reshape(-1, Z.shape[-1])) > ALPHA
    np.testing.assert_array_equal(r, R[a, s])  # the reward is R[a, s], exactly
    # the test can fail: the same samples against a slightly wrong T or Z are rejected
    wrong_T = 0.9 * T + 0.1 / S
    assert chi_square(a * S + s, s2, wrong_T.reshape(-1, S)) < ALPHA
    wrong_Z = Z[:, :, ::-1].reshape(-1, Z.shape[-1])  # observations relabelled
    assert chi_square(a * S + s2, o, wrong_Z) < ALPHA


def test_pomdp_env_initial_state_follows_b0(chi_square):
    model = random_pomdp(5, 2, 2, seed=3)
    env = POMDPEnv(model)
    states = np.array([env.reset(seed=i)[1]["state"] for i in range(4000)])
    b0 = model.b0.numpy()[None]
    assert chi_square(np.zeros_like(states), states, b0) > ALPHA
    assert chi_square(np.zeros_like(states), states, np.roll(b0, 1, -1)) < ALPHA


@pytest.mark.parametrize("static", [True, False])
def test_momdp_env_frequencies_match_model(chi_square, static):
    model = random_momdp(3, 2, 3, 3, static=static, seed=2)
    X, Y, O = model.num_observed, model.num_hidden, model.num_observations
    env = MOMDPEnv(model)
    rng = np.random.default_rng(1)
    obs, info = env.reset(seed=1)
    rows = []
    for a in rng.integers(model.num_actions, size=40_000):
        x, y = info["x"], info["y"]
        obs, r, _, _, info = env.step(int(a))
        rows.append((a, x, y, info["x"], info["y"], obs["observation"], r))
        assert obs["x"] == info["x"]  # the observed part is seen exactly
    a, x, y, x2, y2, o, r = (np.array(c) for c in zip(*rows))
    a, x, y, x2, y2, o = (v.astype(np.int64) for v in (a, x, y, x2, y2, o))
    Tx, Z, R = model.Tx.numpy(), model.Z.numpy(), model.R.numpy()
    row_xy = (a * X + x) * Y + y
    assert chi_square(row_xy, x2, Tx.reshape(-1, X)) > ALPHA
    assert chi_square((a * X + x2) * Y + y2, o, Z.reshape(-1, O)) > ALPHA
    np.testing.assert_array_equal(r, R[a, x, y])
    if static:
        np.testing.assert_array_equal(y2, y)
    else:
        Ty = model.Ty.numpy()
        assert chi_square(row_xy * X + x2, y2, Ty.reshape(-1, Y)) > ALPHA
        assert chi_square(row_xy * X + x2, y2, np.roll(Ty, 1, -1).reshape(-1, Y)) < ALPHA
    wrong_Tx = np.roll(Tx, 1, axis=-1)  # every row's successors shifted by one
    assert chi_square(row_xy, x2, wrong_Tx.reshape(-1, X)) < ALPHA


def test_momdp_env_random_start_follows_the_joint(chi_square):
    g = torch.Generator().manual_seed(0)
    joint = torch.rand(3, 2, generator=g, dtype=torch.float64)
    joint[1] = 0.0
    model = random_momdp(3, 2, 2, 2, seed=2).with_initial(joint / joint.sum())
    env = MOMDPEnv(model)
    starts = []
    for i in range(4000):
        obs, info = env.reset(seed=i)
        assert obs["x"] == info["x"]  # the first x is seen
        starts.append(info["state"])
    starts = np.array(starts)
    p = model.initial.numpy().reshape(1, -1)
    assert chi_square(np.zeros_like(starts), starts, p) > ALPHA
    assert chi_square(np.zeros_like(starts), starts, np.roll(p, 1, -1)) < ALPHA
    check_env(MOMDPEnv(model), skip_render_check=True)


def test_check_env_passes_for_model_envs():
    envs = [
        POMDPEnv(tiger(), horizon=10),
        POMDPEnv(SparsePOMDP.from_dense(tiger()), horizon=10),
        MOMDPEnv(random_momdp(3, 2, 2, 2, seed=0), horizon=5),
        MOMDPEnv(random_momdp(3, 2, 2, 2, static=False, seed=0), horizon=5),
    ]
    for env in envs:
        check_env(env, skip_render_check=True)
    for env_id, model in (("torchhrc/POMDP-v0", tiger()),
                          ("torchhrc/MOMDP-v0", random_momdp(3, 2, 2, 2, seed=0))):  # fmt: skip
        env = gym.make(env_id, model=model, horizon=5, render_mode="ansi")
        check_env(env.unwrapped)
        env.reset(seed=0)
        env.step(0)
        assert env.render().startswith("t=1 a=0")


@pytest.mark.parametrize("make", [lambda: POMDPEnv(tiger()),
                                  lambda: MOMDPEnv(random_momdp(3, 2, 2, 2, static=False,
                                                                seed=0))])  # fmt: skip
def test_reset_seed_fixes_the_episode(make):
    def episode(seed):
        env = make()
        out = [env.reset(seed=seed)]
        out += [env.step(t % env.action_space.n) for t in range(30)]
        return repr(out)

    assert episode(5) == episode(5)
    assert episode(5) != episode(6)


def test_horizon_truncates_and_terminal_terminates():
    env = POMDPEnv(tiger(), horizon=3)
    env.reset(seed=0)
    flags = [env.step(0)[2:4] for _ in range(3)]
    assert flags == [(False, False), (False, False), (False, True)]
    T = torch.tensor([[[0.0, 1.0], [0.0, 1.0]]], dtype=torch.float64)
    one_way = POMDP(T=T, Z=torch.ones(1, 2, 1, dtype=torch.float64), R=torch.zeros(1, 2,
                    dtype=torch.float64), b0=torch.tensor([1.0, 0.0], dtype=torch.float64),
                    discount=0.9)  # fmt: skip
    env = POMDPEnv(one_way, terminal_states=[1])
    env.reset(seed=0)
    assert env.step(0)[2:4] == (True, False)


def test_bad_arguments_name_the_argument():
    with pytest.raises(TypeError, match="model"):
        POMDPEnv(random_momdp(2, 2, 2, 2, seed=0))
    with pytest.raises(ValueError, match="horizon"):
        POMDPEnv(tiger(), horizon=0)
    with pytest.raises(ValueError, match="terminal_states"):
        POMDPEnv(tiger(), terminal_states=[5])
    with pytest.raises(ValueError, match="batch_shape"):
        POMDPEnv(random_pomdp(2, 2, 2, batch_shape=(2,), seed=0))
    env = MOMDPEnv(random_momdp(2, 2, 2, 2, seed=0))
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"action to be an int in \[0, 2\)"):
        env.step(2)
    assert isinstance(env.model, MOMDP)
