"""Scores that choose the number of types: BIC, the exact ICL, gains per transition, and
the rules built on them (``fit_mixture``'s ``criterion=``, ``min_gain``, ``strong_gain``).

Split out of :mod:`.selection` (which fits every k and applies these rules) so that each
file holds one concept; ``torchhrc.mixture.selection`` re-exports every public name.

Example:
    >>> from torchhrc.mixture.criteria import bic
    >>> round(float(bic(-100.0, 10, 50)), 3)
    -119.56
"""

from __future__ import annotations

import math
import warnings
from typing import Any, Literal

import torch

from torchhrc.mixture.counts import SufficientStatistics, sufficient_statistics
from torchhrc.mixture.hard_em import partition_counts, partition_sizes

Method = Literal["soft", "paper"]

__all__ = [
    "DEFAULT_HELDOUT_GAIN",
    "DEFAULT_MIN_GAIN",
    "DEFAULT_STRONG_GAIN",
    "EXACT_ICL_PRIOR",
    "bic",
    "exact_icl",
    "gains_per_transition",
    "num_free_parameters",
    "num_transitions",
    "partition_icl",
]


def num_free_parameters(
    k: int | torch.Tensor, num_symbols: int, *, method: Method = "soft", initial: bool = False
) -> int | torch.Tensor:
    """Free parameters counted by the BIC.

    ``"paper"``: ``k A (A - 1)`` (Select-Best-Model, line 5). ``"soft"``: plus ``k - 1``
    weights, plus ``k (A - 1)`` when first symbols are modelled.

    Example:
        >>> num_free_parameters(2, 7, method="paper")
        84
    """
    A = num_symbols
    n = k * A * (A - 1)
    if method != "paper":
        n = n + (k - 1)
        if initial:
            n = n + k * (A - 1)
    return n


def bic(log_likelihood: torch.Tensor | float, num_parameters: Any, num_data: int) -> Any:
    """``BIC = l - K/2 log n`` (the paper's sign convention: larger is better).

    Example:
        >>> round(bic(-100.0, 84, 54), 3)
        -267.537
    """
    return log_likelihood - num_parameters / 2 * math.log(num_data)


#: Dirichlet concentration of every transition row (and first-symbol distribution) in
#: :func:`exact_icl`: Jeffreys' prior for a multinomial, as Biernacki, Celeux, Govaert (2010)
#: use for the latent class model.
EXACT_ICL_PRIOR = 0.5


def _log_dirichlet_multinomial(
    counts: torch.Tensor, alpha: float, outcomes: int | None = None
) -> torch.Tensor:
    """``(...)`` log marginal probability of the ordered draws with counts ``(..., A)`` under
    a multinomial whose probabilities are integrated out over a symmetric Dirichlet(alpha):
    ``log B(n + alpha) - log B(alpha)``, ``B`` the multivariate Beta function (0 for a row
    without counts). ``outcomes``: the number ``m`` of categories the Dirichlet is over
    (default ``A``); the entries of ``counts`` beyond the ``m`` possible ones must be 0 (a
    category without draws adds ``lgamma(alpha) - lgamma(alpha) = 0``)."""
    A = counts.shape[-1]
    m = A if outcomes is None else outcomes
    return (
        torch.lgamma(counts + alpha).sum(-1)
        - A * math.lgamma(alpha)
        + math.lgamma(m * alpha)
        - torch.lgamma(counts.sum(-1) + m * alpha)
    )


def exact_icl(
    stats: SufficientStatistics,
    assignments: torch.Tensor,
    cluster_mask: torch.Tensor,
    *,
    prior: float = EXACT_ICL_PRIOR,
    weight_prior: float = 1.0,
    outcomes: int | None = None,
) -> torch.Tensor:
    """Exact integrated classification likelihood ``log p(D, z)`` of hard partitions.

    Biernacki, Celeux, Govaert (2010), "Exact and Monte Carlo calculations of integrated
    likelihoods for the latent class model", for Markov chains: with a symmetric
    Dirichlet(``prior``) on every transition row of every cluster and a
    Dirichlet(``weight_prior``) on the weights of the ``k_r`` clusters of run ``r``, the
    parameters integrate out in closed form:

    ``ICL(z) = sum_k sum_a [log B(n_k(a, .) + prior) - log B(prior)]
    + log B(m + weight_prior) - log B(weight_prior)``,

    ``n_k(a, b)`` the transitions ``a -> b`` of the units of cluster ``k``, ``m_k`` the units
    in cluster ``k``, ``B`` the multivariate Beta function (plus the same term for the first
    symbols when they are modelled). A row that a cluster never visits adds exactly 0, a row
    visited ``n`` times with ``s`` distinct successors about ``(s - 1)/2 log n``: no count of
    parameters is needed, unlike BIC's ``k A (A - 1)``.

    Args:
        stats: the distinct units.
        assignments: ``(U, R)`` int64 cluster slot of every distinct row in each run.
        cluster_mask: ``(R, K)`` bool, the slots each run uses (``k_r`` = its row sum).
        prior: Dirichlet concentration of every transition row (default: Jeffreys, 1/2).
        weight_prior: Dirichlet concentration of the mixture weights.
        outcomes: the number of successors each row's Dirichlet is over (default ``A``): for
            the context symbols of :mod:`torchhrc.mixture.history`, the recorded symbols, so
            that ``log p(D, z)`` of a higher-order chain compares with a first-order one's.

    Returns:
        ``(R,)`` float64 (larger is better).

    Example:
        >>> from torchhrc.mixture import sufficient_statistics
        >>> seqs = torch.tensor([[0, 1, 0, 1]] * 5 + [[0, 0, 0, 0]] * 5)
        >>> s = sufficient_statistics(seqs, torch.full((10,), 4), 2)  # 2 distinct rows
        >>> mask = torch.ones(2, 2, dtype=torch.bool)
        >>> icl = exact_icl(s, torch.tensor([[0, 0], [1, 0]]), mask)  # split, then merged
        >>> bool(icl[0] > icl[1])
        True
    """
    R, K = cluster_mask.shape
    A = stats.num_symbols
    counts, first = partition_counts(stats, assignments, K, torch.float64)  # (R*K, A*A)
    out = _log_dirichlet_multinomial(counts.view(R, K, A, A), prior, outcomes).sum((-1, -2))
    if first is not None:
        out = out + _log_dirichlet_multinomial(first.view(R, K, A), prior, outcomes).sum(-1)
    sizes = partition_sizes(assignments, stats.multiplicity.double(), K)  # (R, K)
    k = cluster_mask.sum(-1).double()  # (R,)
    weights = (torch.lgamma(sizes + weight_prior) - math.lgamma(weight_prior)).masked_fill(
        ~cluster_mask, 0.0
    )
    n = sizes.sum(-1)
    return (
        out + weights.sum(-1) + torch.lgamma(k * weight_prior) - torch.lgamma(n + k * weight_prior)
    )


def partition_icl(
    data: Any,
    partitions: list[torch.Tensor],
    order: int = 1,
    *,
    groups: torch.Tensor | None = None,
    initial: bool = True,
    prior: float = EXACT_ICL_PRIOR,
) -> list[float]:
    """The exact ICL ``log p(D, z)`` of given partitions of the same demonstrations, under
    chains of one ``order`` (:func:`exact_icl`; orders 2 and 3 through
    :func:`~torchhrc.mixture.history.context_symbols`, each context's Dirichlet over the
    ``A`` recorded symbols, so that every order scores the same data).

    Partitions found with chains of different orders are compared under one order with it
    (``fit_mixture(order="auto")``, :func:`~torchhrc.mixture.selection.order_to_keep`): each
    order's own exact ICL is of another model, larger at the higher order whatever the
    partition.

    Args:
        data: a :class:`~torchhrc.data.Demonstrations` of ``N`` sequences over ``A`` symbols.
        partitions: ``(N,)`` int64 labels, one tensor per partition (any label values; a
            partition's number of clusters is its number of distinct labels).
        order: the chains' order, 1 to :data:`~torchhrc.mixture.history.MAX_ORDER`.
        groups: ``(N,)`` int64 unit of every sequence (all sequences of a unit share one
            cluster, as ``fit_mixture(unit="subject")``), or None: every sequence alone.
        initial: whether the first symbols are modelled (as ``fit_mixture(initial=)``).
        prior: Dirichlet concentration of every row (default: Jeffreys, 1/2).

    Returns:
        One float per partition (larger is better).

    Raises:
        ValueError: a partition of the wrong shape, or with two labels in one unit.

    Example:
        >>> import torch
        >>> from torchhrc.data import Demonstrations
        >>> d = Demonstrations.from_lists([[("human", "a"), ("human", "b")] * 3] * 4
        ...                               + [[("human", "a"), ("human", "a")] * 3] * 4)
        >>> right, wrong = torch.tensor([0] * 4 + [1] * 4), torch.tensor([0, 1] * 4)
        >>> one, two = partition_icl(d, [right, wrong])
        >>> one > two
        True
    """
    from torchhrc.mixture.history import context_symbols

    lowered = data if order == 1 else context_symbols(data, order).data
    N = lowered.sequences.shape[0]
    stats = sufficient_statistics(lowered.sequences, lowered.lengths, lowered.num_symbols,
                                  initial=initial, groups=groups, deduplicate=False)  # fmt: skip
    out = []
    for i, z in enumerate(partitions):
        if z.shape != (N,):
            raise ValueError(
                f"expected partitions[{i}] of shape ({N},) (one label per sequence), got "
                f"{tuple(z.shape)}"
            )
        labels, z = torch.unique(z, return_inverse=True)
        rows = torch.zeros(stats.counts.shape[0], dtype=torch.long).index_copy_(0, stats.inverse, z)
        if not torch.equal(rows[stats.inverse], z):
            raise ValueError(f"expected partitions[{i}] to give all sequences of a unit one "
                             "label (groups), got two labels in one unit")  # fmt: skip
        mask = torch.ones(1, len(labels), dtype=torch.bool)
        score = exact_icl(stats, rows[:, None], mask, prior=prior, outcomes=data.num_symbols)
        out.append(float(score[0]))
    return out


def _support_parameters(stats: SufficientStatistics) -> int:
    """Free parameters of one chain on the observed support: ``sum_a max(s_a - 1, 0)``.

    ``s_a`` = number of distinct successors of ``a`` seen anywhere in the data.
    """
    A = stats.num_symbols
    seen = ((stats.counts * stats.multiplicity[:, None]).sum(0) > 0).view(A, A)
    return int((seen.sum(-1) - 1).clamp_min(0).sum())


#: The default ``min_gain`` of the soft method, nats per transition. Measured on the
#: place-and-drill corpora of ``docs/clustering.md`` (seeds 0-2): a true type adds 0.04-0.27,
#: a sub-cluster of one type (noise patterns, placement orders) 0.003-0.005.
DEFAULT_MIN_GAIN = 0.015


def num_transitions(stats: SufficientStatistics) -> float:
    """``T``, the number of transitions in the data (all units, with multiplicity).

    Example:
        >>> from torchhrc.mixture import sufficient_statistics
        >>> s = sufficient_statistics(torch.tensor([[0, 1, 1], [1, 0, 0]]), torch.tensor([3, 2]), 2)
        >>> num_transitions(s)
        3.0
    """
    return float((stats.counts.sum(-1) * stats.multiplicity).sum())


def gains_per_transition(log_likelihoods: torch.Tensor, transitions: float) -> torch.Tensor:
    """``(num_k,)`` gain of each k over the previous one, in nats per transition.

    ``gain[i] = (l[i] - l[i - 1]) / T`` for consecutive ``k``; ``gain[0] = nan``.

    Example:
        >>> gains_per_transition(torch.tensor([-100.0, -50.0, -45.0]), 10.0).tolist()
        [nan, 5.0, 0.5]
    """
    gains = torch.full_like(log_likelihoods, math.nan)
    gains[1:] = (log_likelihoods[1:] - log_likelihoods[:-1]) / max(transitions, 1.0)
    return gains


def _largest_strong(gains: torch.Tensor, start: int, strong_gain: float) -> int:
    """The largest index ``i >= start`` such that every k after ``ks[start]`` up to ``ks[i]``
    gains at least ``strong_gain`` over the previous one."""
    index = start
    for i in range(start + 1, gains.shape[0]):
        if not float(gains[i]) >= strong_gain:  # nan (a failed run) counts as no gain
            break
        index = i
    return index


#: The default ``strong_gain`` of ``criterion="icl_or_gain"``, nats per transition: a
#: further type that raises the likelihood by this much is kept although the exact ICL would
#: not pay for it, if it also predicts held-out subjects better and splits people (the
#: subject-consistency checks). It is ``min_gain``, the one effect size of every step: 0.04
#: (tuned on the task suite) rejected real types whose difference is confined to a few
#: transitions of long demonstrations (per-transition gains 0.02-0.036 on held-out tasks,
#: ``docs/clustering.md``, "Held-out tasks").
DEFAULT_STRONG_GAIN = DEFAULT_MIN_GAIN


#: ``criterion="icl_or_gain"`` keeps a strong step only if it also gains this much on units
#: held out of the fit (nats per transition, 5-fold cross-validation): on small studies an
#: extra cluster's in-sample gain is partly overfitting (``docs/clustering.md``). The default
#: of ``fit_mixture``'s ``heldout_gain``; ``torchhrc.tasks.learn`` passes half its
#: ``strong_gain`` (0.005, ``docs/clustering.md``, "The held-out gain").
DEFAULT_HELDOUT_GAIN = 0.01


def _first_best(scores: torch.Tensor, rtol: float = 1e-9) -> torch.Tensor:
    """``(...)`` index of the first entry of the last dim within ``rtol`` of its maximum.

    Restarts that reach one partition with its clusters in another order tie in score up to
    the last bits, which sums in another order (Ray's chunked E-step, another BLAS kernel)
    change: a plain argmax would pick another run, and so other labels, on another machine.

    Example:
        >>> _first_best(torch.tensor([[1.0, 3.0, 3.0 + 1e-12], [2.0, 1.0, -math.inf]]))
        tensor([1, 0])
    """
    top = scores.max(-1, keepdim=True).values
    near = scores >= top - rtol * top.abs().clamp_min(1.0)
    return near.to(torch.int8).argmax(-1)  # the first True


def _smallest_sufficient(
    gains: torch.Tensor, by_score: int, min_gain: float, exempt: torch.Tensor | None = None
) -> int:
    """The smallest index ``i <= by_score`` whose next k gains less than ``min_gain``
    (a step ``i + 1`` with ``exempt[i + 1]`` True is not cut)."""
    for i in range(by_score):
        if exempt is not None and bool(exempt[i + 1]):
            continue
        if not float(gains[i + 1]) >= min_gain:  # nan (a failed run) counts as no gain
            return i
    return by_score


def _one_standard_error(
    values: torch.Tensor, weights: torch.Tensor, se_factor: float
) -> tuple[int, torch.Tensor, torch.Tensor]:
    """The smallest k (index) whose held-out total is within ``se_factor`` standard errors of
    the best: ``sum_u (l_u(k) - l_u(k*)) >= -se_factor * SE_k``, ``SE_k`` the standard error
    of that paired sum over the held-out units (Breiman et al. 1984's one-standard-error rule,
    on paired per-unit differences).

    Returns:
        ``(index, total (num_k,), se (num_k,))``: the chosen index into the ks, each k's
        held-out total and the standard error of its difference to the best k.
    """
    values = torch.nan_to_num(values, nan=-math.inf, posinf=-math.inf)
    total = (values * weights[:, None]).sum(0)  # (num_k,)
    best = int(total.argmax())
    n = float(weights.sum())
    diff = values - values[:, best : best + 1]  # (P, num_k)
    diff = torch.nan_to_num(diff, nan=-math.inf)
    mean = (diff * weights[:, None]).sum(0) / n
    var = ((diff - mean) ** 2 * weights[:, None]).sum(0) / max(n - 1.0, 1.0)
    se = (n * var).sqrt()
    for i in range(best + 1):
        margin = float(total[i] - total[best])
        if math.isfinite(margin) and margin >= -se_factor * float(se[i]):
            return i, total, se
    return best, total, se


def _warn_at_edge(
    stats: SufficientStatistics,
    k: int,
    k_min: int,
    k_max: int,
    per_k: dict[int, dict[str, float]],
    min_gain: float,
) -> None:
    """Warn when the chosen k lies at an edge of the searched range and the data may want
    one beyond it. Upper edge: always (``k = k_max > k_min``). Lower edge ``k = k_min > 1``:
    when ``k_min = 2`` a single chain is fitted in closed form and the warning is given only
    if ``k = 2`` gains less than ``min_gain`` over it (an effect size: on small studies BIC
    often prefers one chain although the types differ by far more than ``min_gain``; that is
    a lack of data, not a sign of one type); for ``k_min > 2`` always."""
    if k_min == k_max:
        return
    if k == k_max:
        warnings.warn(
            f"the chosen number of clusters k = {k} is the largest searched (k_max = {k_max}); "
            "a larger k may fit better: raise k_max, or see docs/clustering.md on "
            "over-splitting large corpora (min_gain)",
            RuntimeWarning,
            stacklevel=3,
        )
    elif k == k_min and k_min > 2:
        warnings.warn(
            f"the chosen number of clusters k = {k} is the smallest searched (k_min = {k_min}); "
            "a smaller k may fit as well: lower k_min",
            RuntimeWarning,
            stacklevel=3,
        )
    elif k == k_min == 2:
        one = _single_chain_log_likelihood(stats)
        A = stats.num_symbols
        gain = (per_k[2]["log_likelihood"] - one) / max(num_transitions(stats), 1.0)
        if gain < min_gain:
            warnings.warn(
                f"the chosen number of clusters k = 2 is the smallest searched, and one cluster "
                f"(a single chain over all {A} symbols) fits as well (gain of k = 2: "
                f"{gain:.4f} nats per transition): the data may hold a single type",
                RuntimeWarning,
                stacklevel=3,
            )


def _single_chain_log_likelihood(stats: SufficientStatistics) -> float:
    """Log-likelihood of one maximum-likelihood chain fitted to all the data (closed form)."""
    A = stats.num_symbols
    total = (stats.counts * stats.multiplicity[:, None]).sum(0).view(A, A).double()
    rows = total.sum(-1, keepdim=True)
    ll = torch.xlogy(total, total / rows.clamp_min(1.0)).sum()
    if stats.first_counts is not None:
        first = (stats.first_counts * stats.multiplicity[:, None]).sum(0).double()
        ll = ll + torch.xlogy(first, first / first.sum().clamp_min(1.0)).sum()
    return float(ll)
