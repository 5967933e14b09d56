"""Tests of the sparse flat path of the solvers (torchhrc.solvers.sparse_model and the sparse
hooks of belief_tree, upper_bound and sarsop): every sparse operation equals its dense
counterpart, and the sparse SARSOP solve equals the dense one under deterministic settings."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from torchhrc.pomdp import POMDP, SparsePOMDP
from torchhrc.solvers import FIBConfig, PBVIConfig, QMDPConfig, solve
from torchhrc.solvers import sparse_model as sparse_module
from torchhrc.solvers.belief_tree import SparseBeliefTree
from torchhrc.solvers.blind import blind_policy, blind_vectors
from torchhrc.solvers.forms import as_solver_model
from torchhrc.solvers.qmdp import mdp_q_values, qmdp_vectors
from torchhrc.solvers.sarsop import SARSOPConfig, fib_corner_values, sarsop
from torchhrc.solvers.sarsop.search import _SARSOP
from torchhrc.solvers.sparse_model import (
    SparseFlatModel,
    blind_iteration_np,
    qmdp_iteration_np,
    sparse_blind_policy,
    sparse_blind_vectors,
)
from torchhrc.solvers.upper_bound import SawtoothUpperBound
from torchhrc.tasks.classic import rock_sample, tiger
from torchhrc.testing import random_pomdp

TIGER_OPTIMUM = 19.3714  # Tiger, discount 0.95 (see tests/solvers/sarsop/test_sarsop.py)


def _sparse_random(S: int = 12, A: int = 3, O: int = 2, seed: int = 0) -> POMDP:
    """A random POMDP whose T has about two successors per (a, s) (a sparse structure)."""
    g = torch.Generator().manual_seed(seed)
    m = random_pomdp(S, A, O, seed=seed)
    keep = torch.rand(A, S, S, generator=g, dtype=torch.float64) < 2.0 / S
    keep[:, torch.arange(S), (torch.arange(S) + 1) % S] = True  # every row nonzero
    T = torch.where(keep, m.T, 0.0)
    T = T / T.sum(-1, keepdim=True)
    b0 = torch.zeros(S, dtype=torch.float64)
    b0[:3] = torch.tensor([0.5, 0.3, 0.2], dtype=torch.float64)
    return POMDP(T=T, Z=m.Z, R=m.R, b0=b0, discount=0.9)


@pytest.fixture(scope="module")
def rs44() -> POMDP:
    return rock_sample(4, 4)


@pytest.mark.parametrize("build", [tiger, _sparse_random, lambda: rock_sample(4, 4)])
def test_prediction_and_backprojection_equal_dense(build) -> None:
    model = build()
    sm = SparseFlatModel.from_model(SparsePOMDP.from_dense(model))
    T = model.T
    assert torch.equal(sm.dense_T(), T)
    A, S, _ = T.shape
    g = torch.Generator().manual_seed(1)
    beliefs = torch.rand(4, S, generator=g, dtype=torch.float64)
    beliefs[0] = model.b0
    beliefs[1, S // 2 :] = 0.0  # a sparse belief
    beliefs = beliefs / beliefs.sum(-1, keepdim=True)
    dense_pred = torch.einsum("bs,ast->bat", beliefs, T)  # (B, A, S)
    torch.testing.assert_close(sm.predict(beliefs), dense_pred)
    for i in range(beliefs.shape[0]):
        b = beliefs[i].numpy()
        np.testing.assert_allclose(sm.predict_np(b), dense_pred[i].numpy(), atol=1e-14)
        cols, pred = sm.predict_columns_np(b)
        full = np.zeros((A, S))
        full[:, cols] = pred
        np.testing.assert_allclose(full, dense_pred[i].numpy(), atol=1e-14)
        # the columns cover every successor and the belief's own support
        assert set(np.flatnonzero(b)) <= set(cols.tolist())
        assert set(np.flatnonzero(dense_pred[i].sum(0).numpy())) <= set(cols.tolist())
        for a in range(A):
            np.testing.assert_allclose(sm.predict_action_np(b, a), full[a], atol=1e-14)
    values = torch.randn(5, S, generator=g, dtype=torch.float64)
    actions = torch.tensor([0, A - 1, 0, 1 % A, A - 1])
    dense_back = torch.einsum("bst,bt->bs", T[actions], values)
    torch.testing.assert_close(sm.backproject(actions, values), dense_back)
    for i in range(5):
        np.testing.assert_allclose(
            sm.backproject_np(int(actions[i]), values[i].numpy()), dense_back[i].numpy()
        )
    torch.testing.assert_close(sm.expect(values[0]), T @ values[0])


def test_duplicate_coordinates_are_summed_and_dense_models_accepted() -> None:
    model = tiger()
    sp = SparsePOMDP.from_dense(model)
    idx, p = sp.transitions
    doubled = SparsePOMDP(
        transitions=(torch.cat([idx, idx]), torch.cat([p, p]) / 2),
        observations_=sp.observations_, R=sp.R, b0=sp.b0, discount=sp.discount,
        states=sp.states, actions=sp.actions, observations=sp.observations,
    )  # fmt: skip
    assert torch.equal(SparseFlatModel.from_model(doubled).dense_T(), model.T)
    assert torch.equal(SparseFlatModel.from_model(model).dense_T(), model.T)
    assert not SparseFlatModel.from_model(model).deterministic  # listening keeps the state
    assert SparseFlatModel.from_model(rock_sample(4, 4)).deterministic
    with pytest.raises(TypeError, match="SparsePOMDP or POMDP"):
        SparseFlatModel.from_model("tiger")  # type: ignore[arg-type]


def test_factored_model_from_sparse_expands_and_backprojects_as_dense(rs44: POMDP) -> None:
    dense = as_solver_model(rs44)
    sparse = as_solver_model(SparsePOMDP.from_dense(rs44))
    g = torch.Generator().manual_seed(0)
    beliefs = torch.rand(3, rs44.num_states, generator=g, dtype=torch.float64)
    beliefs[0] = rs44.b0
    xs_d, J_d = dense.expand(0, beliefs)
    xs_s, J_s = sparse.expand(0, beliefs)
    assert torch.equal(xs_d, xs_s)
    torch.testing.assert_close(J_s, J_d)
    actions = torch.tensor([0, 5, 7])
    values = torch.randn(3, 1, rs44.num_states, generator=g, dtype=torch.float64)
    torch.testing.assert_close(
        sparse.backproject(0, actions, values), dense.backproject(0, actions, values)
    )


def test_blind_vectors_equal_dense_and_iterates_are_lower_bounds(
    rs44: POMDP, monkeypatch: pytest.MonkeyPatch
) -> None:
    sm = SparseFlatModel.from_model(rs44)
    # exact: alpha_a = (I - gamma T_a)^-1 R_a by LU
    eye = torch.eye(rs44.num_states, dtype=rs44.T.dtype)
    exact = torch.linalg.solve(eye - rs44.discount * rs44.T, rs44.R.unsqueeze(-1)).squeeze(-1)
    torch.testing.assert_close(blind_vectors(rs44), exact, atol=1e-6, rtol=0)
    torch.testing.assert_close(sparse_blind_vectors(sm), exact)
    # force the iterative path (the one large models take): monotone from below
    monkeypatch.setattr(sparse_module, "SPARSE_DIRECT_SOLVE_SIZE", 0)
    few = sparse_blind_vectors(sm, max_iterations=5)
    many = sparse_blind_vectors(sm, max_iterations=2000, tol=1e-12)
    assert (few <= many + 1e-12).all() and (many <= exact + 1e-9).all()
    torch.testing.assert_close(many, exact, atol=1e-6, rtol=0)
    policy = sparse_blind_policy(SparsePOMDP.from_dense(rs44))
    assert policy.num_vectors == rs44.num_actions and not policy.is_momdp


def test_sparse_blind_policy_past_the_sparse_direct_size_builds_no_dense_system(
    rs44: POMDP, monkeypatch: pytest.MonkeyPatch
) -> None:
    # 257 states > SPARSE_DIRECT_SOLVE_SIZE: iterated on the nonzeros, to the exact vectors
    assert rs44.num_states > sparse_module.SPARSE_DIRECT_SOLVE_SIZE
    eye = torch.eye(rs44.num_states, dtype=rs44.T.dtype)
    exact = torch.linalg.solve(eye - rs44.discount * rs44.T, rs44.R.unsqueeze(-1)).squeeze(-1)
    sm = SparseFlatModel.from_model(rs44)

    def no_dense(*args: object, **kwargs: object) -> None:
        raise AssertionError("a dense system was built")

    monkeypatch.setattr(SparseFlatModel, "dense_T", no_dense)
    monkeypatch.setattr(torch.linalg, "solve", no_dense)
    policy = sparse_blind_policy(sm)
    torch.testing.assert_close(policy.alphas, exact, rtol=0, atol=1e-9)


@pytest.mark.parametrize("build", [tiger, _sparse_random, lambda: rock_sample(4, 4)])
def test_fib_corner_values_sparse_equal_dense(build) -> None:
    model = build()
    dense = fib_corner_values(model)
    sparse = fib_corner_values(SparsePOMDP.from_dense(model))
    torch.testing.assert_close(sparse, dense, atol=1e-6, rtol=0)


@pytest.mark.parametrize("pairs", [None, 5])
def test_fib_step_over_pairs_equals_the_product_over_every_observation(pairs, monkeypatch) -> None:
    """One FIB step of the sparse path (over the pairs of a nonzero of T and a nonzero of Z)
    against the formula on dense tensors, on a model where most observations are impossible
    after most states (Z keeps one or two outcomes a row), and on RockSample; also with the
    products formed a few pairs at a time (``pairs=5``: runs of whole groups), bit for bit
    the same as all at once."""
    from torchhrc.solvers import sparse_model

    if pairs is not None:
        monkeypatch.setattr(sparse_model, "_FIB_PAIRS", pairs)
    g = torch.Generator().manual_seed(7)
    m = _sparse_random(S=15, A=3, O=6, seed=7)
    mask = torch.rand(m.Z.shape, generator=g, dtype=torch.float64) < 0.25
    mask[..., 0] = True
    Z = torch.where(mask, m.Z, 0.0)
    sparse_z = POMDP(T=m.T, Z=Z / Z.sum(-1, keepdim=True), R=m.R, b0=m.b0, discount=m.discount)
    rng = np.random.default_rng(0)
    for model in (sparse_z, rock_sample(4, 4)):
        form = SparseFlatModel.from_model(model)
        alpha = rng.normal(size=(model.num_actions, model.num_states))
        A, S, O = model.num_actions, model.num_states, model.num_observations
        T, Zd = model.T.numpy(), model.Z.expand(A, S, O).numpy()
        by_hand = np.einsum("ast,ato,bt->asob", T, Zd, alpha).max(-1).sum(-1)
        want = model.R.numpy() + model.discount * by_hand
        np.testing.assert_allclose(form.fib_np(alpha), want, rtol=0, atol=1e-12)
        if pairs is not None:  # the same floats as the products formed all at once
            chunked = form.fib_np(alpha)
            monkeypatch.setattr(sparse_model, "_FIB_PAIRS", 1 << 40)
            assert np.array_equal(chunked, form.fib_np(alpha))
            monkeypatch.setattr(sparse_model, "_FIB_PAIRS", pairs)


def test_sawtooth_on_columns_equals_full_rows() -> None:
    g = torch.Generator().manual_seed(3)
    Y = 40
    ub = SawtoothUpperBound(10.0 + torch.rand(1, Y, generator=g, dtype=torch.float64))
    for _ in range(30):  # points with supports of 2..6 states
        w = int(torch.randint(2, 7, (1,), generator=g))
        idx = torch.randperm(Y, generator=g)[:w]
        b = torch.zeros(Y, dtype=torch.float64)
        b[idx] = torch.rand(w, generator=g, dtype=torch.float64) + 0.1
        b = b / b.sum()
        ub.add_np(b.numpy(), 0, float((b * ub.corner[0]).sum()) - 3.0)
    rng = np.random.default_rng(0)
    cols = np.sort(rng.choice(Y, 15, replace=False))
    rows = np.zeros((8, Y))
    rows[:, cols] = rng.random((8, 15)) * (rng.random((8, 15)) < 0.7)
    # some queries covering the support of a stored point exactly (the point is active)
    for i in range(3):
        pts = ub.points[0][i].numpy()
        rows[i] = pts
        cols = np.union1d(cols, np.flatnonzero(pts))
    x = np.zeros(8, dtype=np.int64)
    full = ub.value_np(rows, x)
    compact = ub.value_np(rows[:, cols], x, cols)
    np.testing.assert_allclose(compact, full, rtol=1e-12, atol=1e-12)
    assert (full[:3] < (rows[:3] * ub.corner[0].numpy()).sum(-1) - 1.0).all()


def test_sparse_belief_tree_stores_supports() -> None:
    g = torch.Generator().manual_seed(0)
    S = 30
    root = torch.zeros(S, dtype=torch.float64)
    root[[1, 4]] = 0.5
    tree = SparseBeliefTree(root, x=0, capacity=2)
    dense = [root]
    for i in range(9):  # grows past the initial capacity
        b = torch.rand(S, generator=g, dtype=torch.float64) * (torch.rand(S, generator=g) < 0.2)
        b[i] += 0.1
        b = b / b.sum()
        tree.add(b, 0, i // 2, i % 3, i % 2)
        dense.append(b)
    stacked = torch.stack(dense)
    assert tree.size == 10
    torch.testing.assert_close(tree.beliefs, stacked)
    for n in range(10):
        np.testing.assert_array_equal(tree.beliefs_np[n], stacked[n].numpy())
    nodes = np.array([7, 2, 0])
    torch.testing.assert_close(tree.csr(nodes).to_dense(), stacked[nodes])
    assert tree.support_sizes().tolist() == [int((r > 0).sum()) for r in stacked]
    assert tree.child(4, 2, 0, 0) == 9 and int(tree.depth[9]) == 3
    # a doubling copies the scalar arrays only (7 int64, 2 float64, the active flag): the
    # supports are each node's own arrays
    assert tree.node_bytes() == 7 * 8 + 2 * 8 + 1


@pytest.mark.numeric
@pytest.mark.parametrize("entries", [1 << 18, 3 * 40])
def test_sparse_tree_keep_alphas_is_the_first_argmax_at_any_block(entries, monkeypatch) -> None:
    """The sparse tree keeps, at each node's belief, the vector of largest value (against a
    plain dense argmax), the first of equal ones, whatever the block of vectors it scores at
    once (``entries // S`` vectors: all 20 at once, or 3 at a time)."""
    import torchhrc.solvers.belief_tree as belief_tree_module

    monkeypatch.setattr(belief_tree_module, "_GATHER_ELEMENTS", entries)
    g = torch.Generator().manual_seed(3)
    S, N = 40, 20
    vectors = torch.randn(N, S, generator=g, dtype=torch.float64)
    root = torch.zeros(S, dtype=torch.float64)
    root[[0, 7]] = 0.5
    tree = SparseBeliefTree(root, x=0, capacity=2)
    for i in range(11):
        b = torch.rand(S, generator=g, dtype=torch.float64) * (torch.rand(S, generator=g) < 0.3)
        b[i] += 0.1
        tree.add(b / b.sum(), 0, 0, i % 3, i)
    nodes = np.array([3, 0, 9, 5, 11, 7])
    keep = tree.keep_alphas(vectors, None, nodes)
    scores = tree.beliefs[nodes] @ vectors.T
    top2 = scores.topk(2, dim=-1).values
    assert (top2[:, 0] - top2[:, 1]).min() > 1e-6  # no near tie: any BLAS's rounding agrees
    winners = set(scores.argmax(-1).tolist())
    assert len(winners) > 2 and keep.tolist() == [i in winners for i in range(N)]
    vectors[12] = vectors[5] + 10.0  # equal vectors in blocks apart, best everywhere:
    vectors[5] = vectors[12]  # the first is kept
    assert tree.keep_alphas(vectors, None, nodes).tolist() == [i == 5 for i in range(N)]
    vectors[5] -= 20.0  # now vector 12 is
    assert tree.keep_alphas(vectors, None, nodes).tolist() == [i == 12 for i in range(N)]


def _same_inits(model: POMDP) -> dict:
    """Both solves start from the same bounds (their equality is tested above, to 1e-6; a
    difference at that level may break a tie differently and grow another tree)."""
    policy = blind_policy(model)
    corner = fib_corner_values(model, tol=1e-12)
    return {"lower_bound_init": lambda m: policy, "upper_bound_init": lambda m: corner}


def _solve_both(model: POMDP, **kw) -> tuple:
    cfg = SARSOPConfig(time_limit=1e9, precision=1e-9, **_same_inits(model), **kw)
    return sarsop(model, cfg), sarsop(SparsePOMDP.from_dense(model), cfg)


@pytest.mark.parametrize(
    ("build", "iterations"), [(tiger, 20), (_sparse_random, 20), (lambda: rock_sample(4, 4), 40)]
)
def test_sparse_sarsop_equals_dense(build, iterations: int) -> None:
    model = build()
    dense, sparse = _solve_both(model, max_iterations=iterations)

    def untimed(info: dict) -> dict:
        init = {k: v for k, v in info["init"].items() if not k.endswith("_s")}
        return {**info, "init": init}

    assert untimed(sparse.info) == untimed(dense.info)
    assert sparse.lower == pytest.approx(dense.lower, abs=1e-9)
    assert sparse.upper == pytest.approx(dense.upper, abs=1e-6)  # FIB's tolerance
    assert [h["n_alphas"] for h in sparse.history] == [h["n_alphas"] for h in dense.history]
    # the value functions agree everywhere; single vectors may differ in entries that no
    # maximum uses (a child vector chosen at a child of probability 0, where the dense and
    # sparse paths round a tie differently: RockSample(4,4) at 40 iterations)
    generator = torch.Generator().manual_seed(0)
    beliefs = torch.rand(2000, model.num_states, generator=generator, dtype=model.b0.dtype)
    beliefs = torch.cat([model.b0[None], beliefs / beliefs.sum(-1, keepdim=True)])
    torch.testing.assert_close(
        (beliefs @ sparse.policy.alphas.T).max(-1).values,
        (beliefs @ dense.policy.alphas.T).max(-1).values,
    )
    assert sparse.policy.action(model.b0).item() == dense.policy.action(model.b0).item()


def test_sparse_sarsop_tree_beliefs_equal_dense_belief_updates(rs44: POMDP) -> None:
    cfg = SARSOPConfig(time_limit=1e9, precision=1e-9, max_iterations=25, **_same_inits(rs44))
    dense = _SARSOP(rs44, cfg, 0.0)
    dense.run()
    sparse = _SARSOP(SparsePOMDP.from_dense(rs44), cfg, 0.0)
    sparse.run()
    assert isinstance(sparse.tree, SparseBeliefTree) and sparse.tree.size == dense.tree.size
    torch.testing.assert_close(sparse.tree.beliefs, dense.tree.beliefs)
    # each child is the Bayes update of its parent (paper Eq. 3, flat)
    tree = sparse.tree
    for n in range(1, tree.size):
        parent, a, o = int(tree.parent[n]), int(tree.action[n]), int(tree.observation[n])
        b = torch.from_numpy(tree.beliefs_np[parent])
        upd = (b @ rs44.T[a]) * rs44.Z[a, :, o]
        torch.testing.assert_close(torch.from_numpy(tree.beliefs_np[n]), upd / upd.sum())


def test_sparse_sarsop_brackets_and_converges_on_tiger() -> None:
    sol = sarsop(SparsePOMDP.from_dense(tiger()), SARSOPConfig(time_limit=1e9, precision=1e-3))
    assert sol.info["stop_reason"] == "precision"
    assert sol.lower <= TIGER_OPTIMUM + 1e-3 and sol.upper >= TIGER_OPTIMUM - 1e-3
    lows = [h["lower"] for h in sol.history]
    ups = [h["upper"] for h in sol.history]
    assert all(lo <= up + 1e-9 for lo, up in zip(lows, ups))
    assert lows == sorted(lows) and ups == sorted(ups, reverse=True)


def test_sparse_sarsop_with_sweeps_and_custom_initialisers(rs44: POMDP) -> None:
    sp = SparsePOMDP.from_dense(rs44)
    seen = []

    def lower(model):
        seen.append(type(model).__name__)
        return sparse_blind_policy(model)

    cfg = SARSOPConfig(time_limit=1e9, precision=1e-9, max_iterations=20, sweep_interval=5,
                       lower_bound_init=lower)  # fmt: skip
    sol = sarsop(sp, cfg)
    assert seen == ["SparsePOMDP"]
    ref = sarsop(rs44, SARSOPConfig(time_limit=1e9, precision=1e-3, max_iterations=60))
    assert sol.lower <= ref.upper + 1e-9 and ref.lower <= sol.upper + 1e-9


def test_solve_takes_sparse_models_with_every_solver() -> None:
    sp = SparsePOMDP.from_dense(tiger())
    sol = solve(sp, SARSOPConfig(time_limit=1e9, precision=0.5))
    assert sol.upper - sol.lower <= 0.5
    sol = solve(sp, PBVIConfig(time_limit=1e9, expansions=4))
    assert sol.lower <= 19.3714 <= sol.upper
    # QMDP at b0 worked by hand (see tests/solvers/test_bounds.py): -1 + 0.95 * 200 = 189
    assert solve(sp, QMDPConfig()).upper == pytest.approx(189.0, abs=1e-6)
    assert 19.3714 <= solve(sp, FIBConfig()).upper < 189.0
    with pytest.raises(TypeError, match="expected model to be a POMDP"):
        solve(object(), QMDPConfig())


def _negative_random() -> POMDP:
    """:func:`_sparse_random` with rewards shifted below zero (``V* < 0``: value iteration from
    zero starts above ``V*``) and some self-loops with probability below one."""
    m = _sparse_random(S=10, A=3, O=2, seed=5)
    T = m.T.clone()
    T[0] = 0.6 * T[0] + 0.4 * torch.eye(10, dtype=torch.float64)  # a stochastic self-loop
    return POMDP(T=T, Z=m.Z, R=m.R - 3.0, b0=m.b0, discount=0.9)


def _exact_q(model: POMDP) -> torch.Tensor:
    """``Q* (A, S)`` of the underlying MDP by dense value iteration to round-off."""
    Q, err = mdp_q_values(model, tol=1e-13)
    assert err < 1e-11
    return Q


@pytest.mark.parametrize(
    "build", [tiger, _sparse_random, _negative_random, lambda: rock_sample(4, 4)]
)
def test_qmdp_iteration_is_an_upper_bound_wherever_it_stops(build) -> None:
    model = build()
    sm = SparseFlatModel.from_model(SparsePOMDP.from_dense(model))
    exact = _exact_q(model).numpy()
    R, g = sm.R.numpy(), sm.discount
    last = None
    for k in (0, 1, 2, 5, 20, 100_000):  # 0: the constant max R / (1 - g) alone
        Q = qmdp_iteration_np(R, g, sm.expect_np, tol=1e-12, max_iterations=k)
        assert Q.shape == exact.shape
        assert (Q >= exact - 1e-9).all(), k  # Q_a >= Q*_a everywhere, at every stop
        if last is not None:  # the running minimum only tightens
            assert (Q <= last + 1e-12).all(), k
        last = Q
    np.testing.assert_allclose(last, exact, rtol=0, atol=1e-9)  # converged: Q*
    # the default tolerance of the solvers' QMDP agrees with the dense QMDP vectors
    np.testing.assert_allclose(sm.qmdp_np(1e-8), qmdp_vectors(model).numpy(), rtol=0, atol=1e-6)


def test_qmdp_iteration_is_exact_after_the_longest_optimal_path_on_rocksample() -> None:
    # RockSample's moves are deterministic and V* >= 0 (the exit pays 10): from zero the
    # iterate after L steps is V* exactly, so the change drops to 0 (not below a tolerance)
    model = rock_sample(4, 4)
    sm = SparseFlatModel.from_model(SparsePOMDP.from_dense(model))
    exact = _exact_q(model).numpy()
    Q = qmdp_iteration_np(sm.R.numpy(), sm.discount, sm.expect_np, tol=1e-300)
    np.testing.assert_allclose(Q, exact, rtol=0, atol=1e-12)


@pytest.mark.parametrize("build", [_sparse_random, _negative_random, lambda: rock_sample(4, 4)])
def test_blind_iteration_with_self_loops_solved_is_a_tighter_lower_bound(build) -> None:
    model = build()
    sm = SparseFlatModel.from_model(SparsePOMDP.from_dense(model))
    eye = torch.eye(model.num_states, dtype=model.T.dtype)
    exact = torch.linalg.solve(eye - model.discount * model.T, model.R.unsqueeze(-1))
    exact = exact.squeeze(-1).numpy()
    p = sm.self_loop_probs()
    np.testing.assert_array_equal(p, torch.diagonal(model.T, dim1=-2, dim2=-1).numpy())
    R, g = sm.R.numpy(), sm.discount
    for k in (1, 2, 3, 10, 40):
        plain = blind_iteration_np(R, g, sm.expect_np, 1e-14, k)
        jacobi = blind_iteration_np(R, g, sm.expect_np, 1e-14, k, self_prob=p)
        assert (jacobi <= exact + 1e-9).all(), k  # still a lower bound at every stop
        assert (jacobi >= plain - 1e-9).all(), k  # and never below the plain iterate
    converged = blind_iteration_np(R, g, sm.expect_np, 1e-14, 100_000, self_prob=p)
    np.testing.assert_allclose(converged, exact, rtol=0, atol=1e-9)
