"""Tests of the policy graph (APPL's polgraph): the Tiger controller of Kaelbling, Littman and
Cassandra (1998), its exact value, depth and probability cuts, MOMDP labels, drawing."""

from __future__ import annotations

import pytest
import torch

from torchhrc.errors import ModelError
from torchhrc.pomdp import POMDP, SparsePOMDP
from torchhrc.solvers import SARSOPConfig, solve
from torchhrc.solvers.blind import blind_policy
from torchhrc.solvers.policy_graph import controller_value, draw_policy_graph, policy_graph
from torchhrc.solvers.qmdp import qmdp_policy
from torchhrc.tasks.classic import rock_sample, tiger

#: Tiger's listening accuracy: the belief after n net observations to one side is
#: 0.85^n / (0.85^n + 0.15^n)
ACCURACY = 0.85


@pytest.fixture(scope="module")
def tiger_solution():
    # converges by precision well before the time limit (about a second), so the policy does
    # not depend on the machine's speed
    return solve(tiger(), SARSOPConfig(time_limit=600.0, precision=1e-5, seed=0))


def _net(n: int) -> float:
    p, q = ACCURACY**n, (1 - ACCURACY) ** n
    return p / (p + q)


def test_tiger_graph_is_the_optimal_controller_of_klc98(tiger_solution):
    """Discount 0.95: listen until the belief is two net observations to one side, then open
    the other door; opening resets the problem to the root (KLC98, Fig. 6)."""
    m = tiger()
    g = policy_graph(m, tiger_solution.policy)
    assert g.closed and len(g.nodes) == 5 and len(g.edges) == 10
    act = {name: i for i, name in enumerate(m.actions)}
    # node by the net count of tiger-left observations: P(tiger-left) = _net(n)
    by_net = {}
    for i, node in enumerate(g.nodes):
        left = float(node.belief[0])
        n = min(range(-2, 3), key=lambda k: abs(left - (_net(k) if k >= 0 else 1 - _net(-k))))
        assert left == pytest.approx(_net(n) if n >= 0 else 1 - _net(-n), abs=1e-9)
        by_net[n] = i
    assert sorted(by_net) == [-2, -1, 0, 1, 2] and by_net[0] == 0  # the root is b0
    for n in (-1, 0, 1):
        assert g.nodes[by_net[n]].action == act["listen"]
    assert g.nodes[by_net[2]].action == act["open-right"]  # tiger heard left twice
    assert g.nodes[by_net[-2]].action == act["open-left"]
    obs = {name: i for i, name in enumerate(m.observations)}
    edges = {(e.source, e.observation): e for e in g.edges}
    for n in (-1, 0, 1):  # listening moves one step along the chain
        assert edges[(by_net[n], obs["tiger-left"])].target == by_net[n + 1]
        assert edges[(by_net[n], obs["tiger-right"])].target == by_net[n - 1]
    for n in (-2, 2):  # opening a door: back to the root on either observation
        for o in obs.values():
            assert edges[(by_net[n], o)].target == 0
            assert edges[(by_net[n], o)].probability == pytest.approx(0.5)
    # P(hear left | belief 0.85 left) = 0.85 * 0.85 + 0.15 * 0.15
    assert edges[(by_net[1], obs["tiger-left"])].probability == pytest.approx(0.745)


def test_controller_value_is_the_optimal_value(tiger_solution):
    """The controller's exact value (a linear solve) lies within SARSOP's bounds."""
    g = policy_graph(tiger(), tiger_solution.policy)
    value = controller_value(tiger(), g)
    assert tiger_solution.lower - 1e-6 <= value <= tiger_solution.upper + 1e-6
    assert value == pytest.approx(19.3713, abs=1e-3)  # Tiger's optimum at discount 0.95


def test_controller_value_of_always_listening():
    """Listening forever: the beliefs run to the corners (merged once equal to 1e-9), the
    graph closes, and its value is -1 / (1 - 0.95) = -20 from any belief."""
    g = policy_graph(tiger(), blind_policy(tiger()))
    assert g.closed
    assert controller_value(tiger(), g) == pytest.approx(-20.0, abs=1e-9)
    cut = policy_graph(tiger(), blind_policy(tiger()), depth=2)
    assert not cut.closed
    with pytest.raises(ModelError, match="closed"):
        controller_value(tiger(), cut)


def test_depth_and_min_prob_cut_the_graph(tiger_solution):
    p = tiger_solution.policy
    one = policy_graph(tiger(), p, depth=1)
    assert [n.depth for n in one.nodes] == [0, 1, 1]
    assert [n.expanded for n in one.nodes] == [True, False, False]
    assert not one.closed and len(one.edges) == 2
    zero = policy_graph(tiger(), p, depth=0)
    assert len(zero.nodes) == 1 and not zero.edges
    # the 0.255 edges (back towards the root) are dropped at 0.3; the nodes they led to
    # are still reached another way
    cut = policy_graph(tiger(), p, min_prob=0.3)
    assert not cut.closed
    assert min(e.probability for e in cut.edges) >= 0.3
    assert len(cut.edges) == 8


def test_max_branch_keeps_the_most_probable_edges(tiger_solution):
    """Tiger listening: the root's two outcomes are 0.5 each (the first kept), and from a
    belief of 0.85 the outcome that confirms it is 0.85^2 + 0.15^2 = 0.745, worked by hand."""
    one = policy_graph(tiger(), tiger_solution.policy, max_branch=1, depth=3)
    assert not one.closed
    out: dict[int, list] = {}
    for edge in one.edges:
        out.setdefault(edge.source, []).append(edge)
    assert all(len(edges) == 1 for edges in out.values())
    assert out[0][0].probability == pytest.approx(0.5) and out[0][0].observation == 0
    assert out[1][0].probability == pytest.approx(ACCURACY**2 + (1 - ACCURACY) ** 2)
    assert one.nodes[2].belief[0] == pytest.approx(_net(2))  # the confirming outcome's belief
    two = policy_graph(tiger(), tiger_solution.policy, max_branch=2)
    full = policy_graph(tiger(), tiger_solution.policy)
    assert two.closed and len(two.edges) == len(full.edges)  # at most 2 outcomes a node
    with pytest.raises(ValueError, match="max_branch"):
        policy_graph(tiger(), tiger_solution.policy, max_branch=0)


def test_edge_probabilities_sum_to_one_and_momdp_labels():
    m = rock_sample(4, 4, form="momdp")
    g = policy_graph(m, qmdp_policy(m), depth=2)
    assert g.factored
    for i, node in enumerate(g.nodes):
        if node.expanded:
            total = sum(e.probability for e in g.edges if e.source == i)
            assert total == pytest.approx(1.0, abs=1e-9)
        label = g.node_label(i)
        assert label.startswith("A: ") and "\nX: " in label and "\nY: " in label
        assert f"X: {m.observed_states[node.x]}" in label
    # an edge's next observed value is its target's
    for e in g.edges:
        assert g.nodes[e.target].x == e.x
    assert "X: " in g.edge_label(0)


def test_policy_of_another_model_is_refused():
    other = POMDP(
        T=torch.eye(3, dtype=torch.float64).expand(2, 3, 3),
        Z=torch.full((2, 3, 2), 0.5, dtype=torch.float64),
        R=torch.zeros(2, 3, dtype=torch.float64),
        b0=torch.full((3,), 1 / 3, dtype=torch.float64),
        discount=0.9,
    )
    with pytest.raises(ModelError, match="columns"):
        policy_graph(other, qmdp_policy(tiger()))
    with pytest.raises(ValueError, match="min_prob"):
        policy_graph(tiger(), qmdp_policy(tiger()), min_prob=1.5)


@pytest.mark.parametrize("suffix", [".png", ".svg"])
def test_draw_writes_an_image(tmp_path, tiger_solution, suffix):
    g = policy_graph(tiger(), tiger_solution.policy)
    path = draw_policy_graph(g, tmp_path / f"g{suffix}")
    data = path.read_bytes()
    if suffix == ".png":
        assert data[:8] == b"\x89PNG\r\n\x1a\n"
    else:
        assert b"<svg" in data[:2000]
    dot = g.to_dot()
    assert dot.count("->") == 10 and dot.count("[label=") == 15
    assert 'n0 [label="A: listen' in dot


def test_controller_value_of_a_fully_observable_model_is_the_mdp_value():
    """Starting in a known state and seeing the state, the beliefs are the corners (the graph
    closes on at most S nodes) and the QMDP policy is the MDP's optimal one: its exact value
    is value iteration's (T is not symmetric: a transposed T is caught)."""
    from torchhrc.solvers import value_iteration
    from torchhrc.testing import random_pomdp

    base = random_pomdp(4, 3, 4, discount=0.9, seed=3)
    eye = torch.eye(4, dtype=torch.float64).expand(3, 4, 4)
    start = torch.tensor([0.0, 0.0, 1.0, 0.0], dtype=torch.float64)
    model = POMDP(T=base.T, Z=eye, R=base.R, b0=start, discount=0.9)
    g = policy_graph(model, qmdp_policy(model))
    assert g.closed and len(g.nodes) <= 4
    exact = float(value_iteration(model.T, model.R, 0.9, tol=1e-12).values @ model.b0)
    assert controller_value(model, g) == pytest.approx(exact, abs=1e-8)
    # a sparse model through its solver form: the same value
    assert controller_value(SparsePOMDP.from_dense(model), g) == pytest.approx(exact, abs=1e-8)
