"""The registered paper tasks and the batched place-and-drill VectorEnv: check_env, the
simulated human's frequencies against the model it should match (chi-square), scoring,
autoreset and determinism."""

from __future__ import annotations

import numpy as np
import pytest
import torch

gym = pytest.importorskip("gymnasium", reason="torchhrc.envs needs the gym extra (gymnasium)")
pytest.importorskip("scipy", reason="the frequency tests use scipy.stats")

from _stated_rewards import stated_reward  # noqa: E402
from gymnasium.utils.env_checker import check_env  # noqa: E402

import torchhrc.envs  # noqa: E402,F401  (registers the ids)
from torchhrc.tasks.interface import behaviour_from_preferences  # noqa: E402
from torchhrc.tasks.pipeline import transition_from_behaviour  # noqa: E402
from torchhrc.tasks.place_and_drill.env import PlaceAndDrillEnv  # noqa: E402
from torchhrc.tasks.place_and_drill.vector_env import PlaceAndDrillVectorEnv  # noqa: E402

ALPHA = 1e-3


def _vector_samples(envs: PlaceAndDrillVectorEnv, steps: int, seed: int):
    """``(x, a, y, x2, reward)`` of every real (non-reset) step, random actions."""
    rng = np.random.default_rng(seed)
    obs, info = envs.reset(seed=seed)
    out = []
    for _ in range(steps):
        a = rng.integers(envs.task.num_actions, size=envs.num_envs)
        obs2, r, _, _, info2 = envs.step(a)
        real = obs2["observation"] == 0  # 1 marks a step that reset the episode
        out.append(np.stack([obs["x"], a, info["y"], obs2["x"], r], -1)[real])
        obs, info = obs2, info2
    data = np.concatenate(out)
    return (*(data[:, i].astype(np.int64) for i in range(4)), data[:, 4])


@pytest.mark.parametrize("env_id", ["torchhrc/PlaceAndDrill-v0", "torchhrc/HandFinishing-v0"])
def test_check_env_passes_for_registered_tasks(env_id):
    env = gym.make(env_id, render_mode="ansi")
    check_env(env.unwrapped)
    obs, info = env.reset(seed=0)
    assert env.observation_space.contains(obs)
    assert info["type"] in ("safe", "efficient", "left", "right")
    assert env.render().startswith("t=0")


@pytest.mark.parametrize("env_id", ["torchhrc/PlaceAndDrill-v0", "torchhrc/HandFinishing-v0"])
def test_reset_seed_fixes_the_episode(env_id):
    def episode(seed):
        env = gym.make(env_id, epsilon=0.3)
        out = [env.reset(seed=seed)]
        out += [env.step(t % 3)[:4] for t in range(10)]
        out += [env.reset()]  # the stream continues deterministically after a seeded reset
        return repr(out)

    assert episode(3) == episode(3)
    assert episode(3) != episode(4)


def test_random_placements_follow_the_expert_model(chi_square):
    """With epsilon = 1 the human places uniformly at random among the empty positions: the
    expert MOMDP's Tx (with the noise: its ``pause``); with epsilon = 0 it does not."""
    for noise in (0.0, 0.3):
        envs = PlaceAndDrillVectorEnv(256, epsilon=1.0, noise=noise)
        x, a, y, x2, r = _vector_samples(envs, 60, seed=1)
        task, X = envs.task, envs.task.num_states
        ones = torch.ones(1, task.num_actions, 1, task.n_positions, dtype=torch.float64)

        def uniform_tx(pause, ones=ones, task=task):  # (A, X, X): a uniform placement or a pause
            behaviour = behaviour_from_preferences(task, ones, pause=pause)
            return transition_from_behaviour(task, behaviour)[..., 0, :].numpy()

        Tx = uniform_tx(noise)
        assert chi_square(a * X + x, x2, Tx.reshape(-1, X)) > ALPHA
        np.testing.assert_array_equal(r, envs.human.score.numpy()[a, x, y])
        if noise == 0.0:  # the test can fail: the same samples against a skipping human
            wrong = uniform_tx(0.2)
            assert chi_square(a * X + x, x2, wrong.reshape(-1, X)) < ALPHA
    ordered = PlaceAndDrillVectorEnv(256, epsilon=0.0)
    x, a, y, x2, r = _vector_samples(ordered, 60, seed=2)
    assert chi_square(a * X + x, x2, Tx.reshape(-1, X)) < ALPHA


def test_ordered_human_follows_its_order_and_types_are_uniform(chi_square):
    envs = PlaceAndDrillVectorEnv(2000, epsilon=0.0)
    obs, info = envs.reset(seed=0)
    obs, *_ = envs.step(np.zeros(2000, dtype=np.int64))  # wait: one placement each
    first = envs.task.status[torch.as_tensor(obs["x"])].argmax(-1)  # the placed position
    np.testing.assert_array_equal(first.numpy(), envs._order[:, 0].numpy())
    assert chi_square(np.zeros(2000, dtype=np.int64), info["y"], np.full((1, 2), 0.5)) > ALPHA
    skewed = PlaceAndDrillVectorEnv(2000, type_probabilities=[0.8, 0.2])
    y = skewed.reset(seed=0)[1]["y"]
    assert chi_square(np.zeros_like(y), y, np.array([[0.8, 0.2]])) > ALPHA
    assert chi_square(np.zeros_like(y), y, np.full((1, 2), 0.5)) < ALPHA


def test_vector_env_autoresets_on_the_next_step():
    envs = PlaceAndDrillVectorEnv(8, epsilon=0.0, horizon=3)
    envs.reset(seed=0)
    drill_all = np.zeros(8, dtype=np.int64)
    for _ in range(3):
        obs, r, term, trunc, info = envs.step(drill_all)
    assert trunc.all() and not term.any() and (info["t"] == 3).all()
    obs, r, term, trunc, info = envs.step(drill_all)
    assert (obs["x"] == 0).all() and (obs["observation"] == 1).all()
    assert (r == 0).all() and not term.any() and not trunc.any() and (info["t"] == 0).all()


def test_an_efficient_robot_terminates_and_matches_the_single_env_law():
    """Drilling whatever is placed finishes in 2n steps at epsilon = 0; the batch and the
    single env agree on the return of every type."""
    envs = PlaceAndDrillVectorEnv(64, epsilon=0.0)
    obs, info = envs.reset(seed=1)
    types = info["y"]
    status = envs.task.status
    total = np.zeros(64)
    ended = np.zeros(64, dtype=bool)
    for _ in range(4):
        placed = (status[torch.as_tensor(obs["x"])] == 1).long()
        a = np.where(placed.any(-1), placed.argmax(-1) + 1, 0)
        obs, r, term, trunc, info = envs.step(a)
        total += np.where(ended, 0.0, r)
        ended |= term
    assert ended.all()
    env = PlaceAndDrillEnv(epsilon=0.0)
    for y_type in range(2):
        probs = [1.0 - y_type, float(y_type)]
        single = PlaceAndDrillEnv(epsilon=0.0, type_probabilities=probs)
        obs, info = single.reset(seed=0)
        ret, done = 0.0, False
        while not done:
            placed = (status[obs["x"]] == 1).long()
            a = int(placed.argmax()) + 1 if placed.any() else 0
            obs, r, term, trunc, info = single.step(a)
            ret, done = ret + r, term or trunc
        assert term and info["y"] == y_type
        batch = total[types == y_type]  # the type's runs (its reward ignores order)
        assert batch.size > 0
        np.testing.assert_allclose(batch, ret)
    assert env.horizon == 12


def test_hand_finishing_moves_follow_the_task_model(chi_square):
    env = gym.make("torchhrc/HandFinishing-v0", epsilon=0.2, horizon=None).unwrapped
    model = env.model
    X, Y = model.num_observed, model.num_hidden
    rng = np.random.default_rng(0)
    rows, nxt = [], []
    obs, info = env.reset(seed=0)
    R = model.R.numpy()
    for a in rng.integers(model.num_actions, size=6000):
        x, y = info["x"], info["y"]
        obs, r, term, _, info = env.step(int(a))
        assert r == R[a, x, y]  # the true type's reward
        rows.append((a * X + x) * Y + y)
        nxt.append(info["x"])
        assert env.observation_space.contains(obs)
        if term:
            obs, info = env.reset()
    rows, nxt = np.array(rows), np.array(nxt)
    Tx = model.Tx.numpy().reshape(-1, X)
    assert chi_square(rows, nxt, Tx) > ALPHA
    assert chi_square(rows, nxt, np.roll(Tx, 1, -1)) < ALPHA


def test_bad_options_name_the_option():
    with pytest.raises(ValueError, match="epsilon"):
        PlaceAndDrillEnv(epsilon=1.5)
    with pytest.raises(ValueError, match="noise"):
        PlaceAndDrillVectorEnv(2, noise=1.0)
    with pytest.raises(ValueError, match="type_probabilities"):
        PlaceAndDrillEnv(type_probabilities=[0.5, 0.6])
    envs = PlaceAndDrillVectorEnv(2)
    envs.reset(seed=0)
    with pytest.raises(ValueError, match="actions"):
        envs.step(np.array([0, 7]))
    with pytest.raises(ValueError, match="noise"):
        gym.make("torchhrc/HandFinishing-v0", noise=-0.1)


def test_registered_ids_make_the_batched_vector_env():
    envs = gym.make_vec(
        "torchhrc/PlaceAndDrill-v0",
        num_envs=8,
        vectorization_mode="vector_entry_point",
        epsilon=0.2,
    )
    assert isinstance(envs, PlaceAndDrillVectorEnv) and envs.human.epsilon == 0.2
    obs, _ = envs.reset(seed=0)
    assert envs.observation_space.contains(obs)
    obs, reward, *_ = envs.step(envs.action_space.sample())
    assert envs.observation_space.contains(obs) and reward.shape == (8,)


def test_vector_env_reset_seed_fixes_the_batch():
    def run(seed):
        envs = PlaceAndDrillVectorEnv(32, epsilon=0.5, noise=0.1)
        out = [envs.reset(seed=seed)]
        rng = np.random.default_rng(0)
        out += [envs.step(rng.integers(4, size=32)) for _ in range(20)]
        return repr(out)

    assert run(7) == run(7)
    assert run(7) != run(8)


def test_place_and_drill_rewards_are_the_tasks_stated_rewards():
    """Every reward of the single and the vector env is the stated reward of the episode's
    true type (a safe person's drill_early is -10, an efficient person's +10), and every
    situation of both types occurs.

    Bug this catches (issue 30): ``PlaceAndDrillEnv``'s rewards swapped between the two types
    (the former test compared the env with its own reward table, so it passed).
    """
    seen = set()
    rng = np.random.default_rng(0)
    env = PlaceAndDrillEnv(epsilon=0.3)
    names = env.task.state_names
    for episode in range(60):
        obs, info = env.reset(seed=episode)
        done = False
        while not done:
            bench = names[obs["x"]]
            a = int(rng.integers(env.task.num_actions))
            obs, r, term, trunc, info = env.step(a)
            assert r == stated_reward(bench, a, info["type"]), (bench, a, info["type"], r)
            seen.add((info["type"], stated_reward(bench, a, info["type"]), bench, a))
            done = term or trunc
    envs = PlaceAndDrillVectorEnv(64, epsilon=0.3)
    x, a, y, _, r = _vector_samples(envs, 30, seed=3)
    labels = envs.human.type_names
    stated = [stated_reward(names[i], j, labels[k]) for i, j, k in zip(x, a, y)]
    np.testing.assert_array_equal(r, stated)
    for label in ("safe", "efficient"):
        # each type met drilling early (the swap's tell: -10 against +10)
        assert any(t == label and b.count("E") and b[act - 1 : act] == "P"
                   for t, _, b, act in seen), label  # fmt: skip
