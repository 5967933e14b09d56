"""The online controller: belief updates match the filter, first step, errors, batches."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from torchhrc.errors import ModelError
from torchhrc.pomdp.belief import momdp_update, update
from torchhrc.solvers import AlphaVectorPolicy
from torchhrc.tasks.controller import Controller
from torchhrc.testing import random_momdp, random_pomdp


def _blind(m):
    return AlphaVectorPolicy.from_action_vectors(m.R, momdp=True)


def test_belief_follows_the_momdp_filter():
    m = random_momdp(4, 3, 2, 2, seed=1)
    policy = _blind(m)
    c = Controller.from_momdp(m, policy)
    c.reset()
    a = c.act(0)
    assert torch.equal(c.belief, m.b0)  # nothing to update at the start
    assert a == int(policy.action(torch.tensor(0), m.b0))
    b = momdp_update(m, 0, m.b0, a, 2, 1).belief
    a2 = c.act((2, 1))
    assert torch.allclose(c.belief, b)
    assert a2 == int(policy.action(torch.tensor(2), b))
    c.reset(torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64))
    assert c.belief.tolist() == [1.0, 0.0, 0.0] and c.history == []


def test_batched_episodes_match_single_ones():
    m = random_momdp(4, 3, 2, 2, seed=2)
    c = Controller.from_momdp(m, _blind(m))
    c.reset(batch=2)
    a = c.act(torch.tensor([0, 1]))
    c.act((torch.tensor([3, 2]), torch.tensor([0, 1])))
    for i, (x0, x1, o) in enumerate(((0, 3, 0), (1, 2, 1))):
        s = Controller.from_momdp(m, _blind(m))
        s.reset()
        assert s.act(x0) == int(a[i])
        s.act((x1, o))
        assert torch.allclose(s.belief, c.belief[i])


def test_impossible_observation_raises():
    m = random_momdp(3, 2, 2, 1, seed=0)
    Tx = torch.zeros_like(m.Tx)
    Tx[..., 0] = 1.0  # every step goes to x = 0
    m = type(m)(Tx=Tx, Ty=None, Z=m.Z, R=m.R, x0=0, b0=m.b0, discount=m.discount)
    c = Controller.from_momdp(m, _blind(m))
    c.reset()
    c.act(0)
    with pytest.raises(ModelError):
        c.act(2)


def test_prior_is_validated():
    m = random_momdp(3, 2, 2, 1, seed=0)
    c = Controller.from_momdp(m, _blind(m))
    with pytest.raises(ModelError, match=r"expected prior of shape \(K=2,\)"):
        c.reset(torch.ones(3) / 3)
    with pytest.raises(ModelError, match="sum to 1"):
        c.reset(torch.tensor([0.7, 0.7]))


def test_flat_pomdp_controller_uses_the_flat_filter():
    p = random_pomdp(3, 2, 2, seed=0)
    policy = AlphaVectorPolicy.from_action_vectors(p.R, momdp=False)
    c = Controller.from_pomdp(p, policy)
    c.reset()
    a = c.act(0)
    c.act(1)
    assert torch.allclose(c.belief, update(p, p.b0, a, 1).belief)


def test_random_start_begins_from_the_belief_given_the_first_state():
    joint = torch.tensor([[0.1, 0.3], [0.0, 0.0], [0.45, 0.15]], dtype=torch.float64)
    model = random_momdp(3, 2, 2, 2, seed=0).with_initial(joint)
    seen = []
    policy = AlphaVectorPolicy.from_action_vectors(model.R, momdp=True)
    c = Controller.from_momdp(model, policy)
    choose = c._choose
    c._choose = lambda x, b: (seen.append(b.clone()), choose(x, b))[1]
    c.reset()
    c.act(0)
    torch.testing.assert_close(seen[-1], torch.tensor([0.25, 0.75], dtype=torch.float64))
    c.reset()
    a = c.act(2)
    first = seen[-1]
    torch.testing.assert_close(first, torch.tensor([0.75, 0.25], dtype=torch.float64))
    c.act((0, 1))  # later steps filter as usual
    x, x2 = torch.tensor(2), torch.tensor(0)
    want = momdp_update(model, x, first, torch.tensor(a), x2, torch.tensor(1)).belief
    torch.testing.assert_close(seen[-1], want)
    # a batch starting at different cells
    c.reset(batch=2)
    c.act(torch.tensor([0, 2]))
    torch.testing.assert_close(seen[-1], torch.tensor([[0.25, 0.75], [0.75, 0.25]],
                                                      dtype=torch.float64))  # fmt: skip
    # an explicit prior wins; a first state without mass is an error
    c.reset(prior=torch.tensor([0.5, 0.5], dtype=torch.float64))
    c.act(0)
    torch.testing.assert_close(seen[-1], torch.tensor([0.5, 0.5], dtype=torch.float64))
    c.reset()
    with pytest.raises(ModelError, match="no mass"):
        c.act(1)


def test_impossible_observation_error_names_only_what_exists():
    m = random_momdp(3, 2, 2, 1, seed=0)
    Tx = torch.zeros_like(m.Tx)
    Tx[..., 0] = 1.0  # every step goes to x = 0
    m = type(m)(Tx=Tx, Ty=None, Z=m.Z, R=m.R, x0=0, b0=m.b0, discount=m.discount)
    c = Controller.from_momdp(m, _blind(m))
    c.reset(batch=3)
    a = c.act(torch.tensor([0, 0, 0]))
    with pytest.raises(ModelError, match=r"episode 1: after action .* state x' = 2") as err:
        c.act(torch.tensor([0, 2, 0]))
    assert "on_zero" not in str(err.value) and "reset(" in str(err.value)
    assert a.shape == (3,)


def test_done_marks_terminal_states():
    # state 2 is absorbing with zero reward: the episode's end
    m = random_momdp(3, 2, 2, 1, seed=3)
    Tx, R = m.Tx.clone(), m.R.clone()
    Tx[:, 2] = 0.0
    Tx[:, 2, :, 2] = 1.0
    R[:, 2] = 0.0
    # state 1: zero reward and action 0 stays, but action 1 leaves: not an end
    Tx[0, 1] = 0.0
    Tx[0, 1, :, 1] = 1.0
    R[:, 1] = 0.0
    m = type(m)(Tx=Tx, Ty=None, Z=m.Z, R=R, x0=0, b0=m.b0, discount=m.discount)
    c = Controller.from_momdp(m, _blind(m))
    assert c.terminal.tolist() == [False, False, True]
    c.reset()
    assert c.done is False
    c.act(0)
    assert c.done is False
    c.act(2)
    assert c.done is True
    c.reset(batch=2)
    c.act(torch.tensor([0, 2]))
    assert c.done.tolist() == [False, True]
    # ints in, ints out; the same action as the tensor form
    c.reset()
    assert isinstance(c.act(1), int)


def test_act_checks_the_state_and_signal_indices():
    # x = 7 of a 4-state model, or x = 0.5, is not a state: said so, not an alpha-vector miss
    m = random_momdp(4, 3, 2, 2, seed=1)
    c = Controller.from_momdp(m, _blind(m))
    for bad, msg in ((7, r"expected x in \[0, 4\).*got 7"), (-1, r"got -1"),
                     (torch.tensor([0, 4]), "got 4"), (np.array([4, 0]), "got 4")):  # fmt: skip
        c.reset(batch=2 if isinstance(bad, (torch.Tensor, np.ndarray)) else None)
        with pytest.raises(ModelError, match=msg):
            c.act(bad)
    for bad in (0.5, 2.0, True, torch.tensor([0.0, 1.0]), "2"):  # not an index: a TypeError
        c.reset(batch=2 if isinstance(bad, torch.Tensor) else None)
        with pytest.raises(TypeError, match="expected x to be an integer index"):
            c.act(bad)
    c.reset()
    assert isinstance(c.act(np.int64(1)), int)  # NumPy integers are indices
    for batch in (0, -2, 2.0):
        with pytest.raises(ModelError, match="expected batch to be a positive int"):
            c.reset(batch=batch)
    c.reset()
    c.act(0)
    with pytest.raises(ModelError, match=r"expected o in \[0, 2\).*got 2"):
        c.act((1, 2))
    # an impossible step names the states when the model has names
    Tx = torch.zeros_like(m.Tx)
    Tx[..., 0] = 1.0  # every step goes to x = 0
    named = type(m)(Tx=Tx, Ty=None, Z=m.Z, R=m.R, x0=0, b0=m.b0, discount=m.discount,
                    observed_states=("start", "b", "c", "d"))  # fmt: skip
    c = Controller.from_momdp(named, _blind(named))
    c.reset()
    c.act(0)
    with pytest.raises(ModelError, match=r"x = 0 \('start'\), the state x' = 2 \('c'\)"):
        c.act(2)
