"""Higher-order chains (torchhrc.mixture.history) and fit_mixture(order=...).

References are independent of the code under test: context symbols and supports worked by
hand or rebuilt from the symbols' names with loops, the second-order exact ICL recomputed
from its definition with a loop over contexts, a corpus whose two types have identical
first-order counts, and one whose two types have the same first- and second-order
statistics (a rhythm against a fair coin)."""

from __future__ import annotations

import math
import warnings
from collections import Counter

import pytest
import torch

from torchhrc.data import Demonstrations
from torchhrc.errors import ModelError
from torchhrc.metrics import adjusted_rand_index
from torchhrc.mixture import MarkovChainMixture, fit_mixture
from torchhrc.mixture.counts import sufficient_statistics
from torchhrc.mixture.criteria import exact_icl, partition_icl
from torchhrc.mixture.history import context_symbols, second_order
from torchhrc.mixture.likelihood import sequence_log_likelihood
from torchhrc.mixture.selection import order_to_keep

W = ("robot", "wait")


def _order_types(subjects: int = 12, per_subject: int = 3) -> tuple[Demonstrations, list[int]]:
    """Two types that do p1, q1, p2, q2 (type 0) or p2, q2, p1, q1 (type 1), a robot wait
    before every step: each type's sequence has the same first-order counts (w -> p1,
    w -> q1, w -> p2, w -> q2 once, each back to w), so only the order across a wait
    tells them apart."""
    a = [W, ("human", "p1"), W, ("human", "q1"), W, ("human", "p2"), W, ("human", "q2")]
    b = [W, ("human", "p2"), W, ("human", "q2"), W, ("human", "p1"), W, ("human", "q1")]
    seqs, subs, types = [], [], []
    for s in range(subjects):
        for _ in range(per_subject):
            seqs.append(a if s % 2 == 0 else b)
            subs.append(f"s{s}")
            types.append(s % 2)
    return Demonstrations.from_lists(seqs, subjects=subs), types


def test_context_symbols_by_hand():
    d = Demonstrations.from_lists(
        [[W, ("human", "a"), W, ("human", "b")], [("human", "b"), W, ("human", "a")]]
    )
    low = second_order(d)
    names = [f"{actor}|{action}" for actor, action in low.data.vocabulary]
    got = [[names[i] for i in row[:n]] for row, n in zip(low.data.sequences.tolist(),
                                                         low.data.lengths.tolist())]  # fmt: skip
    assert got == [
        ["robot|start > wait", "human|robot:wait > a", "robot|human:a > wait",
         "human|robot:wait > b"],
        ["human|start > b", "robot|human:b > wait", "human|robot:wait > a"],
    ]  # fmt: skip
    assert low.outcomes == 3
    index = {n: i for i, n in enumerate(names)}
    # "x > wait" can be followed only by "robot:wait > y"; "wait > y" by "human:y > wait"
    for p, q in [("robot|human:a > wait", "human|robot:wait > b"),
                 ("human|robot:wait > a", "robot|human:a > wait"),
                 ("robot|start > wait", "human|robot:wait > a")]:  # fmt: skip
        assert low.transition_support[index[p], index[q]]
    assert not low.transition_support[index["human|robot:wait > a"], index["human|robot:wait > b"]]
    assert not low.transition_support[index["robot|start > wait"], index["robot|human:a > wait"]]
    assert [names[i] for i in torch.nonzero(low.initial_support).flatten().tolist()] == [
        "human|start > b", "robot|start > wait"]  # fmt: skip


def test_third_order_context_symbols_by_hand():
    d = Demonstrations.from_lists([[W, ("human", "a"), W, ("human", "b")]])
    low = context_symbols(d, 3)
    names = [f"{actor}|{action}" for actor, action in low.data.vocabulary]
    got = [names[i] for i in low.data.sequences[0].tolist()]
    assert got == [
        "robot|start > start > wait",
        "human|start > robot:wait > a",
        "robot|robot:wait > human:a > wait",
        "human|human:a > robot:wait > b",
    ]
    assert low.outcomes == 3
    assert [names[i] for i in torch.nonzero(low.initial_support).flatten().tolist()] == [
        "robot|start > start > wait"
    ]
    follows = {(names[p], names[q]) for p, q in torch.nonzero(low.transition_support).tolist()}
    assert follows == {(got[0], got[1]), (got[1], got[2]), (got[2], got[3])}


@pytest.mark.parametrize("order", [2, 3])
def test_lowering_is_one_to_one_and_stays_on_the_support(order: int):
    g = torch.Generator().manual_seed(3)
    steps = [("human", f"h{i}") for i in range(3)] + [("robot", f"r{i}") for i in range(2)]
    seqs = [[steps[int(j)] for j in torch.randint(0, 5, (int(n),), generator=g)]
            for n in torch.randint(2, 9, (40,), generator=g)]  # fmt: skip
    d = Demonstrations.from_lists(seqs)
    low = context_symbols(d, order)
    back = [[(actor, action.rsplit(" > ", 1)[1]) for actor, action in row] for row in
            low.data.to_lists()]  # fmt: skip
    assert back == seqs
    counts = low.data.transition_counts()
    assert counts[~low.transition_support].sum() == 0
    firsts = low.data.sequences[:, 0]
    assert bool(low.initial_support[firsts].all())
    # the support from the names: q's previous steps are p's last order - 1 steps
    parts = [(*action.split(" > ")[:-1], f"{actor}:{action.rsplit(' > ', 1)[1]}")
             for actor, action in low.data.vocabulary]  # fmt: skip
    want = torch.tensor([[q[: order - 1] == p[1:] for q in parts] for p in parts])
    assert torch.equal(low.transition_support, want)
    assert low.initial_support.tolist() == [set(p[:-1]) == {"start"} for p in parts]


def test_second_order_exact_icl_against_its_definition():
    d, _ = _order_types(subjects=4, per_subject=2)
    d = Demonstrations.from_lists([*d.to_lists()[:5], [W, ("human", "p1"), W, ("human", "p1")]])
    low = second_order(d)
    stats = sufficient_statistics(low.data.sequences, low.data.lengths, low.data.num_symbols,
                                  initial=True)  # fmt: skip
    z = torch.tensor([0, 0, 1, 1, 0, 1])
    got = float(exact_icl(stats, _rows(stats, z), torch.ones(1, 2, dtype=torch.bool),
                          outcomes=low.outcomes)[0])  # fmt: skip
    # by the definition: every (cluster, context) row a Dirichlet(1/2) over the A = 3
    # recorded symbols; the first symbols too; the weights a Dirichlet(1)
    alpha, A = 0.5, low.outcomes
    rows: dict[tuple[int, object], Counter] = {}
    for n, seq in enumerate(d.to_lists()):
        before: object = None  # (a_(t-2), a_(t-1)) of step t; the first step has its own row
        for t, step in enumerate(seq):
            key = (int(z[n]), "first" if t == 0 else before)
            rows.setdefault(key, Counter())[step] += 1
            before = ("start" if t == 0 else before[1], step)  # type: ignore[index]
    want = 0.0
    for counter in rows.values():
        total = sum(counter.values())
        want += sum(math.lgamma(c + alpha) - math.lgamma(alpha) for c in counter.values())
        want += math.lgamma(A * alpha) - math.lgamma(total + A * alpha)
    sizes = [int((z == k).sum()) for k in (0, 1)]
    want += sum(math.lgamma(m + 1.0) for m in sizes) + math.lgamma(2.0) - math.lgamma(6 + 2.0)
    assert got == pytest.approx(want, rel=1e-12)


def _icl_by_definition(d: Demonstrations, z: list[int], order: int, units: list) -> float:
    """``log p(D, z)`` by its definition, with loops: every (cluster, last ``order`` steps)
    row and every cluster's first steps a Dirichlet(1/2) over the A recorded symbols, the
    clusters' shares of the units a Dirichlet(1)."""
    alpha, A = 0.5, d.num_symbols
    rows: dict[tuple[int, object], Counter] = {}
    for n, seq in enumerate(d.to_lists()):
        before: tuple = ("start",) * order
        for t, step in enumerate(seq):
            rows.setdefault((z[n], "first" if t == 0 else before), Counter())[step] += 1
            before = (*before[1:], step)
    want = 0.0
    for counter in rows.values():
        total = sum(counter.values())
        want += sum(math.lgamma(c + alpha) - math.lgamma(alpha) for c in counter.values())
        want += math.lgamma(A * alpha) - math.lgamma(total + A * alpha)
    cluster = dict(zip(units, z))
    sizes = Counter(cluster.values())
    k = len(sizes)
    want += sum(math.lgamma(m + 1.0) for m in sizes.values())
    return want + math.lgamma(k) - math.lgamma(len(cluster) + k)


@pytest.mark.parametrize("order", [1, 2, 3])
def test_partition_icl_against_its_definition(order: int):
    d, _ = _order_types(subjects=4, per_subject=2)
    lists = [*d.to_lists()[:5], [W, ("human", "p1"), W, ("human", "p1")]]
    subjects = ["s0", "s0", "s1", "s1", "s2", "s3"]
    d = Demonstrations.from_lists(lists, subjects=subjects)
    groups = torch.tensor([0, 0, 1, 1, 2, 3])
    by_sequence = [0, 1, 1, 0, 0, 1]
    by_subject = [0, 0, 1, 1, 0, 1]
    labels = torch.tensor([7, 7, 3, 3, 7, 3])  # any label values: the same partition
    got = partition_icl(d, [torch.tensor(by_sequence), labels], order)
    assert got[0] == pytest.approx(_icl_by_definition(d, by_sequence, order, list(range(6))),
                                   rel=1e-12)  # fmt: skip
    assert got[1] == pytest.approx(_icl_by_definition(d, by_subject, order, list(range(6))),
                                   rel=1e-12)  # fmt: skip
    # subjects as units: their sequences share a cluster, the weights count subjects
    (grouped,) = partition_icl(d, [labels], order, groups=groups)
    assert grouped == pytest.approx(_icl_by_definition(d, by_subject, order, subjects), rel=1e-12)
    with pytest.raises(ValueError, match="two labels in one unit"):
        partition_icl(d, [torch.tensor(by_sequence)], order, groups=groups)
    with pytest.raises(ValueError, match=r"partitions\[0\] of shape \(6,\)"):
        partition_icl(d, [torch.zeros(5, dtype=torch.long)], order)


def _rows(stats, z: torch.Tensor) -> torch.Tensor:
    """``(U, 1)`` the cluster of each distinct row (all sequences of a row share it here)."""
    out = torch.zeros(stats.num_distinct, dtype=torch.long)
    out[stats.inverse] = z
    return out[:, None]


def test_second_order_finds_types_first_order_counts_cannot_tell_apart():
    d, types = _order_types()
    options = dict(k_min=1, k_max=4, restarts=5, seed=0, initial=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        first = fit_mixture(d, order=1, **options)
        second = fit_mixture(d, order=2, **options)
        auto = fit_mixture(d, order="auto", **options)
    assert first.k == 1  # identical transition counts: nothing to separate
    assert second.k == 2 and second.order == 2 and second.model.order == 2
    assert adjusted_rand_index(types, second.assignments.tolist()) == pytest.approx(1.0)
    assert auto.order == 2 and auto.k == 2
    assert set(auto.order_comparison) == {"1", "2", "3"}
    assert auto.order_comparison["1"]["k"] == 1 and auto.order_comparison["2"]["k"] == 2
    # the tied orders' partitions scored under each tied order's chains (not the first
    # order's, which found fewer types): under its own order a partition's score is the
    # fit's own exact ICL (two code paths, one number)
    for order in ("2", "3"):
        row = auto.order_comparison[order]
        assert {"exact_icl_at_2", "exact_icl_at_3"} <= set(row) and "exact_icl_at_1" not in row
        assert row[f"exact_icl_at_{order}"] == pytest.approx(row["exact_icl"], rel=1e-9)
        assert row["partition"] == 2.0  # the second and third orders' partitions are one
    assert "exact_icl_at_1" not in auto.order_comparison["1"]  # fewer types: not a candidate
    # smoothing only where a context can go: no mass on impossible successors
    support = second_order(d).transition_support
    assert float(second.model.transition[:, ~support].max()) < 1e-6
    rows = second.model.transition.sum(-1)
    assert torch.allclose(rows, torch.ones_like(rows))
    # first-order chains over the recorded symbols, for the task pipeline
    chains = second.transition_over(d)
    assert chains.shape == (2, d.num_symbols, d.num_symbols)
    p1, q1, wait = d.symbol("human", "p1"), d.symbol("human", "q1"), d.symbol(*W)
    assert float(chains[:, wait, p1].min()) > 0.2 and float(chains[:, p1, wait].min()) > 0.9
    assert int(q1) != int(p1)


def test_auto_keeps_first_order_where_second_finds_no_more_types():
    # two first-order chains: a second order adds parameters and no prediction, so on equal
    # k the first order's log p(D, z) is the larger and it is kept
    chains = torch.tensor([[[0.8, 0.1, 0.1], [0.1, 0.8, 0.1], [0.1, 0.1, 0.8]],
                           [[0.1, 0.8, 0.1], [0.1, 0.1, 0.8], [0.8, 0.1, 0.1]]])  # fmt: skip
    g = torch.Generator().manual_seed(0)
    steps = [("human", "a"), ("human", "b"), ("robot", "c")]
    seqs, subjects, types = [], [], []
    for s in range(20):
        for _ in range(2):
            x, seq = 0, []
            for _ in range(15):
                seq.append(steps[x])
                x = int(torch.multinomial(chains[s % 2, x], 1, generator=g))
            seqs.append(seq)
            subjects.append(f"s{s}")
            types.append(s % 2)
    d = Demonstrations.from_lists(seqs, subjects=subjects)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fit = fit_mixture(d, order="auto", k_min=1, k_max=3, restarts=3, seed=0, initial=True)
    cmp = fit.order_comparison
    assert cmp["1"]["k"] == cmp["2"]["k"] == fit.k == 2
    assert cmp["1"]["exact_icl"] > cmp["2"]["exact_icl"]
    assert fit.order == 1 and fit.model.order == 1
    assert adjusted_rand_index(types, fit.assignments.tolist()) == pytest.approx(1.0)


def test_order_two_model_scores_new_demonstrations_and_round_trips(tmp_path):
    d, _ = _order_types(subjects=8, per_subject=2)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fit = fit_mixture(d, order=2, k_min=2, k_max=2, restarts=3, seed=0, initial=True)
    new = d.subset([0, 2])  # one of each type
    scored = fit.model.prepare(new)
    assert scored.vocabulary == fit.model.vocabulary
    for suffix in (".json", ".safetensors"):
        fit.model.save(tmp_path / f"m{suffix}")
        back = MarkovChainMixture.load(tmp_path / f"m{suffix}")
        assert back.order == 2
        assert torch.equal(back.prepare(new).sequences, scored.sequences)
    unseen = Demonstrations.from_lists([[W, ("human", "p1"), ("human", "q2")]])
    with pytest.raises(ModelError, match="not in the vocabulary"):
        fit.model.prepare(unseen)


def test_bad_order_is_refused():
    d, _ = _order_types(subjects=2, per_subject=2)
    with pytest.raises(ValueError, match="at least one step"):
        second_order(d.subset([]))
    with pytest.raises(TypeError, match="Demonstrations"):
        second_order((torch.zeros(1, 2, dtype=torch.long), torch.tensor([2]), 1))
    with pytest.raises(ValueError, match="order 1, 2, 3 or 'auto'"):
        fit_mixture(d, order=4)
    with pytest.raises(ValueError, match=r"order to be an int in \[2, 3\]"):
        context_symbols(d, 4)
    seqs = torch.tensor([[0, 1, 0, 1]] * 4)
    for order in (2, 3):
        with pytest.raises(TypeError, match="needs a Demonstrations"):
            fit_mixture((seqs, torch.full((4,), 4), 2), order=order)
    with pytest.raises(ModelError, match=r"order an int in \[1, 3\]"):
        MarkovChainMixture(torch.zeros(1, 1, 1, dtype=torch.float64),
                           torch.zeros(1, dtype=torch.float64), order=4)  # fmt: skip


def test_the_order_kept_is_the_one_with_more_types_then_the_larger_exact_icl():
    # five_parts seed 3 (docs/clustering.md): the first order finds the 5 types, the second
    # merges two and still has the far larger log p(D, z): the types are kept
    assert order_to_keep({"1": {"k": 5, "exact_icl": -2472.1},
                          "2": {"k": 4, "exact_icl": -2149.1}}) == 1  # fmt: skip
    assert order_to_keep({"1": {"k": 3, "exact_icl": -1029.8},
                          "2": {"k": 4, "exact_icl": -824.2}}) == 2  # fmt: skip
    assert order_to_keep({"1": {"k": 2, "exact_icl": -700.0},
                          "2": {"k": 2, "exact_icl": -710.0}}) == 1  # fmt: skip
    assert order_to_keep({"1": {"k": 2, "exact_icl": -700.0},
                          "2": {"k": 2, "exact_icl": -690.0}}) == 2  # fmt: skip
    assert order_to_keep({"1": {"k": 2, "exact_icl": -700.0},
                          "2": {"k": 2, "exact_icl": -700.0}}) == 1  # fmt: skip


def test_on_equal_k_the_order_whose_partition_wins_under_every_tied_order_is_kept():
    # five_parts seed 9 (docs/clustering.md, "The partition on equal k"): both orders find
    # 5 types; the second order's own exact ICL is the larger (-2032.2 against -2378.7), but
    # the first order's partition (the true one) scores higher under both orders' chains
    row = {"1": {"k": 5, "exact_icl": -2378.7, "exact_icl_at_1": -2378.7,
                 "exact_icl_at_2": -1936.8},
           "2": {"k": 5, "exact_icl": -2032.2, "exact_icl_at_1": -2498.2,
                 "exact_icl_at_2": -2032.2},
           "3": {"k": 4, "exact_icl": -2107.7}}  # fmt: skip
    assert order_to_keep(row) == 1
    # above the other under one order by no more than the margin (5 nats): each fit's own
    # exact ICL decides, as without the scores
    row["1"]["exact_icl_at_1"] = -2498.2 + 4.9
    assert order_to_keep(row) == 2
    row["1"]["exact_icl_at_1"] = -2498.2 + 5.1
    assert order_to_keep(row) == 1
    # the judges disagree: as without the scores
    row["1"]["exact_icl_at_1"] = -2600.0
    assert order_to_keep(row) == 2
    # a fit with more types is kept whatever the scores of the tied ones
    row["3"]["k"] = 6
    assert order_to_keep(row) == 3
    # paint_crews seed 5: the second and third orders find 4 types, the first 3; the third
    # order's partition (the true one) is ahead under both tied orders' chains, and the
    # first order's, which cannot see the fourth type, is no judge
    row = {"1": {"k": 3, "exact_icl": -989.3},
           "2": {"k": 4, "exact_icl": -831.1, "exact_icl_at_2": -831.1,
                 "exact_icl_at_3": -910.7, "exact_icl_at_1": -1042.4},
           "3": {"k": 4, "exact_icl": -863.0, "exact_icl_at_2": -795.5,
                 "exact_icl_at_3": -863.0, "exact_icl_at_1": -1046.2}}  # fmt: skip
    assert order_to_keep(row) == 3
    # three orders, two with one partition that wins: of those two, the larger own exact ICL
    same = {"k": 3, "exact_icl_at_1": -100.0, "exact_icl_at_2": -90.0, "partition": 1}
    other = {"k": 3, "exact_icl_at_1": -110.0, "exact_icl_at_2": -96.0, "partition": 3}
    three = {"1": {**same, "exact_icl": -100.0}, "2": {**same, "exact_icl": -90.0},
             "3": {**other, "exact_icl": -80.0}}  # fmt: skip
    assert order_to_keep(three) == 2
    three["3"]["exact_icl_at_2"] = -94.0  # within the margin under the second order
    assert order_to_keep(three) == 3


def test_second_order_finds_people_who_each_prefer_an_order():
    # people who each prefer one of two orders (in 19 of 20 of their demonstrations) with a
    # robot that waits between every two of their actions: a first-order chain cannot see
    # the order; the second order's split is a split of people (held-out consistency above
    # the one threshold, 0.5, that both orders share): 2 types, by preference
    a = [W, ("human", "p1"), W, ("human", "q1"), W, ("human", "p2"), W, ("human", "q2")]
    b = [W, ("human", "p2"), W, ("human", "q2"), W, ("human", "p1"), W, ("human", "q1")]
    g = torch.Generator().manual_seed(0)
    seqs, subjects, prefers = [], [], []
    for s in range(30):
        prefers_a = 0.95 if s % 2 == 0 else 0.05
        for _ in range(4):
            seqs.append(a if float(torch.rand((), generator=g)) < prefers_a else b)
            subjects.append(f"s{s}")
            prefers.append(s % 2)
    d = Demonstrations.from_lists(seqs, subjects=subjects)
    options = dict(k_min=1, k_max=3, restarts=5, seed=0, initial=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        first = fit_mixture(d, order=1, **options)
        second = fit_mixture(d, order=2, **options)
    assert first.k == 1
    assert second.k == 2 and adjusted_rand_index(prefers, second.assignments.tolist()) == 1.0
    assert second.per_k[2]["consistency"] > 0.5


def test_auto_keeps_to_first_order_where_second_order_counts_would_not_fit(monkeypatch):
    import torchhrc.mixture.selection as selection

    d, _ = _order_types()
    P = second_order(d).data.num_symbols
    monkeypatch.setattr(selection, "HIGHER_ORDER_MAX_ELEMENTS", d.num_sequences * P * P - 1)
    with pytest.warns(RuntimeWarning, match=r"compared orders \[1\] only"):
        fit = fit_mixture(d, order="auto", k_min=1, k_max=3, restarts=3, seed=0, initial=True)
    assert fit.order == 1 and fit.order_comparison is None and fit.k == 1


def _rhythm_types(subjects: int = 16, per_subject: int = 3, length: int = 16):
    """Two types over the person's actions x and y: "rhythm" repeats the de Bruijn cycle
    x, x, x, y, x, y, y, y (from a random phase), "coin" tosses a fair coin. In the cycle each
    pair of symbols is followed once by x and once by y, so chains that see two symbols back
    (second order) find the two types alike, as first-order ones do; three symbols back,
    "rhythm" is deterministic."""
    g = torch.Generator().manual_seed(11)
    steps = (("human", "x"), ("human", "y"))
    cycle = (0, 0, 0, 1, 0, 1, 1, 1)
    seqs, subjects_, types = [], [], []
    for s in range(subjects):
        for _ in range(per_subject):
            if s % 2 == 0:
                phase = int(torch.randint(8, (), generator=g))
                seq = [steps[cycle[(t + phase) % 8]] for t in range(length)]
            else:
                seq = [steps[int(j)] for j in torch.randint(2, (length,), generator=g)]
            seqs.append(seq)
            subjects_.append(f"s{s}")
            types.append(s % 2)
    return Demonstrations.from_lists(seqs, subjects=subjects_), types


def test_third_order_finds_a_rhythm_lower_orders_cannot_see(tmp_path):
    d, types = _rhythm_types()
    options = dict(k_min=1, k_max=3, restarts=5, seed=0, initial=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        auto = fit_mixture(d, order="auto", **options)
    comparison = auto.order_comparison
    assert comparison["1"]["k"] == 1 and comparison["2"]["k"] == 1
    assert auto.order == 3 and auto.model.order == 3 and auto.k == 2
    assert adjusted_rand_index(types, auto.assignments.tolist()) == pytest.approx(1.0)
    # a new person of each type is read by the fitted third-order chains
    new, new_types = _rhythm_types(subjects=2, per_subject=1, length=16)
    prepared = auto.model.prepare(new)
    ll = sequence_log_likelihood(auto.model, prepared.sequences, prepared.lengths)  # (2, k)
    pairs = int(auto.assignments[types.index(0)])
    assert int(ll[new_types.index(0)].argmax()) == pairs
    assert int(ll[new_types.index(1)].argmax()) != pairs
    auto.model.save(tmp_path / "m.json")
    back = MarkovChainMixture.load(tmp_path / "m.json")
    assert back.order == 3
    assert torch.equal(back.prepare(new).sequences, auto.model.prepare(new).sequences)


def test_auto_leaves_out_a_third_order_with_too_many_contexts(monkeypatch):
    """Its cost grows with the square of its context symbols: above the cap "auto" compares
    orders 1 and 2 only, without a warning (a default, not a failure)."""
    import torchhrc.mixture.selection as selection

    d, _ = _rhythm_types(subjects=8, per_subject=2)
    P = context_symbols(d, 3).data.num_symbols
    monkeypatch.setattr(selection, "THIRD_ORDER_MAX_CONTEXTS", P - 1)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        fit = fit_mixture(d, order="auto", k_min=1, k_max=2, restarts=2, seed=0, initial=True)
    assert set(fit.order_comparison) == {"1", "2"} and fit.order in (1, 2)
    monkeypatch.setattr(selection, "THIRD_ORDER_MAX_CONTEXTS", P)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fit = fit_mixture(d, order="auto", k_min=1, k_max=2, restarts=2, seed=0, initial=True)
    assert set(fit.order_comparison) == {"1", "2", "3"}
    # nor where its counts would not fit (the second order's would: it is compared)
    P2 = context_symbols(d, 2).data.num_symbols
    monkeypatch.setattr(selection, "HIGHER_ORDER_MAX_ELEMENTS", d.num_sequences * P2 * P2)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        fit = fit_mixture(d, order="auto", k_min=1, k_max=2, restarts=2, seed=0, initial=True)
    assert set(fit.order_comparison) == {"1", "2"}
