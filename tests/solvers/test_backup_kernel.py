"""The compiled steps of a one-belief evaluation (:mod:`torchhrc.solvers.backup_kernel`)
agree with their numpy references (``SolverModel.children_np``'s numpy body,
``_SARSOP._upper_np``, and for several observed values ``_SARSOP._lower_np``'s masked product
and ``SawtoothUpperBound.value_np``'s loop over ``x``) up to the order of the sums, and reject
arrays they cannot read."""

from __future__ import annotations

import time
from typing import Any

import numpy as np
import pytest
import torch

from torchhrc.pomdp import POMDP, SparseMOMDP
from torchhrc.solvers import SARSOPConfig, backup_kernel
from torchhrc.solvers.eval_cache import pack, unpack
from torchhrc.solvers.forms import as_solver_model
from torchhrc.solvers.forms.base import SolverModel
from torchhrc.tasks.classic import rock_sample
from torchhrc.testing import random_momdp, random_pomdp

kernel = backup_kernel.load()
needs_extension = pytest.mark.skipif(kernel is None, reason="the C extension is not built")
SARSOP = __import__("torchhrc.solvers.sarsop.search", fromlist=["_SARSOP"])._SARSOP


def _impossible(seed: int) -> POMDP:
    """A random POMDP whose observations are tied to some states (many children have
    probability 0) and with a sparse transition matrix."""
    m = random_pomdp(7, 3, 4, sparsity=0.5, discount=0.9, seed=seed)
    gen = torch.Generator().manual_seed(seed)
    mask = (torch.rand(m.Z.shape, generator=gen, dtype=m.Z.dtype) < 0.4).to(m.Z.dtype)
    mask.scatter_(-1, m.Z.argmax(-1, keepdim=True), 1.0)  # each (a, s2) keeps one
    Z = m.Z * mask
    return POMDP(T=m.T, Z=Z / Z.sum(-1, keepdim=True), R=m.R, b0=m.b0, discount=m.discount)


def _beliefs(S: int, seed: int) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    out = []
    for i in range(6):
        b = rng.random(S) * (rng.random(S) < (0.5 if i % 2 else 1.0))
        b[rng.integers(S)] += 0.1
        out.append(b / b.sum())
    return out


_MODELS = {
    "flat_dense": lambda: random_pomdp(6, 3, 3, seed=0),
    "flat_impossible_1": lambda: _impossible(1),
    "flat_impossible_2": lambda: _impossible(2),
    "momdp_dynamic": lambda: random_momdp(4, 5, 3, 3, static=False, sparsity=0.4, seed=3),
    "momdp_static": lambda: random_momdp(5, 4, 2, 3, sparsity=0.3, seed=4),
    "rocksample_momdp": lambda: rock_sample(4, 4, form="momdp"),
}


@needs_extension
@pytest.mark.parametrize("name", sorted(_MODELS))
def test_compiled_children_equal_the_numpy_children(name: str) -> None:
    model = _MODELS[name]()
    form = as_solver_model(model)
    assert form._kernel is not None
    xs = range(form.num_observed)
    for i, b in enumerate(_beliefs(form.num_hidden, len(name))):
        x = xs[i % len(xs)]
        got = form.children_np(x, b)
        ref = SolverModel.children_np(form, x, b)  # the numpy body
        np.testing.assert_array_equal(got.nz, ref.nz)
        np.testing.assert_array_equal(got.rows_x, ref.rows_x)
        np.testing.assert_array_equal(got.child_x, ref.child_x)
        assert got.cols is None and ref.cols is None
        for name in ("rows", "prob", "reward"):
            np.testing.assert_allclose(getattr(got, name), getattr(ref, name), rtol=1e-13,
                                       atol=1e-15, err_msg=name)  # fmt: skip
        assert got.rows.flags.c_contiguous
        # the impossible children are exactly those of probability 0
        assert set(got.nz.tolist()) == set(np.flatnonzero(ref.prob.reshape(-1) > 0).tolist())


@needs_extension
@pytest.mark.parametrize("seed", [0, 1])
def test_backup_vector_equals_the_numpy_one(seed: int) -> None:
    model = _impossible(seed) if seed else random_pomdp(6, 3, 4, seed=seed)
    form = as_solver_model(model)
    rng = np.random.default_rng(seed)
    vectors = rng.normal(size=(9, model.num_states))
    for a in range(model.num_actions):
        use = rng.integers(0, 9, size=(1, model.num_observations))
        got = form.backup_vector_np(0, a, use, vectors, 0.9)
        ref = SolverModel.backup_vector_np(form, 0, a, use, vectors, 0.9)
        np.testing.assert_allclose(got, ref, rtol=1e-13, atol=1e-13)
    # by hand: R[a] + gamma T[a] (sum_o Z[a, :, o] * vectors[use[o]])
    T, Z, R = model.T.numpy(), model.Z.numpy(), model.R.numpy()
    hand = R[0] + 0.9 * T[0] @ sum(Z[0, :, o] * vectors[use[0, o]] for o in range(Z.shape[-1]))
    np.testing.assert_allclose(form.backup_vector_np(0, 0, use, vectors, 0.9), hand, rtol=1e-12)
    with pytest.raises(IndexError, match="a vector index in use is out of range"):
        form.backup_vector_np(0, 0, np.full((1, model.num_observations), 9), vectors, 0.9)


@needs_extension
@pytest.mark.parametrize("name", sorted(_MODELS))
def test_backup_vector_of_every_dense_form_equals_the_numpy_one(name: str) -> None:
    """The compiled ``backup_vector`` over ``children``'s tables (flat: ``tyk = T``; MOMDP:
    ``Tx (A, Y, K)``, ``Ty`` or the identity of a static hidden value) against the numpy body,
    at every ``x`` and action, and for a MOMDP by hand from ``Tx``, ``Ty``, ``Z``, ``R``."""
    model = _MODELS[name]()
    form = as_solver_model(model)
    rng = np.random.default_rng(len(name))
    vectors = rng.normal(size=(11, form.num_hidden))
    for x in range(form.num_observed):
        K = form.reach_np(x).size
        for a in range(form.num_actions):
            use = rng.integers(0, 11, size=(K, form.num_observations))
            got = form.backup_vector_np(x, a, use, vectors, 0.95)
            ref = SolverModel.backup_vector_np(form, x, a, use, vectors, 0.95)
            np.testing.assert_allclose(got, ref, rtol=1e-13, atol=1e-13)
    if not name.startswith("momdp"):
        return
    # alpha(y) = R(a, x, y) + gamma sum_{x2, y2, o} Tx Ty Z(a, x2, y2, o) vectors[use[x2, o], y2]
    Tx, R, Z = model.Tx.numpy(), model.R.numpy(), model.Z.numpy()  # (A,X,Y,X2) (A,X,Y) (A,X2,Y2,O)
    Ty = model.Ty.numpy() if model.Ty is not None else None  # (A, X, Y, X2, Y2)
    x, a = 1, form.num_actions - 1
    reach = form.reach_np(x)
    use = rng.integers(0, 11, size=(reach.size, form.num_observations))
    hand = R[a, x].copy()
    for y in range(form.num_hidden):
        for k, x2 in enumerate(reach.tolist()):
            for y2 in range(form.num_hidden):
                ty = Ty[a, x, y, x2, y2] if Ty is not None else float(y2 == y)
                for o in range(form.num_observations):
                    hand[y] += (
                        0.95 * Tx[a, x, y, x2] * ty * Z[a, x2, y2, o] * vectors[use[k, o], y2]
                    )
    np.testing.assert_allclose(form.backup_vector_np(x, a, use, vectors, 0.95), hand, rtol=1e-12)
    with pytest.raises(IndexError, match="a vector index in use is out of range"):
        form.backup_vector_np(x, a, np.full_like(use, 11), vectors, 0.95)


def _solver(model: POMDP, iterations: int) -> object:
    cfg = SARSOPConfig(time_limit=1e9, max_iterations=iterations, precision=1e-9)
    solver = SARSOP(model, cfg, time.perf_counter())
    solver.run()
    return solver


@needs_extension
@pytest.mark.parametrize("seed", [0, 3])
def test_compiled_evaluation_equals_the_numpy_one(seed: int) -> None:
    """Fresh and stale (lazy) evaluations of the tree's beliefs after a short solve, whose
    upper bound has points: the same bounds, vectors and Q values both ways."""
    model = _impossible(seed) if seed else random_pomdp(8, 4, 3, discount=0.95, seed=seed)
    solver = _solver(model, 6)
    assert solver._kernel is not None and solver.ub.size > 0
    nodes = range(min(solver.tree.size, 40))
    assert sum(int(solver.belief_id[n]) in solver._cache for n in nodes) >= 5
    _assert_both_paths_agree(solver, [(solver, "_kernel"), (solver.form, "_kernel")])


_NAMES = ("record", "best", "lo", "cu", "child_x", "own")


def _assert_both_paths_agree(solver: object, switches: list[tuple[object, str]]) -> list[tuple]:
    """Evaluate the first 40 tree beliefs, fresh and stale, three ways: as the search does
    (one compiled call, ``backup_one``, where the form has its tables), with the compiled
    steps called one by one (the one-call path switched off), and with every ``(object,
    attribute)`` of ``switches`` (the compiled steps) set to None as well (numpy): the same
    vectors, and bounds within 1e-12. Returns the search's evaluations."""
    tree, out = solver.tree, []
    for node in range(min(tree.size, 40)):
        x, b = int(tree.x[node]), tree.beliefs_np[node]
        stale = solver._cache.get(int(solver.belief_id[node]))
        for st in (None, stale):
            got = solver._evaluate_np(x, b, st)
            for off in (_one_call_off(solver), [*switches, (solver, "_vkernel")]):
                ref = _with_off(solver, off, solver._evaluate_np, x, b, st)
                _assert_same_evaluation(got, ref)
            out.append(got)
    return out


def _one_call_off(solver: object) -> list[tuple[object, str]]:
    """The switch of the one-call path alone: the search's cache of the form's tables, read
    as "none at any x"."""
    return [(solver, "_one_calls")]


class _NoTables(dict):
    def get(self, key: object, default: object = None) -> None:
        return None


def _with_off(solver: object, switches: list[tuple[object, str]], run: Any, *args: Any) -> Any:
    """``run(*args)`` with each ``(object, attribute)`` set to None (the search's table cache
    to one that has none), restored after."""
    saved = [getattr(o, a) for o, a in switches]
    for o, a in switches:
        setattr(o, a, _NoTables() if (o, a) == (solver, "_one_calls") else None)
    try:
        return run(*args)
    finally:
        for (o, a), v in zip(switches, saved):
            setattr(o, a, v)


def _assert_same_evaluation(got: tuple, ref: tuple) -> None:
    for name, g, r in zip(_NAMES, got, ref):
        if name in ("best", "child_x", "own"):
            np.testing.assert_array_equal(g, r, err_msg=name)
        else:
            np.testing.assert_allclose(g, r, rtol=1e-12, atol=1e-12, err_msg=name)


def _numpy_backup(solver: Any, x: int, b: np.ndarray, stale: np.ndarray | None) -> tuple:
    """The numpy steps of a backup (run with the compiled ones off): the evaluation, the
    action of highest ``Q_low``, the vectors at its children (the impossible ones' by
    ``_impossible_best_np``), the new vector by ``SolverModel.backup_vector_np``'s numpy body,
    and how many of the action's children were impossible."""
    ev = solver._evaluate_np(x, b, stale)
    record, best, child_x, own = ev[0], ev[1], ev[4], ev[5]
    q_low, _, prob, _, _ = unpack(record, solver.A, solver.O)
    a = int(q_low.argmax())
    possible = prob[a] > 0
    ch_a = child_x.reshape(prob.shape[0], -1)[a]
    fill = solver._impossible_best_np(x, b, ch_a, possible.reshape(-1), own)
    use = np.where(possible, best.reshape(prob.shape)[a], fill.reshape(possible.shape))
    vectors = solver.alphas.np_vectors
    alpha = SolverModel.backup_vector_np(solver.form, x, a, use, vectors, solver.gamma)
    return ev, a, alpha, int((~possible).sum())


@needs_extension
@pytest.mark.parametrize("name", sorted(_MODELS))
def test_one_call_backup_equals_the_numpy_backup(name: str) -> None:
    """``backup_one`` (children, lower bounds, lazy upper bounds and the new vector in one
    call) against the numpy steps at the beliefs of a short solve, fresh and stale: the same
    evaluation, the same action (the first of highest ``Q_low``), the new vector and its
    value at the belief within 1e-12, impossible children included (their vector: the best
    of their ``x2`` at the belief itself)."""
    solver = _solver(_MODELS[name](), 6)
    assert solver._one_call(0) is not None
    tree, form = solver.tree, solver.form
    numpy_off = [(solver, "_kernel"), (solver, "_vkernel"), (form, "_kernel")]
    impossible = 0
    for node in range(min(tree.size, 40)):
        x, b = int(tree.x[node]), tree.beliefs_np[node]
        stale = solver._cache.get(int(solver.belief_id[node]))
        for st in (None, stale):
            got = solver._backup_compiled(x, b, st, solver._one_call(x), vector=True)

            ev, a, alpha, n_impossible = _with_off(solver, numpy_off, _numpy_backup, solver,
                                                   x, b, st)  # fmt: skip
            _assert_same_evaluation((got.record, got.best, got.lower, got.upper, got.child_x,
                                     got.own), ev)  # fmt: skip
            assert got.action == a
            np.testing.assert_allclose(got.vector, alpha, rtol=1e-12, atol=1e-12)
            np.testing.assert_allclose(got.value, alpha @ b, rtol=1e-12, atol=1e-12)
            impossible += n_impossible
    if "impossible" in name or "rocksample" in name:
        assert impossible > 0  # the impossible children's vectors were compared too


@needs_extension
def test_the_one_call_path_is_taken_where_it_pays(monkeypatch: pytest.MonkeyPatch) -> None:
    """The dense forms give their tables; a flat model's backups go back to the separate
    steps (a BLAS product for the lower bounds) once its vectors times their width pass
    ``ONE_CALL_FLAT_MAX``; a MOMDP's stay in one call; the sparse forms have no tables; and
    the environment switch turns the compiled paths off."""
    bounds = __import__("torchhrc.solvers.sarsop.bounds", fromlist=["ONE_CALL_FLAT_MAX"])
    flat = _solver(random_pomdp(6, 3, 3, seed=0), 3)
    momdp = _solver(random_momdp(4, 5, 3, 3, static=False, seed=3), 3)
    sparse = _solver(SparseMOMDP.from_dense(rock_sample(4, 4, form="momdp")), 2)
    assert flat._one_call(0) is not None and momdp._one_call(0) is not None
    assert sparse._one_call(0) is None
    monkeypatch.setattr(bounds, "ONE_CALL_FLAT_MAX", flat.alphas.size * flat.Y - 1)
    assert flat._one_call(0) is None and momdp._one_call(0) is not None
    monkeypatch.setenv("TORCHHRC_NO_EXTENSION", "1")
    assert _solver(random_momdp(4, 5, 3, 3, static=False, seed=3), 1)._one_call(0) is None


@needs_extension
def test_one_call_backup_by_hand() -> None:
    """Two observed values, one action, two observations, hidden values ``Y = 2``, static:
    from ``x = 0`` the action leads to ``x2 = 1`` surely. ``Z[1, y2=0] = (1, 0)`` and
    ``Z[1, y2=1] = (0.5, 0.5)`` over the observations. Vectors: at ``x = 0`` rows 0 ``(0, 0)``
    and 1 ``(3, 1)``; at ``x = 1`` rows 2 ``(1, 2)`` and 3 ``(2, 4)``; ``R = 1``, gamma 0.5.

    At ``b = (1, 0)`` the child ``o = 0`` is ``(1, 0)`` (``P = 1``), best row 3 (2 against 1),
    and ``o = 1`` is impossible. Its vector is the best of ``x2 = 1`` at ``b`` itself: row 3
    again (not row 0, the first index, nor row 1, the best at ``b`` under ``x = 0``). The new
    vector: ``1 + 0.5 sum_o Z[y2, o] V3[y2]`` = ``(1 + 0.5 * 2, 1 + 0.5 * (0.5 * 4 + 0.5 * 4))
    = (2, 3)``, worth 2 at ``b``; ``Q_low = 1 + 0.5 * 2 = 2``; ``V_low(b)`` under ``x = 0``:
    row 1, 3; the corners (10) bound the rest."""
    tx = np.ones((1, 2, 1))  # Tx[a, x=0, y, k=0] (x2_0 = 1)
    z = np.zeros((1, 1, 2, 2))  # Z[a, k, o, y2]
    z[0, 0, 0] = (1.0, 0.5)
    z[0, 0, 1] = (0.0, 0.5)
    RT = np.ones((2, 1))
    cx = np.ones(2, dtype=np.int64)
    tables = (tx, np.empty((0, 0, 0, 0)), z, RT, cx)
    V = np.array([[0.0, 0.0], [3.0, 1.0], [1.0, 2.0], [2.0, 4.0]])
    scoring = (V, [np.array([0, 1]), np.array([2, 3])], np.array([2, 2]))
    empty_i, empty_d = np.empty(0, dtype=np.int64), np.empty(0)
    saw = (np.full((2, 2), 10.0), [(empty_i, empty_d)] * 2, empty_i, empty_d, empty_i, empty_i,
           empty_d, empty_i)  # fmt: skip
    b = np.array([1.0, 0.0])
    out = backup_kernel.backup_one(kernel, b, 0, tables, scoring, saw, None, 0.5)
    assert out.prob.tolist() == [[[1.0, 0.0]]] and out.best.tolist() == [3, 0]
    # the record: q_low, q_up, then prob, low and up in (a, k, o) order
    assert out.record.tolist() == [2.0, 6.0, 1.0, 0.0, 2.0, 0.0, 10.0, 0.0]
    assert out.low.tolist() == [[[2.0, 0.0]]] and out.q_low.tolist() == [2.0]
    assert (out.lower, out.own, out.upper, out.q_up.tolist()) == (3.0, 1, 10.0, [6.0])
    assert out.action == 0 and out.vector.tolist() == [2.0, 3.0] and out.value == 2.0
    assert out.child_x.tolist() == [1, 1]
    # the same action twice: Q_low ties exactly, and the first is taken (numpy's argmax)
    twice = (np.concatenate([tx, tx]), tables[1], np.concatenate([z, z]), np.ones((2, 2)),
             np.ones(4, dtype=np.int64))  # fmt: skip
    tie = backup_kernel.backup_one(kernel, b, 0, twice, scoring, saw, None, 0.5)
    assert tie.q_low.tolist() == [2.0, 2.0] and tie.action == 0
    assert tie.vector.tolist() == [2.0, 3.0]
    b = np.array([0.25, 0.75])
    out = backup_kernel.backup_one(kernel, b, 0, tables, scoring, saw, None, 0.5)
    only = backup_kernel.backup_one(kernel, b, 0, tables, scoring, saw, None, 0.5, vector=False)
    assert only.action == -1 and only.vector is None and np.isnan(only.value)
    assert only.q_low.tolist() == out.q_low.tolist()
    # errors name what is wrong
    with pytest.raises(IndexError, match="x=2 is outside"):
        backup_kernel.backup_one(kernel, b, 2, tables, scoring, saw, None, 0.5)
    with pytest.raises(TypeError, match="gid to be a list"):
        backup_kernel.backup_one(kernel, b, 0, tables, (V, tuple(scoring[1]), scoring[2]), saw,
                                 None, 0.5)  # fmt: skip
    with pytest.raises(ValueError, match=r"backup_one\(\): inconsistent shapes for A=1"):
        backup_kernel.backup_one(kernel, np.ones(3) / 3, 0, tables, scoring, saw, None, 0.5)
    with pytest.raises(ValueError, match="V \\(N, Y\\) and corner"):
        backup_kernel.backup_one(kernel, b, 0, tables, (V[:, :1].copy(), *scoring[1:]), saw,
                                 None, 0.5)  # fmt: skip
    with pytest.raises(ValueError, match="stale, a record"):
        backup_kernel.backup_one(kernel, b, 0, tables, scoring, saw, np.zeros(7), 0.5)
    # a stale record is read (one action: the lazy loop refreshes it whole, the same record)
    stale = out.record.copy()
    stale[1], stale[-2] = 4.0, 8.0
    lazy = backup_kernel.backup_one(kernel, b, 0, tables, scoring, saw, stale, 0.5)
    np.testing.assert_array_equal(lazy.record, out.record)
    with pytest.raises(ValueError, match="n=0 >= 1 vector"):
        backup_kernel.backup_one(kernel, b, 0, tables, (V, scoring[1], np.array([2, 0])), saw,
                                 None, 0.5)  # fmt: skip


@needs_extension
def test_a_stale_evaluation_refreshes_only_what_can_win() -> None:
    """A hand-made case of the lazy loop: two actions, one child each, no sawtooth point.
    Action 1's cached Q_up (5) beats action 0's (3): it is refreshed to 1 + 0.5 * 2 = 2,
    then action 0 (3 > 2) is refreshed to 0 + 0.5 * 4 = 2; both now fresh, the loop stops."""
    rows = np.array([[1.0, 0.0], [0.0, 1.0], [0.5, 0.5]])  # children of a=0, a=1, then b
    corner = np.array([[4.0, 2.0]])  # one observed value
    nz, rx = np.array([0, 1]), np.zeros(3, dtype=np.int64)
    empty_i, empty_f = np.empty(0, dtype=np.int64), np.empty(0)
    saw = (corner, [(empty_i, empty_f)], empty_i, empty_f, empty_i, empty_i, empty_f, empty_i)
    low_r, best_r = np.array([1.0, 2.0, 1.5]), np.array([3, 4, 5])
    reward = np.array([0.0, 1.0])
    stale = (np.array([3.0, 5.0]), np.array([7.0, 9.0]))
    low, best, q_low, up, q_up, cu = backup_kernel.bound_children(
        kernel, rows, rx, nz, low_r, best_r, reward, 0.5, stale, saw, 2
    )
    assert up.tolist() == [4.0, 2.0] and q_up.tolist() == [2.0, 2.0] and cu == 3.0
    assert low.tolist() == [1.0, 2.0] and best.tolist() == [3, 4]
    assert q_low.tolist() == [0.5, 2.0]
    # action 0 cached below what action 1 refreshes to: it stays stale (1 < 2)
    stale = (np.array([1.0, 5.0]), np.array([7.0, 9.0]))
    _, _, _, up, q_up, _ = backup_kernel.bound_children(
        kernel, rows, rx, nz, low_r, best_r, reward, 0.5, stale, saw, 2
    )
    assert up.tolist() == [7.0, 2.0] and q_up.tolist() == [1.0, 2.0]
    # an impossible child (nz = [1]): 0 in low, best and up; its action sums nothing
    _, best, q_low, up, q_up, cu = backup_kernel.bound_children(
        kernel, rows[1:], rx[1:], nz[1:], low_r[1:], best_r[1:], reward, 0.5, None, saw, 2
    )
    assert best.tolist() == [0, 4] and q_low.tolist() == [0.0, 2.0] and up.tolist() == [0.0, 2.0]
    assert q_up.tolist() == [0.0, 2.0] and cu == 3.0


@needs_extension
def test_bad_arrays_get_clear_errors() -> None:
    S, A, O = 3, 2, 2
    b, T = np.full(S, 1 / 3), np.full((A, 1, S, S), 1 / 3)
    z, RT = np.full((A, 1, O, S), 0.5), np.zeros((S, A))
    no_tx, cx = np.empty((0, 0, 0)), np.zeros(A * O, dtype=np.int64)
    rows, rows_x = np.empty((A * O + 1, S)), np.empty(A * O + 1, dtype=np.int64)
    prob, nz, reward = np.empty(A * O), np.empty(A * O, dtype=np.int64), np.empty(A)
    out = (rows, rows_x, prob, nz, reward)
    assert backup_kernel.children(kernel, b, no_tx, T, z, RT, cx, *out, 0) == A * O
    np.testing.assert_allclose(prob, 0.5)
    with pytest.raises(TypeError, match="expected tyk to be a C-contiguous 4-D float64"):
        backup_kernel.children(kernel, b, no_tx, T.astype(np.float32), z, RT, cx, *out, 0)
    with pytest.raises(TypeError, match="expected rows to be a C-contiguous writable"):
        ro = rows.copy()
        ro.flags.writeable = False
        backup_kernel.children(kernel, b, no_tx, T, z, RT, cx, ro, *out[1:], 0)
    with pytest.raises(ValueError, match=r"A=2 actions, K=1 next observed values, O=2 obs"):
        backup_kernel.children(kernel, b, no_tx, T, z, RT, cx, rows[:-1], *out[1:], 0)
    with pytest.raises(ValueError, match=r"tx \(A, Y, K\) and/or tyk"):  # neither given
        backup_kernel.children(kernel, b, no_tx, np.empty((0, 0, 0, 0)), z, RT, cx, *out, 0)
    empty_i, empty_f = np.empty(0, dtype=np.int64), np.empty(0)
    saw = (np.zeros((1, S)), [(empty_i, empty_f)], empty_i, empty_f, empty_i, empty_i, empty_f,
           empty_i)  # fmt: skip
    rx = np.zeros(A * O + 1, dtype=np.int64)
    args = (rows, rx, np.arange(A * O), np.zeros(A * O + 1),
            np.zeros(A * O + 1, dtype=np.int64), np.zeros(A), 0.9, None, saw, A * O)  # fmt: skip
    backup_kernel.bound_children(kernel, *args)
    with pytest.raises(IndexError, match="nz must increase strictly"):
        backup_kernel.bound_children(kernel, rows, rx, np.array([0, 2, 1, 3]), *args[3:])
    with pytest.raises(ValueError, match="m \\+ 1 rows"):
        backup_kernel.bound_children(kernel, rows[:-1], *args[1:])
    with pytest.raises(ValueError, match="multiple of A actions"):
        backup_kernel.bound_children(kernel, *args[:-1], 5)
    with pytest.raises(ValueError, match="stale_q"):
        backup_kernel.bound_children(kernel, *args[:7], (np.zeros(A), np.zeros(1)), *args[8:])
    far = [(np.array([7]), np.array([-1.0]))]  # a point past the storage
    with pytest.raises(IndexError, match="a point is out of range"):
        backup_kernel.bound_children(kernel, *args[:8], (saw[0], far, *saw[2:]), A * O)
    with pytest.raises(IndexError, match="observed value 1, outside"):
        backup_kernel.bound_children(kernel, rows, rx + 1, *args[2:])


@needs_extension
@pytest.mark.parametrize("name", ["random_dynamic", "random_static", "rocksample_sparse"])
def test_grouped_evaluation_equals_the_numpy_one(name: str) -> None:
    """A MOMDP's children have several observed values: each is scored against its own
    ``x``'s vectors and bounded by its own ``x``'s points, compiled or in numpy, fresh and
    stale, at the beliefs of a short solve: the same vectors and bounds."""
    model = {
        "random_dynamic": lambda: random_momdp(5, 4, 3, 3, static=False, sparsity=0.3, seed=2),
        "random_static": lambda: random_momdp(6, 3, 2, 4, seed=5, discount=0.9),
        "rocksample_sparse": lambda: SparseMOMDP.from_dense(rock_sample(4, 4, form="momdp")),
    }[name]()
    solver = _solver(model, 12)
    assert solver._kernel is not None and solver.ub._group_kernel is not None
    assert solver.ub.size > 0
    got = _assert_both_paths_agree(solver, [(solver, "_kernel"), (solver.ub, "_group_kernel")])
    # the children of some belief lie at several observed values
    assert any(np.unique(ev[4]).size > 1 for ev in got)


def test_grouped_lower_bounds_on_given_columns_equal_the_full_rows() -> None:
    """Rows of several observed values given on a subset of the hidden values (the columns of
    :class:`~torchhrc.solvers.forms.base.Children`) score as the full rows, zero elsewhere."""
    solver = _solver(random_momdp(5, 6, 3, 3, static=False, seed=8), 8)
    rng = np.random.default_rng(0)
    cols = np.array([0, 2, 3, 5])
    rows = np.zeros((7, 6))
    rows[:, cols] = rng.random((7, cols.size))
    rows_x = rng.integers(0, 5, 7)
    for same in (False, True):
        rx = np.full(7, rows_x[0]) if same else rows_x
        want = solver._lower_np(rows, rx)
        got = solver._lower_np(np.ascontiguousarray(rows[:, cols]), rx, cols)
        np.testing.assert_allclose(got[0], want[0], rtol=1e-13, atol=1e-13)
        np.testing.assert_array_equal(got[1], want[1])


@needs_extension
def test_group_scores_and_upper_by_hand() -> None:
    # x = 0 has vectors 5: (1, 0) and 7: (0, 2); x = 1 has 2: (1, 1) and 9: (2, 0), rows
    # of the one store V (the other rows: never read)
    V = np.full((10, 2), -9.0)
    V[5], V[7], V[2], V[9] = (1.0, 0.0), (0.0, 2.0), (1.0, 1.0), (2.0, 0.0)
    gid = [np.array([5, 7, -1]), np.array([2, 9])]
    gn = np.array([2, 2])
    rows = np.array([[1.0, 0.0], [0.5, 0.5], [0.2, 0.4]])
    val, best = backup_kernel.group_scores(kernel, rows, np.array([0, 1, 0]), V, gid, gn)
    # row 0 at x=0: 1 vs 0; row 1 at x=1: 1 vs 1, a tie to the first; row 2 at x=0: 0.2 vs 0.8
    assert val.tolist() == [1.0, 1.0, 0.8] and best.tolist() == [5, 2, 7]
    # the same rows given on their column 1 only (column 0 dropped): 0 vs 0, 0.5 vs 0 (x=1),
    # 0 vs 0.8; and columns gathered, transposed, for a BLAS product
    on_one = np.ascontiguousarray(rows[:, 1:])
    val, best = backup_kernel.group_scores(kernel, on_one, np.array([0, 1, 0]), V, gid, gn,
                                           np.array([1]))  # fmt: skip
    assert val.tolist() == [0.0, 0.5, 0.8] and best.tolist() == [5, 2, 7]
    out = backup_kernel.gather_columns(kernel, V, 8, np.array([1, 0, 1]))
    np.testing.assert_array_equal(out, V[:8][:, [1, 0, 1]].T)
    with pytest.raises(ValueError, match="cols within V's width"):
        backup_kernel.gather_columns(kernel, V, 8, np.array([2]))
    with pytest.raises(ValueError, match="n <= V's rows"):
        backup_kernel.gather_columns(kernel, V, 11, np.array([0]))
    with pytest.raises(ValueError, match=r"vector indices in \[0, 10\)"):
        far = [gid[0], np.array([2, 10])]
        backup_kernel.group_scores(kernel, rows, np.array([0, 1, 0]), V, far, gn)
    # the upper bound: corner[x] . b, lowered by x's one point b_1 = (0.5, 0.5) of value 1
    # at x = 1 (corner (4, 2): gain 1 - 3 = -2): row (0.2, 0.4) at x = 1: 1.6 - 2 * 0.4 = 0.8
    corner = np.array([[1.0, 1.0], [4.0, 2.0]])
    idx, inv = np.array([0, 1]), np.array([2.0, 2.0])
    off, wid, gain = np.array([0]), np.array([2]), np.array([-2.0])
    sorted_points = [(np.zeros(0, dtype=np.int64), np.zeros(0)), (np.array([0]), np.array([-2.0]))]
    sig = np.array([0b11])  # the point covers hidden values 0 and 1
    out, storage = np.empty(3), (idx, inv, off, wid, gain, sig)
    backup_kernel.group_upper(kernel, rows, np.array([0, 1, 1]), (corner, sorted_points, *storage),
                              out)  # fmt: skip
    np.testing.assert_allclose(out, [1.0, 3.0 - 2.0, 1.6 - 0.8], rtol=0, atol=1e-15)
    # row (1, 0) at x = 1 misses hidden value 1 of the point: skipped by its signature, the
    # corner value 4 (the formula's term is 0 there too); and without signatures the same
    for s in (sig, np.empty(0, dtype=np.int64)):
        one = np.empty(1)
        backup_kernel.group_upper(
            kernel,
            rows[:1],
            np.array([1]),
            (corner, sorted_points, idx, inv, off, wid, gain, s),
            one,
        )
        assert one.tolist() == [4.0]
    with pytest.raises(ValueError, match="sawtooth storage"):  # signatures of another length
        backup_kernel.group_upper(kernel, rows, np.array([0, 1, 1]),
                                  (corner, sorted_points, *storage[:5], np.zeros(2, np.int64)),
                                  out)  # fmt: skip
    # errors name the argument
    with pytest.raises(TypeError, match="gid to be a list"):
        backup_kernel.group_scores(kernel, rows, np.array([0, 1, 0]), V, tuple(gid), gn)
    with pytest.raises(IndexError, match="observed value 2, outside"):
        backup_kernel.group_scores(kernel, rows, np.array([0, 2, 0]), V, gid, gn)
    with pytest.raises(ValueError, match="n=0 >= 1 vector"):
        backup_kernel.group_scores(kernel, rows, np.array([0, 1, 0]), V, gid, np.array([0, 2]))
    # one row, scored under each x: (0.5, 0.5) at x = 0 (0.5 vs 1) and at x = 1 (the tie)
    val, best = backup_kernel.group_scores(kernel, rows[1:2], np.array([0, 1]), V, gid, gn)
    assert val.tolist() == [1.0, 1.0] and best.tolist() == [7, 2]
    with pytest.raises(ValueError, match="rows of B rows"):
        backup_kernel.group_scores(kernel, rows, np.array([0, 1]), V, gid, gn)
    with pytest.raises(TypeError, match="sorted\\[0\\] to be an \\(order, key\\) pair"):
        backup_kernel.group_upper(kernel, rows, np.array([0, 1, 1]),
                                  (corner, [None, None], *storage), out)  # fmt: skip
    far = [sorted_points[0], (np.array([3]), np.array([-2.0]))]  # a point past the storage
    with pytest.raises(IndexError, match="a point is out of range"):
        backup_kernel.group_upper(kernel, rows, np.array([0, 1, 1]), (corner, far, *storage),
                                  out)  # fmt: skip


def test_the_environment_switch_selects_the_numpy_path(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("TORCHHRC_NO_EXTENSION", "1")
    assert backup_kernel.load() is None
    form = as_solver_model(random_pomdp(4, 2, 2, seed=0))
    assert form._kernel is None
    b = np.full(4, 0.25)
    ch = form.children_np(0, b)  # the numpy body
    np.testing.assert_allclose(ch.prob.sum((-1, -2)), 1.0)


@needs_extension
def test_refresh_active_compiled_equals_the_level_by_level_numpy(monkeypatch) -> None:
    """BeliefTree.refresh_active: the compiled pass in index order and the numpy loop over
    depth levels deactivate the same nodes (every descendant of an inactive node) on a
    random tree; the kernel refuses a parent listed after its child and a non-bool mask."""
    from torchhrc.solvers.belief_tree import BeliefTree

    rng = np.random.default_rng(0)
    parents = [int(rng.integers(n)) for n in range(1, 400)]
    off = rng.choice(np.arange(1, 400), size=12, replace=False)

    def refreshed() -> BeliefTree:
        tree = BeliefTree(torch.tensor([0.5, 0.5], dtype=torch.float64), x=0, capacity=4)
        for n, parent in enumerate(parents, start=1):
            tree.add(torch.tensor([0.5, 0.5], dtype=torch.float64), 0, parent, 0, n)
        tree.active[off] = False
        tree.refresh_active()
        return tree

    trees = [refreshed()]
    monkeypatch.setattr(backup_kernel, "load", lambda: None)  # read when a tree is built
    trees.append(refreshed())
    assert trees[0]._kernel is not None and trees[1]._kernel is None
    np.testing.assert_array_equal(trees[0].active[:400], trees[1].active[:400])
    inactive = set(off.tolist())
    for n in range(1, 400):  # by hand: inactive iff an ancestor (or itself) was switched off
        m, hit = n, False
        while m >= 0 and not hit:
            hit, m = m in inactive, int(trees[0].parent[m])
        assert trees[0].active[n] == (not hit)
    with pytest.raises(ValueError, match="parent must come before"):
        kernel.propagate_inactive(np.array([-1, 2, 0]), np.ones(3, dtype=bool))
    with pytest.raises(ValueError, match="bool"):
        kernel.propagate_inactive(np.array([-1, 0]), np.ones(2))


@needs_extension
@pytest.mark.parametrize("K, O", [(1, 5), (3, 30)])  # 5 children of an action; 90 (numpy's way)
def test_trial_step_chooses_as_the_python_step(K: int, O: int) -> None:
    """``trial_step`` against ``_argmax_tie`` (the first of equal actions) and
    ``_child_choice`` on random evaluations with equal and near-equal Q_up (within and just
    outside 1e-12 relative), impossible children, equal excesses and no possible child."""
    from torchhrc.solvers.sarsop.trial import _Trials

    class _First:
        cfg = SARSOPConfig(tie_break="first")

    rng = np.random.default_rng(5)
    A, seen_ties, seen_none = 6, 0, 0
    for case in range(400):
        prob = rng.integers(0, 3, (A, K, O)) * 0.25  # coarse: equal excesses happen
        if case % 7 == 0:
            prob[:] = 0.0  # no possible child
        low = -rng.integers(0, 3, (A, K, O)) * prob
        up = low + rng.integers(0, 3, (A, K, O)) * prob
        # the tolerance is relative above 1 and absolute below: values of 0.1 to 6,000
        q_up = rng.integers(1, 4, A) * [0.1, 10.0, 2000.0][case % 3]
        top = q_up.max()
        if case % 2 == 0:  # a near tie inside the tolerance, and one just outside it
            q_up[rng.integers(A)] = top - 0.7e-12 * max(1.0, abs(top))
            q_up[rng.integers(A)] = top - 2e-12 * max(1.0, abs(top))
        q_low = rng.random(A) - 5.0
        target = float(rng.random()) * 0.5
        record = pack(q_low, q_up, prob, low, up)
        got = kernel.trial_step(record, A, O, target)
        assert unpack(record, A, O)[3].tolist() == low.tolist()  # (the layout read back)
        a = _Trials._argmax_tie(_First(), q_up)
        k, o, p = _Trials._child_choice(prob[a], up[a], low[a], target)
        top = max(q_up.tolist())
        ties = sum(v >= top - 1e-12 * max(1.0, abs(top)) for v in q_up.tolist())
        want = (max(q_low.tolist()), a, ties, k, o, p, float(low[a, k, o]), float(up[a, k, o]))
        assert got == want, case
        seen_ties += ties > 1
        seen_none += p <= 0
    assert seen_ties > 50 and seen_none > 20  # not vacuous


@needs_extension
def test_trial_step_refuses_what_it_cannot_read() -> None:
    record = np.zeros(2 * 2 + 3 * 2 * 1 * 3)  # A = 2, K = 1, O = 3
    kernel.trial_step(record, 2, 3, 0.1)
    with pytest.raises(ValueError, match=r"2 A \+ 3 A K O entries .* got 21 entries"):
        kernel.trial_step(np.zeros(21), 2, 3, 0.1)
    with pytest.raises(ValueError, match="A=0"):
        kernel.trial_step(record, 0, 3, 0.1)
    with pytest.raises(TypeError, match="record"):
        kernel.trial_step(record.astype(np.float32), 2, 3, 0.1)
    with pytest.raises(TypeError, match="record"):
        kernel.trial_step(np.zeros((2, 11)), 2, 3, 0.1)


@needs_extension
@pytest.mark.parametrize("tie_break", ["random", "first"])
def test_a_search_with_the_compiled_trial_step_takes_the_python_steps_path(
    tie_break: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The same solves, step for step, with and without ``trial_step`` (equal actions drawn
    by the seeded generator included): the same iterations, backups and bounds, bit for bit."""
    from torchhrc.solvers.sarsop import sarsop
    from torchhrc.tasks.classic import tiger

    def run(model) -> list:
        cfg = SARSOPConfig(time_limit=1e9, max_iterations=60, precision=1e-9, seed=3,
                           tie_break=tie_break)  # fmt: skip
        sol = sarsop(model, cfg)
        return [sol.info["backups"]] + [(h["lower"], h["upper"]) for h in sol.history]

    models = [tiger(), rock_sample(4, 4, form="momdp"), random_momdp(4, 3, 3, 2, seed=1)]
    compiled = [run(m) for m in models]
    monkeypatch.setattr(kernel, "trial_step", None)
    assert [run(m) for m in models] == compiled

    def refuse(*args):  # as for arrays it cannot read: the trial goes on in Python
        raise TypeError("expected record to be a C-contiguous 1-D float64 array")

    monkeypatch.setattr(kernel, "trial_step", refuse)
    assert [run(m) for m in models] == compiled


def _planted_vectors(seed: int, N: int = 40, Y: int = 6, equal: bool = True) -> np.ndarray:
    """``(N, Y)`` random alpha vectors with planted dominance: vectors a little and 1e-9
    below others, one above two others' maximum and, with ``equal``, equal pairs (random
    normal rows in 6 dimensions seldom dominate each other on their own)."""
    rng = np.random.default_rng(seed)
    V = rng.normal(size=(N, Y))
    V[7] = V[2] - 0.5  # dominated
    V[9] = V[4] - 1e-9  # dominated, and within atol=1e-6 of dominating back
    V[11] = np.maximum(V[0], V[1]) + 0.1  # dominates 0 and 1
    if equal:
        V[5] = V[3]  # equal: the first of the two is kept
        V[13] = V[11]  # equal to it
    return V


@needs_extension
@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("grouped", [False, True])
@pytest.mark.parametrize("atol", [0.0, 1e-6])
def test_dominated_equals_prune_dominated(seed: int, grouped: bool, atol: float) -> None:
    """The compiled dominance test drops what :func:`~torchhrc.solvers.pruning.
    prune_dominated` drops, on shuffled candidates of a store (their order the tie order),
    in one group or several (the groups unsorted), with and without a tolerance."""
    from torchhrc.solvers.pruning import prune_dominated

    rng = np.random.default_rng(100 + seed)
    V = _planted_vectors(seed)
    ids = np.concatenate([[13, 11, 5, 3], rng.permutation(np.arange(40))])
    ids = ids[np.sort(np.unique(ids, return_index=True)[1])][:34]  # distinct, order kept
    groups = rng.integers(0, 3, 40)[ids] if grouped else None
    if grouped:
        groups[:6] = 1  # the planted pairs in one group: (13, 11), (5, 3)
    expected = prune_dominated(torch.from_numpy(V[ids]),
                               None if groups is None else torch.from_numpy(groups),
                               atol=atol).numpy()  # fmt: skip
    got = backup_kernel.dominated(kernel, V, ids, groups, atol)
    assert got.dtype == bool and got.shape == (ids.size,)
    np.testing.assert_array_equal(got, expected)
    assert 0 < got.sum() < ids.size
    # the first listed of two equal vectors is kept: 13 before 11, 5 before 3
    at = {int(i): k for k, i in enumerate(ids)}
    assert got[at[13]] and not got[at[11]] and got[at[5]] and not got[at[3]]


@needs_extension
@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.parametrize("X", [1, 3])
def test_keep_alphas_equals_the_torch_pruning(seed: int, X: int) -> None:
    """:func:`~torchhrc.solvers.backup_kernel.keep_alphas` keeps what the tree's torch rule
    keeps (:func:`~torchhrc.solvers.pruning.prune_by_beliefs` at the given beliefs, each
    against its own observed value's vectors, then
    :func:`~torchhrc.solvers.pruning.prune_dominated` on the winners): the winners, all the
    vectors of an observed value without a belief (the last one, where X = 3), and no
    dominated vector; the beliefs gathered a few rows at a time. (No two vectors are equal:
    equal scores at a belief would leave the winner to the last bits of each BLAS's sums.)"""
    from torchhrc.solvers.pruning import prune_by_beliefs, prune_dominated

    rng = np.random.default_rng(seed)
    N, Y = 40, 6
    V = _planted_vectors(seed, N, Y, equal=False)
    store = np.vstack([V, np.full((8, Y), np.nan)])  # capacity beyond the rows in use
    observed = rng.integers(0, X, N)
    gid = [np.concatenate([np.flatnonzero(observed == x), np.full(3, -1)]) for x in range(X)]
    gn = np.bincount(observed, minlength=X).astype(np.int64)
    beliefs = rng.dirichlet(np.ones(Y), size=30)
    beliefs[3] = np.eye(Y)[0]  # a corner: the vectors' first entries decide
    nodes = rng.choice(30, size=24, replace=False)
    nodes_x = rng.integers(0, max(X - 1, 1), nodes.size)  # no belief at x = X - 1 (X > 1)
    groups = None if X == 1 else torch.from_numpy(observed)
    by_beliefs = prune_by_beliefs(torch.from_numpy(V), torch.from_numpy(beliefs), groups,
                                  None if X == 1 else torch.from_numpy(nodes_x),
                                  rows=torch.from_numpy(nodes))  # fmt: skip
    idx = by_beliefs.nonzero().squeeze(-1)
    expected = by_beliefs.clone()
    expected[idx] = prune_dominated(
        torch.from_numpy(V)[idx], None if groups is None else groups[idx]
    )
    original = backup_kernel._BLOCK_ROWS
    try:
        backup_kernel._BLOCK_ROWS = 5 * N  # five beliefs a block (N vectors > Y)
        got = backup_kernel.keep_alphas(kernel, store, gid, gn, observed, beliefs, nodes, nodes_x)
    finally:
        backup_kernel._BLOCK_ROWS = original
    np.testing.assert_array_equal(got, expected.numpy())
    if X > 1:  # the observed value without a belief keeps all its undominated vectors
        last = np.flatnonzero(observed == X - 1)
        alone = prune_dominated(torch.from_numpy(V[last])).numpy()
        assert last.size > 2 and (got[last] == alone).all() and alone.sum() > 2
    assert 0 < got.sum() < N


@needs_extension
@pytest.mark.parametrize("name", ["tiger", "rocksample_momdp", "random_momdp"])
def test_a_search_prunes_with_the_compiled_kernel(name: str, monkeypatch: pytest.MonkeyPatch
                                                  ) -> None:  # fmt: skip
    """SARSOP's alpha pruning of a dense model with float64 vectors takes the compiled kernel,
    which keeps what the tree's torch rule keeps (``BeliefTree.keep_alphas`` at the tree's
    observed values; a vector may differ only where it scores within 1e-9 of a winner),
    and every pruning of the search keeps the lower bound at every active tree belief (the
    best score among the vectors of the belief's own observed value, read from the tree,
    before and after; the kept set also holds the vectors the kept ones' plans refer to, so
    dominated vectors may stay); the solve still brackets the value (Tiger's 19.3713, from
    the exact tests of the bounds)."""
    from torchhrc.solvers.sarsop import sarsop
    from torchhrc.solvers.sarsop.pruning import _Pruning
    from torchhrc.tasks.classic import tiger

    model = {
        "tiger": tiger,
        "rocksample_momdp": lambda: rock_sample(4, 4, form="momdp"),
        "random_momdp": lambda: random_momdp(4, 5, 3, 3, static=False, seed=3),
    }[name]()
    calls, prunings, current = [], [], []
    real_keep, real_prune = backup_kernel.keep_alphas, _Pruning._prune_alphas

    def values(search, nodes: np.ndarray) -> np.ndarray:
        n = search.alphas.size
        V, obs = search.alphas.np_vectors[:n], search.alphas.np_observed[:n]
        scores = search.tree.beliefs_np[nodes] @ V.T  # (M, n)
        return np.where(search.tree.x[nodes][:, None] == obs[None, :], scores, -np.inf).max(1)

    def checked_prune(search) -> bool:
        nodes = np.flatnonzero(search.tree.active[: search.tree.size])
        before = values(search, nodes)
        current[:] = [search]
        ran = real_prune(search)
        if ran:
            np.testing.assert_allclose(values(search, nodes), before, rtol=1e-12, atol=1e-12)
            prunings.append(search.alphas.size)
        return ran

    def checked_keep(kernel, V, gid, gn, observed, beliefs, nodes, nodes_x, atol=0.0):
        keep = real_keep(kernel, V, gid, gn, observed, beliefs, nodes, nodes_x, atol)
        tree, n = current[0].tree, observed.shape[0]  # the torch rule at the tree's own x
        groups = torch.from_numpy(observed.copy()) if gn.shape[0] > 1 else None
        ref = tree.keep_alphas(torch.from_numpy(V[:n].copy()), groups, nodes).numpy()
        scores = beliefs[nodes] @ V[:n].T
        mine = tree.x[nodes][:, None] == observed[None, :]
        gap = np.where(mine, scores.max(1, where=mine, initial=-np.inf)[:, None] - scores, np.inf)
        for i in np.flatnonzero(keep != ref).tolist():  # only where a winner is a near tie
            assert (gap[:, i] <= 1e-9).any(), f"vector {i}: kept {keep[i]}, torch {ref[i]}"
        calls.append(int((keep != ref).sum()))
        return keep

    monkeypatch.setattr(backup_kernel, "keep_alphas", checked_keep)
    monkeypatch.setattr(_Pruning, "_prune_alphas", checked_prune)
    sol = sarsop(model, SARSOPConfig(precision=1e-3, time_limit=1e9, max_iterations=150))
    assert len(prunings) >= 3 and len(calls) == len(prunings)
    if name == "tiger":
        assert sol.lower <= 19.3713 <= sol.upper and sol.upper - sol.lower <= 1e-3
        calls.clear()
        monkeypatch.setenv("TORCHHRC_NO_EXTENSION", "1")  # the torch rule
        sol = sarsop(model, SARSOPConfig(precision=1e-3, time_limit=1e9, max_iterations=150))
        assert not calls and sol.lower <= 19.3713 <= sol.upper


@needs_extension
def test_dominated_refuses_what_it_cannot_read() -> None:
    V = np.zeros((3, 2))
    with pytest.raises(ValueError, match="ids within V's rows"):
        kernel.dominated(V, np.array([0, 3]), np.empty(0, dtype=np.int64),
                         np.empty(2, dtype=np.int64), 0.0)  # fmt: skip
    with pytest.raises(ValueError, match="groups non-decreasing"):
        kernel.dominated(V, np.array([0, 1]), np.array([1, 0]), np.empty(2, dtype=np.int64), 0.0)
    with pytest.raises(TypeError, match="keep"):
        kernel.dominated(V, np.array([0, 1]), np.empty(0, dtype=np.int64), np.empty(2), 0.0)
    with pytest.raises(ValueError, match="groups of shape"):
        backup_kernel.dominated(kernel, V, np.array([0, 1]), np.array([0]))
