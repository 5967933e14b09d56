"""Issue 12.1: the default clustering keeps the true number of types as the corpus grows.

The corpus: place-and-drill, 3 demonstrations per subject, a fresh random placement order in
every demonstration, every step (human and robot) replaced with probability 0.1 by a
uniformly random action of its actor; 2 types ("safe", "efficient") at 3 positions, or 3
("safe", "efficient", "lagging") at 4. With BIC alone the soft method split the types into
sub-clusters of noise patterns and orders (k = 4 at 10,000 sequences, ARI 0.5); ``min_gain``
(0.015 nats per transition) was set on seeds 0-2, the default criterion (the larger of BIC's
and the exact ICL's k, Jeffreys' prior) chosen on seeds 0-5; these tests use seeds 10-18,
which neither was tuned on. Sizes 100,000 and 1,000,000 are one-off measurements
(docs/clustering.md, benchmarks/bench_mixture.py --study). Since the third round the default
reads the positions of this corpus as exchangeable objects (``test_objects.py``); the tests
of the raw position symbols below say ``objects="raw"``.
"""

import warnings

import pytest

from torchhrc.metrics import adjusted_rand_index
from torchhrc.mixture import fit_mixture
from torchhrc.tasks.place_and_drill import scaling_study, simulate_study


def corpus(n_sequences, types, seed):
    return scaling_study(n_sequences, types, seed=seed)


def _fit(demos, seed, **options):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # edge warnings are tested below
        fit = fit_mixture(demos, seed=seed, **options)
    return fit, adjusted_rand_index(list(demos.types), fit.assignments.tolist())


@pytest.mark.parametrize("seed", [10, 11, 12])
def test_two_types_at_the_paper_size(seed):
    fit, ari = _fit(corpus(54, 2, seed), seed)
    assert fit.k == 2 and ari >= 0.95


@pytest.mark.slow
@pytest.mark.parametrize("types", [2, 3])
@pytest.mark.parametrize("seed", [10, 11, 12])
def test_true_types_at_1000_sequences(types, seed):
    fit, ari = _fit(corpus(1002, types, seed), seed)
    assert fit.k == types and ari >= 0.95
    # the rule, not BIC, set k here: every further cluster gained less than min_gain
    assert all(fit.per_k[k]["gain"] < 0.015 for k in range(types + 1, 11))
    if types > 2:  # (k = 2 = k_min has no gain)
        assert fit.per_k[types]["gain"] > 2 * 0.015  # a true type gains more than twice that


@pytest.mark.slow
@pytest.mark.parametrize("types", [2, 3])
def test_true_types_at_10000_sequences_where_bic_alone_over_splits(types):
    seed = 10
    demos = corpus(10002, types, seed)
    fit, ari = _fit(demos, seed)
    assert fit.k == types and ari >= 0.95
    if types == 2:  # with 3 types BIC alone over-splits from about 100,000 sequences on
        bic_only, bic_ari = _fit(demos, seed, min_gain=0.0, min_consistency=0.0, objects="raw")
        assert bic_only.k > types and bic_ari < 0.9  # the failure of the issue
        # the split check alone removes it too: the clusters past 2 part each subject's
        # sequences (their ICC within the 2 types is 0.11-0.13, docs/clustering.md)
        split_only, split_ari = _fit(demos, seed, min_gain=0.0, objects="raw")
        assert split_only.k == types and split_ari >= 0.95


def test_paper_method_is_unchanged_by_min_gain():
    demos = corpus(300, 2, 10)
    default, _ = _fit(demos, 10, method="paper", k_max=5)
    explicit, _ = _fit(demos, 10, method="paper", k_max=5, min_gain=0.0)
    assert default.k == explicit.k and default.per_k == explicit.per_k


def test_warning_at_the_upper_edge():
    demos = corpus(1002, 3, 10)
    with pytest.warns(RuntimeWarning, match="largest searched"):
        fit = fit_mixture(demos, k_min=1, k_max=2, restarts=2, seed=0)
    assert fit.k == 2


def test_warning_when_one_cluster_fits_as_well_as_two():
    """All subjects "safe": k = 2 gains less than min_gain over one chain."""
    demos = simulate_study(
        n_subjects=100,
        strategies=("safe",),
        noise=0.1,
        robot_noise=0.1,
        order_change=1.0,
        deviation="uniform",
        seed=10,
    )
    with pytest.warns(RuntimeWarning, match="single type"):
        fit_mixture(demos, k_min=2, k_max=4, restarts=4, seed=0)


def test_no_edge_warning_on_a_clear_two_type_study():
    demos = corpus(1002, 2, 11)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        assert fit_mixture(demos, seed=11).k == 2


@pytest.mark.parametrize("seed", [10, 11, 12])
def test_three_exchangeable_types_at_the_paper_size(seed):
    """54 sequences, 3 types, positions declared exchangeable (``relabel_objects``): the
    default finds the three types; BIC alone (``criterion="bic"``), which charges every chain
    ``A (A - 1) = 90`` parameters x ``1/2 log 18`` although a chain visits half of them,
    finds two. The 2-type corpus of the same size keeps k = 2."""
    demos = corpus(54, 3, seed).relabel_objects()
    fit, ari = _fit(demos, seed)
    assert fit.k == 3 and ari >= 0.95
    assert fit.criterion == "icl_or_gain"
    assert max(fit.per_k, key=lambda k: fit.per_k[k]["exact_icl"]) == 3
    bic_only, _ = _fit(demos, seed, criterion="bic")
    assert bic_only.k == 2
    two = corpus(54, 2, seed).relabel_objects()
    fit2, ari2 = _fit(two, seed)
    assert fit2.k == 2 and ari2 >= 0.95


@pytest.mark.slow
def test_three_types_at_300_sequences_mostly_found_where_bic_alone_finds_two():
    """300 sequences (100 subjects), 3 types over the raw position symbols (``objects="raw"``;
    the default detects exchangeable objects and finds them at 54): BIC alone gives
    k = 2 on every seed 10-18; the default finds the three types on 6 of them (measured:
    seeds 10, 13, 14, 16, 17, 18; ARI >= 0.97). At 54 sequences neither does
    (docs/clustering.md: the evidence for a third type is too small there)."""
    found = 0
    for seed in range(10, 19):
        demos = corpus(300, 3, seed)
        fit, ari = _fit(demos, seed, objects="raw")
        bic_only, _ = _fit(demos, seed, criterion="bic", objects="raw")
        assert bic_only.k == 2
        assert fit.k in (2, 3)
        found += fit.k == 3 and ari >= 0.95
    assert found >= 6
