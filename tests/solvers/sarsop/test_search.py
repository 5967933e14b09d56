"""SARSOP's search details taken from APPL: the ``V_hat`` bins, impossible children, ties."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
import torch

from torchhrc.solvers.sarsop import SARSOPConfig, sarsop
from torchhrc.solvers.sarsop.bins import _Bins
from torchhrc.solvers.sarsop.search import _SARSOP
from torchhrc.tasks.classic import rock_sample, tag
from torchhrc.testing import random_momdp


def _bins() -> _Bins:
    # two observed values: x=0 corners in [0, 10], x=1 corners in [100, 110]; Y = 2
    corner = np.array([[0.0, 10.0], [100.0, 110.0]])
    return _Bins(corner, math.log(2.0), 10)  # levels of 5 and 10 bins per axis


def test_bins_levels_and_alone_predicts_upper():
    bins = _bins()
    assert bins.sizes == (5, 10)
    b = np.array([0.5, 0.5])  # initial upper bound 5.0 (x=0), entropy log 2 (top bin)
    bins.update(7, 0, b, math.log(2.0), upper=9.0, lower=2.0)
    # alone in its bin: predicted at its upper bound (APPL: a new node is explored)
    assert bins.predict(7, upper=9.0, lower=2.0) == 9.0
    bins.update(8, 0, b, math.log(2.0), upper=8.0, lower=4.0)
    # two beliefs in the same bin: the mean of their lower bounds, 3.0, within [lower, upper]
    assert bins.predict(7, upper=9.0, lower=2.0) == pytest.approx(3.0)
    assert bins.predict(8, upper=8.0, lower=4.0) == pytest.approx(4.0)  # clamped to lower
    assert bins.predict(7, upper=2.5, lower=2.0) == pytest.approx(2.5)  # clamped to upper
    # an update replaces the belief's entry (one per distinct belief, not per visit)
    bins.update(7, 0, b, math.log(2.0), upper=9.0, lower=6.0)
    assert bins.predict(8, upper=8.0, lower=0.0) == pytest.approx(5.0)
    counts = [sum(c[1] for (x, _, _), c in level.items() if x == 0) for level in bins.cells]
    assert counts == [2, 2]
    # never binned: its upper bound
    assert bins.predict(99, upper=1.5, lower=0.0) == 1.5


class _ReferenceBins:
    """The ``V_hat`` rule written plainly, a dict per belief and per bin (the bins' storage
    before they moved to flat arrays): each bin holds the sum of its beliefs' latest lower
    bounds, their count, and the sum of their latest squared errors, an error measured
    against the bin's mean before the update (against the upper bound for a bin's first
    belief, and a bin left with one belief restarts its sum at that one's error)."""

    def __init__(self, corner: np.ndarray, max_entropy: float, n: int) -> None:
        self.corner, self.max_entropy = corner, max_entropy
        self.sizes = ((n + 1) // 2, n)
        self.bins: dict[tuple, dict[str, float]] = {}
        self.beliefs: dict[int, dict] = {}

    def update(self, key, x, belief, entropy, upper, lower) -> None:
        me = self.beliefs.get(key)
        if me is None:
            u0 = float(self.corner[x] @ belief)
            lo, span = self.corner[x].min(), self.corner[x].max() - self.corner[x].min()
            me = self.beliefs[key] = {"bins": [], "err2": [], "lower": lower}
            for lv, k in enumerate(self.sizes):
                i = int(min(k - 1, max(0.0, (u0 - lo) / span * k)))
                j = int(min(k - 1, max(0.0, entropy / self.max_entropy * k)))
                b = self.bins.setdefault((lv, x, i, j), {"sum": 0.0, "n": 0, "sq": 0.0})
                err = upper - lower if b["n"] == 0 else b["sum"] / b["n"] - lower
                b["sq"] += err * err
                b["sum"] += lower
                b["n"] += 1
                me["bins"].append(b)
                me["err2"].append(err * err)
            return
        for lv, b in enumerate(me["bins"]):
            if b["n"] == 1:
                err = upper - lower
                b["sq"] = err * err
            else:
                err = b["sum"] / b["n"] - lower
                b["sq"] += err * err - me["err2"][lv]
            me["err2"][lv] = err * err
            b["sum"] += lower - me["lower"]
        me["lower"] = lower

    def predict(self, key, upper, lower) -> float:
        me = self.beliefs.get(key)
        if me is None or me["bins"][0]["n"] <= 1:
            return upper
        coarse, fine = me["bins"]
        b = fine if fine["sq"] + 1e-10 < coarse["sq"] else coarse
        return min(upper, max(lower, b["sum"] / b["n"]))


def test_bins_predict_as_the_plain_rule_over_a_long_run():
    """Thousands of updates and predictions of beliefs at three observed values, most of them
    updated many times: the bins' predictions equal the plain rule's (the same arithmetic),
    and the beliefs fall in many bins of both levels (the test is not one bin's)."""
    rng = np.random.default_rng(3)
    corner = rng.random((3, 4)) * 10.0
    bins, ref = _Bins(corner, math.log(4.0), 10), _ReferenceBins(corner, math.log(4.0), 10)
    beliefs = rng.dirichlet(np.full(4, 0.3), 300)
    entropy = [float(-(b[b > 0] * np.log(b[b > 0])).sum()) for b in beliefs]
    for key in rng.integers(0, 300, 6000).tolist():
        x = key % 3
        lower = float(rng.normal(5.0, 2.0))
        upper = lower + float(rng.random()) * 3.0
        assert bins.predict(key, upper, lower) == ref.predict(key, upper, lower)
        bins.update(key, x, beliefs[key], entropy[key], upper, lower)
        ref.update(key, x, beliefs[key], entropy[key], upper, lower)
    assert bins.predict(10**6, 1.0, 0.0) == 1.0  # never binned
    assert min(len(level) for level in bins.cells) >= 20
    assert len(ref.beliefs) == 300


def test_bins_are_per_observed_value_and_fixed_by_the_initial_upper_bound():
    bins = _bins()
    b = np.array([0.5, 0.5])
    bins.update(1, 0, b, math.log(2.0), upper=9.0, lower=2.0)
    # the same belief under x=1 (initial upper bound 105, the middle of x=1's range) lands in
    # x=1's own bins, so it does not count as a neighbour of node 1
    bins.update(2, 1, b, math.log(2.0), upper=104.0, lower=100.0)
    assert bins.predict(1, upper=9.0, lower=2.0) == 9.0
    assert bins.predict(2, upper=104.0, lower=100.0) == 104.0
    cell0 = bins.where(1)
    assert cell0 == bins.where(2)  # same relative position within each x's range
    # the bin does not move when the belief's upper bound falls later
    bins.update(1, 0, b, math.log(2.0), upper=3.0, lower=2.5)
    assert bins.where(1) == cell0
    # the finer level is chosen where its error is smaller: two beliefs share the coarse bin
    # of (ub 0.0..2.0) but not the fine one
    lo = np.array([1.0, 0.0])  # initial upper 0.0, entropy 0: coarse (0, 0), fine (0, 0)
    mid = np.array([0.85, 0.15])  # initial upper 1.5: coarse (0, j), fine (1, j)
    h = -(0.85 * math.log(0.85) + 0.15 * math.log(0.15))
    bins.update(10, 0, lo, 0.0, upper=1.0, lower=0.0)
    bins.update(11, 0, lo, 0.0, upper=1.0, lower=0.2)
    assert bins.predict(10, upper=1.0, lower=0.0) == pytest.approx(0.1)
    assert bins.where(10) == [(0, 0), (0, 0)]
    bins.update(12, 0, mid, h, upper=2.0, lower=1.0)
    assert bins.where(12)[0][0] == 0 and bins.where(12)[1][0] == 1
    assert bins.where(13) is None and bins.where(10**6) is None  # never binned


def _solver(model) -> _SARSOP:
    return _SARSOP(model, SARSOPConfig(time_limit=1e9, max_iterations=5), time.perf_counter())


@pytest.mark.parametrize("make", [lambda: tag(), lambda: rock_sample(4, 4, form="momdp")])
def test_impossible_children_take_the_best_vector_at_the_parent_belief(make):
    """APPL's rule (``BackupAlphaPlaneMOMDP::getNewAlphaPlaneQ``, a ``NULL`` edge): the vector
    a backup uses at a child of probability 0 is the best vector of the child's ``x2`` at the
    parent belief; checked against a brute-force argmax, in the numpy and the torch path."""
    solver = _solver(make())
    solver.run()  # some vectors to choose from
    tree, form = solver.tree, solver.form
    n = solver.alphas.size
    vec = solver.alphas.vectors[:n].numpy()
    obs = solver.alphas.observed[:n].numpy()
    checked = 0
    for node in range(min(tree.size, 40)):
        x = int(tree.x[node])
        b = tree.beliefs_np[node]
        ch = form.children_np(x, b)
        possible = np.zeros(ch.child_x.shape[0], dtype=bool)
        possible[ch.nz] = True
        best = solver._impossible_best_np(x, b, ch.child_x, possible)
        imp = np.setdiff1d(np.arange(ch.child_x.shape[0]), ch.nz)
        for c in imp.tolist():
            x2 = int(ch.child_x[c])
            scores = np.where(obs == x2, vec @ b, -np.inf)
            assert scores[best[c]] == pytest.approx(scores.max(), abs=1e-12)
            checked += 1
        # the torch path gives the same vectors (batched over beliefs)
        xs, J = form.expand(x, tree.beliefs[node].unsqueeze(0))
        shape = tuple(J.shape[:4])
        got = solver._impossible_best(tree.beliefs[node].unsqueeze(0), xs, shape).numpy()
        for c in imp.tolist():
            assert vec[got[c]] @ b == pytest.approx(vec[best[c]] @ b, abs=1e-12)
    assert checked > 0


def test_tie_break_first_takes_the_lowest_action_and_is_validated():
    solver = _SARSOP(random_momdp(2, 3, 3, 2, discount=0.9, seed=1),
                     SARSOPConfig(tie_break="first"), time.perf_counter())  # fmt: skip
    q = np.array([1.0, 3.0, 3.0, 3.0 - 1e-15, 2.0])
    assert all(solver._argmax_tie(q) == 1 for _ in range(20))
    rnd = _SARSOP(random_momdp(2, 3, 3, 2, discount=0.9, seed=1), SARSOPConfig(seed=3),
                  time.perf_counter())  # fmt: skip
    assert {rnd._argmax_tie(q) for _ in range(60)} == {1, 2, 3}
    with pytest.raises(ValueError, match="tie_break"):
        SARSOPConfig(tie_break="last")  # type: ignore[arg-type]


def test_tie_break_first_solve_is_deterministic_and_brackets():
    model = random_momdp(3, 4, 3, 2, discount=0.9, seed=5)
    cfg = SARSOPConfig(time_limit=1e9, max_iterations=30, tie_break="first", explore_after=None)
    a, b = sarsop(model, cfg), sarsop(model, SARSOPConfig(time_limit=1e9, max_iterations=30,
                                                          tie_break="first", seed=9,
                                                          explore_after=None))  # fmt: skip
    # the seed only draws among ties, which "first" never does, and among near-equal
    # children once the lower bound stalls, which explore_after=None never does
    assert a.lower == b.lower and a.upper == b.upper
    assert a.lower <= a.upper
    assert torch.equal(a.policy.alphas, b.policy.alphas)


def test_child_draw_takes_the_children_within_the_share_of_the_largest_excess():
    """After a stall a trial draws its child uniformly among the possible children whose
    excess gap ``(up - low) - target * P`` is at least ``explore_within`` times the largest;
    where no excess is above 0 it takes the deterministic choice."""
    solver = _SARSOP(random_momdp(2, 3, 3, 2, discount=0.9, seed=1),
                     SARSOPConfig(seed=4), time.perf_counter())  # fmt: skip
    prob = np.array([[0.2, 0.2, 0.0], [0.2, 0.2, 0.2]])
    gap = np.array([[1.02, 0.97, 5.0], [0.52, 0.94, 0.93]])  # (1, 2) is impossible: P = 0
    low = np.zeros_like(gap)
    target = 0.1  # excess: 1.0, 0.95, -, 0.5, 0.92, 0.91
    draws = {solver._child_draw(prob, gap, low, target)[:2] for _ in range(300)}
    assert draws == {(0, 0), (0, 1), (1, 1), (1, 2)}  # 0.9 of 1.0: not (1, 0), not P = 0
    k, o, p = solver._child_draw(prob, gap, low, target)
    assert p == prob[k, o]
    strict = _SARSOP(random_momdp(2, 3, 3, 2, discount=0.9, seed=1),
                     SARSOPConfig(seed=4, explore_within=1.0), time.perf_counter())  # fmt: skip
    assert {strict._child_draw(prob, gap, low, target)[:2] for _ in range(50)} == {(0, 0)}
    shut = np.full_like(gap, 0.01)  # every excess <= 0: the first possible child, as before
    assert solver._child_draw(prob, shut, low, target) == solver._child_choice(
        prob, shut, low, target) == (0, 0, 0.2)  # fmt: skip


def test_trials_draw_only_after_explore_after_trials_without_a_rise():
    """The count of trials that drew their children, recomputed from the history: a trial
    draws once the lower bound at the start has not risen over the ``explore_after`` trials
    before it. Same seed, same solve."""
    model = rock_sample(4, 4, form="momdp")
    for after in (3, 8):
        cfg = SARSOPConfig(time_limit=1e9, max_iterations=60, explore_after=after, seed=2)
        sol = sarsop(model, cfg)
        lows = [e["lower"] for e in sol.history]  # entry 0: before the first trial
        stall, expected = 0, 0
        for t in range(1, len(lows)):
            expected += stall >= after  # trial t starts after t - 1 recorded iterations
            rose = lows[t] > max(lows[:t]) + 1e-9 * max(1.0, abs(lows[t]))
            stall = 0 if rose else stall + 1
        assert sol.info["explored_trials"] == expected > 0
        again = sarsop(model, cfg)
        assert (again.lower, again.upper) == (sol.lower, sol.upper)
    never = sarsop(model, SARSOPConfig(time_limit=1e9, max_iterations=60, explore_after=None))
    assert never.info["explored_trials"] == 0

    # the draw steers the trials: with ties among actions taken first, the seed then
    # changes the search only where the trials draw their children
    def runs(after):
        configs = [SARSOPConfig(time_limit=1e9, max_iterations=40, explore_after=after,
                                tie_break="first", seed=seed) for seed in range(4)]  # fmt: skip
        solved = [sarsop(model, config) for config in configs]
        return {(s.lower, s.upper, s.info["n_beliefs"]) for s in solved}

    assert len(runs(None)) == 1 and len(runs(0)) > 1


def test_explore_after_auto_draws_on_wide_beliefs_only(monkeypatch):
    """``explore_after="auto"`` (the default) resolves by the beliefs' width: never below
    ``EXPLORE_MIN_WIDTH`` entries (RockSample(4,4) as a MOMDP: 16 hidden values), and
    ``EXPLORE_AFTER`` trials at or above it (the same model with the threshold lowered to
    16): then the solve is the one of ``explore_after=EXPLORE_AFTER`` given explicitly."""
    from torchhrc.solvers.sarsop import search
    from torchhrc.solvers.sarsop.config import EXPLORE_AFTER, EXPLORE_MIN_WIDTH

    assert (EXPLORE_AFTER, EXPLORE_MIN_WIDTH) == (10, 10_000)  # the documented defaults
    model = rock_sample(4, 4, form="momdp")

    def solve(**kw):
        cfg = SARSOPConfig(time_limit=1e9, max_iterations=60, seed=2, **kw)
        sol = sarsop(model, cfg)
        return sol.info["explore_after"], sol.info["explored_trials"], sol.lower, sol.upper

    narrow = solve()
    assert narrow[:2] == (None, 0) and narrow == solve(explore_after=None)
    monkeypatch.setattr(search, "EXPLORE_MIN_WIDTH", 16)
    wide = solve()
    assert wide[0] == EXPLORE_AFTER and wide[1] > 0
    assert wide == solve(explore_after=EXPLORE_AFTER)
    monkeypatch.setattr(search, "EXPLORE_MIN_WIDTH", 17)
    assert solve()[:2] == (None, 0)


def test_trials_near_discount_one_run_past_a_thousand_steps():
    """Identity moves and one observation: every child of b0 is b0 again, and the value is
    the best fixed action's, ``max_a b0 . R_a / (1 - g)``. At discount 0.9999 a trial ends by
    its targets (``U <= max(U_t, L + eps g^-t)`` with ``eps = gap / 2``) after about
    ``ln(2) / (1 - g)`` = 6,932 steps; the former cap of 1,000 steps cut it short."""
    from torchhrc.pomdp import POMDP

    S, A, g = 3, 2, 0.9999
    R = torch.tensor([[1.0, 0.0, 2.0], [0.5, 1.5, 0.5]], dtype=torch.float64)
    b0 = torch.tensor([0.2, 0.5, 0.3], dtype=torch.float64)
    model = POMDP(T=torch.eye(S, dtype=torch.float64).expand(A, S, S).clone(),
                  Z=torch.ones(A, S, 1, dtype=torch.float64), R=R, b0=b0,
                  discount=g)  # fmt: skip
    sol = sarsop(model, SARSOPConfig(time_limit=1e9, precision=1e-3, max_iterations=1))
    # by hand: b0 . R_0 = 0.2 + 0.6 = 0.8, b0 . R_1 = 0.1 + 0.75 + 0.15 = 1.0
    best = float((R @ b0).max()) / (1.0 - g)
    assert best == pytest.approx(10_000.0)
    assert sol.info["n_beliefs"] > 6_000  # one trial, a node a step
    assert sol.lower - 1e-6 <= best <= sol.upper + 1e-6


class _TorchCalls(torch.overrides.TorchFunctionMode):
    """The names of the torch functions and tensor methods called while active."""

    def __init__(self) -> None:
        super().__init__()
        self.names: set[str] = set()

    def __torch_function__(self, func, types, args=(), kwargs=None):  # type: ignore[no-untyped-def]
        self.names.add(getattr(func, "__name__", str(func)))
        return func(*args, **(kwargs or {}))


#: what a small dense CPU solve may still call: metadata (shape, dtype and device getters,
#: ``dim``, ``numel``, ``is_floating_point``) and the numpy view of a tensor (no kernel)
_NO_KERNEL = {"__get__", "dim", "numel", "is_floating_point", "numpy"}


@pytest.mark.skipif(
    __import__("torchhrc.solvers.backup_kernel", fromlist=["load"]).load() is None,
    reason="the compiled kernels are not built (TORCHHRC_NO_EXTENSION or no compiler)",
)
@pytest.mark.parametrize("kind", ["tiger", "pomdp 0", "pomdp 1", "momdp", "static momdp"])
def test_small_dense_cpu_solve_runs_no_torch_kernel(kind):
    """A small dense model's whole SARSOP solve on the CPU (flat, and a MOMDP with a moving
    or a static hidden value), from the model to the policy, reads and makes its tensors
    through numpy (torchhrc._host): each first call of a libtorch operation maps that
    kernel's code into the process (Tiger's net peak was 13.8 MB, three times APPL's whole
    process; docs/benchmarks.md, "A small solve without libtorch's kernels")."""
    from torchhrc.tasks.classic import tiger
    from torchhrc.testing import random_pomdp

    model = {
        "tiger": tiger,
        "pomdp 0": lambda: random_pomdp(12, 3, 4, seed=0),
        "pomdp 1": lambda: random_pomdp(12, 3, 4, seed=1),
        "momdp": lambda: random_momdp(4, 3, 3, 3, seed=2, static=False),
        "static momdp": lambda: random_momdp(4, 3, 3, 3, seed=3, static=True),
    }[kind]()
    calls = _TorchCalls()
    with calls:
        sol = sarsop(model, SARSOPConfig(max_iterations=40, time_limit=600))
    assert sol.info["iterations"] == 40 or sol.info["stop_reason"] == "precision"
    assert sol.info["backups"] > 100 and sol.info["n_points"] > 0
    assert calls.names <= _NO_KERNEL, sorted(calls.names - _NO_KERNEL)
