"""Is a cluster a property of the person? Subject consistency of a mixture's clusters.

A human type, in the paper's sense, belongs to a person: every demonstration of one subject
comes from that subject's type. A cluster that describes *sequences* rather than *people*
(the demonstrations with a slip, or with one of a type's history-dependent patterns, which a
first-order chain cannot represent) is not a type, even when it raises the likelihood on
held-out subjects: with enough data every likelihood criterion keeps such a split
(``docs/clustering.md``, "A type belongs to a person").

The check reads each sequence's own posterior over the clusters (from that sequence alone,
``r[n, c] = P(z = c | x_n)``, under the chains refitted without the sequence's subject:
:func:`held_out_posteriors`) and asks how much of its variance lies *between* subjects: the
intraclass correlation of the one-way analysis of variance with subjects as groups
(Shrout & Fleiss 1979, ICC(1); unequal group sizes as in Snedecor & Cochran, ``n0``):

    MSB = sum_g n_g (mean_g - mean)^2 / (G - 1)
    MSW = sum_n (r_n - mean_(g(n)))^2 / (N - G)
    n0  = (N - sum_g n_g^2 / N) / (G - 1)
    ICC = (MSB - MSW) / (MSB + (n0 - 1) MSW)

``ICC`` near 1: a subject's demonstrations agree on the cluster (a type); near 0: whether a
demonstration looks like the cluster varies as much within a subject as between subjects.
:func:`~torchhrc.mixture.fit_mixture` (soft method, subjects known) keeps a k only if each of
its clusters has ``ICC >= min_consistency`` (0.5: most of the variance between people).

Example:
    >>> import torch
    >>> r = torch.tensor([[1.0], [1.0], [0.0], [0.0]])  # two subjects, each consistent
    >>> intraclass_correlation(r, torch.tensor([0, 0, 1, 1]))
    tensor([1.], dtype=torch.float64)
"""

from __future__ import annotations

import math
from typing import Any

import torch

from torchhrc._checks import check_tensor
from torchhrc.errors import ModelError

__all__ = [
    "DEFAULT_MIN_CONSISTENCY",
    "cluster_consistency",
    "intraclass_correlation",
    "split_consistency",
]

#: The least subject consistency (ICC) each cluster of the chosen k must have (soft method,
#: subjects known; chains of every order alike): a type is a property of a person,
#: most of the variance between people. With each sequence read held out (since 2026-12-05)
#: on the task suite (``docs/clustering.md``, "Read without the subject"): the true types
#: 0.67-1.0 at 30 subjects x 4 demonstrations and 0.90-1.0 at 300; the k + 1 fits the
#: selection recorded 0.41 at most at 30 x 4 and 0.35 at 300 x 4.
DEFAULT_MIN_CONSISTENCY = 0.5


def intraclass_correlation(
    values: torch.Tensor, groups: torch.Tensor, *, strata: torch.Tensor | None = None
) -> torch.Tensor:
    """ICC(1) of every column of ``values`` with rows grouped by ``groups``.

    With ``strata`` (groups nested in strata, e.g. subjects in the types of a coarser
    clustering) the between-group mean square is taken about each stratum's mean,
    ``MSB = sum_g n_g (mean_g - mean_(s(g)))^2 / (G - S)``: the share of the variance that
    lies between groups *of one stratum* (the one-way analysis within strata, pooled).

    Args:
        values: ``(N, C)`` float, one row per observation (e.g. a sequence's cluster
            posteriors).
        groups: ``(N,)`` int64 group of every row (e.g. its subject), any ids ``>= 0``.
        strata: ``(N,)`` int64 stratum of every row, the same for all rows of a group
            (default: one stratum, the plain ICC(1)).

    Returns:
        ``(C,)`` float64 in ``(-inf, 1]``; ``nan`` where it is undefined: fewer than 2 groups
        (more groups than strata), no group with 2 or more rows, or a column without variance.

    Raises:
        ValueError: shapes that do not match, or negative group ids.

    Example:
        >>> import torch
        >>> v = torch.tensor([[1.0], [0.0], [1.0], [0.0]])  # each subject has both
        >>> intraclass_correlation(v, torch.tensor([0, 0, 1, 1]))
        tensor([-1.], dtype=torch.float64)
    """
    check_tensor("values", values)
    check_tensor("groups", groups, floating=False)
    if values.ndim != 2:
        raise ValueError(f"expected values of shape (N, C), got {tuple(values.shape)}")
    if groups.shape != values.shape[:1]:
        raise ValueError(
            f"expected groups of shape ({values.shape[0]},) (one per row of values), "
            f"got {tuple(groups.shape)}"
        )
    if groups.numel() and int(groups.min()) < 0:
        raise ValueError(f"expected group ids >= 0, got {int(groups.min())}")
    if strata is not None:
        check_tensor("strata", strata, floating=False)
        if strata.shape != groups.shape:
            raise ValueError(f"expected strata of shape {tuple(groups.shape)} (one per row), "
                             f"got {tuple(strata.shape)}")  # fmt: skip
    v = values.to(torch.float64)
    _, g = torch.unique(groups, return_inverse=True)
    N, C = v.shape
    G = int(g.max()) + 1 if N else 0
    nan = torch.full((C,), math.nan, dtype=torch.float64, device=v.device)
    _, s = torch.unique(torch.zeros_like(g) if strata is None else strata, return_inverse=True)
    S = int(s.max()) + 1 if N else 0
    if G - S < 1 or N <= G:
        return nan
    n = torch.bincount(g, minlength=G).to(v)  # (G,)
    sums = v.new_zeros(G, C).index_add_(0, g, v)
    mean_g = sums / n[:, None]  # (G, C)
    stratum = s.new_zeros(G).scatter_(0, g, s)  # (G,) the stratum of every group
    size_s = v.new_zeros(S).index_add_(0, stratum, n)  # (S,)
    mean_s = v.new_zeros(S, C).index_add_(0, stratum, sums) / size_s[:, None]  # (S, C)
    msb = (n[:, None] * (mean_g - mean_s[stratum]) ** 2).sum(0) / (G - S)
    msw = ((v - mean_g[g]) ** 2).sum(0) / (N - G)
    n0 = (N - float((n**2).sum()) / N) / (G - 1)
    denominator = msb + (n0 - 1.0) * msw
    return torch.where(denominator > 0, (msb - msw) / denominator, nan)


def split_consistency(rows: torch.Tensor, coarser: torch.Tensor, groups: torch.Tensor) -> float:
    """Is going from a coarser clustering to this one a split of people? The largest ICC of
    ``rows``' clusters among the subjects of one coarser cluster (:func:`intraclass_correlation`
    with ``strata``: each subject in the coarser cluster holding most of its posterior mass).

    A cluster that splits off a real type from a coarser one separates the subjects of that
    coarser cluster (ICC near 1 within it); one that splits each subject's sequences at random
    (slips, history a first-order chain cannot hold) does not, although its plain ICC over all
    subjects can reach 0.5 from the coarser types alone (the other types' subjects sit at 0).
    Clusters untouched by the split vary little within a stratum and do not count (``nan``).

    Args:
        rows: ``(N, K)`` each sequence's own posterior over the finer clustering's clusters.
        coarser: ``(N, K')`` the same over the coarser clustering's (e.g. ``K' = K - 1``).
        groups: ``(N,)`` int64 subject of every sequence.

    Returns:
        The largest defined ICC within strata, or ``nan`` (none defined).

    Example:
        >>> import torch
        >>> g = torch.tensor([0, 0, 1, 1, 2, 2, 3, 3])
        >>> one = torch.ones(8, 1)  # a coarser clustering of one cluster: the plain ICC
        >>> rows = torch.tensor([[1.0, 0.0]] * 4 + [[0.0, 1.0]] * 4)  # subjects 0-1 and 2-3
        >>> split_consistency(rows, one, g)
        1.0
    """
    _, g = torch.unique(groups, return_inverse=True)
    G = int(g.max()) + 1 if g.numel() else 0
    mass = coarser.new_zeros(G, coarser.shape[-1]).index_add_(0, g, coarser)  # (G, K')
    strata = mass.argmax(-1)[g]  # (N,)
    icc = intraclass_correlation(rows, g, strata=strata)
    defined = icc[~icc.isnan()]
    return float(defined.max()) if defined.numel() else math.nan


def _held_out_sum(
    sequence_counts: torch.Tensor,
    pair_row: torch.Tensor,
    pair_unit: torch.Tensor,
    unit_counts: torch.Tensor,
    total: torch.Tensor,
    row_of: torch.Tensor,
    responsibilities: torch.Tensor,
    low: float,
) -> torch.Tensor:
    """``(P, K)`` sum over the counts of each pair's sequence of ``log theta`` without its unit.

    ``theta[k, d] = (total[k, d] - r[u, k] c_u[d]) / (sum_(d' in row(d)) of the same)``: one
    row ``row_of[d]`` of ``total`` (pseudo-counts included) per outcome ``d``. Only the
    outcomes a sequence holds are visited (its nonzero counts: the tables stay sparse)."""
    K = total.shape[0]
    row_total = total.new_zeros(K, int(row_of.max()) + 1).index_add_(1, row_of, total)
    unit_rows = unit_counts.new_zeros(unit_counts.shape[0], row_total.shape[1])
    unit_rows.index_add_(1, row_of, unit_counts)  # (U, rows)
    nq, nd = sequence_counts.nonzero(as_tuple=True)  # row-major: grouped by sequence row
    lengths = torch.bincount(nq, minlength=sequence_counts.shape[0])
    starts = torch.cumsum(lengths, 0) - lengths
    per_pair = lengths[pair_row]
    pair = torch.repeat_interleave(torch.arange(len(pair_row), device=nq.device), per_pair)
    first = torch.repeat_interleave(torch.cumsum(per_pair, 0) - per_pair, per_pair)
    entry = starts[pair_row][pair] + torch.arange(len(pair), device=nq.device) - first
    q, d, u = nq[entry], nd[entry], pair_unit[pair]
    ru = responsibilities[u]  # (E, K)
    tiny = torch.finfo(total.dtype).tiny
    numerator = (total[:, d].T - ru * unit_counts[u, d][:, None]).clamp_min(tiny)
    row = row_of[d]
    denominator = (row_total[:, row].T - ru * unit_rows[u, row][:, None]).clamp_min(tiny)
    log_theta = (numerator.log() - denominator.log()).clamp_min(low)
    weighted = sequence_counts[q, d][:, None] * log_theta
    return total.new_zeros(len(pair_row), K).index_add_(0, pair, weighted)


def held_out_posteriors(
    per_sequence: Any,
    units: Any,
    log_transition: torch.Tensor,
    log_initial: torch.Tensor | None,
    log_weights: torch.Tensor,
    *,
    pseudo_transition: float | torch.Tensor,
    pseudo_initial: float | torch.Tensor,
    weight_pseudo_count: float,
    floor: float = 1e-10,
) -> torch.Tensor:
    """Each sequence's posterior over the clusters from that sequence alone, under the chains
    refitted *without its subject*: one M-step from the fit's responsibilities of the other
    subjects, with the fit's pseudo-counts.

    Why held out: a cluster fitted to the sequences of a few subjects predicts those sequences
    well because it was fitted to them, so their in-sample posteriors agree within those
    subjects (an ICC of 0.6-0.7 for two subjects' slips in ``lead_or_follow``, seed 1, second
    order) though the cluster holds nothing that other people share. Refitted without the
    subject, it predicts that subject's sequences only as well as the other members make it
    (ICC 0.2-0.3 there), while a type that many people share barely moves.

    Args:
        per_sequence: :class:`~torchhrc.mixture.counts.SufficientStatistics` with one unit
            per sequence (``inverse (N,)``: each sequence's distinct row).
        units: the fit's statistics by subject (``inverse (N,)``: each sequence's subject row;
            a row of multiplicity ``m`` stands for ``m`` subjects with those counts, one of
            whom is left out).
        log_transition: ``(K, A, A)``; log_initial: ``(K, A)`` or None; log_weights: ``(K,)``:
            the fit, whose responsibilities by subject are recomputed from them.
        pseudo_transition: the M-step's pseudo-count: a float or ``(A, A)``
            (:class:`~torchhrc.mixture._em.Smoothing`).
        pseudo_initial: a float or ``(A,)``.
        weight_pseudo_count: the pseudo-count on cluster sizes.
        floor: a probability below it counts as it (a finite penalty).

    Returns:
        ``(N, K)`` float64, rows summing to 1.

    Example:
        >>> import torch
        >>> from torchhrc.mixture import sufficient_statistics
        >>> seqs = torch.tensor([[0, 0, 0], [0, 0, 0], [1, 1, 1], [1, 1, 1]])
        >>> lengths, groups = torch.full((4,), 3), torch.tensor([0, 0, 1, 1])
        >>> by_seq = sufficient_statistics(seqs, lengths, 2)
        >>> by_subject = sufficient_statistics(seqs, lengths, 2, groups=groups)
        >>> lt = torch.tensor([[[0.9, 0.1], [0.5, 0.5]], [[0.5, 0.5], [0.1, 0.9]]]).log()
        >>> post = held_out_posteriors(by_seq, by_subject, lt, None, torch.zeros(2).log_softmax(0),
        ...     pseudo_transition=0.5, pseudo_initial=0.5, weight_pseudo_count=1.0)
        >>> post.argmax(-1).tolist()  # each subject alone in its cluster: refitted, it is empty
        [1, 1, 0, 0]
    """
    from torchhrc.mixture._em import e_table

    low = math.log(floor)
    A = log_transition.shape[-1]
    lt = log_transition.to(torch.float64).clamp_min(low)
    C = units.counts.to(torch.float64)  # (U, A * A)
    with_initial = log_initial is not None and units.first_counts is not None
    F = units.first_counts.to(C) if with_initial else None
    li = log_initial.to(C).clamp_min(low)[None] if with_initial else None
    joint = e_table(C, F, lt[None], li)[:, 0] + log_weights.to(C)
    r = (joint - torch.logsumexp(joint, -1, keepdim=True)).exp()  # (U, K)
    rm = r * units.multiplicity.to(C)[:, None]
    # the distinct (sequence row, subject row) pairs: the unit each sequence is scored without
    q_of = per_sequence.inverse
    key = q_of * C.shape[0] + units.inverse.to(q_of.device)
    pairs, pair_of = torch.unique(key, return_inverse=True)
    pair_row, pair_unit = pairs // C.shape[0], pairs % C.shape[0]
    pt = torch.as_tensor(pseudo_transition, dtype=C.dtype, device=C.device)
    total = rm.T @ C + pt.expand(A, A).reshape(-1)  # (K, A * A) the fit's M-step counts
    rows = torch.arange(A * A, device=C.device) // A  # each transition's row: its source
    out = _held_out_sum(per_sequence.counts.to(C), pair_row, pair_unit, C, total, rows, r, low)
    if with_initial and per_sequence.first_counts is not None:
        pi = torch.as_tensor(pseudo_initial, dtype=C.dtype, device=C.device)
        first_total = rm.T @ F + pi.expand(A)  # (K, A), one row
        one_row = torch.zeros(A, dtype=torch.long, device=C.device)
        out = out + _held_out_sum(per_sequence.first_counts.to(C), pair_row, pair_unit, F,
                                  first_total, one_row, r, low)  # fmt: skip
    sizes = rm.sum(0)[None] - r[pair_unit] + weight_pseudo_count  # (P, K)
    tiny = torch.finfo(C.dtype).tiny
    out = out + sizes.clamp_min(tiny).log() - sizes.sum(-1, keepdim=True).clamp_min(tiny).log()
    return (out - torch.logsumexp(out, -1, keepdim=True)).exp()[pair_of]


def cluster_consistency(
    model: Any,
    demonstrations: Any,
    *,
    pseudo_count: float | None = None,
    weight_pseudo_count: float | None = None,
    floor: float = 1e-10,
) -> torch.Tensor:
    """How much each cluster of ``model`` is a property of the subject (ICC, see the module),
    each sequence read under the chains refitted without its subject
    (:func:`held_out_posteriors`).

    Args:
        model: a fitted :class:`~torchhrc.mixture.MarkovChainMixture` (``fit.model``).
        demonstrations: the :class:`~torchhrc.data.Demonstrations` it was fitted to (with
            subject ids; read in the model's form through ``model.prepare``).
        pseudo_count, weight_pseudo_count: the fit's (``None``: ``fit_mixture``'s defaults,
            0.1 and 1; for a higher-order model on the context symbols' support only).
        floor: probability floor of unseen transitions.

    Returns:
        ``(K,)`` float64, one ICC per cluster (``nan`` where undefined: e.g. one demonstration
        per subject), as :func:`~torchhrc.mixture.fit_mixture` records it for the soft method
        (subjects with equal summed counts pooled into one group).

    Raises:
        ModelError: data without subject ids, or a higher-order model and demonstrations
            other than the ones it was fitted to.

    Example:
        >>> from torchhrc.mixture import fit_mixture
        >>> from torchhrc.tasks import make_task
        >>> demos, _ = make_task("pace").demonstrations(subjects=12, per_subject=3, seed=0)
        >>> fit = fit_mixture(demos, k_min=3, k_max=3, restarts=2, initial=True, seed=0)
        >>> bool((cluster_consistency(fit.model, demos) > 0.5).all())
        True
    """
    from torchhrc.mixture._em import (
        DEFAULT_PSEUDO_COUNT,
        DEFAULT_WEIGHT_PSEUDO_COUNT,
        Smoothing,
        pseudo_parts,
    )
    from torchhrc.mixture.counts import sufficient_statistics
    from torchhrc.mixture.history import context_symbols

    subjects = getattr(demonstrations, "subject_index", None)
    if subjects is None or isinstance(demonstrations, tuple):
        raise ModelError(
            "cluster_consistency needs Demonstrations with subject ids, got "
            f"{type(demonstrations).__name__}"
        )
    alpha = DEFAULT_PSEUDO_COUNT if pseudo_count is None else float(pseudo_count)
    smoothing: float | Smoothing = alpha
    order = getattr(model, "order", 1)
    if order == 1:
        data = model.prepare(demonstrations)
    else:  # prepare's lowering, with the support it knows (data in the model's symbols)
        source = demonstrations
        if model.objects == "exchangeable":
            source = source.relabel_objects(separator=model.object_separator)
        lowered = context_symbols(source, order)
        if lowered.data.vocabulary != model.vocabulary:
            raise ModelError(
                "cluster_consistency of a higher-order model needs the demonstrations it "
                "was fitted to (their context symbols differ from the model's)"
            )
        smoothing = Smoothing.on_support(alpha, lowered.transition_support,
                                         lowered.initial_support)  # fmt: skip
        data = lowered.data
    initial = model.log_initial is not None
    args = (data.sequences, data.lengths, data.num_symbols)
    per_sequence = sufficient_statistics(*args, initial=initial, dtype=torch.float64)
    by_subject = sufficient_statistics(
        *args, groups=demonstrations.subject_index, initial=initial, dtype=torch.float64
    )
    pt, pi = pseudo_parts(smoothing)
    rows = held_out_posteriors(
        per_sequence, by_subject, model.log_transition, model.log_initial, model.log_weights,
        pseudo_transition=pt, pseudo_initial=pi,
        weight_pseudo_count=(DEFAULT_WEIGHT_PSEUDO_COUNT if weight_pseudo_count is None
                             else float(weight_pseudo_count)),
        floor=floor,
    )  # fmt: skip
    return intraclass_correlation(rows, by_subject.inverse)
