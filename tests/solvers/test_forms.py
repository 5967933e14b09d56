"""Tests of the model forms under the point-based solvers (torchhrc.solvers.forms).

Every form implements one interface; its numpy one-belief operations (SARSOP's sequential
path) must agree with its torch batched ones (the path a device backend runs), and SARSOP
must give valid bounds through either path on every form.
"""

from __future__ import annotations

import sys
import time

import numpy as np
import pytest
import torch

from torchhrc.errors import ModelError
from torchhrc.pomdp import SparsePOMDP
from torchhrc.solvers import PBVIConfig, SARSOPConfig, pbvi
from torchhrc.solvers.backup import point_backup
from torchhrc.solvers.blind import blind_policy
from torchhrc.solvers.forms import (
    DenseForm,
    MOMDPForm,
    SolverModel,
    SparseForm,
    as_solver_model,
)
from torchhrc.solvers.sarsop.search import _SARSOP
from torchhrc.tasks.classic import rock_sample, tiger
from torchhrc.testing import random_momdp, random_pomdp

FORMS = {
    "dense": lambda: random_pomdp(6, 3, 3, discount=0.9, seed=11),
    "dense_support": lambda: rock_sample(4, 4),  # S = 257: the support-restricted products
    "momdp_static": lambda: random_momdp(4, 3, 2, 3, static=True, sparsity=0.3, seed=1),
    "momdp_dynamic": lambda: random_momdp(4, 3, 2, 3, static=False, sparsity=0.3, seed=2),
    "sparse": lambda: SparsePOMDP.from_dense(rock_sample(4, 4)),
    "momdp_random_start": lambda: random_momdp(
        4, 3, 2, 3, static=False, sparsity=0.3, seed=2
    ).with_initial(torch.full((4, 3), 1.0 / 12, dtype=torch.float64)),
}
KINDS = {"dense": DenseForm, "dense_support": DenseForm, "momdp_static": MOMDPForm,
         "momdp_dynamic": MOMDPForm, "sparse": SparseForm,
         "momdp_random_start": MOMDPForm}  # fmt: skip


def _beliefs(form: SolverModel, n: int, seed: int) -> torch.Tensor:
    """``n`` beliefs: ``b0`` and random ones on the support of a few of ``b0``'s children."""
    g = torch.Generator().manual_seed(seed)
    rows = [form.b0]
    _, J = form.expand(form.x0, form.b0.unsqueeze(0))
    J = J.reshape(-1, form.num_hidden)
    J = J[J.sum(-1) > 0]
    for i in range(n - 1):
        support = J[i % J.shape[0]] > 0
        w = torch.rand(form.num_hidden, generator=g, dtype=form.b0.dtype) * support
        rows.append(w / w.sum())
    return torch.stack(rows)


@pytest.mark.parametrize("name", sorted(FORMS))
def test_adapter_picks_the_form_once_and_passes_forms_through(name: str) -> None:
    form = as_solver_model(FORMS[name]())
    assert type(form) is KINDS[name]
    assert as_solver_model(form) is form
    A, X, Y = form.num_actions, form.num_observed, form.num_hidden
    assert tuple(form.R.shape) == (A, X, Y) and tuple(form.b0.shape) == (Y,)
    assert int(np.prod(form.state_shape)) == X * Y


def test_adapter_rejects_unknown_and_batched_models() -> None:
    with pytest.raises(TypeError, match="POMDP, MOMDP or SparsePOMDP"):
        as_solver_model("tiger")
    with pytest.raises(ModelError, match="batch_shape"):
        as_solver_model(random_pomdp(2, 2, 2, batch_shape=(2,), seed=0))


@pytest.mark.parametrize("name", sorted(FORMS))
def test_numpy_children_equal_the_batched_expansion(name: str) -> None:
    """children_np (rows on their columns, probabilities, rewards) = expand (paper Eq. 3)."""
    form = as_solver_model(FORMS[name]())
    for x in sorted({form.x0, int(form.reach[form.x0][-1])}):
        beliefs = _beliefs(form, 4, seed=x)
        xs, J = form.expand(x, beliefs)  # (B, A, K, O, Y)
        B, A, K, O, Y = J.shape
        for i in range(B):
            b = beliefs[i].numpy()
            ch = form.children_np(x, b)
            np.testing.assert_allclose(ch.prob, J[i].sum(-1).numpy(), atol=1e-12)
            cols = np.arange(Y) if ch.cols is None else ch.cols
            flat = J[i].reshape(A * K * O, Y).numpy()
            assert np.all(flat[np.setdiff1d(np.arange(A * K * O), ch.nz)] == 0)
            np.testing.assert_allclose(ch.rows[:-1], flat[ch.nz][:, cols], atol=1e-12)
            # the rows' supports lie inside the columns they are given on
            np.testing.assert_allclose(flat[ch.nz].sum(-1), ch.rows[:-1].sum(-1), atol=1e-12)
            np.testing.assert_allclose(ch.rows[-1], b[cols])
            assert ch.rows_x[-1] == x
            np.testing.assert_array_equal(ch.rows_x[:-1], ch.child_x[ch.nz])
            np.testing.assert_array_equal(ch.child_x.reshape(A, K, O)[0, :, 0], xs.numpy())
            R = form.R[:, x, :].numpy()  # (A, Y)
            np.testing.assert_allclose(ch.reward, R @ b, atol=1e-12)
            a, k, o = np.unravel_index(int(ch.nz[-1]), (A, K, O))
            np.testing.assert_allclose(form.child_np(x, b, a, k, o), flat[ch.nz[-1]], atol=1e-12)


@pytest.mark.parametrize("name", sorted(FORMS))
def test_numpy_backprojection_equals_the_batched_one(name: str) -> None:
    """backproject_np(x, a, v) = backproject(x, [a], v) = sum_{k, y2} Tx Ty v (the transpose
    of the prediction: <pred(b), v> = <b, backproject(v)> for every b)."""
    form = as_solver_model(FORMS[name]())
    g = torch.Generator().manual_seed(0)
    x = form.x0
    K = form.reach[x].numel()
    actions = torch.arange(form.num_actions)
    values = torch.randn(form.num_actions, K, form.num_hidden, generator=g, dtype=torch.float64)
    batched = form.backproject(x, actions, values)  # (A, Y)
    beliefs = _beliefs(form, 3, seed=1)
    pred = form.predict(x, beliefs)  # (B, A, K, Y)
    for a in range(form.num_actions):
        got = form.backproject_np(x, a, values[a].numpy())
        np.testing.assert_allclose(got, batched[a].numpy(), atol=1e-12)
        lhs = (pred[:, a] * values[a]).sum((-1, -2))
        torch.testing.assert_close(lhs, beliefs @ batched[a])
        obs = form.observation_slice(x, torch.tensor([a]))[0]
        np.testing.assert_array_equal(obs.numpy(), form.observation_np(x)[a])


@pytest.mark.parametrize("name", ["dense", "momdp_dynamic", "sparse", "momdp_random_start"])
def test_sarsop_torch_path_brackets_the_numpy_path(name: str) -> None:
    """The batched torch path (what a device runs; forced here on the CPU) and the numpy path
    bound the same optimal value: each one's lower bound is below the other's upper bound."""
    model = FORMS[name]()
    cfg = SARSOPConfig(time_limit=1e9, precision=1e-9, max_iterations=15)
    cpu = _SARSOP(model, cfg, time.perf_counter())
    ref = cpu.run()
    dev = _SARSOP(model, cfg, time.perf_counter())
    dev._np = False  # the device path: torch evaluate/expand/backproject, batched backups
    sol = dev.run()
    assert sol.info["iterations"] == 15 and dev.backups > 0
    assert sol.lower <= sol.upper and ref.lower <= ref.upper
    assert sol.lower <= ref.upper + 1e-9 and ref.lower <= sol.upper + 1e-9
    # the tree beliefs are normalised Bayes updates in both paths
    sums = dev.tree.beliefs.sum(-1)
    torch.testing.assert_close(sums, torch.ones_like(sums))


def test_sarsop_torch_path_reaches_the_tiger_optimum_on_every_flat_form() -> None:
    for model in (tiger(), SparsePOMDP.from_dense(tiger())):
        solver = _SARSOP(model, SARSOPConfig(time_limit=1e9, precision=1e-3), 0.0)
        solver._np = False
        sol = solver.run()
        assert sol.info["stop_reason"] == "precision"
        assert sol.lower <= 19.3714 <= sol.upper + 1e-9


class _SupportMOMDP(MOMDPForm):
    """A new form in a few lines: a MOMDP whose one-belief children are given on their
    support columns only (what a sparse MOMDP form would do)."""

    def children_np(self, x, b):  # type: ignore[no-untyped-def]
        ch = super().children_np(x, b)
        cols = np.flatnonzero(ch.rows.any(0))
        ch.rows, ch.cols = np.ascontiguousarray(ch.rows[:, cols]), cols
        return ch


def test_a_new_form_is_one_class_and_column_children_of_a_momdp_bound_correctly() -> None:
    from torchhrc.tasks.classic import rock_sample

    model = rock_sample(4, 4, form="momdp")
    form = _SupportMOMDP(model)
    assert as_solver_model(form) is form
    b = form.b0.numpy()
    ch = form.children_np(form.x0, b)
    assert ch.cols is not None and ch.rows.shape[1] == ch.cols.size
    cfg = SARSOPConfig(time_limit=1e9, precision=1e-9, max_iterations=20)
    ref = _SARSOP(model, cfg, 0.0)
    ref.run()
    solver = _SARSOP(form, cfg, 0.0)
    sol = solver.run()
    # the same search up to round-off: the same bounds, to 1e-9
    assert sol.lower == pytest.approx(ref.history[-1]["lower"], rel=1e-9)
    assert sol.upper == pytest.approx(ref.history[-1]["upper"], rel=1e-9)
    # and each row is bounded against its own observed value's vectors only
    rows = torch.from_numpy(ch.rows[:-1])
    full = torch.zeros(rows.shape[0], form.num_hidden, dtype=rows.dtype)
    full[:, torch.from_numpy(ch.cols)] = rows
    low, _ = solver._lower_np(ch.rows[:-1], ch.rows_x[:-1], ch.cols)
    ref_low, _ = solver._lower_np(full.numpy(), ch.rows_x[:-1])
    np.testing.assert_allclose(low, ref_low, rtol=1e-12, atol=1e-12)


# -- PBVI on every form --------------------------------------------------------------------------
@pytest.mark.parametrize("build", [tiger, lambda: rock_sample(4, 4)])
def test_sparse_pbvi_operations_equal_the_dense_ones(build) -> None:  # type: ignore[no-untyped-def]
    """The sparse form's simulation step draws the same successors as the dense one (the same
    inverse-CDF draw over the stored nonzeros) and its belief-side point backup equals the
    dense kernel (Pineau et al. 2003)."""
    model = build()
    dense, sparse = as_solver_model(model), as_solver_model(SparsePOMDP.from_dense(model))
    beliefs = _beliefs(dense, 6, seed=3)
    M = beliefs.shape[0]
    actions = torch.arange(M) % model.num_actions
    x = torch.zeros(M, dtype=torch.long)
    xd, bd = dense.simulate(x, beliefs, actions, torch.Generator().manual_seed(5))
    xs, bs = sparse.simulate(x, beliefs, actions, torch.Generator().manual_seed(5))
    assert torch.equal(xd, xs)
    torch.testing.assert_close(bs, bd)
    policy = blind_policy(model)
    ref = point_backup(model, policy, beliefs)
    got = sparse.point_backup(policy, x, beliefs)
    torch.testing.assert_close(got.q_values, ref.q_values)
    assert torch.equal(got.actions, ref.actions)
    torch.testing.assert_close(got.alphas, ref.alphas)
    torch.testing.assert_close(got.values, ref.values)
    for kind in ("fib", "qmdp"):  # upper bounds: at or above the dense ones' fixed point
        up_d, up_s = dense.upper_vectors(kind, 1e-10), sparse.upper_vectors(kind, 1e-10)
        torch.testing.assert_close(up_s, up_d, atol=1e-6, rtol=0)


def test_pbvi_solves_a_sparse_model_as_its_dense_form() -> None:
    model = rock_sample(4, 4)
    cfg = PBVIConfig(time_limit=1e9, expansions=2, backups_per_expansion=5, seed=0)
    ref = pbvi(model, cfg)
    sol = pbvi(SparsePOMDP.from_dense(model), cfg)
    assert sol.info["n_beliefs"] == ref.info["n_beliefs"]
    # the blind initialisations differ within their tolerance (LU against iteration)
    assert sol.lower == pytest.approx(ref.lower, abs=1e-6)
    assert sol.upper >= sol.lower and abs(sol.upper - ref.upper) < 1e-3
    torch.testing.assert_close(sol.info["beliefs"], ref.info["beliefs"])


_SPARSE_BACKUP_PEAK_SCRIPT = r"""
import json
import torch
from torchhrc.pomdp import SparsePOMDP
from torchhrc.solvers._memory import peak_resident_bytes, release_free_memory, resident_bytes
from torchhrc.solvers.forms import as_solver_model, sparse
from torchhrc.solvers.policy import AlphaVectorPolicy

# a ring of S states (from s: s or s + 1 + a), M beliefs: the (M, A, S) block is 268 MB
S, A, O, M, m = 8192, 16, 2, 256, 2
g = torch.Generator().manual_seed(0)
act, src = torch.arange(A).repeat_interleave(S), torch.arange(S).repeat(A)
def coo(cols):
    return torch.stack((act.repeat_interleave(2), src.repeat_interleave(2), cols.reshape(-1)), 1)
half = torch.full((A * S * 2,), 0.5, dtype=torch.float64)
model = SparsePOMDP(transitions=(coo(torch.stack([src, (src + 1 + act) % S], 1)), half),
                    observations_=(coo(torch.stack([src % O, (src + 1) % O], 1)), half),
                    R=torch.randn(A, S, generator=g, dtype=torch.float64),
                    b0=torch.full((S,), 1.0 / S, dtype=torch.float64), discount=0.95,
                    states=tuple(map(str, range(S))), actions=tuple(map(str, range(A))),
                    observations=tuple(map(str, range(O))))
form = as_solver_model(model)
sparse.CHUNK_ELEMENTS = m * A * O * S  # m beliefs a chunk
policy = AlphaVectorPolicy(torch.randn(8, S, generator=g, dtype=torch.float64),
                           torch.randint(0, A, (8,), generator=g))
beliefs = torch.rand(M, S, generator=g, dtype=torch.float64)
beliefs /= beliefs.sum(1, keepdim=True)
release_free_memory()
before = resident_bytes()
result = form.point_backup(policy, torch.zeros(M, dtype=torch.int64), beliefs)
print(json.dumps({"grew": peak_resident_bytes() - before, "result": result.alphas.nbytes,
                  "chunk": sparse.CHUNK_ELEMENTS * 8, "block": M * A * S * 8}))
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="/proc/self/statm")
def test_sparse_point_backup_holds_its_result_and_one_chunk_not_every_action_vector() -> None:
    """The sparse form's point backup keeps, across its chunks of beliefs, only the ``(M, S)``
    result: in a fresh process (its own peak, :func:`peak_resident_bytes`), 256 beliefs of
    8192 states, 16 actions, 2 beliefs a chunk grow the peak by less than twice the 16 MiB
    result, eight 4 MiB ``(m, A, O, S)`` chunk blocks and 16 MiB of slack (80 MiB; about 50
    are used). Keeping each chunk's ``(m, A, S)`` vectors and concatenating them (what it
    did) held two 256 MiB ``(M, A, S)`` blocks."""
    import json
    import os
    import subprocess

    env = dict(os.environ, OMP_NUM_THREADS="1")
    out = subprocess.run([sys.executable, "-c", _SPARSE_BACKUP_PEAK_SCRIPT], env=env,
                         capture_output=True, text=True, check=True)  # fmt: skip
    r = json.loads(out.stdout.splitlines()[-1])
    assert r["grew"] < 2 * r["result"] + 8 * r["chunk"] + (16 << 20) < r["block"], r


@pytest.mark.parametrize("build", [lambda: random_pomdp(70, 3, 4, discount=0.9, seed=4),
                                   lambda: random_pomdp(80, 3, 3, discount=0.95, sparsity=0.95,
                                                        seed=5)])  # fmt: skip
def test_dense_fib_start_bounds_qmdp_and_its_step_is_the_fib_operator(build) -> None:  # type: ignore[no-untyped-def]
    """The CPU path of the dense form (numpy QMDP from zero with the contraction bound; the
    FIB step in numpy, or per-action sparse products when ``T`` is sparse): the QMDP vectors
    bound the exact ``Q*`` from above within the tolerance's slack, and one step equals
    :func:`~torchhrc.solvers.fib.fib_backup`. (Models too large for FIB's policy iteration:
    a few states get FIB's fixed point instead, tests/solvers/test_fib_exact.py.)"""
    from torchhrc.solvers.clock import NEVER
    from torchhrc.solvers.fib import fib_backup
    from torchhrc.solvers.qmdp import mdp_q_values

    model = build()
    form = as_solver_model(model)
    tol = 1e-6
    Q, step = form.fib_start(tol, NEVER, {})
    exact, err = mdp_q_values(model, tol=1e-12)
    g = model.discount
    assert bool((Q >= exact - err - 1e-12).all())  # an upper bound
    assert float((Q - exact).max()) <= 2 * g * tol / (1 - g) + 1e-9  # and a tight one
    torch.testing.assert_close(step(Q), fib_backup(model, Q), rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("static", [True, False])
def test_momdp_qmdp_start_bounds_q_star_and_stops_at_the_deadline(static) -> None:  # type: ignore[no-untyped-def]
    """The MOMDP form starts FIB from the same CPU QMDP as the flat forms: an upper bound on
    the exact ``Q*`` within the tolerance's slack, and still one when the deadline has passed
    before the first iteration (``max R / (1 - gamma)`` then)."""
    from torchhrc.solvers.clock import NEVER, Deadline
    from torchhrc.solvers.qmdp import mdp_q_values

    model = random_momdp(4, 3, 3, 2, discount=0.9, static=static, seed=6)
    form = as_solver_model(model)
    exact, err = mdp_q_values(model, tol=1e-12)
    g, tol = model.discount, 1e-6
    Q = form.qmdp_start(tol, NEVER)
    assert Q.shape == exact.shape == (3, 4, 3)
    assert bool((Q >= exact - err - 1e-12).all())
    assert float((Q - exact).max()) <= 2 * g * tol / (1 - g) + 1e-9
    late = form.qmdp_start(tol, Deadline(0.0, lambda: 1.0))  # already passed
    assert bool((late >= exact - err - 1e-12).all())
    assert float(late.max()) <= float(model.R.max()) / (1 - g) + 1e-9
    start, _ = form.fib_start(tol, NEVER, {})
    torch.testing.assert_close(start, Q, rtol=0, atol=0)  # what FIB starts from


def test_the_forms_and_the_kernels_import_no_algorithm_above_them():
    """The layers of solvers/ (docs/architecture.md): the tensor kernels, then the forms,
    then the algorithms. No module of the two lower layers imports an algorithm module, not
    even inside a function (that was the import circle fib/qmdp <-> forms)."""
    import ast
    from pathlib import Path

    import torchhrc.solvers

    root = Path(torchhrc.solvers.__file__).parent
    lower = [*sorted((root / "forms").glob("*.py"))] + [
        root / f"{name}.py"
        for name in ("tensor_bounds", "_factored", "blind", "backup", "sparse_model", "sampling")
    ]
    above = {f"torchhrc.solvers.{m}" for m in
             ("qmdp", "fib", "sarsop", "pbvi", "evaluate", "policy_graph")}  # fmt: skip
    for path in lower:
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom):
                names = {node.module or ""} | {f"{node.module}.{a.name}" for a in node.names}
            elif isinstance(node, ast.Import):
                names = {a.name for a in node.names}
            else:
                continue
            assert not names & above, (path.name, sorted(names & above))


def test_a_form_and_a_prepared_sparse_model_in_another_dtype():
    """``as_solver_model`` hands a form back as it is (found by its type like every model),
    and rebuilds a prepared :class:`SparseFlatModel` in the dtype asked for (it raised a
    TypeError): the float32 QMDP vectors are the float64 ones to float32's precision."""
    from torchhrc.solvers.sparse_model import SparseFlatModel

    form = as_solver_model(tiger())
    assert as_solver_model(form) is form
    prepared = SparseFlatModel.from_model(SparsePOMDP.from_dense(tiger()))
    assert as_solver_model(prepared).sparse is prepared  # its own dtype: itself
    single = as_solver_model(prepared, dtype=torch.float32)
    assert single.sparse.dtype == torch.float32 and single.R.dtype == torch.float32
    assert single.sparse.nnz == prepared.nnz
    torch.testing.assert_close(
        single.upper_vectors("qmdp", 1e-6).double(),
        as_solver_model(prepared).upper_vectors("qmdp", 1e-6),
        rtol=1e-5,
        atol=1e-4,
    )
