"""An independent reference for the default clustering method (issue 16.1).

``fit_mixture``'s default is: one cluster label per subject (``unit="auto"`` on a
``Demonstrations``), k-means++ partitions as the starting point, a smoothed M-step from that
partition, em-EM (``short_iterations`` of soft EM for every restart, then the restart of each
k with the best log-likelihood runs to convergence), soft EM with a Dirichlet pseudo-count
``alpha = 0.1`` on every transition and ``beta = 1`` on every cluster size, the larger of the
k chosen by BIC (``k A (A - 1) + k - 1`` free parameters, ``n`` = the number of subjects) and
by the exact ICL (the hard partition of each k's final parameters scored with Dirichlet(1/2)
transition rows and Dirichlet(1) weights integrated out), and the ``min_gain`` rule (the
smallest k whose next k gains less than 0.015 nats per transition). The split and merge
restarts that follow the em-EM by default (``split_merge=True``) are turned off here and
checked on their own in ``tests/mixture/test_runs.py``.

The reference below re-implements all of it in plain Python (lists, ``math``, loops over
subjects, sequences, steps, clusters and symbols; no torch, no batching, no deduplication of
identical units, nothing from ``torchhrc.mixture``). Its only input from the library is the
k-means++ partition, passed explicitly (a random starting point, not part of the M-step).
The constants of the default are written here as numbers, so a changed default or a wrong
M-step shows as a disagreement.
"""

import math

import pytest
import torch

import torchhrc.mixture.runs as runs
import torchhrc.mixture.selection as selection
from torchhrc.mixture import fit_mixture, kmeans_pp_init, sufficient_statistics
from torchhrc.mixture.soft_em import soft_em
from torchhrc.tasks.place_and_drill import simulate_study

ALPHA = 0.1  # transition pseudo-count of the default
BETA = 1.0  # cluster-size pseudo-count of the default
MIN_GAIN = 0.015  # nats per transition
JEFFREYS = 0.5  # Dirichlet concentration of every transition row in the exact ICL
TOL = 1e-6  # relative log-likelihood change that ends a run
SHORT = 5  # em-EM short iterations
CAP = 200  # iteration cap


# ----------------------------------------------------------------------------- reference
def units_of(sequences, subjects):
    """Group the sequences by subject, in order of first appearance: ``[[seq, ...], ...]``."""
    order, groups = [], {}
    for seq, subject in zip(sequences, subjects):
        if subject not in groups:
            groups[subject] = []
            order.append(subject)
        groups[subject].append(seq)
    return [groups[s] for s in order], order


def unit_counts(unit, A):
    """``n[a][b]`` transitions of all sequences of one unit."""
    n = [[0.0] * A for _ in range(A)]
    for seq in unit:
        for j in range(1, len(seq)):
            n[seq[j - 1]][seq[j]] += 1.0
    return n


def m_step(units, resp, k, A):
    """MAP M-step: ``theta_k(b|a) = (sum_u r_uk n_u(a,b) + alpha) / (sum_u r_uk n_u(a) + A alpha)``,
    ``w_k = (sum_u r_uk + beta) / (U + k beta)``."""
    theta, weights = [], []
    U = len(units)
    for c in range(k):
        n = [[0.0] * A for _ in range(A)]
        for u, unit in enumerate(units):
            for seq in unit:
                for j in range(1, len(seq)):
                    n[seq[j - 1]][seq[j]] += resp[u][c]
        rows = []
        for a in range(A):
            total = sum(n[a]) + A * ALPHA
            rows.append([(n[a][b] + ALPHA) / total for b in range(A)])
        theta.append(rows)
        weights.append((sum(resp[u][c] for u in range(U)) + BETA) / (U + k * BETA))
    return theta, weights


def e_step(units, theta, weights):
    """Responsibilities ``r[u][k]`` and the marginal log-likelihood
    ``sum_u log sum_k w_k P(x_u | k)``."""
    k = len(weights)
    resp, total = [], 0.0
    for unit in units:
        joint = []
        for c in range(k):
            lp = math.log(weights[c])
            for seq in unit:
                for j in range(1, len(seq)):
                    lp += math.log(theta[c][seq[j - 1]][seq[j]])
            joint.append(lp)
        top = max(joint)
        mass = sum(math.exp(v - top) for v in joint)
        lse = top + math.log(mass)
        total += lse
        resp.append([math.exp(v - lse) for v in joint])
    return resp, total


def em(units, theta, weights, max_iterations):
    """Soft EM until ``|l_t - l_{t-1}| <= tol |l_t|`` or the cap; returns the last parameters,
    their log-likelihood and the iterations."""
    A = len(theta[0])
    resp, ll = e_step(units, theta, weights)
    iterations = 0
    while iterations < max_iterations:
        iterations += 1
        theta, weights = m_step(units, resp, len(weights), A)
        resp, new = e_step(units, theta, weights)
        done = abs(new - ll) <= TOL * abs(new)
        ll = new
        if done:
            break
    return theta, weights, ll, iterations


def exact_icl(units, resp, k, A):
    """``log p(D, z)`` of the hard partition ``z_u = argmax_c r[u][c]`` (first maximum), the
    transition rows (Dirichlet(1/2)) and weights (Dirichlet(1)) integrated out, written as
    sequential predictive probabilities: every transition ``a -> b`` of cluster ``c``, in
    turn, has probability ``(n_c(a, b) + 1/2) / (n_c(a) + A / 2)`` given the ones before it,
    and every unit joins cluster ``c`` with probability ``(m_c + 1) / (m + k)``."""
    z = [row.index(max(row)) for row in resp]
    n = [[[0.0] * A for _ in range(A)] for _ in range(k)]
    m = [0.0] * k
    total = 0.0
    for u, unit in enumerate(units):
        c = z[u]
        total += math.log((m[c] + 1.0) / (sum(m) + k))
        m[c] += 1.0
        for seq in unit:
            for j in range(1, len(seq)):
                a, b = seq[j - 1], seq[j]
                total += math.log((n[c][a][b] + JEFFREYS) / (sum(n[c][a]) + A * JEFFREYS))
                n[c][a][b] += 1.0
    return total


def reference_fit(
    sequences,
    subjects,
    A,
    ks,
    restarts,
    partitions,
    min_gain=MIN_GAIN,
    criterion="bic_or_exact_icl",
):
    """The default ``fit_mixture`` in loops. ``partitions[(k, restart)]``: the starting
    cluster of every unit. Returns the selected k, its parameters and responsibilities
    (clusters by decreasing size), its log-likelihood, and per-k BIC and log-likelihood."""
    units, _ = units_of(sequences, subjects)
    U = len(units)
    T = sum(len(s) - 1 for s in sequences)
    best = {}
    for k in ks:
        short = []
        for r in range(restarts):
            z = partitions[(k, r)]
            hard = [[1.0 if z[u] == c else 0.0 for c in range(k)] for u in range(U)]
            theta, weights = m_step(units, hard, k, A)
            short.append(em(units, theta, weights, min(SHORT, CAP)))
        lls = [s[2] for s in short]
        pick = lls.index(max(lls))  # the first best restart
        theta, weights, ll, _ = em(units, short[pick][0], short[pick][1], CAP)
        params = k * A * (A - 1) + (k - 1)
        best[k] = dict(theta=theta, weights=weights, ll=ll, bic=ll - params / 2 * math.log(U))
        best[k]["exact_icl"] = exact_icl(units, e_step(units, theta, weights)[0], k, A)
    names = ("bic", "exact_icl") if criterion == "bic_or_exact_icl" else (criterion,)
    by_bic = max(max(ks, key=lambda k: (best[k][c], -k)) for c in names)
    chosen = by_bic
    for k in ks:
        if k >= by_bic:
            break
        if (best[k + 1]["ll"] - best[k]["ll"]) / T < min_gain:
            chosen = k
            break
    theta, weights = best[chosen]["theta"], best[chosen]["weights"]
    resp, ll = e_step(units, theta, weights)
    sizes = [sum(resp[u][c] for u in range(U)) for c in range(chosen)]
    order = sorted(range(chosen), key=lambda c: (-sizes[c], c))
    return dict(
        k=chosen,
        theta=[theta[c] for c in order],
        weights=[weights[c] for c in order],
        resp=[[row[c] for c in order] for row in resp],
        ll=ll,
        bic=best[chosen]["bic"],
        per_k=best,
    )


# ----------------------------------------------------------------------------- harness
def _study(seed):
    # 8 subjects x 3 demonstrations, 2 positions (A = 6), noisy: some subjects share rows,
    # others not, so deduplication and grouping are both exercised
    return simulate_study(n_subjects=8, n_demos=3, n_positions=2, noise=(0.0, 0.3), seed=seed)


def _partitions(demos, ks, restarts, seed):
    """The k-means++ partitions ``fit_mixture`` starts from, per unit (subject)."""
    _, order = units_of(demos.to_lists(), demos.subjects)
    index = {s: i for i, s in enumerate(order)}
    groups = torch.tensor([index[s] for s in demos.subjects])
    stats = sufficient_statistics(demos.sequences, demos.lengths, demos.num_symbols, groups=groups)
    run_k = torch.tensor(ks).repeat_interleave(restarts)
    mask = torch.arange(max(ks)) < run_k[:, None]
    z = kmeans_pp_init(stats, mask, generator=torch.Generator().manual_seed(seed))  # (U', R)
    first = {}
    for n, s in enumerate(demos.subjects):
        first.setdefault(s, n)
    row = [int(stats.inverse[first[s]]) for s in order]
    return {
        (k, r): [int(z[row[u], i * restarts + r]) for u in range(len(order))]
        for i, k in enumerate(ks)
        for r in range(restarts)
    }


def _symbols(demos):
    return [demos.sequences[n, : int(demos.lengths[n])].tolist() for n in range(len(demos))]


def _compare(demos, seed, ks=(2, 3, 4), restarts=3, **options):
    ref = reference_fit(
        _symbols(demos),
        demos.subjects,
        demos.num_symbols,
        list(ks),
        restarts,
        _partitions(demos, list(ks), restarts, seed),
        **{k: v for k, v in options.items() if k != "objects"},
    )
    options.setdefault("objects", "raw")  # the automatic choice: test_auto_objects_* below
    # the reference implements this rule (the soft default before issue 31; the default
    # "icl_or_gain" adds held-out folds: tests/mixture/test_selection.py)
    options.setdefault("criterion", "bic_or_exact_icl")
    options.setdefault("split_merge", False)  # not in the reference: tests/mixture/test_runs.py
    with pytest.MonkeyPatch.context() as patch:  # nor the exact-ICL refinement: test_refine.py
        patch.setattr(selection, "refine_partition", lambda stats, z, k, **kw: z)
        # nor the split restarts of a k fitted below k - 1: test_runs.py
        patch.setattr(runs, "_split_where_worse", lambda stats, result, mask, em: result)
        fit = fit_mixture(demos, k_min=ks[0], k_max=ks[-1], restarts=restarts, seed=seed,
                          **options)  # fmt: skip
    assert fit.k == ref["k"]
    torch.testing.assert_close(
        fit.model.transition, torch.tensor(ref["theta"], dtype=torch.float64), atol=1e-10, rtol=0
    )
    torch.testing.assert_close(
        fit.model.weights, torch.tensor(ref["weights"], dtype=torch.float64), atol=1e-10, rtol=0
    )
    assert fit.log_likelihood == pytest.approx(ref["ll"], abs=1e-10, rel=1e-13)
    _, order = units_of(demos.to_lists(), demos.subjects)
    unit = {s: i for i, s in enumerate(order)}
    resp = torch.tensor([ref["resp"][unit[s]] for s in demos.subjects], dtype=torch.float64)
    torch.testing.assert_close(fit.responsibilities, resp, atol=1e-10, rtol=0)
    for k in ks:
        assert fit.per_k[k]["log_likelihood"] == pytest.approx(
            ref["per_k"][k]["ll"], abs=1e-10, rel=1e-13
        )
        assert fit.per_k[k]["bic"] == pytest.approx(ref["per_k"][k]["bic"], abs=1e-10, rel=1e-13)
        assert fit.per_k[k]["exact_icl"] == pytest.approx(
            ref["per_k"][k]["exact_icl"], abs=1e-9, rel=1e-12
        )
    return fit


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_default_fit_equals_the_loop_reference(seed):
    demos = _study(seed)
    fit = _compare(demos, seed)
    assert fit.responsibilities.shape == (demos.num_sequences, fit.k)


@pytest.mark.parametrize("criterion", ["bic", "exact_icl"])
def test_each_criterion_alone_equals_the_loop_reference(criterion):
    for seed in (4, 5):
        _compare(_study(seed), seed, criterion=criterion, min_gain=0.0)


def _three_chains(seed, subjects=20, demos=2, length=8, A=3):
    """Three chains over ``A`` symbols (step +1, step -1, stay), 10% uniform noise, two
    demonstrations per subject: BIC finds the three."""
    from torchhrc.data import Demonstrations

    g = torch.Generator().manual_seed(seed)
    rows, subject_ids = [], []
    for s in range(subjects):
        step = (1, -1, 0)[s % 3]
        for _ in range(demos):
            x = [int(torch.randint(0, A, (1,), generator=g))]
            for _ in range(length - 1):
                noisy = float(torch.rand(1, generator=g)) < 0.1
                x.append(
                    int(torch.randint(0, A, (1,), generator=g)) if noisy else (x[-1] + step) % A
                )
            rows.append([("human", f"s{v}") for v in x])
            subject_ids.append(f"S{s:02d}")
    vocabulary = [("human", f"s{v}") for v in range(A)]
    return Demonstrations.from_lists(rows, subjects=subject_ids, vocabulary=vocabulary)


def test_min_gain_rule_is_exercised_and_matches():
    """BIC picks k = 3; with ``min_gain`` just above the gain of k = 3 the rule keeps k = 2,
    and the reference follows it (both values of the option agree)."""
    demos = _three_chains(0)
    wide = _compare(demos, 0, min_gain=0.0)
    assert wide.k == 3
    narrow = _compare(demos, 0, min_gain=wide.per_k[3]["gain"] * 1.01)
    assert narrow.k == 2


def test_soft_em_iterations_equal_the_loop_reference():
    """The EM kernel alone, from given parameters, for a fixed number of iterations."""
    demos = _study(3)
    _, order = units_of(demos.to_lists(), demos.subjects)
    index = {s: i for i, s in enumerate(order)}
    groups = torch.tensor([index[s] for s in demos.subjects])
    A = demos.num_symbols
    stats = sufficient_statistics(demos.sequences, demos.lengths, A, groups=groups)
    g = torch.Generator().manual_seed(0)
    k = 3
    theta0 = torch.rand(1, k, A, A, generator=g, dtype=torch.float64) + 0.05
    theta0 = theta0 / theta0.sum(-1, keepdim=True)
    w0 = torch.tensor([[0.5, 0.3, 0.2]], dtype=torch.float64)
    units, _ = units_of(_symbols(demos), demos.subjects)
    theta, weights = theta0[0].tolist(), w0[0].tolist()
    resp, ll = e_step(units, theta, weights)
    for t in range(1, 6):
        theta, weights = m_step(units, resp, k, A)
        resp, ll = e_step(units, theta, weights)
        res = soft_em(
            stats,
            theta0.log(),
            w0.log(),
            torch.ones(1, k, dtype=torch.bool),
            pseudo_count=ALPHA,
            weight_pseudo_count=BETA,
            max_iterations=t,
            tol=0.0,
        )
        assert int(res.iterations[0]) == t
        torch.testing.assert_close(
            res.log_transition[0].exp(),
            torch.tensor(theta, dtype=torch.float64),
            atol=1e-10,
            rtol=0,
        )
        torch.testing.assert_close(
            res.log_weights[0].exp(), torch.tensor(weights, dtype=torch.float64), atol=1e-10, rtol=0
        )
        assert float(res.log_likelihood[0]) == pytest.approx(ll, abs=1e-10, rel=1e-13)


@pytest.mark.parametrize(
    "name, value",
    [
        ("DEFAULT_PSEUDO_COUNT", 0.5),
        ("DEFAULT_PSEUDO_COUNT", 0.02),
        ("DEFAULT_WEIGHT_PSEUDO_COUNT", 0.0),
        ("DEFAULT_WEIGHT_PSEUDO_COUNT", 3.0),
    ],
)
def test_a_wrong_default_prior_is_caught(monkeypatch, name, value):
    """The comparison fails when the library's M-step uses other pseudo-counts than the
    reference's 0.1 and 1 (the mutation of issue 16.1)."""
    monkeypatch.setattr(selection, name, value)
    with pytest.raises(AssertionError):
        _compare(_study(0), 0)


# ----------------------------------------------------------------------------- objects="auto"
def reference_relabel(steps):
    """Objects of ``verb_object`` actions renamed 1, 2, ... by first use, sequence by sequence."""
    out = []
    for seq in steps:
        names, new = {}, []
        for actor, action in seq:
            verb, sep, obj = action.rpartition("_")
            if sep and verb and obj:
                names.setdefault(obj, str(len(names) + 1))
                new.append((actor, f"{verb}_{names[obj]}"))
            else:
                new.append((actor, action))
        out.append(new)
    return out


def reference_multiplicity(seq, objects):
    """How many sequences relabel to the same form as ``seq`` with the same first step: every
    injective renaming of its objects into ``objects``, counted by enumeration."""
    import itertools

    relabelled = reference_relabel([seq])[0]
    count = 0
    for image in itertools.permutations(objects, len({a.rpartition("_")[2] for _, a in
                                                      relabelled if "_" in a})):  # fmt: skip
        renamed = [
            (actor, f"{a.rpartition('_')[0]}_{image[int(a.rpartition('_')[2]) - 1]}")
            if "_" in a
            else (actor, a)
            for actor, a in relabelled
        ]
        count += renamed[0] == seq[0]
    return count


def _indexed(steps):
    """Symbol indices over the canonical vocabulary (human first, action names sorted)."""
    vocab = sorted({s for seq in steps for s in seq}, key=lambda s: (s[0] != "human", s[1]))
    return [[vocab.index(s) for s in seq] for seq in steps], len(vocab)


@pytest.mark.parametrize("seed", [3, 4])
def test_auto_objects_equals_the_loop_reference(seed):
    """``objects="auto"``: the reference fits the recorded symbols and the relabelled ones (in
    loops), subtracts from the latter's scores the log of the number of injections counted by
    enumeration, and keeps the form whose selected partition has the larger exact ICL; the
    library agrees on the form, k, the parameters and the comparison (BIC and exact ICL)."""
    from torchhrc.data import Demonstrations

    sim = simulate_study(n_subjects=9, n_demos=3, n_positions=3, noise=0.1, robot_noise=0.1,
                         order_change=1.0, deviation="uniform",
                         strategies=("safe", "efficient", "lagging"), seed=seed)  # fmt: skip
    raw_steps = sim.to_lists()
    # the same corpus with every type's screws in one fixed order: positions now matter
    ordered = Demonstrations.from_lists(
        [[(a, f"{v.rpartition('_')[0]}_{'ABC'[int(v.rpartition('_')[2]) - 1]}") if "_" in v
          else (a, v) for a, v in seq] for seq in reference_relabel(raw_steps)],
        subjects=sim.subjects, sequence_ids=sim.sequence_ids, types=sim.types,
        vocabulary=sim.vocabulary,
    )  # fmt: skip
    ks, restarts = [2, 3, 4], 3
    forms = {}
    for name, demos in (("random orders", sim), ("fixed order", ordered)):
        steps = demos.to_lists()
        relabelled = reference_relabel(steps)
        shift = sum(math.log(reference_multiplicity(seq, "ABC")) for seq in steps)
        ref = {}
        for form, data in (("raw", steps), ("exchangeable", relabelled)):
            symbols, A = _indexed(data)
            lib = demos if form == "raw" else demos.relabel_objects()
            assert [[lib.vocabulary[i] for i in row] for row in _symbols(lib)] == data
            ref[form] = reference_fit(symbols, demos.subjects, A, ks, restarts,
                                      _partitions(lib, ks, restarts, seed))  # fmt: skip
        for r in ref.values():
            r["exact_icl"] = r["per_k"][r["k"]]["exact_icl"]
        ref["exchangeable"]["bic"] -= shift
        ref["exchangeable"]["exact_icl"] -= shift
        best = max(ref, key=lambda form: ref[form]["exact_icl"])
        fit = fit_mixture(demos, k_min=2, k_max=4, restarts=restarts, seed=seed,
                          criterion="bic_or_exact_icl")  # the reference's rule  # fmt: skip
        assert fit.objects == best == fit.model.objects
        assert fit.k == ref[best]["k"]
        torch.testing.assert_close(fit.model.transition,
                                   torch.tensor(ref[best]["theta"], dtype=torch.float64),
                                   atol=1e-10, rtol=0)  # fmt: skip
        for form in ref:
            compared = fit.object_comparison[form]
            assert compared["bic"] == pytest.approx(ref[form]["bic"], abs=1e-9)
            assert compared["exact_icl"] == pytest.approx(ref[form]["exact_icl"], abs=1e-8)
            assert fit.object_comparison[form]["k"] == ref[form]["k"]
        forms[name] = best
    # both forms are exercised: exchangeable for the random orders, raw for the fixed one
    assert forms == {"random orders": "exchangeable", "fixed order": "raw"}
