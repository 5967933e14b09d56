"""The agent adapter: a SARSOP policy with its belief filter acting in an environment earns
what evaluate_policy says it earns on the model; its beliefs are the library's updates."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

pytest.importorskip("gymnasium", reason="torchhrc.envs needs the gym extra (gymnasium)")

from torchhrc.envs import (
    BeliefAgent,
    MOMDPEnv,
    POMDPEnv,
    RandomAgent,
    rollout,
)
from torchhrc.pomdp.belief import momdp_update, update
from torchhrc.solvers import SARSOPConfig, evaluate_policy, solve
from torchhrc.tasks.classic import tiger
from torchhrc.tasks.place_and_drill.hand_coded import build_expert_momdp, load_expert_model
from torchhrc.tasks.place_and_drill.vector_env import PlaceAndDrillVectorEnv
from torchhrc.testing import random_momdp

Z95 = 1.959963984540054


def _agrees(env_returns: np.ndarray, result) -> None:
    """The two 95% intervals overlap: |mean_env - mean_eval| <= half_env + half_eval."""
    half_env = Z95 * env_returns.std(ddof=1) / math.sqrt(env_returns.size)
    half_eval = (result.ci_high - result.ci_low) / 2
    gap = abs(env_returns.mean() - result.mean)
    assert gap <= half_env + half_eval, (env_returns.mean(), half_env, result.mean, half_eval)


def test_sarsop_return_in_pomdp_env_matches_evaluate_policy():
    model = tiger()
    policy = solve(model, SARSOPConfig(time_limit=10.0, precision=0.05, seed=0)).policy
    H = 30
    returns = rollout(POMDPEnv(model, horizon=H), BeliefAgent(model, policy), episodes=300,
                      seed=0, discount=model.discount)  # fmt: skip
    _agrees(returns, evaluate_policy(model, policy, episodes=4000, horizon=H, seed=1))
    blind = rollout(POMDPEnv(model, horizon=H), RandomAgent(POMDPEnv(model).action_space,
                    seed=0), episodes=400, seed=0, discount=model.discount)  # fmt: skip
    assert returns.mean() > blind.mean() + 20  # the comparison has power: random is far worse


@pytest.mark.parametrize("name", ["place_and_drill_expert", "random"])
def test_sarsop_return_in_momdp_env_matches_evaluate_policy(name):
    if name == "random":
        model = random_momdp(4, 2, 3, 2, seed=5)
        H, terminal = 25, ()
    else:
        model = build_expert_momdp(load_expert_model())
        H, terminal = 12, (model.num_observed - 1,)
    policy = solve(model, SARSOPConfig(time_limit=10.0, precision=0.05, seed=0)).policy
    env = MOMDPEnv(model, horizon=H, terminal_observed=terminal)
    returns = rollout(env, BeliefAgent(model, policy), episodes=300, seed=0,
                      discount=model.discount)  # fmt: skip
    _agrees(returns, evaluate_policy(model, policy, episodes=4000, horizon=H, seed=1))


def test_agent_beliefs_are_the_library_updates():
    model = random_momdp(3, 2, 2, 3, static=False, seed=0)
    policy = solve(model, SARSOPConfig(time_limit=5.0, precision=0.1, seed=0)).policy
    env, agent = MOMDPEnv(model), BeliefAgent(model, policy)
    obs, _ = env.reset(seed=0)
    agent.reset(obs)
    x, belief = obs["x"], model.b0
    for _ in range(10):
        a = agent.act(obs)
        assert a == int(policy.action(torch.tensor(x), belief))
        obs, *_ = env.step(a)
        agent.observe(a, obs)
        belief = momdp_update(model, x, belief, a, obs["x"], obs["observation"]).belief
        x = obs["x"]
        torch.testing.assert_close(agent.belief[0], belief)
    flat = tiger()
    flat_policy = solve(flat, SARSOPConfig(time_limit=5.0, precision=0.1, seed=0)).policy
    agent = BeliefAgent(flat, flat_policy)
    agent.reset(2)
    agent.observe(0, 1)
    torch.testing.assert_close(agent.belief[0], update(flat, flat.b0, 0, 1).belief)


def test_agent_acts_on_a_vector_env_batch():
    envs = PlaceAndDrillVectorEnv(16, epsilon=0.0)
    model = envs.model
    policy = solve(model, SARSOPConfig(time_limit=5.0, precision=0.05, seed=0)).policy
    agent = BeliefAgent(model, policy)
    obs, _ = envs.reset(seed=0)
    agent.reset(obs)
    for _ in range(30):
        a = agent.act(obs)
        assert a.shape == (16,)
        obs, *_ = envs.step(a)
        agent.observe(a, obs)  # episodes the env restarted (observation 1) restart at b0
        restarted = torch.as_tensor(obs["observation"] == 1)
        torch.testing.assert_close(agent.belief[restarted], model.b0.expand(16, -1)[restarted])
    assert agent.belief.shape == (16, model.num_hidden)
    torch.testing.assert_close(agent.belief.sum(-1), torch.ones(16, dtype=torch.float64))


def test_flat_policy_of_a_momdp_filters_on_the_flat_model():
    """A policy solved on ``to_pomdp()`` acts in the MOMDP env through flat observations
    ``x2 * O + o`` and the flat belief update."""
    model = random_momdp(3, 2, 2, 2, seed=4)
    flat = model.to_pomdp()
    policy = solve(flat, SARSOPConfig(time_limit=5.0, precision=0.1, seed=0)).policy
    env, agent = MOMDPEnv(model), BeliefAgent(model, policy)
    obs, _ = env.reset(seed=1)
    agent.reset(obs)
    belief = flat.b0
    for _ in range(8):
        a = agent.act(obs)
        assert a == int(policy.action(belief))
        obs, *_ = env.step(a)
        agent.observe(a, obs)
        o_flat = obs["x"] * model.num_observations + obs["observation"]
        belief = update(flat, belief, a, o_flat).belief
        torch.testing.assert_close(agent.belief[0], belief)
