"""The sparse MOMDP (torchhrc.pomdp.sparse_momdp, torchhrc.solvers.forms.sparse_momdp).

Reference: the dense MOMDP form of the same model. Every operation of the solver interface
(children, back-projection, initial bounds, PBVI's backup and simulation) must agree with it,
and SARSOP and PBVI must reach the same bounds through either form.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np
import pytest
import torch

from torchhrc.errors import ModelError
from torchhrc.io import format_pomdpx, read_pomdpx
from torchhrc.io import pomdpx as pomdpx_io
from torchhrc.pomdp import SparseMOMDP
from torchhrc.solvers import PBVIConfig, SARSOPConfig, pbvi, sarsop, solve
from torchhrc.solvers.clock import NEVER
from torchhrc.solvers.forms import MOMDPForm, SparseMOMDPForm, as_solver_model
from torchhrc.solvers.forms import sparse_momdp as sparse_momdp_module
from torchhrc.solvers.policy import AlphaVectorPolicy
from torchhrc.solvers.sarsop.search import _SARSOP
from torchhrc.solvers.sparse_model import blind_iteration_np, qmdp_iteration_np
from torchhrc.tasks.classic import rock_sample
from torchhrc.testing import random_momdp

MODELS = {
    "rock_sample_4_4": lambda: rock_sample(4, 4, form="momdp"),  # Ty not the identity (sampling)
    "dynamic": lambda: random_momdp(5, 4, 3, 3, static=False, sparsity=0.4, seed=3),
    "static": lambda: random_momdp(4, 3, 2, 3, static=True, sparsity=0.3, seed=1),
}


def _pair(name: str) -> tuple[MOMDPForm, SparseMOMDPForm]:
    model = MODELS[name]()
    return as_solver_model(model), as_solver_model(SparseMOMDP.from_dense(model))


def _random_beliefs(Y: int, n: int, seed: int) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    b = torch.rand(n, Y, generator=g, dtype=torch.float64)
    b[0, : Y // 2] = 0.0  # one belief on part of the hidden values
    return b / b.sum(-1, keepdim=True)


@pytest.mark.parametrize("name", sorted(MODELS))
def test_every_operation_equals_the_dense_momdp_form(name: str) -> None:
    dense, sparse = _pair(name)
    assert type(sparse) is SparseMOMDPForm and sparse.factored
    assert as_solver_model(sparse) is sparse
    for attr in ("num_actions", "num_observed", "num_hidden", "num_observations", "x0"):
        assert getattr(sparse, attr) == getattr(dense, attr)
    assert sparse.state_shape == dense.state_shape
    torch.testing.assert_close(sparse.R, dense.R, rtol=0, atol=0)
    A, Y = dense.num_actions, dense.num_hidden
    for x in range(dense.num_observed):
        b = _random_beliefs(Y, 3, seed=x)
        xs_d, J_d = dense.expand(x, b)
        xs_s, J_s = sparse.expand(x, b)
        assert torch.equal(xs_d, xs_s)
        torch.testing.assert_close(J_s, J_d, rtol=0, atol=1e-14)
        torch.testing.assert_close(sparse.reward(x, b), dense.reward(x, b))
        K = xs_d.numel()
        v = torch.randn(A, K, Y, generator=torch.Generator().manual_seed(x), dtype=torch.float64)
        acts = torch.arange(A)
        torch.testing.assert_close(sparse.backproject(x, acts, v), dense.backproject(x, acts, v))
        bn = b[0].numpy()
        np.testing.assert_allclose(sparse.predict_np(x, bn), dense.predict_np(x, bn), atol=1e-14)
        for a in range(A):
            np.testing.assert_allclose(
                sparse.backproject_np(x, a, v[a].numpy()), dense.backproject_np(x, a, v[a].numpy()),
                atol=1e-13,
            )  # fmt: skip
            for k in range(K):
                np.testing.assert_allclose(
                    sparse.predict_action_np(x, bn, a, k), dense.predict_action_np(x, bn, a, k),
                    atol=1e-14,
                )  # fmt: skip
        cd, cs = dense.children_np(x, bn), sparse.children_np(x, bn)
        np.testing.assert_array_equal(cs.nz, cd.nz)
        np.testing.assert_array_equal(cs.rows_x, cd.rows_x)
        np.testing.assert_allclose(cs.rows, cd.rows, atol=1e-14)
        np.testing.assert_allclose(cs.prob, cd.prob, atol=1e-14)
        np.testing.assert_allclose(cs.reward, cd.reward, atol=1e-14)


@pytest.mark.parametrize("name", sorted(MODELS))
def test_initial_bounds_equal_the_dense_momdp_form(name: str) -> None:
    dense, sparse = _pair(name)
    # the sparse form keeps one vector per kind of action (identical actions, identical
    # vectors): each of its vectors is the dense form's of the same (action, x), and every
    # dense vector it drops equals one it keeps at the same x
    got, want = sparse.blind_policy(100_000), dense.blind_policy(100_000)
    key = {(int(a), int(x)): v for a, x, v in zip(want.actions, want.observed, want.alphas)}
    for a, x, v in zip(got.actions, got.observed, got.alphas):
        torch.testing.assert_close(v, key[int(a), int(x)], rtol=0, atol=1e-7)
    for (a, x), v in key.items():
        kept = got.alphas[got.observed == x]
        assert bool(((kept - v).abs().amax(-1) <= 1e-7).any()), (a, x)
    fd, _ = dense.fib_corner_values(1e-11, NEVER, 100_000)
    fs, _ = sparse.fib_corner_values(1e-11, NEVER, 100_000)
    torch.testing.assert_close(fs, fd, rtol=0, atol=1e-8)
    # FIB operator itself, one step from the same vectors
    qd = dense.upper_vectors("qmdp", 1e-11)
    torch.testing.assert_close(sparse.upper_vectors("qmdp", 1e-11), qd, rtol=0, atol=1e-8)
    if dense.Ty is not None:
        step = torch.from_numpy(sparse.fib_np(qd.numpy()))
        torch.testing.assert_close(step, dense._fib(qd), rtol=0, atol=1e-12)


def test_blind_vectors_iterated_past_the_direct_size_are_a_converging_lower_bound() -> None:
    from torchhrc.solvers.forms import sparse_momdp as module

    _, sparse = _pair("rock_sample_4_4")
    old = module.SPARSE_DIRECT_SOLVE_SIZE
    module.SPARSE_DIRECT_SOLVE_SIZE = 10**6  # force the dense LU (272 states)
    try:
        exact = sparse.blind_vectors()
    finally:
        module.SPARSE_DIRECT_SOLVE_SIZE = old
    # past SPARSE_DIRECT_SOLVE_SIZE (RockSample(4, 4): 272 states) the form iterates
    few = sparse.blind_vectors(max_iterations=3)
    chain = sparse.blind_vectors(max_iterations=5)
    many = sparse.blind_vectors()
    assert bool((few <= exact + 1e-12).all()) and bool((few < exact - 1e-3).any())
    torch.testing.assert_close(many, exact, rtol=0, atol=1e-6)
    # every blind chain of RockSample(4, 4) is at most 4 deterministic moves into a state that
    # loops on itself (a wall, a check, the exit), whose value each step solves exactly: the
    # fifth iterate is the exact value (plain iteration needs log(tol) / log(gamma) steps)
    torch.testing.assert_close(chain, exact, rtol=0, atol=1e-9)


def test_blind_policy_past_the_sparse_direct_size_builds_no_dense_system(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # RockSample(4, 4) as a MOMDP, 272 states: the form iterates on its nonzeros (a dense
    # (A, S, S) LU of a 1,600-state RockSample took 2 s and 530 MB), to the same vectors
    _, sparse = _pair("rock_sample_4_4")
    assert sparse.num_observed * sparse.num_hidden > sparse_momdp_module.SPARSE_DIRECT_SOLVE_SIZE

    def no_dense_solve(*args: object, **kwargs: object) -> None:
        raise AssertionError("a dense LU was built")

    with monkeypatch.context() as m:
        m.setattr(np.linalg, "solve", no_dense_solve)
        policy = sparse.blind_policy()
    monkeypatch.setattr(sparse_momdp_module, "SPARSE_DIRECT_SOLVE_SIZE", 10**6)
    want = sparse.blind_vectors()  # (A, X, Y) by the LU, as below SPARSE_DIRECT_SOLVE_SIZE
    got = policy.alphas.view(sparse.num_observed, -1, sparse.num_hidden)
    kinds = torch.from_numpy(np.sort(sparse.distinct_actions()[0].acts))
    torch.testing.assert_close(got, want[kinds].transpose(0, 1), rtol=0, atol=1e-9)


@pytest.mark.parametrize("name", sorted(MODELS))
def test_expectations_of_the_distinct_actions_equal_the_dense_products(name: str) -> None:
    dense, sparse = _pair(name)
    m = dense.model
    A, X, Y = sparse.num_actions, sparse.num_observed, sparse.num_hidden
    P = m.Tx.unsqueeze(-1) * (torch.eye(Y).view(1, 1, Y, 1, Y) if m.Ty is None else m.Ty)
    P = P.to(torch.float64)  # (A, X, Y, X2, Y2)
    g = torch.Generator().manual_seed(2)
    V = torch.randn(X, Y, generator=g, dtype=torch.float64)
    per_action = torch.randn(A, X, Y, generator=g, dtype=torch.float64)
    want = torch.einsum("axyzw,zw->axy", P, V)
    got = torch.from_numpy(sparse.expect_np(V.numpy()))
    torch.testing.assert_close(got, want, rtol=0, atol=1e-12)
    want_pa = torch.einsum("axyzw,azw->axy", P, per_action)
    torch.testing.assert_close(torch.from_numpy(sparse.expect_np(per_action.numpy())), want_pa,
                               rtol=0, atol=1e-12)  # fmt: skip
    # actions are merged exactly when their rewards and transitions are equal
    rows, inverse = sparse.distinct_actions()
    R = sparse.R
    for a in range(A):
        for b in range(A):
            same = bool((R[a] == R[b]).all()) and bool((P[a] == P[b]).all())
            assert (inverse[a] == inverse[b]) == same, (a, b)
        assert rows.acts[inverse[a]] in [b for b in range(A) if inverse[b] == inverse[a]]
    # the distinct actions' expectations, spread back, are every action's
    assert torch.equal(
        torch.from_numpy(rows.expect(V.numpy())[inverse]), got
    )  # bit-identical: the same products in the same order
    if name == "rock_sample_4_4":  # the four checks stay put: one kind (moves, sample, check)
        assert len(rows.acts) == A - 3


def test_momdp_bounds_on_distinct_actions_equal_those_on_every_action(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # bit-identical: the iterations on the distinct actions take the same maxima of the same
    # floats as on all of them
    _, sparse = _pair("rock_sample_4_4")
    R, g = sparse.R.numpy(), sparse.discount
    every = qmdp_iteration_np(R, g, sparse.expect_np, 1e-9)
    assert np.array_equal(sparse.qmdp_np(1e-9), every)
    monkeypatch.setattr(sparse_momdp_module, "SPARSE_DIRECT_SOLVE_SIZE", 0)  # iterate
    got = sparse.blind_vectors(max_iterations=3).numpy()
    A, X, Y = R.shape
    loops = sparse_momdp_module.self_loop_probs(sparse.row, sparse.col, sparse.prob, A, X * Y)
    want = blind_iteration_np(R, g, sparse.expect_np, 1e-8, 3, self_prob=loops.reshape(R.shape))
    assert np.array_equal(got, want)


def test_sarsop_reaches_the_dense_momdp_bounds() -> None:
    """From the same initial bounds the search is the same up to round-off of the products
    (so the bounds agree after a fixed number of iterations); with each form's own initial
    bounds (equal to 1e-7, tested above) both converge on RockSample(4, 4)'s optimal value."""
    model = rock_sample(4, 4, form="momdp")
    sparse = SparseMOMDP.from_dense(model)
    dense = as_solver_model(model)
    low = dense.blind_policy()
    up = dense.fib_corner_values(1e-10, NEVER, 100_000)[0]
    cfg = SARSOPConfig(time_limit=1e9, precision=1e-9, max_iterations=25,
                       lower_bound_init=lambda m: low, upper_bound_init=lambda m: up)  # fmt: skip
    ref = _SARSOP(model, cfg, time.perf_counter()).run()
    got = _SARSOP(sparse, cfg, time.perf_counter()).run()
    assert got.lower == pytest.approx(ref.lower, rel=1e-9)
    assert got.upper == pytest.approx(ref.upper, rel=1e-9)
    assert got.policy.num_vectors == ref.policy.num_vectors
    a = sarsop(model, SARSOPConfig(time_limit=1e9, precision=1e-3))
    b = solve(sparse, SARSOPConfig(time_limit=1e9, precision=1e-3))
    assert b.policy.is_momdp and b.upper - b.lower <= 1e-3 + 1e-12
    assert b.lower <= a.upper + 1e-9 and a.lower <= b.upper + 1e-9


def test_sarsop_torch_path_brackets_the_numpy_path() -> None:
    sparse = SparseMOMDP.from_dense(MODELS["dynamic"]())
    cfg = SARSOPConfig(time_limit=1e9, precision=1e-9, max_iterations=15)
    ref = _SARSOP(sparse, cfg, time.perf_counter()).run()
    dev = _SARSOP(sparse, cfg, time.perf_counter())
    dev._np = False  # the batched torch path
    sol = dev.run()
    assert sol.lower <= sol.upper and ref.lower <= ref.upper
    assert sol.lower <= ref.upper + 1e-9 and ref.lower <= sol.upper + 1e-9


@pytest.mark.parametrize("factored", [True, False])
def test_pbvi_gives_the_dense_momdp_result(factored: bool) -> None:
    model = rock_sample(4, 4, form="momdp")
    cfg = PBVIConfig(expansions=3, time_limit=1e9, factored=factored)
    ref = pbvi(model, cfg)
    got = pbvi(SparseMOMDP.from_dense(model), cfg)
    assert got.policy.is_momdp == ref.policy.is_momdp == factored
    assert got.lower == pytest.approx(ref.lower, abs=1e-6)
    # the FIB upper bound is iterated to PBVI's tolerance (1e-5 here) in both forms (the dense
    # form runs the FIB operator, this one QMDP: equal for one y2 per (a, x, y, x2))
    assert got.upper == pytest.approx(ref.upper, abs=1e-3)
    if factored:  # (flat: the sparse and dense flat forms prune ties near 0 differently)
        # the same value function; the sparse form's blind policy does not repeat the
        # identical checks' vectors, so PBVI keeps fewer
        form = as_solver_model(model)
        g = torch.Generator().manual_seed(0)
        b = torch.rand(64, form.num_hidden, generator=g, dtype=torch.float64)
        b = b / b.sum(-1, keepdim=True)
        for x in range(form.num_observed):
            xs = torch.full((64,), x)
            torch.testing.assert_close(
                form.value(got.policy, xs, b), form.value(ref.policy, xs, b), rtol=0, atol=1e-6
            )
        assert got.policy.num_vectors < ref.policy.num_vectors


def test_point_backup_and_simulation_equal_the_dense_form() -> None:
    dense, sparse = _pair("dynamic")
    policy = dense.blind_policy(100_000)
    x = torch.tensor([0, 1, 0, 4, 2])
    beliefs = _random_beliefs(dense.num_hidden, 5, seed=7)
    rd, rs = dense.point_backup(policy, x, beliefs), sparse.point_backup(policy, x, beliefs)
    torch.testing.assert_close(rs.alphas, rd.alphas)
    assert torch.equal(rs.actions, rd.actions) and torch.equal(rs.observed, x)
    torch.testing.assert_close(rs.q_values, rd.q_values)
    # simulation: the next beliefs are the normalised children of the sampled (x2, o)
    actions = torch.tensor([0, 1, 2, 0, 1])
    x2, b2 = sparse.simulate(x, beliefs, actions, torch.Generator().manual_seed(0))
    torch.testing.assert_close(b2.sum(-1), torch.ones(5, dtype=torch.float64))
    for m in range(5):
        reach = dense.reach[int(x[m])]
        assert int(x2[m]) in reach.tolist()
        _, J = dense.expand(int(x[m]), beliefs[m : m + 1])
        k = int((reach == x2[m]).nonzero())
        cands = J[0, actions[m], k]  # (O, Y)
        cands = cands[cands.sum(-1) > 0]
        dist = (cands / cands.sum(-1, keepdim=True) - b2[m]).abs().amax(-1)
        assert float(dist.min()) < 1e-12


def test_conversions_round_trip() -> None:
    model = MODELS["dynamic"]()
    sm = SparseMOMDP.from_dense(model)
    joint = model.Tx.unsqueeze(-1) * model.Ty
    torch.testing.assert_close(sm.joint_dense(), joint)
    back = sm.to_dense()
    torch.testing.assert_close(back.Tx.unsqueeze(-1) * back.Ty, joint)
    flat, ref = sm.to_pomdp(), model.to_pomdp()
    for f in ("T", "Z", "R", "b0"):
        torch.testing.assert_close(getattr(flat, f), getattr(ref, f))
    static = SparseMOMDP.from_dense(MODELS["static"]())
    torch.testing.assert_close(static.to_dense().Tx, MODELS["static"]().Tx)


def test_invalid_models_are_rejected_with_the_reason() -> None:
    sm = SparseMOMDP.from_dense(MODELS["dynamic"]())
    index, prob = sm.transitions
    fields = dict(Z=sm.Z, R=sm.R, x0=sm.x0, b0=sm.b0, discount=sm.discount)
    with pytest.raises(ModelError, match="sums to"):
        SparseMOMDP(transitions=(index, prob * 0.5), **fields)
    bad = index.clone()
    bad[0, 4] = 99
    with pytest.raises(ModelError, match="out of range"):
        SparseMOMDP(transitions=(bad, prob), **fields)
    with pytest.raises(TypeError, match="int64"):
        SparseMOMDP(transitions=(index.float(), prob), **fields)
    with pytest.raises(ModelError, match="x0"):
        SparseMOMDP(transitions=(index, prob), **{**fields, "x0": 99})
    with pytest.raises(ModelError, match="R"):
        SparseMOMDP(transitions=(index, prob), **{**fields, "R": sm.R[:, :1]})
    with pytest.raises(TypeError, match="MOMDP"):
        SparseMOMDP.from_dense("not a model")  # type: ignore[arg-type]


def test_read_pomdpx_returns_the_sparse_momdp_when_the_dense_one_does_not_fit(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A file whose hidden variable changes: with the size limits lowered below its dense
    ``Ty`` (but above ``Tx`` and ``Z``) it is read as a SparseMOMDP equal to the MOMDP, by
    either limit (``AUTO_SPARSE_ENTRIES`` for every dense tensor, ``AUTO_SPARSE_MOMDP_ENTRIES``
    for a MOMDP's ``Tx`` and ``Ty`` alone)."""
    model = random_momdp(3, 4, 2, 2, static=False, sparsity=0.3, seed=5)
    text = format_pomdpx(model)
    dense = read_pomdpx(text)
    assert type(dense).__name__ == "MOMDP" and dense.Ty is not None
    with monkeypatch.context() as m:
        m.setattr(pomdpx_io, "AUTO_SPARSE_MOMDP_ENTRIES", 100)  # Tx 72, Ty 288
        assert isinstance(read_pomdpx(text), SparseMOMDP)
        assert type(read_pomdpx(text, sparse=False)).__name__ == "MOMDP"  # only for "auto"
    monkeypatch.setattr(pomdpx_io, "AUTO_SPARSE_ENTRIES", 100)  # Tx 72, Z 48, Ty 288
    sm = read_pomdpx(text)
    assert isinstance(sm, SparseMOMDP)
    torch.testing.assert_close(sm.joint_dense(), dense.Tx.unsqueeze(-1) * dense.Ty)
    for f in ("Z", "R", "b0"):
        torch.testing.assert_close(getattr(sm, f), getattr(dense, f))
    assert sm.x0 == dense.x0 and sm.discount == dense.discount
    assert sm.hidden_states == dense.hidden_states and sm.actions == dense.actions
    # sparse=True still means the flat sparse model; sparse=False the dense one or an error
    assert type(read_pomdpx(text, sparse=True)).__name__ == "SparsePOMDP"
    cfg = SARSOPConfig(time_limit=1e9, precision=1e-6, max_iterations=40)
    a, b = solve(dense, cfg), solve(sm, cfg)
    assert b.lower <= a.upper + 1e-9 and a.lower <= b.upper + 1e-9


def test_unsorted_and_duplicated_nonzeros_give_the_same_form() -> None:
    # read_pomdpx gives the nonzeros sorted and unique (the form then skips its sort); a user's
    # may come in any order, a cell split in parts: the form sums and sorts them
    import dataclasses

    model = SparseMOMDP.from_dense(rock_sample(4, 4, form="momdp"))
    index, prob = model.transitions
    g = torch.Generator().manual_seed(0)
    order = torch.randperm(prob.numel(), generator=g)
    split = order[: prob.numel() // 3]  # a third of the cells in two halves
    index2 = torch.cat([index[order], index[split]])
    prob2 = torch.cat([prob[order], torch.zeros(0, dtype=prob.dtype)])
    prob2[: split.numel()] *= 0.5
    prob2 = torch.cat([prob2, prob[split] * 0.5])
    messy = dataclasses.replace(model, transitions=(index2, prob2))
    a, b = SparseMOMDPForm(model), SparseMOMDPForm(messy)
    assert np.array_equal(a.row, b.row) and np.array_equal(a.col, b.col)
    np.testing.assert_allclose(a.prob, b.prob, rtol=0, atol=1e-15)
    assert np.array_equal(a._act, b._act) and np.array_equal(a._x, b._x)
    torch.testing.assert_close(a.blind_vectors(), b.blind_vectors(), rtol=0, atol=1e-12)


def test_sarsop_is_unchanged_by_the_blind_policy_without_repeated_vectors() -> None:
    # the form's blind policy drops the vectors of actions identical to an earlier one; SARSOP
    # prunes dominated vectors (of equal ones the first stays) before it starts, so the solve
    # is bit-identical to one given every action's vector
    model = SparseMOMDP.from_dense(rock_sample(4, 4, form="momdp"))
    form = as_solver_model(model)
    every = AlphaVectorPolicy.from_action_vectors(form.blind_vectors(), momdp=True)
    assert form.blind_policy().num_vectors < every.num_vectors
    cfg = {"time_limit": 1e9, "precision": 1e-9, "max_iterations": 25}
    a = sarsop(model, SARSOPConfig(**cfg))
    b = sarsop(model, SARSOPConfig(**cfg, lower_bound_init=lambda m: every))
    assert (a.lower, a.upper) == (b.lower, b.upper)
    assert [h["lower"] for h in a.history] == [h["lower"] for h in b.history]
    assert torch.equal(a.policy.alphas, b.policy.alphas)
    assert torch.equal(a.policy.actions, b.policy.actions)


def test_a_random_start_solves_as_the_dense_one():
    joint = torch.rand(4, 3, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    joint[1] = 0.0
    dense = random_momdp(4, 3, 2, 2, static=False, discount=0.8, seed=0)
    dense = dense.with_initial(joint / joint.sum())
    sparse = SparseMOMDP.from_dense(dense)
    assert sparse.random_start and torch.equal(sparse.initial, dense.initial)
    assert torch.equal(sparse.to_dense().initial, dense.initial)
    assert as_solver_model(sparse).roots[0].tolist() == [0, 2, 3]
    cfg = SARSOPConfig(time_limit=60, precision=0.02)
    a, b = sarsop(dense, cfg), sarsop(sparse, cfg)
    assert a.info["stop_reason"] == b.info["stop_reason"] == "precision"
    assert a.lower <= b.upper + 1e-9 and b.lower <= a.upper + 1e-9  # the same optimum
    # the flat sparse form starts from the joint (it acts before it sees x)
    flat = sparse.to_sparse_pomdp()
    torch.testing.assert_close(flat.b0, dense.to_pomdp().b0, rtol=0, atol=0)
    with pytest.raises(ModelError, match="b0 must be initial"):
        dataclasses.replace(sparse, b0=torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64))
