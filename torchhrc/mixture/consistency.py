"""Is a cluster a property of the person? Subject consistency of a mixture's clusters.

A human type, in the paper's sense, belongs to a person: every demonstration of one subject
comes from that subject's type. A cluster that describes *sequences* rather than *people*
(the demonstrations with a slip, or with one of a type's history-dependent patterns, which a
first-order chain cannot represent) is not a type, even when it raises the likelihood on
held-out subjects: with enough data every likelihood criterion keeps such a split
(``docs/clustering.md``, "A type belongs to a person").

The check reads each sequence's own posterior over the clusters (from that sequence alone,
``r[n, c] = P(z = c | x_n)``) and asks how much of its variance lies *between* subjects: the
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
#: subjects known): a type is a property of a person. Measured on the task suite, the paper's
#: study, the kitchen and synthetic chains (``docs/clustering.md``): true types 0.75-1.0 at
#: 30 and 300 subjects x 4 demonstrations; the extra clusters that likelihood criteria keep
#: with 300 subjects 0.22-0.35.
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


def _posteriors(
    counts: torch.Tensor,
    first_counts: torch.Tensor | None,
    log_transition: torch.Tensor,
    log_initial: torch.Tensor | None,
    log_weights: torch.Tensor,
    floor: float,
) -> torch.Tensor:
    """``(U, K)`` posterior of each count row from its own counts (finite: floored)."""
    from torchhrc.mixture._em import e_table

    low = math.log(floor)
    lt = log_transition.clamp_min(low)[None]
    li = None if log_initial is None or first_counts is None else log_initial.clamp_min(low)[None]
    joint = e_table(counts, first_counts, lt.to(counts.dtype), li)[:, 0] + log_weights.to(counts)
    return (joint - torch.logsumexp(joint, -1, keepdim=True)).exp()


def row_consistency(
    sequence_stats: Any,
    groups: torch.Tensor,
    log_transition: torch.Tensor,
    log_initial: torch.Tensor | None,
    log_weights: torch.Tensor,
    *,
    floor: float = 1e-10,
) -> torch.Tensor:
    """:func:`intraclass_correlation` of one mixture's clusters, from per-sequence statistics.

    Args:
        sequence_stats: :class:`~torchhrc.mixture.counts.SufficientStatistics` with one unit
            per sequence (``inverse (N,)``: each sequence's distinct row).
        groups: ``(N,)`` subject (group) of every sequence. :func:`fit_mixture` and
            :func:`cluster_consistency` pool subjects whose summed counts are equal (they are
            one unit row of the fit, whatever the data's storage: memory or shards).
        log_transition: ``(K, A, A)``; log_initial: ``(K, A)`` or None; log_weights: ``(K,)``.
        floor: a probability below it counts as it (an unseen transition is a finite penalty).

    Returns:
        ``(K,)`` float64 ICC of every cluster (``nan``: undefined, see
        :func:`intraclass_correlation`).
    """
    rows = _posteriors(sequence_stats.counts, sequence_stats.first_counts, log_transition,
                       log_initial, log_weights, floor)  # fmt: skip
    return intraclass_correlation(rows[sequence_stats.inverse], groups)


def cluster_consistency(model: Any, demonstrations: Any, *, floor: float = 1e-10) -> torch.Tensor:
    """How much each cluster of ``model`` is a property of the subject (ICC, see the module).

    Args:
        model: a fitted :class:`~torchhrc.mixture.MarkovChainMixture` (``fit.model``).
        demonstrations: the :class:`~torchhrc.data.Demonstrations` it was fitted to (with
            subject ids; read in the model's form through ``model.prepare``).
        floor: probability floor of unseen transitions.

    Returns:
        ``(K,)`` float64, one ICC per cluster (``nan`` where undefined: e.g. one demonstration
        per subject), as :func:`~torchhrc.mixture.fit_mixture` records it (subjects with
        equal summed counts pooled into one group).

    Raises:
        ModelError: data without subject ids.

    Example:
        >>> from torchhrc.mixture import fit_mixture
        >>> from torchhrc.tasks import make_task
        >>> demos, _ = make_task("pace").demonstrations(subjects=12, per_subject=3, seed=0)
        >>> fit = fit_mixture(demos, k_min=3, k_max=3, restarts=2, initial=True, seed=0)
        >>> bool((cluster_consistency(fit.model, demos) > 0.5).all())
        True
    """
    from torchhrc.mixture.counts import sufficient_statistics

    subjects = getattr(demonstrations, "subject_index", None)
    if subjects is None or isinstance(demonstrations, tuple):
        raise ModelError(
            "cluster_consistency needs Demonstrations with subject ids, got "
            f"{type(demonstrations).__name__}"
        )
    data = model.prepare(demonstrations)
    initial = model.log_initial is not None
    args = (data.sequences, data.lengths, data.num_symbols)
    per_sequence = sufficient_statistics(*args, initial=initial, dtype=torch.float64)
    by_subject = sufficient_statistics(
        *args, groups=demonstrations.subject_index, dtype=torch.float64
    )
    log_initial = None if model.log_initial is None else model.log_initial.to(torch.float64)
    return row_consistency(
        per_sequence, by_subject.inverse, model.log_transition.to(torch.float64), log_initial,
        model.log_weights.to(torch.float64), floor=floor,
    )  # fmt: skip
