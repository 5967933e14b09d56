"""Subject consistency: a type belongs to a person (``torchhrc.mixture.consistency``)."""

from __future__ import annotations

import itertools
import warnings
from pathlib import Path

import pytest
import torch

from torchhrc.errors import ModelError
from torchhrc.metrics import adjusted_rand_index
from torchhrc.mixture import fit_mixture
from torchhrc.mixture.consistency import (
    cluster_consistency,
    intraclass_correlation,
    split_consistency,
)
from torchhrc.mixture.sharded import ShardedCorpus
from torchhrc.tasks import make_task

pytestmark = pytest.mark.numeric


def test_icc_worked_by_hand() -> None:
    """Groups {1, 2, 3} and {5, 7}: MSB = 19.2, MSW = 4/3, n0 = 2.4, so
    ICC = (19.2 - 4/3) / (19.2 + 1.4 * 4/3) = 0.848101..."""
    values = torch.tensor([[1.0], [2.0], [3.0], [5.0], [7.0]])
    icc = intraclass_correlation(values, torch.tensor([4, 4, 4, 9, 9]))  # any group ids
    assert icc.tolist() == pytest.approx([(19.2 - 4 / 3) / (19.2 + 1.4 * 4 / 3)], rel=1e-12)
    # per column; the extremes: all variance between groups, all within
    two = torch.tensor([[1.0, 1.0], [1.0, 0.0], [0.0, 1.0], [0.0, 0.0]])
    assert intraclass_correlation(two, torch.tensor([0, 0, 1, 1])).tolist() == [1.0, -1.0]


def _sub_cluster() -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """3 types x 4 subjects x 4 sequences; a cluster holding 3 of the 4 sequences of every
    subject of type 0 (a split of each person's sequences, not of people)."""
    subject = torch.arange(12).repeat_interleave(4)  # (48,)
    kind = subject // 4  # the subject's type
    column = ((kind == 0) & (torch.arange(48) % 4 != 0)).double()
    return column.view(48, 1), subject, kind


def test_icc_within_strata_worked_by_hand() -> None:
    """The sub-cluster's plain ICC: grand mean 1/4, MSB = (16 (3/4 - 1/4)^2 + 32 (1/4)^2) / 11
    = 6/11, MSW = 4 * 4 * 3/16 / 36 = 1/12, n0 = 4, ICC = (6/11 - 1/12) / (6/11 + 3/12) =
    0.5810 (above 0.5: the other types' subjects at 0 make it look like a property of people).
    Within the types (strata): every type-0 subject has mean 3/4, MSB = 0 over G - S = 9
    degrees of freedom, ICC = (0 - 1/12) / (0 + 3/12) = -1/3."""
    values, subject, kind = _sub_cluster()
    plain = intraclass_correlation(values, subject)
    assert plain.tolist() == pytest.approx([(6 / 11 - 1 / 12) / (6 / 11 + 3 / 12)], rel=1e-12)
    within = intraclass_correlation(values, subject, strata=kind)
    assert within.tolist() == pytest.approx([-1 / 3], rel=1e-12)
    # one stratum is the plain ICC; a type's own cluster splits people: 1 within its stratum
    one = intraclass_correlation(values, subject, strata=torch.zeros_like(kind))
    assert one.tolist() == pytest.approx(plain.tolist(), rel=1e-12)
    own = (kind == 0).double().view(48, 1)
    assert intraclass_correlation(own, subject, strata=kind // 2).tolist() == [1.0]
    with pytest.raises(ValueError, match="strata of shape"):
        intraclass_correlation(values, subject, strata=kind[:3])


def test_split_consistency_tells_a_split_of_people_from_one_of_sequences() -> None:
    values, subject, kind = _sub_cluster()
    coarse = torch.nn.functional.one_hot(kind, 3).double()  # (48, 3): the types
    random_split = torch.cat([coarse, values], -1)
    random_split[:, 0] -= values[:, 0]  # type 0's sequences part in cluster 0, part in 3
    assert split_consistency(random_split, coarse, subject) < 0.0
    merged = torch.stack([(kind == 0).double(), (kind > 0).double()], -1)  # types 1, 2 merged
    assert split_consistency(coarse, merged, subject) == pytest.approx(1.0)


def test_icc_undefined_cases_are_nan_and_bad_input_is_named() -> None:
    one_each = intraclass_correlation(torch.rand(4, 2), torch.arange(4))  # no within-group info
    assert one_each.isnan().all()
    constant = intraclass_correlation(torch.ones(4, 1), torch.tensor([0, 0, 1, 1]))
    assert constant.isnan().all()
    with pytest.raises(ValueError, match="groups of shape"):
        intraclass_correlation(torch.rand(4, 2), torch.zeros(3, dtype=torch.long))
    with pytest.raises(ValueError, match="values of shape"):
        intraclass_correlation(torch.rand(4), torch.zeros(4, dtype=torch.long))
    with pytest.raises(ValueError, match="min_consistency"):
        fit_mixture((torch.zeros(2, 3, dtype=torch.long), torch.full((2,), 3), 2),
                    min_consistency=1.5)  # fmt: skip


@pytest.fixture(scope="module")
def lead_or_follow_large():
    """``lead_or_follow`` at 300 subjects x 4 demonstrations: the followers' history
    dependence, which a first-order chain cannot represent, makes every likelihood criterion
    keep a third cluster of followers' sequences (docs/clustering.md)."""
    world = make_task("lead_or_follow")
    return world.demonstrations(subjects=300, per_subject=4, noise=0.05, seed=0)


def test_a_cluster_of_sequences_is_not_a_type(lead_or_follow_large) -> None:
    demos, types = lead_or_follow_large
    options = dict(k_min=1, k_max=4, restarts=10, initial=True, seed=0)
    without = fit_mixture(demos, min_consistency=0.0, **options)
    fit = fit_mixture(demos, **options)
    assert without.k == 3  # what the likelihood criteria alone keep
    assert fit.k == 2 and adjusted_rand_index(types.tolist(), fit.assignments.tolist()) == 1.0
    # the record: the true types are consistent within subjects, the extra cluster is not
    assert fit.per_k[2]["consistency"] > 0.9
    assert fit.per_k[3]["consistency"] < 0.5
    assert "consistency" not in fit.per_k[1]  # one cluster: nothing to tell apart
    # the public diagnostic agrees with the record of the chosen k
    icc = cluster_consistency(fit.model, demos)
    assert float(icc.min()) == pytest.approx(fit.per_k[2]["consistency"], abs=1e-9)
    # the extra cluster of the 3-cluster fit holds followers' sequences of the same subjects
    assert float(cluster_consistency(without.model, demos).min()) < 0.5


def test_sharded_corpus_runs_the_same_check(lead_or_follow_large, tmp_path: Path) -> None:
    demos, _ = lead_or_follow_large
    subjects = demos.unique_subjects
    for i in range(3):
        demos.select_subjects(subjects[i::3]).write_csv(tmp_path / f"part{i}.csv")
    options = dict(k_min=1, k_max=4, restarts=10, initial=True, seed=0)
    memory = fit_mixture(demos, **options)
    shards = fit_mixture(ShardedCorpus(sorted(tmp_path.glob("*.csv"))), **options)
    assert shards.k == memory.k == 2
    for k in (2, 3, 4):
        assert shards.per_k[k]["consistency"] == pytest.approx(
            memory.per_k[k]["consistency"], abs=1e-6
        )
    # merged statistics by subject hold no sequence's own counts: skipped, with a warning
    merged = ShardedCorpus(sorted(tmp_path.glob("*.csv"))).statistics(initial=True)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        fit = fit_mixture(merged, objects="raw", **options)
    assert any("min_consistency" in str(w.message) for w in caught)
    assert all("consistency" not in row for row in fit.per_k.values())


def test_cluster_consistency_needs_subjects() -> None:
    demos, _ = make_task("pace").demonstrations(subjects=6, per_subject=2, seed=0)
    fit = fit_mixture(demos, k_min=2, k_max=2, restarts=2, initial=True, seed=0)
    with pytest.raises(ModelError, match="subject ids"):
        cluster_consistency(fit.model, (demos.sequences, demos.lengths, demos.num_symbols))


def test_cli_min_consistency_option(lead_or_follow_large, tmp_path: Path, capsys) -> None:
    """``torchhrc cluster --min-consistency`` is fit_mixture's ``min_consistency``."""
    import json

    from torchhrc.cli import main

    demos, _ = lead_or_follow_large
    demos.write_csv(tmp_path / "lead.csv")
    argv = ["cluster", str(tmp_path / "lead.csv"), "--k-min", "1", "--k-max", "4", "--json"]
    ks = {}
    for value in ("0", "0.5"):
        assert main([*argv, "--min-consistency", value]) == 0
        report = json.loads(capsys.readouterr().out)
        ks[value] = report["k"]
        assert report["per_k"]["3"]["consistency"] < 0.5
    assert ks == {"0": 3, "0.5": 2}


def _held_out_reference(per_seq, sequences, subjects, model, alpha, weight_alpha):
    """Each sequence's posterior under chains refitted without its subject, by loops: the
    subject responsibilities from the model, then for every subject an M-step over the
    others' expected counts (the definition, written independently of the batched code)."""
    lt, li, lw = model.log_transition, model.log_initial, model.log_weights
    A = lt.shape[-1]
    S = int(subjects.max()) + 1
    counts = torch.zeros(S, A, A, dtype=torch.float64)
    first = torch.zeros(S, A, dtype=torch.float64)
    for seq, s in zip(sequences, subjects.tolist()):
        first[s, seq[0]] += 1
        for x, y in itertools.pairwise(seq):
            counts[s, x, y] += 1
    joint = torch.einsum("sab,kab->sk", counts, lt) + first @ li.T + lw
    r = (joint - joint.logsumexp(-1, keepdim=True)).exp()
    out = []
    for seq, s in zip(sequences, subjects.tolist()):
        keep = torch.arange(S) != s
        n = torch.einsum("sk,sab->kab", r[keep], counts[keep]) + alpha
        f = r[keep].T @ first[keep] + alpha
        w = r[keep].sum(0) + weight_alpha
        score = (w / w.sum()).log() + (f / f.sum(-1, keepdim=True)).log()[:, seq[0]]
        theta = (n / n.sum(-1, keepdim=True)).log()
        for x, y in itertools.pairwise(seq):
            score = score + theta[:, x, y]
        out.append((score - score.logsumexp(-1)).exp())
    return torch.stack(out)


def test_held_out_posteriors_match_their_definition() -> None:
    from torchhrc.mixture import sufficient_statistics
    from torchhrc.mixture.consistency import held_out_posteriors

    demos, _ = make_task("pace").demonstrations(subjects=8, per_subject=3, seed=1)
    # two subjects with the same demonstrations: one row of multiplicity 2, one left out
    lists = demos.to_lists()
    lists[3:6] = lists[0:3]
    from torchhrc.data import Demonstrations

    demos = Demonstrations.from_lists(lists, subjects=[s for s in demos.subjects],
                                      vocabulary=demos.vocabulary)  # fmt: skip
    fit = fit_mixture(demos, k_min=3, k_max=3, restarts=2, initial=True, seed=0)
    args = (demos.sequences, demos.lengths, demos.num_symbols)
    per_seq = sufficient_statistics(*args, initial=True, dtype=torch.float64)
    by_subject = sufficient_statistics(*args, groups=demos.subject_index, initial=True,
                                       dtype=torch.float64)  # fmt: skip
    assert by_subject.num_distinct < by_subject.num_units  # the pooled pair is there
    m = fit.model
    got = held_out_posteriors(per_seq, by_subject, m.log_transition, m.log_initial,
                              m.log_weights, pseudo_transition=0.1, pseudo_initial=0.1,
                              weight_pseudo_count=1.0)  # fmt: skip
    sequences = [demos.sequences[n, : demos.lengths[n]].tolist() for n in range(len(lists))]
    want = _held_out_reference(per_seq, sequences, demos.subject_index, m, 0.1, 1.0)
    torch.testing.assert_close(got, want, rtol=1e-9, atol=1e-12)


def test_a_cluster_fitted_to_few_people_is_judged_without_them() -> None:
    """``lead_or_follow`` (2 types) at 30 x 4, seed 1, second-order chains: the 3-cluster
    fit's third cluster holds 2 followers (what their slips share). Fitted to them, it predicts
    their sequences (in-sample ICC of every cluster above 0.5, the check before it read each
    sequence held out); refitted without the subject, it does not (held-out ICC below 0.5), so
    the selection keeps the 2 true types."""
    demos, types = make_task("lead_or_follow").demonstrations(subjects=30, per_subject=4,
                                                              noise=0.05, seed=1)  # fmt: skip
    options = dict(order=2, k_min=1, k_max=3, restarts=10, initial=True, seed=1,
                   parameters="support")  # fmt: skip
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        three = fit_mixture(demos, **{**options, "k_min": 3, "min_consistency": 0.0})
        fit = fit_mixture(demos, **options)
    m = three.model
    data = m.prepare(demos)
    A = m.log_transition.shape[-1]
    counts = torch.zeros(data.num_sequences, A, A, dtype=torch.float64)
    for n in range(data.num_sequences):
        x = data.sequences[n, : data.lengths[n]].tolist()
        for a, b in itertools.pairwise(x):
            counts[n, a, b] += 1
    firsts = torch.nn.functional.one_hot(data.sequences[:, 0], A).double()
    joint = torch.einsum("nab,kab->nk", counts, m.log_transition) + firsts @ m.log_initial.T
    joint = joint + m.log_weights
    in_sample = intraclass_correlation((joint - joint.logsumexp(-1, keepdim=True)).exp(),
                                       demos.subject_index)  # fmt: skip
    assert float(in_sample.min()) > 0.5
    assert float(cluster_consistency(m, demos).min()) < 0.5
    assert fit.k == 2 and adjusted_rand_index(types.tolist(), fit.assignments.tolist()) == 1.0
