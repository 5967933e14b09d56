import math

import pytest
import torch

from torchhrc.data import Demonstrations
from torchhrc.errors import ModelError
from torchhrc.metrics import adjusted_rand_index
from torchhrc.mixture import (
    fit_mixture,
    num_free_parameters,
    partition_chains,
    sequence_log_likelihood,
)
from torchhrc.tasks.place_and_drill import simulate_study


@pytest.mark.slow
def test_paper_like_study_picks_two_types():
    """18 subjects x 3 demos, 3 positions, noise 0..0.15: k = 2 and ARI >= 0.95.

    Every seed picks k = 2; the ARI is 1.0 on five of these six seeds and 0.786 on seed 3,
    where a noisy "safe" subject's demonstrations look "efficient" (its three sequences are
    more likely under the efficient chain even for a model fitted to the true labels), so
    the ARI is asserted on average over the seeds.
    """
    aris = []
    for seed in range(6):
        demos = simulate_study(seed=seed)
        fit = fit_mixture(demos, seed=seed)
        assert fit.k == 2
        assert fit.assignments.shape == (54,) and fit.responsibilities.shape == (54, 2)
        aris.append(adjusted_rand_index(list(demos.types), fit.assignments.tolist()))
    assert sum(aris) / len(aris) >= 0.95
    assert sorted(aris)[1] == 1.0


@pytest.mark.slow
def test_paper_method_picks_two_types_on_paper_like_data():
    for seed in (0, 1):
        demos = simulate_study(seed=seed)
        fit = fit_mixture(demos, method="paper", seed=seed)
        assert fit.k == 2
        assert adjusted_rand_index(list(demos.types), fit.assignments.tolist()) >= 0.75
        # BIC = l - K/2 log n with the paper's K = k |A| (|A| - 1), n = 54 sequences
        A = demos.num_symbols
        assert fit.bic == pytest.approx(fit.log_likelihood - 2 * A * (A - 1) / 2 * math.log(54))
        # l is the classification log-likelihood of the returned model and partition
        ll = sequence_log_likelihood(fit.model, demos.sequences, demos.lengths)
        own = ll.gather(-1, fit.assignments[:, None]).squeeze(-1)
        own = own + fit.model.log_weights[fit.assignments]
        assert own.sum().item() == pytest.approx(fit.log_likelihood)


def _harder_study(seed):
    return simulate_study(
        n_subjects=150,
        n_demos=3,
        n_positions=4,
        strategies=("safe", "efficient", "pairs"),
        noise=0.1,
        seed=seed,
    )


def _position_abstract(demos):
    """The same demonstrations over (actor, verb) symbols: place_A, place_B, ... -> place."""
    return demos.map_actions(lambda actor, action: action.split("_")[0])


@pytest.mark.slow
def test_harder_study_default_method_finds_three_strategies():
    """The issue's harder data (3 strategies, 4 positions, 150 subjects, noise 0.1) with the
    screw positions treated as exchangeable objects (``relabel_objects``: renamed by first
    use in each sequence): the default method picks k = 3 and recovers the strategies.
    Over raw position symbols no criterion can (docs/clustering.md): every subject keeps its
    own placement order, and partitions by order explain those symbols better.
    """
    for seed in range(3):
        demos = _harder_study(seed).relabel_objects()
        assert demos.num_symbols == 10  # place_1..4, wait, drill_1..4, wait
        fit = fit_mixture(demos, seed=seed)
        assert fit.k == 3
        assert adjusted_rand_index(list(demos.types), fit.assignments.tolist()) >= 0.9


@pytest.mark.slow
def test_harder_study_position_abstract_default_finds_three_paper_finds_two():
    """The issue's harder data over (actor, verb) symbols (10 -> 4): the strategies are then
    the chains (placement orders no longer enter the symbols). The default (k-means++,
    em-EM, soft EM, BIC) picks k = 3 with ARI 1.0 on seeds 0-4; the paper's random-init
    hard EM picks k = 2 (ARI 0.57: "pairs" merged into another type) on the same data.
    """
    for seed in range(3):
        demos = _position_abstract(_harder_study(seed))
        assert demos.num_symbols == 4
        fit = fit_mixture(demos, seed=seed)
        assert fit.k == 3
        assert adjusted_rand_index(list(demos.types), fit.assignments.tolist()) >= 0.9
        paper = fit_mixture(demos, method="paper", seed=seed)
        assert paper.k == 2


@pytest.mark.parametrize("method", ["soft", "paper"])
def test_same_seed_same_result(method):
    demos = simulate_study(n_subjects=8, seed=4)
    a = fit_mixture(demos, k_max=4, restarts=5, method=method, seed=7)
    b = fit_mixture(demos, k_max=4, restarts=5, method=method, seed=7)
    assert a.k == b.k and a.per_k == b.per_k
    assert torch.equal(a.assignments, b.assignments)
    assert torch.equal(a.model.log_transition, b.model.log_transition)
    g = torch.Generator().manual_seed(7)
    c = fit_mixture(demos, k_max=4, restarts=5, method=method, generator=g)
    assert c.per_k == a.per_k


def test_fit_on_tuple_and_well_separated_chains():
    # three chains over 3 symbols with disjoint dominant transitions, 30 sequences each
    g = torch.Generator().manual_seed(0)
    N, L = 90, 10
    kind = torch.arange(N) % 3
    seqs = torch.zeros(N, L, dtype=torch.long)
    seqs[:, 0] = torch.randint(0, 3, (N,), generator=g)
    for j in range(1, L):
        step = torch.stack([seqs[:, j - 1], (seqs[:, j - 1] + 1) % 3, (seqs[:, j - 1] + 2) % 3])
        nxt = step.gather(0, kind[None]).squeeze(0)
        noise = torch.rand(N, generator=g) < 0.05
        seqs[:, j] = torch.where(noise, torch.randint(0, 3, (N,), generator=g), nxt)
    lengths = torch.full((N,), L)
    for method, criterion in (("soft", "bic"), ("soft", "icl"), ("paper", "bic")):
        fit = fit_mixture(
            (seqs, lengths, 3), k_min=1, k_max=5, restarts=4, method=method, criterion=criterion
        )
        assert fit.k == 3
        assert adjusted_rand_index(kind.tolist(), fit.assignments.tolist()) == 1.0
        assert set(fit.per_k) == {1, 2, 3, 4, 5}
        assert torch.isfinite(fit.model.log_weights).all()
        # clusters are ordered by size, responsibilities are distributions
        torch.testing.assert_close(fit.responsibilities.sum(-1), torch.ones(N, dtype=torch.float64))


def test_num_free_parameters():
    assert num_free_parameters(3, 7, method="paper") == 3 * 7 * 6
    assert num_free_parameters(3, 7) == 3 * 7 * 6 + 2
    assert num_free_parameters(3, 7, initial=True) == 3 * 7 * 6 + 2 + 3 * 6


def test_bad_arguments_are_reported():
    seqs, lengths = torch.tensor([[0, 1, 0]]), torch.tensor([3])
    with pytest.raises(ValueError, match="k_min <= k_max"):
        fit_mixture((seqs, lengths, 2), k_min=3, k_max=2)
    with pytest.raises(ValueError, match="method"):
        fit_mixture((seqs, lengths, 2), method="hard")
    with pytest.raises(ValueError, match="restarts"):
        fit_mixture((seqs, lengths, 2), restarts=0)
    with pytest.raises(TypeError, match="tuple"):
        fit_mixture((seqs, lengths))
    with pytest.raises(ModelError, match="not a symbol"):
        fit_mixture((seqs, lengths, 1))
    with pytest.raises(ValueError, match="unit='subject'"):
        fit_mixture((seqs, lengths, 2), unit="subject")
    with pytest.raises(ValueError, match="seed or generator"):
        fit_mixture((seqs, lengths, 2), seed=1, generator=torch.Generator())


def test_dtype_and_subject_units_are_respected():
    demos = simulate_study(n_subjects=6, seed=2)
    fit = fit_mixture(demos, k_max=3, restarts=3, dtype=torch.float32)
    assert fit.model.log_transition.dtype == torch.float32
    assert fit.responsibilities.dtype == torch.float32
    # unit="auto" with a Demonstrations: one cluster per subject
    for subject in set(demos.subjects):
        members = [i for i, s in enumerate(demos.subjects) if s == subject]
        assert len(set(fit.assignments[members].tolist())) == 1
    per_sequence = fit_mixture(demos, k_max=3, restarts=3, unit="sequence")
    assert per_sequence.num_distinct >= fit.num_distinct


def test_icl_or_gain_is_the_exact_icl_raised_by_steps_confirmed_out_of_sample():
    """Issue 31's default: with ``strong_gain = inf`` it is the exact ICL's choice; with
    ``strong_gain = 0`` every step above the exact ICL's k gains in the fit and on held-out
    subjects (at least ``DEFAULT_HELDOUT_GAIN`` nats per transition), and the held-out record
    is there exactly when a step above the exact ICL's k gained in the fit, for the k from the
    exact ICL's to the largest such step."""
    from torchhrc.mixture.selection import DEFAULT_HELDOUT_GAIN
    from torchhrc.tasks.suite import make_task

    demos, _ = make_task("lead_and_pace").demonstrations(subjects=16, per_subject=3, seed=1)
    common = dict(k_min=1, k_max=5, restarts=4, seed=0, initial=True)
    icl = fit_mixture(demos, criterion="exact_icl", **common)
    never = fit_mixture(demos, criterion="icl_or_gain", strong_gain=math.inf, **common)
    assert never.k == icl.k and torch.equal(never.assignments, icl.assignments)
    assert never.criterion == "icl_or_gain" and "heldout" not in never.per_k[icl.k]
    always = fit_mixture(demos, criterion="icl_or_gain", strong_gain=0.0, **common)
    T = float((demos.lengths - 1).sum())
    pk = always.per_k
    assert always.k >= icl.k
    tried = icl.k < 5 and pk[icl.k + 1]["gain"] >= 0.0  # a step above the ICL's k gains
    strong = icl.k  # the largest k every step to which gains in the fit
    while strong < 5 and pk[strong + 1]["gain"] >= 0.0:
        strong += 1
    # this corpus exercises the held-out check, cross-validated for the k the steps go
    # through only
    assert tried and {k for k in pk if "heldout" in pk[k]} == set(range(icl.k, strong + 1))
    for k in range(icl.k + 1, always.k + 1):
        assert pk[k]["gain"] >= 0.0
        assert pk[k]["heldout"] - pk[k - 1]["heldout"] >= DEFAULT_HELDOUT_GAIN * T
    assert always.k == 4 > icl.k  # two steps confirmed (measured 2026-12-04: icl 2, then 4)
    # heldout_gain is the confirmation's threshold: no step passes an infinite one, and the
    # same scores are recorded
    steps = [(pk[k]["heldout"] - pk[k - 1]["heldout"]) / T for k in (icl.k + 1, icl.k + 2)]
    refused = fit_mixture(demos, criterion="icl_or_gain", strong_gain=0.0,
                          heldout_gain=math.inf, **common)  # fmt: skip
    assert refused.k == never.k == icl.k
    assert refused.per_k[icl.k + 1]["heldout"] == pytest.approx(pk[icl.k + 1]["heldout"])
    assert steps[0] < steps[1]  # measured: 0.045 and 0.089 nats per transition
    first = fit_mixture(demos, criterion="icl_or_gain", strong_gain=0.0,
                        heldout_gain=(steps[0] + steps[1]) / 2, **common)  # fmt: skip
    assert first.k == icl.k  # the first step fails, and the steps go one by one
    with pytest.raises(ValueError, match="heldout_gain"):
        fit_mixture(demos, heldout_gain=-0.1, **common)
    assert fit_mixture(demos, **common).criterion == "icl_or_gain"  # the soft default
    # people who lead or follow by their history: a 3rd cluster gains in the fit (0.035 nats
    # per transition) but not on held-out subjects (0.006): refused
    demos, _ = make_task("lead_or_follow").demonstrations(subjects=16, per_subject=3, seed=0)
    icl = fit_mixture(demos, criterion="exact_icl", **common)
    always = fit_mixture(demos, criterion="icl_or_gain", strong_gain=0.0, **common)
    pk, T = always.per_k, float((demos.lengths - 1).sum())
    assert always.k == icl.k == 2 and pk[3]["gain"] > 0.0
    assert pk[3]["heldout"] - pk[2]["heldout"] < DEFAULT_HELDOUT_GAIN * T


def test_heldout_criterion_picks_the_smallest_k_within_one_standard_error():
    from torchhrc.tasks.suite import make_task

    # the best held-out k is 4, and 3 is within one standard error of it (measured)
    demos, _ = make_task("screws_hands_off").demonstrations(subjects=16, per_subject=3, seed=0)
    fit = fit_mixture(demos, k_min=1, k_max=4, restarts=4, seed=0, criterion="heldout",
                      min_gain=0.0)  # fmt: skip
    pk = fit.per_k
    best = max(pk, key=lambda k: pk[k]["heldout"])
    assert pk[best]["heldout_se"] == 0.0
    within = [k for k in pk if pk[k]["heldout"] - pk[best]["heldout"] >= -pk[k]["heldout_se"]]
    assert fit.k == min(within) < best and fit.criterion == "heldout"


def _one_row_apart(p=0.85, subjects=40, per_subject=4, length=120, A=6):
    """Two types of chains over ``A`` symbols (each symbol to the next two, 1/2 each) that
    differ in one row: from symbol 0 the second type goes to 1 with probability ``p``."""
    from torchhrc import Demonstrations

    g = torch.Generator().manual_seed(0)
    base = torch.zeros(A, A)
    for a in range(A):
        base[a, (a + 1) % A] = base[a, (a + 2) % A] = 0.5
    other = base.clone()
    other[0, 1], other[0, 2] = p, 1.0 - p
    rows, subject_ids, types = [], [], []
    for s in range(subjects):
        chain = base if s % 2 == 0 else other
        for _ in range(per_subject):
            x = [int(torch.randint(A, (), generator=g))]
            for _ in range(length - 1):
                x.append(int(torch.multinomial(chain[x[-1]], 1, generator=g)))
            rows.append([("human", f"s{v}") for v in x])
            subject_ids.append(f"S{s:02d}")
            types.append(s % 2)
    vocabulary = [("human", f"s{v}") for v in range(A)]
    demos = Demonstrations.from_lists(rows, subjects=subject_ids, vocabulary=vocabulary)
    return demos, types


def test_a_step_the_exact_icl_takes_and_that_splits_people_is_not_cut_by_min_gain():
    """Two types whose chains differ in one of 6 rows: the second cluster gains less than
    ``min_gain`` per transition (the rest of the chain dilutes it), but the exact ICL prefers
    it and each person's demonstrations agree on it (consistency well above 0.5): kept. With
    the consistency check off, the ``min_gain`` cut applies as before."""
    demos, types = _one_row_apart()
    common = dict(k_min=1, k_max=3, restarts=3, seed=0)
    fit = fit_mixture(demos, **common)
    pk = fit.per_k
    assert pk[2]["gain"] < 0.015 * 0.8  # well below min_gain (measured 0.0096)
    assert pk[2]["exact_icl"] > pk[1]["exact_icl"] + 20.0  # measured +86
    assert pk[2]["split_consistency"] > 0.6  # measured 0.76
    assert fit.k == 2 and adjusted_rand_index(types, fit.assignments.tolist()) == 1.0
    assert fit_mixture(demos, min_consistency=0.0, **common).k == 1  # cut by min_gain


def _sequence_level(subjects=30, per_subject=4, length=30, A=6):
    """Each demonstration, not each person, draws one of two chains (over ``A`` symbols, each
    symbol to the next two, or to the third and fourth after it, 1/2 each): two clusters of
    demonstrations that every person shares."""
    from torchhrc import Demonstrations

    g = torch.Generator().manual_seed(0)
    base, other = torch.zeros(A, A), torch.zeros(A, A)
    for a in range(A):
        base[a, (a + 1) % A] = base[a, (a + 2) % A] = 0.5
        other[a, (a + 3) % A] = other[a, (a + 4) % A] = 0.5
    rows, subject_ids = [], []
    for s in range(subjects):
        for _ in range(per_subject):
            chain = base if float(torch.rand((), generator=g)) < 0.5 else other
            x = [int(torch.randint(A, (), generator=g))]
            for _ in range(length - 1):
                x.append(int(torch.multinomial(chain[x[-1]], 1, generator=g)))
            rows.append([("human", f"s{v}") for v in x])
            subject_ids.append(f"S{s:02d}")
    vocabulary = [("human", f"s{v}") for v in range(A)]
    return Demonstrations.from_lists(rows, subjects=subject_ids, vocabulary=vocabulary)


def test_next_step_names_the_thresholds_its_step_falls_short_of():
    """``MixtureFit.next_step``: why ``k + 1`` was not chosen. Two types one row apart (k = 2):
    a third cluster gains far less than ``min_gain``. Clusters of demonstrations that every
    person shares: the second cluster gains 0.1 nats per transition, but no person's
    demonstrations agree on it (subject consistency 0.04), so k = 1 and the step to 2 falls
    short of the consistency checks only. Without them, the gain cut alone."""
    common = dict(k_min=1, k_max=3, restarts=3, seed=0)
    demos, _ = _one_row_apart()
    fit = fit_mixture(demos, **common)
    step = fit.next_step
    assert fit.k == 2 and step["k"] == 3
    assert {"min_gain", "strong_gain"} <= set(step["short_of"])
    assert step["values"]["gain"] == fit.per_k[3]["gain"] < step["thresholds"]["min_gain"]
    shared = _sequence_level()
    fit = fit_mixture(shared, **common)
    step = fit.next_step
    assert fit.k == 1 and step["k"] == 2
    assert step["short_of"] == ["consistency", "split_consistency"]
    assert step["values"]["gain"] > 0.05 and step["values"]["consistency"] < 0.2
    off = fit_mixture(demos, min_consistency=0.0, **common)  # cut by min_gain (see above)
    # (a step the exact ICL takes needs no strong_gain)
    assert off.k == 1 and off.next_step["short_of"] == ["min_gain"]
    assert "consistency" not in off.next_step["values"]
    at_max = fit_mixture(demos, k_min=1, k_max=2, restarts=3, seed=0)
    assert at_max.k == 2 and at_max.next_step is None  # no k above k_max
    assert fit_mixture(demos, criterion="bic", **common).next_step is None


def test_partition_chains_of_a_hard_partition_counted_by_hand():
    """One-hot weights: each cluster's chain is its sequences' transition counts plus the
    pseudo-count, normalised; a row no sequence visits is ``alpha``-uniform."""
    h = lambda a: ("human", a)  # noqa: E731
    demos = Demonstrations.from_lists(
        [[h("a"), h("b"), h("a")], [h("a"), h("a"), h("b")], [h("b"), h("b"), h("b")]]
    )
    z = torch.tensor([0, 0, 1])
    chains = partition_chains(demos, torch.nn.functional.one_hot(z, 2).double(),
                              pseudo_count=0.5)  # fmt: skip
    # cluster 0: a->b twice, b->a once, a->a once; cluster 1: b->b twice
    expected = torch.tensor([[[1.5 / 4, 2.5 / 4], [1.5 / 2, 0.5 / 2]],
                             [[0.5, 0.5], [0.5 / 3, 2.5 / 3]]], dtype=torch.float64)  # fmt: skip
    torch.testing.assert_close(chains, expected, atol=1e-12, rtol=0)
    with pytest.raises(ModelError, match=r"weights of shape \(N, k\) for the N = 3"):
        partition_chains(demos, torch.ones(2, 2))
