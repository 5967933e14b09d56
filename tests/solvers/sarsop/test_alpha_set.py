"""SARSOP's alpha set: the dominance lookup used when pruning keeps referenced vectors."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from torchhrc.solvers.eval_cache import unpack
from torchhrc.solvers.sarsop import SARSOPConfig, sarsop
from torchhrc.solvers.sarsop.alpha_set import _AlphaSet
from torchhrc.solvers.sarsop.search import _SARSOP


def _brute_force(V: np.ndarray, obs: np.ndarray, need: np.ndarray, kept: np.ndarray) -> list:
    out = []
    for i in need.tolist():
        hits = [j for j in kept.tolist() if obs[j] == obs[i] and (V[j] >= V[i]).all()]
        out.append(hits[0] if hits else -1)
    return out


def test_dominating_finds_the_first_pointwise_dominating_kept_vector_of_the_same_x() -> None:
    rng = np.random.default_rng(0)
    n, Y, X = 300, 40, 3
    # coarse values, so that ties and dominance are common; a few exact copies shifted up
    V = rng.integers(0, 3, size=(n, Y)).astype(np.float64)
    V[200:260] = V[:60] + rng.integers(0, 2, size=(60, Y))
    obs = rng.integers(0, X, size=n)
    obs[200:260] = obs[:60]
    alphas = _AlphaSet(
        torch.from_numpy(V), torch.zeros(n, dtype=torch.long), torch.from_numpy(obs), X
    )
    kept = np.sort(rng.choice(n, size=150, replace=False))
    need = np.setdiff1d(np.arange(n), kept)
    found = alphas._dominating(need, kept)
    assert found.tolist() == _brute_force(V, obs, need, kept)
    assert (found >= 0).sum() >= 8  # the case is not vacuous (10 found)


def _children_bounds_after_pruning(model, iterations: int, monkeypatch, rule: bool) -> tuple:
    """Solve with SARSOP; at every alpha pruning compare, at each active tree belief
    evaluated since the previous pruning, the lower bounds its cached evaluation holds for the
    children a later backup may combine (possible, under an action not pruned as sub-optimal)
    with their lower bounds under the pruned set. Returns (children checked, children whose
    bound dropped)."""
    original = _SARSOP.prune
    counts = [0, 0]

    def prune(self) -> None:
        before = self.alphas.size
        act = np.flatnonzero(self.tree.active[: self.tree.size])
        first = {}
        for n in act.tolist():  # one node per distinct belief
            first.setdefault(int(self.belief_id[n]), n)
        # the beliefs whose children the pruning protects (SARSOPConfig.prune_alphas)
        cached = {b: self._cache[b] for b in first if b in self._child_best}
        original(self)
        if self.alphas.size == before:
            return  # no alpha pruning this iteration
        for b, record in cached.items():
            q_low, q_up, prob, low, _up = unpack(record, self.A, self.O)
            n = first[b]
            live = (q_up >= q_low.max())[:, None, None] & (prob > 0)
            fresh = self._evaluate_np(int(self.tree.x[n]), self.tree.beliefs_np[n])[0]
            now = unpack(fresh, self.A, self.O)[3]
            tol = 1e-9 * np.maximum(1.0, np.abs(low))
            counts[0] += int(live.sum())
            counts[1] += int((now < low - tol)[live].sum())

    monkeypatch.setattr(_SARSOP, "prune", prune)
    if not rule:
        monkeypatch.setattr(_SARSOP, "_child_winners", lambda self, nodes: np.zeros(0, np.int64))
    sarsop(model, SARSOPConfig(time_limit=1e9, precision=1e-9, max_iterations=iterations))
    return tuple(counts)


@pytest.mark.parametrize("form", ["flat", "momdp"])
def test_pruning_keeps_the_children_bounds_of_active_tree_beliefs(form, monkeypatch) -> None:
    from torchhrc.tasks.classic import rock_sample
    from torchhrc.testing import random_pomdp

    if form == "flat":
        model = random_pomdp(6, 3, 3, discount=0.9, seed=11)
    else:
        model = rock_sample(4, 4, form="momdp")
    checked, dropped = _children_bounds_after_pruning(model, 40, monkeypatch, rule=True)
    assert checked > 1000 and dropped == 0
    # the property is not automatic: pruning to the tree-belief winners and what they refer
    # to lowers some of those children's bounds
    with monkeypatch.context() as m:
        _, dropped = _children_bounds_after_pruning(model, 40, m, rule=False)  # 8 / 20 drop
    assert dropped > 0


@pytest.mark.parametrize("form", ["flat", "momdp"])
def test_alpha_pruning_keeps_the_lower_bound_at_every_active_tree_node(form, monkeypatch):
    """The pruning scores one node per distinct belief; the lower bound at every active node
    (the duplicates of a belief included) is the same before and after it, by the tree
    beliefs' winners alone (the children's winners, which often cover them too, left out)."""
    from torchhrc.tasks.classic import rock_sample, tiger

    # (tiger: listening left then right returns to a belief the tree holds already)
    model = tiger() if form == "flat" else rock_sample(4, 4, form="momdp")
    original = _SARSOP._prune_alphas
    seen = {"prunings": 0, "nodes": 0, "duplicates": 0}

    def bounds(self, act):
        rows, xs = self.tree.beliefs_np[act], self.tree.x[act]
        return self._lower_np(np.ascontiguousarray(rows), xs.astype(np.int64))[0]

    def prune_alphas(self):
        act = np.flatnonzero(self.tree.active[: self.tree.size])
        before = bounds(self, act)
        ran = original(self)
        if ran:
            after = bounds(self, act)
            assert (after >= before - 1e-9 * np.maximum(1.0, np.abs(before))).all()
            seen["prunings"] += 1
            seen["nodes"] += act.size
            seen["duplicates"] += act.size - np.unique(self.belief_id[act]).size
        return ran

    monkeypatch.setattr(_SARSOP, "_prune_alphas", prune_alphas)
    monkeypatch.setattr(_SARSOP, "_child_winners", lambda self, nodes: np.zeros(0, np.int64))
    sarsop(model, SARSOPConfig(time_limit=1e9, precision=1e-9, max_iterations=60))
    # not vacuous: prunings ran over trees holding beliefs more than once
    assert seen["prunings"] >= 2 and seen["duplicates"] > 0


def test_child_records_start_afresh_at_each_alpha_pruning(monkeypatch) -> None:
    """A pruning protects the children of the beliefs evaluated since the previous one only:
    the records are cleared when the vectors are pruned, and every belief recorded is one
    whose evaluation the search cached."""
    from torchhrc.testing import random_pomdp

    original_prune, original_winners = _SARSOP.prune, _SARSOP._child_winners
    calls, recorded_sizes = [0], []

    def winners(self, nodes):
        calls[0] += 1
        return original_winners(self, nodes)

    def prune(self) -> None:
        recorded = set(self._child_best)
        assert recorded <= set(self._cache)
        before = calls[0]
        original_prune(self)
        if calls[0] > before:  # an alpha pruning ran
            recorded_sizes.append(len(recorded))
            assert self._child_best == {}

    monkeypatch.setattr(_SARSOP, "_child_winners", winners)
    monkeypatch.setattr(_SARSOP, "prune", prune)
    model = random_pomdp(6, 3, 3, discount=0.9, seed=11)
    sol = sarsop(model, SARSOPConfig(time_limit=1e9, precision=1e-9, max_iterations=40))
    assert len(recorded_sizes) >= 2 and min(recorded_sizes) > 0  # prunings with records
    assert sol.lower <= sol.upper


def test_vectors_held_narrower_are_rounded_down_by_at_most_one_step() -> None:
    """A float32 store of float64 vectors (``SARSOPConfig(alpha_dtype=torch.float32)``):
    every entry stored is the largest float32 at or below the computed one (so a stored
    vector is a lower bound wherever the computed one is), through the constructor, ``add``
    and ``add_np``; a float64 store keeps them bit for bit."""
    g = torch.Generator().manual_seed(0)
    v = (torch.rand(6, 50, generator=g, dtype=torch.float64) - 0.5) * 40.0
    v[0, :3] = torch.tensor([0.5, -2.0, 19.0], dtype=torch.float64)  # exact in float32

    def below(stored: torch.Tensor, exact: torch.Tensor) -> None:
        s = stored.double()
        assert bool((s <= exact).all())
        above = torch.nextafter(stored, torch.full_like(stored, torch.inf)).double()
        assert bool((above > exact).all())  # the next float32 up is above: the largest below

    obs = torch.zeros(2, dtype=torch.long)
    store = _AlphaSet(v[:2], torch.tensor([0, 1]), obs, 1, dtype=torch.float32)
    store.add(v[2:4], torch.tensor([0, 1]), obs)
    store.add_np(v[4].numpy(), 0, 0)
    store.add_np(v[5].numpy(), 1, 0)
    assert store.vectors.dtype == torch.float32 and store.size == 6
    below(store.vectors[:6], v)
    assert store.vectors[0, :3].tolist() == [0.5, -2.0, 19.0]
    same = _AlphaSet(v[:2], torch.tensor([0, 1]), obs, 1)
    same.add_np(v[4].numpy(), 0, 0)
    assert same.vectors.dtype == torch.float64
    assert torch.equal(same.vectors[:3], torch.cat([v[:2], v[4:5]]))
