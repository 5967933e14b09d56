"""Subject consistency: a type belongs to a person (``torchhrc.mixture.consistency``)."""

from __future__ import annotations

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
