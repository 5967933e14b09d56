"""Exact-ICL refinement of a hard partition (``torchhrc.mixture.refine``) and its use by the
selection (``fit_mixture``)."""

from __future__ import annotations

import warnings

import pytest
import torch

import torchhrc.mixture.selection as selection
from torchhrc.data import Demonstrations
from torchhrc.metrics import adjusted_rand_index
from torchhrc.mixture import fit_mixture, sufficient_statistics
from torchhrc.mixture.criteria import exact_icl
from torchhrc.mixture.refine import refine_partition

pytestmark = pytest.mark.numeric


def _icl(stats, z, k, outcomes=None):
    mask = torch.ones(1, k, dtype=torch.bool)
    return float(exact_icl(stats, z[:, None], mask, outcomes=outcomes)[0])


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_refinement_ends_where_no_single_move_raises_the_exact_icl(seed: int) -> None:
    """From a random start: the exact ICL (computed from scratch by ``exact_icl``) rises, no
    cluster is emptied, and no single move of a unit to another cluster raises it further."""
    g = torch.Generator().manual_seed(seed)
    N, L, A, k = 40, 9, 4, 3
    chains = torch.rand(k, A, A, generator=g) ** 3
    chains = chains / chains.sum(-1, keepdim=True)
    rows = []
    for n in range(N):
        x = [int(torch.randint(A, (), generator=g))]
        for _ in range(L - 1):
            x.append(int(torch.multinomial(chains[n % k, x[-1]], 1, generator=g)))
        rows.append(x)
    seqs = torch.tensor(rows)
    groups = torch.arange(N) // 2  # two sequences per subject
    stats = sufficient_statistics(seqs, torch.full((N,), L), A, groups=groups, initial=True)
    start = torch.randint(k, (stats.counts.shape[0],), generator=g)
    start[:k] = torch.arange(k)  # every cluster used
    z = refine_partition(stats, start, k)
    best = _icl(stats, z, k)
    assert best > _icl(stats, start, k)
    assert torch.bincount(z, minlength=k).min() >= 1
    for u in range(len(z)):
        for c in range(k):
            if c == int(z[u]) or int((z == z[u]).sum()) == 1:
                continue
            moved = z.clone()
            moved[u] = c
            assert _icl(stats, moved, k) <= best + 1e-9


def test_refinement_checks_its_input() -> None:
    stats = sufficient_statistics(torch.tensor([[0, 1], [1, 0]]), torch.tensor([2, 2]), 2)
    with pytest.raises(ValueError, match="shape"):
        refine_partition(stats, torch.zeros(3, dtype=torch.long), 2)
    with pytest.raises(ValueError, match=r"in \[0, 2\)"):
        refine_partition(stats, torch.tensor([0, 2]), 2)


def _lingering(subjects: int, seed: int) -> tuple[Demonstrations, list[int]]:
    """The held-out task ``slow_sanding`` (benchmarks/heldout_tasks.py) simulated directly:
    four steps (cut, sand, drill, finish), each the person's; each turn the robot holds the
    piece, or waits (a slip, 1 in 40). With the piece held a brisk person does the step; a
    careful one, at the sanding step, lingers 2 turns in 3 (the robot acts again). Unheld,
    either does the step half the time (the careful one a third of the time when sanding).
    A person slips into doing the step 1 turn in 20. 4 demonstrations per subject, half the
    subjects careful."""
    g = torch.Generator().manual_seed(seed)

    def draw() -> float:
        return float(torch.rand((), generator=g))

    seqs, ids, types = [], [], []
    for s in range(subjects):
        careful = s % 2
        for _ in range(4):
            seq, step = [], 0
            while step < 4 and len(seq) < 40:
                held = draw() >= 0.025
                seq.append(("robot", "hold" if held else "wait"))
                act = 1.0 if held else 0.5
                if careful and step == 1:
                    act = 1 / 3
                if draw() < 0.05 + 0.95 * act:
                    seq.append(("human", ("cut", "sand", "drill", "finish")[step]))
                    step += 1
            seqs.append(seq)
            ids.append(f"s{s:03d}")
            types.append(careful)
    return Demonstrations.from_lists(seqs, subjects=ids), types


def test_the_selection_keeps_the_refined_partition_where_the_exact_icl_prefers_k(monkeypatch):
    """300 subjects (seed 2): the mixture's maximum likelihood moves careful people who
    lingered once into the brisk cluster; the refinement moves them back (log p(D, z) charges
    a brisk chain for allowing a linger). Without it (monkeypatched away) the partition is
    worse."""
    demos, types = _lingering(300, seed=2)
    options = dict(order=2, k_min=1, k_max=3, restarts=5, initial=True, seed=0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fit = fit_mixture(demos, **options)
        monkeypatch.setattr(selection, "refine_partition", lambda stats, z, k, **kw: z)
        plain = fit_mixture(demos, **options)
    assert fit.k == plain.k == 2
    refined_ari = adjusted_rand_index(types, fit.assignments.tolist())
    plain_ari = adjusted_rand_index(types, plain.assignments.tolist())
    assert fit.per_k[2]["refined_moves"] >= 1
    assert fit.per_k[2]["exact_icl_refined"] > fit.per_k[2]["exact_icl_recorded"]
    assert refined_ari > plain_ari and refined_ari >= 0.9
    # the kept model's figures are recorded beside the EM run's, and they are the fit's
    assert fit.per_k[2]["log_likelihood_refined"] == pytest.approx(fit.log_likelihood, abs=1e-9)
    assert fit.per_k[2]["bic_refined"] == pytest.approx(fit.bic, abs=1e-9)
    assert fit.per_k[2]["log_likelihood"] == pytest.approx(plain.per_k[2]["log_likelihood"])
    assert fit.per_k[2]["log_likelihood_refined"] != pytest.approx(fit.per_k[2]["log_likelihood"])


def test_no_refinement_where_the_exact_icl_prefers_fewer_clusters() -> None:
    """30 subjects of the same two types: the exact ICL prefers one cluster, and moves by it
    would drift towards one; the selection keeps EM's partition (nothing recorded)."""
    demos, _ = _lingering(30, seed=0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fit = fit_mixture(demos, order=2, k_min=1, k_max=3, restarts=5, initial=True, seed=0,
                          min_consistency=0.0)  # fmt: skip
    for row in fit.per_k.values():
        assert "refined_moves" not in row


def test_the_order_comparison_reads_the_refined_partition() -> None:
    """``order="auto"`` compares the kept partitions' log p(D, z): the refined one's."""
    demos, _ = _lingering(300, seed=2)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fit = fit_mixture(demos, order="auto", k_min=1, k_max=3, restarts=5, initial=True,
                          seed=0)  # fmt: skip
    assert fit.order == 2 and "exact_icl_refined" in fit.per_k[2]
    assert fit.order_comparison["2"]["exact_icl"] == pytest.approx(
        fit.per_k[2]["exact_icl_refined"], abs=1e-6
    )


def test_k_min_2_refines_against_one_cluster() -> None:
    """``fit_mixture``'s own default range starts at k = 2: its k = 2 partition is refined
    against the one-cluster partition, as with k_min = 1."""
    demos, types = _lingering(300, seed=2)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fit = fit_mixture(demos, order=2, k_min=2, k_max=3, restarts=5, initial=True, seed=0)
    assert fit.k == 2 and fit.per_k[2]["refined_moves"] >= 1
    assert adjusted_rand_index(types, fit.assignments.tolist()) >= 0.9
