"""Select-Best-Model: fit every k in ``k_min..k_max`` with restarts, choose by BIC (or ICL).

The paper's Select-Best-Model(k_min, k_max, numOfIterations): for each k, run EM
``restarts`` times, score each run by ``BIC = l(D; theta) - K/2 log n`` with
``K = k |A| (|A| - 1)`` free transition parameters and ``n`` sequences, keep the best run
per k, and return the k with the best BIC. Here all ``(k, restart)`` pairs are one batch
of ``R = (k_max - k_min + 1) * restarts`` runs with ``k_max`` cluster slots each (a run
with a smaller k masks its extra slots), so the whole selection is one tensor program; the
kernels pack the runs by k, so masked slots cost nothing (:mod:`._em`).

Methods:

* ``"paper"``: the paper's random initialisation and hard EM (:mod:`.hard_em`), its BIC.
* ``"soft"`` (default, the better one): k-means++ initialisation (:mod:`.init`) and soft
  EM with Dirichlet smoothing (:mod:`.soft_em`); its BIC also counts the ``k - 1`` free
  mixture weights (and ``k (A - 1)`` first-symbol parameters when ``initial=True``, as
  :func:`torchhrc.tasks.learn` sets it), and ``l`` is the marginal log-likelihood. By default
  the k is the exact ICL's (below), raised where every further cluster gains at least
  ``strong_gain`` (= ``min_gain``, 0.015) nats per transition, confirmed on held-out units
  (``"icl_or_gain"``, issue 31), and that k is an upper bound: the
  smallest k whose next cluster gains less than ``min_gain`` (0.015) nats per transition is
  chosen, so a large corpus is not cut into sub-clusters of one type (issue 12.1,
  ``docs/clustering.md``), unless the exact ICL prefers that next cluster and it passes the
  subject-consistency checks. With ``split_merge=True`` every k is also restarted from the
  fits of k - 1 and k + 1 with a cluster split or two merged.

A ``RuntimeWarning`` says when the chosen k lies at the edge of the range searched.

Criteria (``criterion=``): ``"bic"`` (the paper's); ``"icl"``, the integrated completed
likelihood ``ICL = BIC - H(r)`` (Biernacki, Celeux, Govaert 2000), ``H`` the entropy of the
responsibilities (0 for hard EM); ``"exact_icl"``, the exact integrated classification
likelihood ``log p(D, z)`` of each k's partition with the chains and weights integrated out
under Dirichlet priors (Biernacki, Celeux, Govaert 2010; :func:`exact_icl`); and
``"bic_or_exact_icl"``, the larger of the k that BIC and the exact ICL choose;
``"icl_or_gain"`` (the soft method's default), the exact ICL's k or the largest k reached by
steps that each gain ``strong_gain``; ``"heldout"``, held-out likelihood by subject
(cross-validation, one-standard-error rule). The exact ICL needs no parameter count: a
transition row that a cluster never visits costs nothing and a sparsely visited row little,
where BIC charges every one of the ``A (A - 1)`` transitions of every chain ``1/2 log n``
(``docs/clustering.md``).

Example:
    >>> import torch
    >>> from torchhrc.mixture import fit_mixture
    >>> seqs = torch.tensor([[0, 1, 0, 1]] * 6 + [[0, 0, 0, 0]] * 4)
    >>> fit = fit_mixture((seqs, torch.full((10,), 4), 2), k_min=1, k_max=3, restarts=3)
    >>> fit.k, fit.assignments.tolist()
    (2, [0, 0, 0, 0, 0, 0, 1, 1, 1, 1])
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Literal

import torch
import torch.nn.functional as F

from torchhrc.errors import ModelError
from torchhrc.mixture._em import (
    DEFAULT_PSEUDO_COUNT,
    DEFAULT_WEIGHT_PSEUDO_COUNT,
    EMResult,
    Smoothing,
    e_table,
    pseudo_parts,
)
from torchhrc.mixture.consistency import (
    DEFAULT_MIN_CONSISTENCY,
    held_out_posteriors,
    intraclass_correlation,
    split_consistency,
)
from torchhrc.mixture.counts import SufficientStatistics, check_sequences, sufficient_statistics
from torchhrc.mixture.criteria import (
    DEFAULT_HELDOUT_GAIN,
    DEFAULT_MIN_GAIN,
    DEFAULT_STRONG_GAIN,
    EXACT_ICL_PRIOR,
    _first_best,
    _largest_strong,
    _one_standard_error,
    _smallest_sufficient,
    _support_parameters,
    _warn_at_edge,
    bic,
    exact_icl,
    gains_per_transition,
    num_free_parameters,
    num_transitions,
    partition_icl,
)
from torchhrc.mixture.history import MAX_ORDER, SecondOrder, context_symbols, num_contexts
from torchhrc.mixture.model import MarkovChainMixture
from torchhrc.mixture.refine import refine_partition
from torchhrc.mixture.runs import _em_all_k, _heldout_scores, _soft_initial_parameters
from torchhrc.mixture.soft_em import soft_pass

__all__ = [
    "CRITERIA",
    "DEFAULT_MIN_GAIN",
    "DEFAULT_OBJECTS_SAMPLE",
    "DEFAULT_PSEUDO_COUNT",
    "DEFAULT_STRONG_GAIN",
    "DEFAULT_WEIGHT_PSEUDO_COUNT",
    "EXACT_ICL_PRIOR",
    "ClusterConfig",
    "MixtureFit",
    "bic",
    "exact_icl",
    "fit_mixture",
    "gains_per_transition",
    "num_free_parameters",
    "num_transitions",
    "order_to_keep",
    "partition_chains",
]

Method = Literal["soft", "paper"]
Criterion = Literal["icl_or_gain", "heldout", "bic", "icl", "exact_icl", "bic_or_exact_icl"]
#: The names ``criterion=`` takes.
CRITERIA: tuple[str, ...] = (
    "icl_or_gain", "heldout", "bic", "icl", "exact_icl", "bic_or_exact_icl",
)  # fmt: skip
Objects = Literal["auto", "raw", "exchangeable"]
#: ``fit_mixture(order=...)``: chains of order 1, 2 or 3, or the three compared.
Order = Literal[1, 2, 3, "auto"]


@dataclass(frozen=True)
class MixtureFit:
    """The selected mixture and the model-selection record.

    Attributes:
        model: the selected :class:`MarkovChainMixture` (``k`` clusters, ordered by
            decreasing size).
        k: the selected number of clusters.
        bic: the selected model's BIC.
        icl: the selected model's ICL.
        log_likelihood: the selected model's log-likelihood (classification log-likelihood
            for ``"paper"``, marginal for ``"soft"``).
        assignments: ``(N,)`` int64 cluster of every sequence (most responsible one; with
            ``unit="subject"`` all sequences of a subject share their subject's cluster).
        responsibilities: ``(N, k)`` posterior cluster probabilities (one-hot for ``"paper"``).
        per_k: ``k -> {"bic", "icl", "exact_icl", "log_likelihood", "gain"}`` of the best run
            of every k (``gain``: over the previous k, nats per transition, see ``min_gain``;
            every k but ``k_min`` has one; ``exact_icl``: see :func:`exact_icl`).
        method: ``"soft"`` or ``"paper"``; criterion: the ``criterion`` used.
        converged: whether the selected run converged before ``max_iterations``.
        iterations: EM iterations of the selected run.
        num_distinct: distinct sequences (by transition counts) the EM worked on.
        objects: the form of the demonstrations the model is over, ``"raw"`` or
            ``"exchangeable"`` (see ``fit_mixture(objects=...)``; also ``model.objects``).
        object_comparison: with ``objects="auto"`` on data with objects, the two forms'
            selected fits, ``form -> {"k", "bic", "exact_icl", "log_likelihood", "units"}``
            (on the recorded demonstrations; ``units``: the units compared, a sample of a
            large corpus); else ``None``.
        order: ``1``, ``2`` or ``3``, the chains' order (``fit_mixture(order=...)``; also
            ``model.order``); above 1, ``model.vocabulary`` names context symbols.
        order_comparison: with ``order="auto"``, each order's selected fit,
            ``"1"/"2"/"3" -> {"k", "exact_icl", "log_likelihood"}`` (``exact_icl``: of the
            recorded demonstrations in all, :func:`order_to_keep`), and where several
            orders found the most types, each of those orders' partition scored under each
            of those orders' chains, ``"exact_icl_at_<order>"``, and ``"partition"``, the
            lowest of those orders with the same partition; else ``None``.
        next_step: with ``criterion="icl_or_gain"``, why ``k + 1`` was not chosen:
            ``{"k": k + 1, "short_of": [...]}``, the thresholds its step falls below, of
            ``"min_gain"`` and ``"strong_gain"`` (its gain per transition; a step the exact
            ICL does not take needs ``strong_gain``), ``"heldout_gain"`` (its held-out gain
            per transition, where cross-validated), ``"consistency"`` and
            ``"split_consistency"`` (its subject consistency and split consistency, against
            ``min_consistency``), with their ``"values"`` and ``"thresholds"``; an empty
            ``short_of``: the step met each threshold it was measured against, and the rule
            stopped below it (a step before it refused). None for ``k_max`` and other
            criteria.
    """

    model: MarkovChainMixture
    k: int
    bic: float
    icl: float
    log_likelihood: float
    assignments: torch.Tensor
    responsibilities: torch.Tensor
    per_k: dict[int, dict[str, float]]
    method: str
    criterion: str
    converged: bool
    iterations: int
    num_distinct: int = field(repr=False)
    objects: str = "raw"
    object_comparison: dict[str, dict[str, float]] | None = field(default=None, repr=False)
    order: int = 1
    order_comparison: dict[str, dict[str, float]] | None = field(default=None, repr=False)
    next_step: dict[str, Any] | None = field(default=None, repr=False)

    def transition_over(
        self, demonstrations: Any, *, pseudo_count: float | None = None
    ) -> torch.Tensor:
        """Each cluster's chain over the fitted demonstrations' own (recorded) symbols.

        ``objects="raw"``: the model's transition probabilities. ``"exchangeable"``: the
        model's chains are over relabelled symbols, so the chains over the recorded ones are
        estimated from the fit's clusters: ``theta_k(b | a) ∝ sum_n r_nk n_n(a, b) + alpha``,
        ``r`` the responsibilities, ``n_n`` the transition counts of sequence ``n`` (the
        soft method's M-step; a row without counts is uniform).

        Args:
            demonstrations: the :class:`~torchhrc.data.Demonstrations` that were fitted
                (``N`` sequences, in the same order).
            pseudo_count: ``alpha`` (default ``DEFAULT_PSEUDO_COUNT``; unused for raw fits).

        Returns:
            ``(k, A, A)`` transition probabilities over ``demonstrations.vocabulary``
            (:func:`partition_chains` with the fit's responsibilities).

        Raises:
            ModelError: ``demonstrations`` has a different number of sequences.

        Example:
            >>> seqs = torch.tensor([[0, 1, 0, 1]] * 5 + [[0, 0, 0, 0]] * 5)
            >>> fit = fit_mixture((seqs, torch.full((10,), 4), 2), k_min=1, k_max=3, restarts=2)
            >>> fit.transition_over(None).shape
            torch.Size([2, 2, 2])
        """
        if self.objects == "raw" and self.order == 1:
            return self.model.transition
        N = self.responsibilities.shape[0]
        if demonstrations.num_sequences != N:
            raise ModelError(
                f"expected the {N} fitted demonstrations, got {demonstrations.num_sequences}"
            )
        return partition_chains(demonstrations, self.responsibilities, pseudo_count=pseudo_count)


def partition_chains(
    demonstrations: Any, weights: torch.Tensor, *, pseudo_count: float | None = None
) -> torch.Tensor:
    """Each cluster's first-order chain over the demonstrations' recorded symbols, given
    each sequence's cluster weights: ``theta_k(b | a) ∝ sum_n w_nk n_n(a, b) + alpha``,
    ``n_n`` the transition counts of sequence ``n`` (the soft method's M-step; a row
    without counts is uniform). With one-hot weights, the chains of a hard partition.

    Args:
        demonstrations: :class:`~torchhrc.data.Demonstrations` (``N`` sequences over ``A``
            symbols).
        weights: ``(N, k)`` each sequence's weight in each cluster (responsibilities, or
            ``F.one_hot(assignments, k)``).
        pseudo_count: ``alpha`` (default ``DEFAULT_PSEUDO_COUNT``).

    Returns:
        ``(k, A, A)`` float64 transition probabilities over ``demonstrations.vocabulary``.

    Raises:
        ModelError: ``weights`` not of shape ``(N, k)`` for the ``N`` demonstrations.

    Example:
        >>> from torchhrc.data import Demonstrations
        >>> h, r = ("human", "a"), ("robot", "b")
        >>> demos = Demonstrations.from_lists([[h, r, h], [h, h, h]])  # symbols: a, b
        >>> chains = partition_chains(demos, torch.eye(2), pseudo_count=0.0)
        >>> chains[0, 0].tolist(), chains[1, 0].tolist()  # after a: b in the first, a in the second
        ([0.0, 1.0], [1.0, 0.0])
    """
    N = demonstrations.num_sequences
    if weights.dim() != 2 or weights.shape[0] != N:
        raise ModelError(f"expected weights of shape (N, k) for the N = {N} demonstrations, "
                         f"got {tuple(weights.shape)}")  # fmt: skip
    alpha = DEFAULT_PSEUDO_COUNT if pseudo_count is None else float(pseudo_count)
    A = demonstrations.num_symbols
    chains = weights.new_zeros(weights.shape[1], A, A, dtype=torch.float64)
    for start in range(0, N, 65536):  # (chunk, A, A) counts at a time
        part = demonstrations.subset(torch.arange(start, min(start + 65536, N)))
        counts = part.transition_counts(per_sequence=True)  # (n, A, A)
        w = weights[start : start + 65536].to(counts)  # (n, k)
        chains += torch.einsum("nk,nab->kab", w, counts)
    chains = chains + alpha  # (k, A, A)
    rows = chains.sum(-1, keepdim=True)
    uniform = torch.full_like(chains, 1.0 / chains.shape[-1])
    return torch.where(rows > 0, chains / rows.clamp_min(1e-300), uniform)


@dataclass(frozen=True, kw_only=True)
class ClusterConfig:
    """Settings of the clustering into types (:func:`fit_mixture`'s options), as one value.

    Every field left ``None`` takes the default of the function that uses the config:
    :func:`fit_mixture`'s own, or those :func:`torchhrc.tasks.learn` documents (``k_min=1``,
    ``k_max=6``, ``restarts=20``, ``parameters="support"``, ``initial=True``). A typo in a
    field is a ``TypeError``. See :func:`fit_mixture` for what each one means.

    Example:
        >>> ClusterConfig(criterion="bic", k_max=4).options()
        {'k_max': 4, 'criterion': 'bic'}
    """

    k_min: int | None = None
    k_max: int | None = None
    restarts: int | None = None
    method: Method | None = None
    criterion: Criterion | None = None
    unit: Literal["auto", "sequence", "subject"] | None = None
    parameters: Literal["auto", "full", "support"] | None = None
    pseudo_count: float | None = None
    weight_pseudo_count: float | None = None
    max_iterations: int | None = None
    short_iterations: int | None = None
    split_merge: bool | None = None
    tol: float | None = None
    floor: float | None = None
    initial: bool | None = None
    min_gain: float | None = None
    strong_gain: float | None = None
    heldout_gain: float | None = None
    min_consistency: float | None = None
    folds: int | None = None
    se_factor: float | None = None
    objects: Objects | None = None
    object_separator: str | None = None
    objects_sample: int | None = None
    order: Order | None = None

    def options(self) -> dict[str, Any]:
        """The fields that are set, as keyword arguments of :func:`fit_mixture`."""
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)
                if getattr(self, f.name) is not None}  # fmt: skip


def _unpack(data: Any) -> tuple[torch.Tensor, torch.Tensor, int, tuple[Any, ...] | None]:
    """``Demonstrations`` or ``(sequences, lengths, num_symbols)`` -> tensors, A, vocabulary."""
    if isinstance(data, tuple):
        if len(data) != 3:
            raise TypeError(
                "expected data to be a Demonstrations or a tuple (sequences (N, L), "
                f"lengths (N,), num_symbols), got a tuple of {len(data)} items"
            )
        sequences, lengths, num_symbols = data
        vocabulary = None
    elif all(hasattr(data, a) for a in ("sequences", "lengths", "num_symbols")):
        sequences, lengths, num_symbols = data.sequences, data.lengths, data.num_symbols
        vocabulary = getattr(data, "vocabulary", None)
    else:
        raise TypeError(
            "expected data to be a Demonstrations or a tuple (sequences, lengths, num_symbols), "
            f"got {type(data).__name__}"
        )
    if isinstance(num_symbols, bool) or not isinstance(num_symbols, int) or num_symbols < 1:
        raise ValueError(f"expected num_symbols to be a positive int, got {num_symbols!r}")
    sequences, lengths = check_sequences(sequences, lengths, num_symbols)
    if sequences.shape[0] < 1:
        raise ModelError("expected at least one sequence, got N = 0")
    return sequences, lengths, num_symbols, vocabulary


def _generator(seed: int | None, generator: torch.Generator | None) -> torch.Generator:
    if generator is not None:
        if seed is not None:
            raise ValueError("pass either seed or generator, not both")
        return generator
    return torch.Generator().manual_seed(0 if seed is None else int(seed))


def _groups(data: Any, unit: str, method: str) -> torch.Tensor | None:
    """``(N,)`` group index of every sequence for ``unit``, or None (every sequence alone)."""
    subjects = getattr(data, "subjects", None) if not isinstance(data, tuple) else None
    if unit == "auto":
        unit = "subject" if (method == "soft" and subjects is not None) else "sequence"
    if unit == "sequence":
        return None
    if subjects is None:
        raise ValueError(
            "unit='subject' needs data with subject ids (a Demonstrations), got "
            f"{type(data).__name__}"
        )
    index: dict[Any, int] = {}
    return torch.tensor([index.setdefault(s, len(index)) for s in subjects], dtype=torch.long)


def fit_mixture(
    data: Any,
    *,
    k_min: int = 2,
    k_max: int = 10,
    restarts: int = 20,
    method: Method = "soft",
    criterion: Criterion | None = None,
    unit: Literal["auto", "sequence", "subject"] = "auto",
    parameters: Literal["auto", "full", "support"] = "auto",
    seed: int | None = None,
    generator: torch.Generator | None = None,
    pseudo_count: float | None = None,
    weight_pseudo_count: float | None = None,
    max_iterations: int | None = None,
    short_iterations: int = 5,
    split_merge: bool = False,
    tol: float = 1e-6,
    floor: float = 1e-10,
    initial: bool = False,
    min_gain: float | None = None,
    strong_gain: float | None = None,
    heldout_gain: float | None = None,
    min_consistency: float | None = None,
    folds: int = 5,
    se_factor: float = 1.0,
    objects: Objects | None = None,
    object_separator: str = "_",
    objects_sample: int | None = None,
    order: Order = 1,
    dtype: torch.dtype = torch.float64,
    progress: Callable[[int, int], None] | None = None,
    ray: bool | str | None = None,
) -> MixtureFit:
    """Cluster sequences into human types and choose their number (Select-Best-Model).

    Args:
        data: a :class:`torchhrc.data.Demonstrations`, a tuple ``(sequences (N, L) int64,
            lengths (N,) int64, num_symbols)``, or a corpus in shards
            (:class:`torchhrc.mixture.ShardedCorpus`: CSV or Parquet files), whose shards are
            reduced to their distinct units one by one (or as Ray tasks, ``ray=``) and merged
            exactly: the same fit as the corpus in memory, with the same defaults
            (``objects="auto"`` included: the corpus relabels its shards as views).
        k_min, k_max: the range of k (``1 <= k_min <= k_max``).
        restarts: EM runs per k (the paper's numOfIterations, 20).
        method: ``"soft"`` (k-means++ + smoothed soft EM, the default) or ``"paper"``
            (random init + hard EM, exactly the paper's algorithm). The soft method then
            refines the chosen k's partition by single-unit moves that raise its exact ICL
            (:func:`~torchhrc.mixture.refine.refine_partition`), where the refined
            partition's exact ICL is above the previous k's best run's (k = 2: above the one
            cluster's; a k whose k - 1 was not searched is not refined) (recorded as
            ``per_k[k]["refined_moves"]`` and ``"exact_icl_refined"``; the chains are
            re-estimated from it by one smoothed M-step, whose ``"log_likelihood_refined"``
            and ``"bic_refined"`` are the fit's ``log_likelihood`` and ``bic``, while
            ``"log_likelihood"`` and ``"bic"`` stay the EM run's).
        criterion: how the k is chosen among the best run of every k: ``"icl_or_gain"``
            (the soft method's default): the exact ICL's k (:func:`exact_icl`, Jeffreys'
            prior, no parameter count), or a larger k when every step up to it raises the
            log-likelihood by at least ``strong_gain`` nats per transition (an effect the
            exact ICL's prior cost hides on small studies: three types of the kitting study
            of issue 31), each step confirmed on held-out units (``folds``-fold
            cross-validation of the k from the exact ICL's to that larger one, recorded as
            ``per_k[k]["heldout"]`` for those k); ``"heldout"``: the smallest k whose
            held-out log-likelihood by unit
            (``folds``-fold cross-validation over subjects) is within ``se_factor`` standard
            errors of the best k's; ``"bic"`` (the paper's; the default of ``"paper"``);
            ``"icl"`` (BIC minus the entropy of the responsibilities); ``"exact_icl"``;
            ``"bic_or_exact_icl"`` (the larger of BIC's k and the exact ICL's k, the soft
            default before issue 31). ``min_gain`` then caps the k on large corpora. Why
            this default, measured on the generated task suite, the paper's study and the
            kitchen: ``docs/clustering.md`` ("Choosing k on tasks nobody tuned for").
        unit: what gets one cluster label: ``"sequence"`` (the paper) or ``"subject"`` (all
            demonstrations of a subject share one type, their evidence adds up; needs a
            ``Demonstrations``). ``"auto"``: ``"subject"`` for ``"soft"`` when subject ids
            are known, else ``"sequence"``. The BIC's ``n`` is the number of units.
        parameters: the BIC's parameter count: ``"full"`` (the paper's ``k A (A - 1)``)
            or ``"support"`` (only transitions observed somewhere in the data are free:
            ``k sum_a (s_a - 1)``, ``s_a`` the distinct successors of ``a``). ``"auto"``:
            ``"full"`` for both methods (``"support"`` over-splits small studies: k = 3,
            ARI 0.75 on 4 of 12 paper-like studies of 54 sequences, ``docs/clustering.md``).
            It changes the BIC only, so it selects k only with ``criterion="bic"`` or
            ``"icl"``; ``per_k`` reports the BIC either way.
        seed, generator: randomness (one of them; default seed 0). Same seed, same result.
        pseudo_count: Dirichlet pseudo-count on transitions (``"soft"`` only; ``None``:
            ``DEFAULT_PSEUDO_COUNT``, 0.1).
        weight_pseudo_count: pseudo-count on cluster sizes (``"soft"`` only; ``None``:
            ``DEFAULT_WEIGHT_PSEUDO_COUNT``, 1).
        max_iterations: EM iteration cap (default 100 for ``"paper"``, 200 for ``"soft"``).
        short_iterations: ``"soft"`` runs the em-EM strategy (Biernacki, Celeux, Govaert
            2003): every restart runs this many iterations, then the best restart of each k
            (by log-likelihood) runs to convergence.
        split_merge: ``"soft"`` then restarts every k from the fit of k - 1 with each
            cluster split in two (2-means of its members' transition frequencies) and from
            the fit of k + 1 with each cluster merged into its nearest one, keeping a
            restart where its log-likelihood is higher (split and merge moves after Ueda et
            al. 2000's SMEM; deterministic). Random starts of k clusters can miss a
            partition that the neighbouring k holds but for one split or merge (a held-out
            task with 5 types: its k = 5 fit no better than k = 4 on 2 seeds of 10,
            ``docs/clustering.md``). Off by default: it multiplies a default selection's
            time by about 4 (the paper-size fits of ``tests/mixture/test_objects.py``:
            63 -> 280 CPU-s), measured 2026-12-04 at commit 72e9ac6.
            Without it, a k whose best run ends below the best run of k - 1 in
            log-likelihood (a failed search: k chains hold every mixture of k - 1) is still
            restarted from the splits of the k - 1 fit (``docs/clustering.md``, "A k fitted
            below k - 1").
        tol: relative log-likelihood change that stops soft EM.
        floor: probability that stands for 0 in the paper's E-step (see :mod:`.hard_em`).
        initial: also model each cluster's first-symbol distribution (a type's opening
            move: with short demonstrations it can be much of what tells types apart;
            :func:`torchhrc.tasks.learn` sets it by default, ``docs/clustering.md``).
        min_gain: the least log-likelihood, in nats per transition of the data, that one
            more cluster must add to be kept (an effect size, so it does not grow with the
            corpus). The criterion's k is reduced to the smallest ``k`` whose ``k + 1``
            gains less than this over ``k``: ``(l(k + 1) - l(k)) / T < min_gain``, ``T`` the
            number of transitions. ``None``: ``DEFAULT_MIN_GAIN`` (0.015) for ``"soft"``, 0
            (off: the paper's BIC alone) for ``"paper"``. Why: BIC's penalty grows like
            ``log n`` while the misfit of first-order chains to real data grows like ``n``, so
            on large corpora BIC alone cuts every type into sub-clusters of noise patterns
            and orders (``docs/clustering.md``). With ``criterion="icl_or_gain"`` a step to
            ``k + 1`` that the exact ICL itself prefers over ``k`` and that passes both
            subject-consistency checks (``min_consistency`` > 0) is not cut: the checks catch
            sub-clusters of one type directly, and a real type may differ from another in a
            little of the data (a rhythm, a held-out task: 0.005-0.014 nats per transition).
        strong_gain: ``criterion="icl_or_gain"``'s effect size, nats per transition
            (``None``: ``DEFAULT_STRONG_GAIN``, 0.015, the ``min_gain`` default).
        heldout_gain: ``criterion="icl_or_gain"``'s confirmation of a strong step: its gain
            on held-out units, nats per transition of the data, must be at least this and
            beyond ``se_factor`` standard errors of its per-unit differences (``None``:
            ``DEFAULT_HELDOUT_GAIN``, 0.01; :func:`torchhrc.tasks.learn` passes half its
            ``strong_gain``: near that effect size a real type's held-out gain is a median
            three quarters of its in-sample gain, a spurious cluster's a fifth,
            ``docs/clustering.md``, "The held-out gain").
        min_consistency: a type belongs to a person: with subjects as units (``unit``), the
            chosen k is lowered while one of its clusters has a subject consistency below
            this (the intraclass correlation of the sequences' own cluster posteriors with
            subjects as groups, each sequence read under the chains refitted without its
            subject, :mod:`torchhrc.mixture.consistency`: the share of their variance that
            lies between subjects). It removes the clusters of sequences, not
            of people, that every likelihood criterion keeps on large corpora when the chains
            are misspecified (``docs/clustering.md``, "A type belongs to a person"). ``None``:
            ``DEFAULT_MIN_CONSISTENCY`` (0.5, both orders) for ``"soft"``, 0 (off) for ``"paper"``.
            Recorded as ``per_k[k]["consistency"]`` (the smallest of the k clusters) whenever
            subjects with several sequences are the units, also when the check is off (0).
            The k is also lowered while the step to it from k - 1 splits no one's people:
            ``per_k[k]["split_consistency"]``, the largest ICC of its clusters among the
            subjects of one cluster of k - 1
            (:func:`~torchhrc.mixture.consistency.split_consistency`), below this. A
            cluster that takes part of each person's sequences of one type has a plain ICC up
            to about 0.6 from the other types' subjects alone, and one near 0 within them.
        folds, se_factor: the number of folds over units of the held-out scores
            (``criterion="heldout"`` and ``"icl_or_gain"``) and the factor of their
            standard-error rules.
        objects: how object names in the actions are read (``docs/clustering.md``,
            "Exchangeable objects"): ``"raw"``, the symbols as recorded (the paper);
            ``"exchangeable"``, every demonstration's objects renamed in order of first use
            (:meth:`~torchhrc.data.Demonstrations.relabel_objects`: a type is then a strategy
            whatever objects it was applied to); ``"auto"``: select a model in both forms and
            keep the one whose selected partition has the larger exact ICL
            (:func:`exact_icl`, ``log p(D, z)`` with the chains integrated out) on the
            recorded demonstrations. Both forms are models of the same data: under
            exchangeable objects a demonstration touching ``m`` of the ``M`` objects is its
            relabelled form times a uniformly random injection of its objects,
            ``log p(x) = log p(relabel(x)) - log(M! / (M - m)!)``
            (:meth:`~torchhrc.data.Demonstrations.relabel_log_multiplicity`). Types that are
            mirror images (one strategy on different objects, e.g. "left first" and "right
            first") are one type in the exchangeable form: pass ``"raw"`` when such
            object preferences are the types sought. ``None``: ``"auto"`` for ``"soft"``,
            ``"raw"`` for ``"paper"``. Data without object names (a tuple of tensors, fewer
            than 2 objects) are fitted raw by ``"auto"``; merged statistics of shards raise a
            ModelError when their vocabulary names objects (they cannot be relabelled). The fit
            records the choice (``objects``, ``object_comparison``, ``model.objects``); score
            new demonstrations through ``fit.model.prepare``.
        object_separator: the separator between verb and object (``place_A``: ``"_"``).
        objects_sample: ``"auto"`` compares the two forms on the whole corpus when it has at
            most this many units (subjects, or sequences), else on a random sample of this
            many units (``seed``), and fits the whole corpus once, in the chosen form.
            ``None``: ``DEFAULT_OBJECTS_SAMPLE`` (3,000).
        order: ``1``, first-order chains (the paper); ``2``, second-order chains
            ``P(a_t | a_(t-2), a_(t-1))``, fitted as first-order chains over context symbols
            (:mod:`torchhrc.mixture.history`; needs a ``Demonstrations``; the model's
            ``order`` is 2 and :meth:`MixtureFit.transition_over` gives first-order chains
            over the recorded symbols): they see a type's order across a step every type
            shares (a robot that waits between every two of the person's actions); ``3``,
            third-order chains ``P(a_t | a_(t-3), a_(t-2), a_(t-1))``, the same way: across a
            robot's move they see the person's last two actions (a rhythm, such as drill,
            drill, saw, saw, that one step back does not show); ``"auto"``: select k in the
            three orders (the objects' reading chosen in first order) and keep the fit with
            the most types; on equal k the one whose partition has the larger exact ICL
            (``log p(D, z)`` of the recorded data in all) under the chains of every order
            that found as many (:func:`~torchhrc.mixture.criteria.partition_icl`), else the
            larger exact ICL under its own order (:func:`order_to_keep`): a type any order's
            rule finds is kept
            (``docs/clustering.md``, "Second-order chains" and "Third-order chains"). Above
            first order the ``per_k`` rows add ``exact_icl_recorded`` (the exact ICL with each
            context's Dirichlet over the recorded symbols). The fit records ``order`` and
            ``order_comparison``. ``"auto"`` on counts or shards is first order; an order
            whose counts would not fit (:data:`HIGHER_ORDER_MAX_ELEMENTS`) is left out of
            the comparison, with a warning for the second order; the third order is left
            out without one there and where it has more than
            :data:`THIRD_ORDER_MAX_CONTEXTS` context symbols (its cost grows with their
            square; ``order_comparison`` lists the orders compared).
        dtype: float dtype of the computation (float32 halves time and memory on big data).
        progress: ``progress(iteration, runs_still_running)`` after every EM iteration.
        ray: run every soft-EM E-step on a Ray cluster (:class:`torchhrc.mixture.RayEStep`,
            the distinct rows split among its actors), for data in memory as for a sharded
            corpus, whose shards are then also reduced in Ray tasks: ``True`` or ``"local"``
            (a local cluster, unless Ray is already initialised) or ``"HOST:PORT"``;
            ``None``/``False``: everything in this process. ``method="paper"`` has no
            E-step to distribute: ``ray`` then only reduces a sharded corpus's shards, and
            with data in memory it is an error rather than silently ignored.

    Returns:
        :class:`MixtureFit`. With ``objects="exchangeable"`` (chosen or given) its
        log-likelihoods, BICs and ICLs (also in ``per_k``) are those of the recorded
        demonstrations (the relabelled ones' minus the injection terms above).

    Raises:
        TypeError, ValueError, ModelError: invalid data or options (the message names them).

    Example:
        >>> import torch
        >>> seqs = torch.tensor([[0, 1, 0, 1]] * 5 + [[0, 0, 0, 0]] * 5)
        >>> fit_mixture((seqs, torch.full((10,), 4), 2), k_min=1, k_max=3, restarts=2).k
        2
    """
    if not isinstance(initial, bool):
        raise TypeError(f"expected initial to be a bool, got {initial!r}")
    if objects is None:
        objects = "auto" if method == "soft" else "raw"
    if objects not in ("auto", "raw", "exchangeable"):
        raise ValueError(f"expected objects 'auto', 'raw' or 'exchangeable', got {objects!r}")
    if not isinstance(object_separator, str) or not object_separator:
        raise TypeError(
            f"expected object_separator to be a non-empty str, got {object_separator!r}"
        )
    if objects_sample is None:
        objects_sample = DEFAULT_OBJECTS_SAMPLE
    bad_sample = isinstance(objects_sample, bool) or not isinstance(objects_sample, int)
    if bad_sample or objects_sample < 2:
        raise ValueError(f"expected objects_sample to be an int >= 2, got {objects_sample!r}")
    options: dict[str, Any] = dict(
        k_min=k_min, k_max=k_max, restarts=restarts, method=method, criterion=criterion,
        unit=unit, parameters=parameters, pseudo_count=pseudo_count,
        weight_pseudo_count=weight_pseudo_count, max_iterations=max_iterations,
        short_iterations=short_iterations, split_merge=split_merge, tol=tol, floor=floor,
        initial=initial, min_gain=min_gain, strong_gain=strong_gain, heldout_gain=heldout_gain,
        min_consistency=min_consistency, folds=folds, se_factor=se_factor, dtype=dtype,
        progress=progress, ray=ray,
    )  # fmt: skip
    if isinstance(order, bool) or order not in (*range(1, MAX_ORDER + 1), "auto"):
        raise ValueError(f"expected order 1, 2, 3 or 'auto', got {order!r}")
    lowerable = callable(getattr(data, "with_vocabulary", None)) and not isinstance(data, tuple)
    if order != "auto" and order > 1 and not lowerable:
        raise TypeError(
            f"order={order} renames each step to its context (the previous steps, step) and "
            f"needs a Demonstrations, got {type(data).__name__}"
        )
    orders = [1]  # "auto": the orders whose counts fit (on counts or shards: first order)
    while order == "auto" and lowerable and orders[-1] < MAX_ORDER:
        m = orders[-1] + 1
        P = num_contexts(data, m)
        too_large = data.num_sequences * P * P > HIGHER_ORDER_MAX_ELEMENTS
        if m == 3 and (too_large or P > THIRD_ORDER_MAX_CONTEXTS):
            break  # the third order is an extra, bounded by its cost: no warning
        if too_large:
            warnings.warn(
                f"fit_mixture(order='auto') compared orders {orders} only: order {m}'s counts "
                f"would hold up to {data.num_sequences} x {P}^2 elements (N sequences x "
                f"context symbols squared, more than {HIGHER_ORDER_MAX_ELEMENTS}); pass "
                f"order={m} to fit them anyway",
                RuntimeWarning,
                stacklevel=2,
            )
            break
        orders.append(m)
    if order != "auto" or len(orders) == 1:
        return _fit_objects(data, objects, object_separator, objects_sample, 1 if order ==
                            "auto" else order, options, seed, generator)  # fmt: skip
    start = generator.get_state() if generator is not None else None
    fits, caught = _each_from(
        start,
        generator,
        tuple(orders),
        # the objects' reading is chosen once, in first order; the others read them so
        lambda form, done: _fit_objects(
            data, objects if form == 1 else done[1].objects, object_separator,
            objects_sample, form, options, seed, generator,
        ),
    )  # fmt: skip
    comparison = {
        str(form): {"k": float(f.k), "exact_icl": _recorded_icl(f),
                    "log_likelihood": f.log_likelihood}
        for form, f in fits.items()
    }  # fmt: skip
    most = max(f.k for f in fits.values())
    tied = [form for form, f in fits.items() if f.k == most]
    if len(tied) > 1:  # the tied orders' partitions, each scored under each tied order
        read = data
        if fits[1].objects == "exchangeable":
            read = data.relabel_objects(separator=fits[1].model.object_separator, keep_unused=True)
        groups = _groups(data, options["unit"], options["method"])
        same = {form: next(o for o in tied if _same_partition(fits[o].assignments,
                                                              fits[form].assignments))
                for form in tied}  # fmt: skip
        distinct = sorted(set(same.values()))
        for judge in tied:  # an order that found fewer types cannot see what divides them
            scores = partition_icl(read, [fits[form].assignments for form in distinct], judge,
                                   groups=groups, initial=options["initial"])  # fmt: skip
            for form in tied:
                row = comparison[str(form)]
                row[f"exact_icl_at_{judge}"] = scores[distinct.index(same[form])]
                row["partition"] = float(same[form])
    best = order_to_keep(comparison)
    _rewarn(caught[best])
    return dataclasses.replace(fits[best], order_comparison=comparison)


#: ``fit_mixture(order="auto")`` fits chains of order ``m > 1`` only while ``N P_m^2``
#: (sequences x order-``m`` context symbols squared, the dense counts' size before identical
#: sequences merge) is at most this (2^27: 1 GiB in float64); above it the lower orders alone
#: (with a warning where the second order is left out).
HIGHER_ORDER_MAX_ELEMENTS = 1 << 27
#: ``fit_mixture(order="auto")`` compares third-order chains only where they have at most
#: this many context symbols: its tables hold ``P^2`` entries a cluster, so a selection in
#: third order costs about ``(P_3 / P_1)^2`` times a first-order one (``five_parts`` at
#: 300 x 4, ``P_3 = 510``: 274 CPU-s for the third order alone). Above it, orders 1
#: and 2 are compared (``order_comparison`` lists the orders compared); ``order=3`` fits it
#: whatever its size (``docs/clustering.md``, "Third-order chains").
THIRD_ORDER_MAX_CONTEXTS = 128


def _recorded_icl(fit: MixtureFit) -> float:
    """The exact ICL of ``fit``'s selected partition as ``log p(D, z)`` of the recorded
    symbols (for context symbols, the Dirichlet over the recorded symbols; for a refined
    partition, the refined one's, which is computed so)."""
    row = fit.per_k[fit.k]
    return row.get("exact_icl_refined", row.get("exact_icl_recorded", row["exact_icl"]))


#: ``fit_mixture(order="auto")`` on equal k keeps the order whose partition's exact ICL is
#: above every other partition's by more than this, in nats, under the chains of every
#: order that found as many types (a Bayes factor above e^5 = 150, "very strong" evidence on
#: Kass and Raftery's 1995 scale); below it each fit's own exact ICL decides, as before
#: (:func:`order_to_keep`). Chosen over the whole goal-2 bench (``docs/clustering.md``,
#: "The partition on equal k"): at 3 nats ("strong", e^3 = 20) a partition 3.6 nats ahead
#: under both orders was the worse one (``slow_sanding`` seed 6 at 300 x 4, ARI 0.896
#: against 0.922).
PARTITION_MARGIN = 5.0


def order_to_keep(comparison: dict[str, dict[str, float]]) -> int:
    """``fit_mixture(order="auto")``'s choice from each order's selected fit: a type that
    any order's rule finds is kept, so the order with the largest ``k``. On equal ``k``, where
    the tied orders' partitions were scored under each tied order's chains
    (``exact_icl_at_<order>``: :func:`~torchhrc.mixture.criteria.partition_icl`, the same
    data and prior for all; ``partition``: the lowest order with the same partition), the
    orders whose partition is above every other partition by more than
    :data:`PARTITION_MARGIN` nats under every one of them (an order that found fewer types
    is no judge: its chains cannot see what divides them); among those (or all tied orders,
    where no partition wins so), the larger exact ICL of each fit under its own order
    (``log p(D, z)`` of the recorded data); on equal both, the lower order.

    Why score the partitions under one order: each order's own exact ICL is of a different
    model, and the higher order's is larger whatever the partition (below), so comparing them
    compares the orders, not the partitions. ``five_parts`` (a held-out task of
    ``benchmarks/heldout_tasks.py``) seed 9 at 30 x 4: both orders found 5 types, the first
    with the true partition, the second with two types mixed (ARI 0.84); under the second
    order's chains the first order's partition scores -1936.8 against the second's own
    -2032.2, and under the first order's -2378.7 against -2498.2 (``docs/clustering.md``,
    "The partition on equal k").

    Why not the exact ICL alone: a second-order chain predicts the many steps fixed by the
    task (a robot that answers each action) far better, so its ``log p(D, z)`` is the larger
    on nearly every task whatever the partition, and with five types it often selects one
    type fewer (two merged) than the first order does (``docs/clustering.md``, "Second-order
    chains").

    Args:
        comparison: ``{"1": {"k": ..., "exact_icl": ...}, "2": {...}, ...}`` (the orders
            compared), with ``exact_icl_at_<order>`` and ``partition`` where scored.

    Example:
        >>> order_to_keep({"1": {"k": 5, "exact_icl": -2400.0},
        ...                "2": {"k": 4, "exact_icl": -1950.0}})
        1
        >>> order_to_keep({"1": {"k": 2, "exact_icl": -735.0}, "2": {"k": 2, "exact_icl": -637.0}})
        2
    """
    orders = sorted(int(o) for o in comparison)
    most = max(comparison[str(o)]["k"] for o in orders)
    tied = [o for o in orders if comparison[str(o)]["k"] == most]
    judges = [o for o in tied if all(f"exact_icl_at_{o}" in comparison[str(t)] for t in tied)]
    if len(tied) > 1 and judges:
        part = {o: int(comparison[str(o)].get("partition", o)) for o in tied}
        distinct = sorted(set(part.values()))

        def score(p: int, judge: int) -> float:
            return comparison[str(p)][f"exact_icl_at_{judge}"]

        for p in distinct:
            rivals = [q for q in distinct if q != p]
            if rivals and all(score(p, j) > score(q, j) + PARTITION_MARGIN
                              for j in judges for q in rivals):  # fmt: skip
                tied = [o for o in tied if part[o] == p]
                break
    return max(tied, key=lambda o: (comparison[str(o)]["exact_icl"], -o))


def _same_partition(a: torch.Tensor, b: torch.Tensor) -> bool:
    """Whether two ``(N,)`` labelings are one partition (labels renamed one to one)."""
    pairs = torch.unique(torch.stack([a, b]), dim=1).shape[1]
    return pairs == torch.unique(a).numel() == torch.unique(b).numel()


def _fit_objects(
    data: Any,
    objects: str,
    object_separator: str,
    objects_sample: int,
    order: int,
    options: dict[str, Any],
    seed: int | None,
    generator: torch.Generator | None,
) -> MixtureFit:
    """:func:`fit_mixture` in one order: the objects as given, or both forms compared."""
    has_objects = callable(getattr(data, "relabel_objects", None)) and not isinstance(data, tuple)
    if objects == "exchangeable" and not has_objects:
        raise TypeError(
            "objects='exchangeable' needs a Demonstrations (action names <verb>_<object>), "
            f"got {type(data).__name__}"
        )
    if objects == "auto" and (not has_objects or data.num_objects(separator=object_separator) < 2):
        objects = "raw"  # nothing to exchange
    if objects != "auto":
        fit, caught = _caught(
            lambda: _select_form(data, objects, object_separator, options, seed, generator, order)
        )
        _rewarn(caught, stacklevel=4)
        return fit

    # "auto": compare the two forms (on a sample of units for a large corpus)
    start = generator.get_state() if generator is not None else None
    groups = _groups(data, options["unit"], options["method"])
    units = data.num_sequences if groups is None else int(groups.max()) + 1
    sample = data
    if units > objects_sample:
        pick = _generator(seed, generator)
        chosen_units = torch.randperm(units, generator=pick)[:objects_sample]
        keep = torch.zeros(units, dtype=torch.bool)
        keep[chosen_units] = True
        sample = data.subset(keep if groups is None else keep[groups])
    fits, caught = _each_from(
        start,
        generator,
        ("raw", "exchangeable"),
        lambda form, _: _select_form(sample, form, object_separator, options, seed, generator,
                                     order),
    )  # fmt: skip
    comparison = {
        form: {
            "k": float(f.k),
            "bic": f.bic,
            "exact_icl": _recorded_icl(f),
            "log_likelihood": f.log_likelihood,
            "units": float(min(units, objects_sample)),
        }
        for form, f in fits.items()
    }
    # the exact ICL of each form's selected partition, log p(D, z) of the recorded data: no
    # parameter count (BIC charges every chain A (A - 1) parameters; the forms' selected k
    # may differ, and a chain visits a fraction of its transitions, docs/clustering.md)
    score = {form: comparison[form]["exact_icl"] for form in fits}
    best = "exchangeable" if score["exchangeable"] > score["raw"] else "raw"
    if sample is data:
        fit = fits[best]
        _rewarn(caught[best], stacklevel=4)
    else:
        if start is not None:
            generator.set_state(start)  # type: ignore[union-attr]
        fit, found = _caught(
            lambda: _select_form(data, best, object_separator, options, seed, generator, order)
        )
        _rewarn(found, stacklevel=4)
    return dataclasses.replace(fit, object_comparison=comparison)


#: ``fit_mixture(objects="auto")`` compares the raw and the exchangeable-object forms on the
#: whole corpus up to this many units, else on a random sample of this many (and then fits the
#: corpus once, in the chosen form). At 3,000 units (9,000 sequences of the issue-12 study)
#: the exact-ICL margin is thousands of nats either way (``docs/clustering.md``).
DEFAULT_OBJECTS_SAMPLE = 3000


def _each_from(
    start: torch.Tensor | None,
    generator: torch.Generator | None,
    forms: tuple[Any, ...],
    fit: Callable[[Any, dict[Any, MixtureFit]], MixtureFit],
) -> tuple[dict[Any, MixtureFit], dict[Any, list[warnings.WarningMessage]]]:
    """``fit(form, fits so far)`` for every form, each from the generator's state ``start``
    (as a seed would give it), and the warnings each raised (not shown)."""
    fits: dict[Any, MixtureFit] = {}
    caught: dict[Any, list[warnings.WarningMessage]] = {}
    for form in forms:
        if start is not None:
            generator.set_state(start)  # type: ignore[union-attr]
        fits[form], caught[form] = _caught(lambda form=form: fit(form, fits))
    return fits, caught


def _caught(run: Callable[[], MixtureFit]) -> tuple[MixtureFit, list[warnings.WarningMessage]]:
    """``run()`` and the warnings it raised (not shown)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        fit = run()
    return fit, list(caught)


def _rewarn(caught: list[warnings.WarningMessage], stacklevel: int = 3) -> None:
    """Show warnings caught by :func:`_caught` as fit_mixture's own (``stacklevel``: from
    here to fit_mixture's caller)."""
    for w in caught:
        warnings.warn(w.message, w.category, stacklevel=stacklevel)


def _select_form(
    data: Any,
    objects: str,
    separator: str,
    options: dict[str, Any],
    seed: int | None,
    generator: torch.Generator | None,
    order: int = 1,
) -> MixtureFit:
    """Select-Best-Model on ``data`` read as ``objects`` (``"raw"`` or ``"exchangeable"``),
    in ``order`` 1, 2 or 3 (:mod:`torchhrc.mixture.history`)."""
    if objects == "raw":
        return _select_order(data, order, seed, generator, options)
    # every symbol the recorded vocabulary can relabel to, so that a new subject's
    # demonstrations (over the same recorded vocabulary) can be scored
    relabelled = data.relabel_objects(separator=separator, keep_unused=True)
    fit = _select_order(relabelled, order, seed, generator, options)
    # the likelihood of the recorded demonstrations: each is its relabelled form times one
    # of M!/(M-m)! equally likely injections of its objects (the first step's given, unless
    # the first symbol is modelled)
    shift = float(
        data.relabel_log_multiplicity(separator=separator, given_first=not options["initial"]).sum()
    )
    per_k = {
        k: {
            name: (value - shift if name in ("bic", "icl", "exact_icl", "exact_icl_recorded",
                                             "exact_icl_refined", "log_likelihood",
                                             "log_likelihood_refined", "bic_refined")
                   else value)
            for name, value in row.items()
        }
        for k, row in fit.per_k.items()
    }  # fmt: skip
    model = dataclasses.replace(fit.model, objects="exchangeable", object_separator=separator)
    return dataclasses.replace(
        fit,
        model=model,
        bic=fit.bic - shift,
        icl=fit.icl - shift,
        log_likelihood=fit.log_likelihood - shift,
        per_k=per_k,
        objects="exchangeable",
    )


def _select_order(
    data: Any,
    order: int,
    seed: int | None,
    generator: torch.Generator | None,
    options: dict[str, Any],
) -> MixtureFit:
    """Select-Best-Model on ``data`` as recorded (``order`` 1) or renamed to its context
    symbols (``order`` 2 or 3, :func:`~torchhrc.mixture.history.context_symbols`)."""
    if order == 1:
        return _select(data, seed=seed, generator=generator, **options)
    lowered = context_symbols(data, order)
    fit = _select(lowered.data, seed=seed, generator=generator, support=lowered, **options)
    return dataclasses.replace(fit, model=dataclasses.replace(fit.model, order=order),
                               order=order)  # fmt: skip


def _check_gain(name: str, value: Any) -> None:
    """A ValueError naming ``name`` unless ``value`` is a real number >= 0 (a gain in nats
    per transition)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not value >= 0:
        raise ValueError(f"expected {name} to be a float >= 0 (nats per transition), got {value!r}")


def _select(
    data: Any,
    *,
    k_min: int,
    k_max: int,
    restarts: int,
    method: Method,
    criterion: Criterion | None,
    unit: str,
    parameters: str,
    seed: int | None,
    generator: torch.Generator | None,
    pseudo_count: float | None,
    weight_pseudo_count: float | None,
    max_iterations: int | None,
    short_iterations: int,
    split_merge: bool,
    tol: float,
    floor: float,
    initial: bool,
    min_gain: float | None,
    strong_gain: float | None,
    heldout_gain: float | None,
    min_consistency: float | None,
    folds: int,
    se_factor: float,
    dtype: torch.dtype,
    progress: Callable[[int, int], None] | None,
    ray: bool | str | None,
    support: SecondOrder | None = None,
) -> MixtureFit:
    """:func:`fit_mixture` for one form of the data (its options, ``objects`` aside);
    ``support``: the data are context symbols whose successors it restricts (the soft
    method's smoothing and the exact ICL's Dirichlet, :mod:`torchhrc.mixture.history`)."""
    # a ShardedCorpus (or its merged CorpusStatistics): statistics computed shard by shard
    sharded = callable(getattr(data, "statistics", None))
    if not sharded:
        sequences, lengths, A, vocabulary = _unpack(data)
    if ray is not None and not isinstance(ray, (bool, str)):
        raise TypeError(f"expected ray to be a bool or an address string, got {ray!r}")
    # hard EM has no E-step to distribute: ray= applies only to a corpus whose shards it
    # reduces (a ShardedCorpus, not data in memory or merged statistics), never in silence
    if ray and method == "paper" and not (sharded and hasattr(data, "paths")):
        raise ValueError(
            f"ray={ray!r} runs the soft method's E-steps on Ray; method='paper' (hard EM) has "
            "none to distribute and runs in this process: pass ray=None, or method='soft'"
        )
    for name, value in (("k_min", k_min), ("k_max", k_max), ("restarts", restarts)):
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise ValueError(f"expected {name} to be a positive int, got {value!r}")
    if k_max < k_min:
        raise ValueError(f"expected k_min <= k_max, got k_min = {k_min}, k_max = {k_max}")
    if method not in ("soft", "paper"):
        raise ValueError(f"expected method 'soft' or 'paper', got {method!r}")
    if criterion is None:
        criterion = "icl_or_gain" if method == "soft" else "bic"
    if criterion not in CRITERIA:
        raise ValueError(
            f"expected criterion one of {', '.join(map(repr, CRITERIA))} (or None), "
            f"got {criterion!r}"
        )
    if strong_gain is None:
        strong_gain = DEFAULT_STRONG_GAIN
    if heldout_gain is None:
        heldout_gain = DEFAULT_HELDOUT_GAIN
    _check_gain("strong_gain", strong_gain)
    _check_gain("heldout_gain", heldout_gain)
    if isinstance(folds, bool) or not isinstance(folds, int) or folds < 2:
        raise ValueError(f"expected folds to be an int >= 2, got {folds!r}")
    if isinstance(se_factor, bool) or not isinstance(se_factor, (int, float)) or not se_factor >= 0:
        raise ValueError(f"expected se_factor to be a float >= 0, got {se_factor!r}")
    if unit not in ("auto", "sequence", "subject"):
        raise ValueError(f"expected unit 'auto', 'sequence' or 'subject', got {unit!r}")
    if parameters not in ("auto", "full", "support"):
        raise ValueError(f"expected parameters 'auto', 'full' or 'support', got {parameters!r}")
    if not isinstance(dtype, torch.dtype) or not dtype.is_floating_point:
        raise TypeError(f"expected dtype to be a floating torch.dtype, got {dtype}")
    if max_iterations is not None and max_iterations < 1:
        raise ValueError(f"expected max_iterations >= 1, got {max_iterations}")
    if short_iterations < 1:
        raise ValueError(f"expected short_iterations >= 1, got {short_iterations}")
    if not isinstance(split_merge, bool):
        raise TypeError(f"expected split_merge to be a bool, got {split_merge!r}")
    if pseudo_count is None:
        pseudo_count = DEFAULT_PSEUDO_COUNT
    smoothing: float | Smoothing = pseudo_count
    if support is not None:
        smoothing = Smoothing.on_support(
            pseudo_count, support.transition_support, support.initial_support
        )
    if weight_pseudo_count is None:
        weight_pseudo_count = DEFAULT_WEIGHT_PSEUDO_COUNT
    if min_gain is None:
        min_gain = DEFAULT_MIN_GAIN if method == "soft" else 0.0
    _check_gain("min_gain", min_gain)
    if min_consistency is None:
        min_consistency = DEFAULT_MIN_CONSISTENCY if method == "soft" else 0.0
    if (
        isinstance(min_consistency, bool)
        or not isinstance(min_consistency, (int, float))
        or not (0 <= min_consistency <= 1)
    ):
        raise ValueError(
            f"expected min_consistency to be a float in [0, 1], got {min_consistency!r}"
        )
    gen = _generator(seed, generator)
    by_subject = False
    if sharded:
        by = unit if unit != "auto" else ("subject" if method == "soft" else "sequence")
        corpus = data.statistics(unit=by, initial=initial, dtype=dtype, ray=ray)
        stats, vocabulary, A = corpus.stats, corpus.vocabulary, corpus.stats.num_symbols
        by_subject = by == "subject"
    else:
        groups = _groups(data, unit, method)
        by_subject = groups is not None
        stats = sufficient_statistics(
            sequences, lengths, A, initial=initial, groups=groups, dtype=dtype
        )
    device = stats.counts.device
    ks = torch.arange(k_min, k_max + 1, device=device)
    em: dict[str, Any] = dict(
        method=method, restarts=restarts, pseudo_count=smoothing,
        weight_pseudo_count=weight_pseudo_count, tol=tol, max_iterations=max_iterations,
        short_iterations=short_iterations, floor=floor, initial=initial, dtype=dtype,
        split_restarts=split_merge,
    )  # fmt: skip
    e_step = None
    if ray and method != "paper":  # every E-step on the Ray cluster, M-steps here
        from torchhrc.mixture.ray_estep import RayEStep

        e_step = RayEStep(stats, dtype=dtype, ray=ray)
    try:
        result, run_k, cluster_mask, per_group = _em_all_k(
            stats, ks, gen, e_step=e_step, progress=progress, **em
        )
    finally:
        if e_step is not None:
            e_step.close()

    if parameters == "auto":  # see the docstring: "support" over-splits small studies
        parameters = "full"
    n_params = num_free_parameters(run_k.to(dtype), A, method=method, initial=initial)
    if parameters == "support":
        full_chain = A * (A - 1)
        n_params = n_params - run_k.to(dtype) * (full_chain - _support_parameters(stats))
    n = stats.num_units
    bics = bic(result.log_likelihood, n_params, n)  # (R,)
    icls = bics - result.entropy
    # the partition of every run: the most responsible slot of every distinct row
    exact = exact_icl(stats, result.assignments, cluster_mask).to(bics.dtype)  # (R,)
    # context symbols: the rule above selects with the Dirichlet over all P of them (the
    # second-order rows cost more, which keeps the rule's calibration: docs/clustering.md,
    # "Second-order chains"); log p(D, z) with it over the A recorded symbols is recorded
    # too, to compare with the first order (order="auto")
    recorded = None
    if support is not None:
        recorded = exact_icl(stats, result.assignments, cluster_mask, outcomes=support.outcomes)
    scores = {"bic": bics, "icl": icls, "exact_icl": exact}
    used = criterion
    if criterion == "heldout" and (len(ks) == 1 or stats.num_units < 3):
        used = "bic_or_exact_icl"  # nothing to choose, or too few units to hold any out
    # "bic_or_exact_icl": the best run of each k by BIC, the larger of the two criteria's k;
    # "heldout": the best run of each k by BIC (by log-likelihood: the same k)
    names = {"bic_or_exact_icl": ("bic", "exact_icl"), "heldout": ("bic",),
             "icl_or_gain": ("bic", "exact_icl")}.get(used, (used,))  # fmt: skip
    grouped = [torch.nan_to_num(scores[c], nan=-math.inf).view(len(ks), per_group) for c in names]
    best_run = torch.arange(len(ks), device=device) * per_group + _first_best(grouped[0])
    by_score = max(int(g.max(-1).values.argmax()) for g in grouped)  # index into ks
    heldout: dict[int, dict[str, float]] = {}
    consistency: torch.Tensor | None = None
    split = None
    if by_subject and len(ks) > 1:  # recorded always, applied when min_consistency > 0
        both = _consistency_per_k(
            data, sharded, stats, result, best_run, run_k,
            initial=initial, dtype=dtype, ray=ray, floor=floor,
            smoothing=smoothing if method == "soft" else 0.0,
            weight_pseudo_count=weight_pseudo_count if method == "soft" else 0.0,
        )  # fmt: skip
        consistency, split = (None, None) if both is None else both
    exempt = None  # the steps the min_gain cut spares
    if used == "icl_or_gain" and consistency is not None and split is not None:
        if min_consistency > 0:  # a step the exact ICL itself takes, that splits people
            better = exact[best_run].cpu()
            better = torch.cat([better.new_zeros(1, dtype=torch.bool), better[1:] > better[:-1]])
            exempt = better & (consistency >= min_consistency) & (split >= min_consistency)
    if used == "icl_or_gain":  # the exact ICL's k, or more where each step gains strong_gain
        transitions = num_transitions(stats)
        steps = gains_per_transition(result.log_likelihood[best_run], transitions)
        by_score = _smallest_sufficient(
            steps, int(grouped[1].max(-1).values.argmax()), min_gain, exempt
        )
        strong = _largest_strong(steps, by_score, float(strong_gain))
        if strong > by_score and stats.num_units >= 3:  # confirmed on held-out units
            # only the k the steps to confirm go through are cross-validated (the others
            # cost as much and decide nothing)
            lo = by_score
            values, weights = _heldout_scores(stats, ks[lo : strong + 1], gen, folds, em)
            total = (values * weights[:, None]).sum(0)  # (strong + 1 - lo,)
            held = float(weights.sum())  # the units held out (not ``n`` above: BIC's below)
            while by_score < strong:  # the step gains enough, beyond its own noise
                step = values[:, by_score + 1 - lo] - values[:, by_score - lo]  # (P,) per unit
                mean = float((step * weights).sum()) / held
                se = math.sqrt(held * float(((step - mean) ** 2 * weights).sum())
                               / max(held - 1, 1))  # fmt: skip
                need = max(heldout_gain * max(transitions, 1.0), se_factor * se)
                if not mean * held >= need:
                    break
                by_score += 1
            heldout = {int(ks[lo + i]): {"heldout": float(t)} for i, t in enumerate(total)}
    if used == "heldout":  # held-out likelihood by unit, the smallest k within se_factor SEs
        values, weights = _heldout_scores(stats, ks, gen, folds, em)
        by_score, total, se = _one_standard_error(values, weights, se_factor)
        heldout = {
            int(ks[i]): {"heldout": float(total[i]), "heldout_se": float(se[i])}
            for i in range(len(ks))
        }
    lls = result.log_likelihood[best_run]  # (num_k,)
    gains = gains_per_transition(lls, num_transitions(stats))  # (num_k,), nan for ks[0]
    index = by_score
    if min_gain > 0:
        index = _smallest_sufficient(gains, by_score, float(min_gain), exempt)
    if consistency is not None and split is not None and min_consistency > 0:
        # not all clusters are types, or the step from k - 1 splits no one's people
        while index > 0 and (float(consistency[index]) < min_consistency
                             or float(split[index]) < min_consistency):  # fmt: skip
            index -= 1
    chosen = int(best_run[index])
    per_k = {
        int(ks[i]): {
            "bic": float(bics[best_run[i]]),
            "icl": float(icls[best_run[i]]),
            "exact_icl": float(exact[best_run[i]]),
            **({} if recorded is None else {"exact_icl_recorded": float(recorded[best_run[i]])}),
            "log_likelihood": float(lls[i]),
            **({"gain": float(gains[i])} if i > 0 else {}),
            **heldout.get(int(ks[i]), {}),
            **(
                {"consistency": float(consistency[i])}
                if consistency is not None and not math.isnan(float(consistency[i]))
                else {}
            ),
            **(
                {"split_consistency": float(split[i])}
                if split is not None and not math.isnan(float(split[i]))
                else {}
            ),
        }
        for i in range(len(ks))
    }
    _warn_at_edge(stats, int(ks[index]), k_min, k_max, per_k, float(min_gain))
    k = int(run_k[chosen])
    outcomes = None if support is None else support.outcomes
    floor_icl = None  # log p(D, z) of the best partition into k - 1 clusters
    if index > 0:
        floor_icl = float((exact if recorded is None else recorded)[best_run[index - 1]])
    elif k == 2:  # one cluster: its partition needs no fit
        one = torch.zeros(stats.counts.shape[0], 1, dtype=torch.long, device=stats.counts.device)
        mask = torch.ones(1, 1, dtype=torch.bool, device=one.device)
        floor_icl = float(exact_icl(stats, one, mask, outcomes=outcomes)[0])
    if method == "soft" and k >= 2 and floor_icl is not None:
        # the k-partition with the larger log p(D, z), where log p(D, z) itself prefers k
        # clusters to k - 1 (docs/clustering.md, "Refining the partition by its exact ICL")
        refined = _refine_run(stats, result, chosen, k, smoothing, weight_pseudo_count,
                              outcomes=outcomes, floor_icl=floor_icl)  # fmt: skip
        if refined is not None:
            result, moved, icl = refined
            chosen = 0
            n_params_run = n_params[best_run[index]].reshape(1)
            bics = bic(result.log_likelihood, n_params_run, n)
            icls = bics - result.entropy
            per_k[int(ks[index])].update({
                "refined_moves": float(moved), "exact_icl_refined": icl,
                # the kept model's figures beside the EM run's (log_likelihood, bic)
                "log_likelihood_refined": float(result.log_likelihood[0]),
                "bic_refined": float(bics[0]),
            })  # fmt: skip
    fit = _finish(stats, result, chosen, k, bics, icls, per_k, method, used, vocabulary)
    if used != "icl_or_gain" or index + 1 >= len(ks):
        return fit
    thresholds = {"min_gain": float(min_gain), "strong_gain": float(strong_gain),
                  "heldout_gain": float(heldout_gain),
                  "min_consistency": float(min_consistency)}  # fmt: skip
    step = _short_of(per_k, int(ks[index]), int(ks[index + 1]), thresholds,
                     icl_k=int(ks[int(grouped[1].max(-1).values.argmax())]),
                     transitions=num_transitions(stats))  # fmt: skip
    return dataclasses.replace(fit, next_step=step)


def _short_of(per_k: dict[int, dict[str, float]], k: int, nxt: int,
              thresholds: dict[str, float], *, icl_k: int, transitions: float,
              ) -> dict[str, Any]:  # fmt: skip
    """``MixtureFit.next_step``: the thresholds the step from ``k`` to ``nxt`` falls below
    (its records in ``per_k``; ``icl_k`` the exact ICL's k, ``transitions`` the data's)."""
    row, short = per_k[nxt], []
    gain = row.get("gain", math.nan)
    values: dict[str, float] = {"gain": gain}
    if not gain >= thresholds["min_gain"]:
        short.append("min_gain")
    if nxt > icl_k and not gain >= thresholds["strong_gain"]:
        short.append("strong_gain")
    if "heldout" in row and "heldout" in per_k[k]:
        values["heldout_gain"] = (row["heldout"] - per_k[k]["heldout"]) / max(transitions, 1.0)
        if not values["heldout_gain"] >= thresholds["heldout_gain"]:
            short.append("heldout_gain")
    for name in ("consistency", "split_consistency"):
        if name in row and thresholds["min_consistency"] > 0:
            values[name] = row[name]
            if not row[name] >= thresholds["min_consistency"]:
                short.append(name)
    return {"k": nxt, "short_of": short, "values": values, "thresholds": dict(thresholds)}


def _refine_run(
    stats: SufficientStatistics,
    result: EMResult,
    run: int,
    k: int,
    smoothing: float | Smoothing,
    weight_pseudo_count: float,
    *,
    outcomes: int | None,
    floor_icl: float,
) -> tuple[EMResult, int, float] | None:
    """Run ``run``'s partition refined by exact-ICL moves
    (:func:`~torchhrc.mixture.refine.refine_partition`) and its chains re-estimated from it
    (one smoothed M-step), as a one-run EMResult with the number of units moved and the
    refined partition's exact ICL; None when no unit moves or when the refined partition's
    exact ICL is not above ``floor_icl`` (the exact ICL then prefers fewer clusters, and its
    moves drift towards them)."""
    z0 = result.assignments[:, run]
    if int(z0.max()) >= k:  # not a partition into the run's k slots
        return None
    z = refine_partition(stats, z0, k, prior=EXACT_ICL_PRIOR, outcomes=outcomes)
    moved = int((z != z0).sum())
    mask = torch.ones(1, k, dtype=torch.bool, device=z.device)
    icl = float(exact_icl(stats, z[:, None], mask, outcomes=outcomes)[0])
    if moved == 0 or not icl > floor_icl:
        return None
    dtype = result.log_transition.dtype
    lt, lw, li = _soft_initial_parameters(stats, z[:, None], mask, smoothing,
                                          weight_pseudo_count, dtype)  # fmt: skip
    scored = soft_pass(stats, lt, lw, li, mask)  # its log-likelihood and entropy
    one = EMResult(
        log_transition=lt,
        log_weights=lw,
        log_initial=li,
        assignments=z[:, None],
        log_likelihood=scored.log_likelihood,
        entropy=scored.entropy,
        iterations=result.iterations[run : run + 1],
        converged=result.converged[run : run + 1],
    )
    return one, moved, icl


def _consistency_per_k(
    data: Any,
    sharded: bool,
    stats: SufficientStatistics,
    result: EMResult,
    best_run: torch.Tensor,
    run_k: torch.Tensor,
    *,
    initial: bool,
    dtype: torch.dtype,
    ray: bool | str | None,
    floor: float,
    smoothing: float | Smoothing,
    weight_pseudo_count: float,
) -> tuple[torch.Tensor, torch.Tensor] | None:
    """``(num_k,)`` the smallest subject consistency (ICC) over the clusters of every k's
    best run (``nan`` where undefined: one sequence per subject, k = 1), and ``(num_k,)``
    the split consistency of every k's best run against the previous k's
    (:func:`~torchhrc.mixture.consistency.split_consistency`; ``nan`` for the first k);
    or None when the data has no per-sequence counts (merged statistics of shards, computed
    by subject).

    The subjects are the unit rows of ``stats`` (``stats.inverse (N,)``: subjects with equal
    summed counts share a row, the same grouping in memory and in shards); the sequences'
    own counts come from a second reduction by sequence, and each is read under the chains
    refitted without its subject (:func:`~torchhrc.mixture.consistency.held_out_posteriors`,
    with the fit's ``smoothing`` and ``weight_pseudo_count``)."""
    if sharded:
        try:
            per_sequence = data.statistics(unit="sequence", initial=initial, dtype=dtype,
                                           ray=ray).stats  # fmt: skip
        except ModelError:  # merged CorpusStatistics: computed by subject only
            warnings.warn(
                "fit_mixture: the subject-consistency check (min_consistency) needs each "
                "sequence's counts, which merged statistics by subject do not hold; it was "
                "skipped (fit the ShardedCorpus itself to run it)",
                stacklevel=4,
            )
            return None
    else:
        sequences, lengths, A, _ = _unpack(data)
        per_sequence = sufficient_statistics(sequences, lengths, A, initial=initial, dtype=dtype)
    groups = stats.inverse.to(per_sequence.inverse.device)
    pseudo_transition, pseudo_initial = pseudo_parts(smoothing)
    out, splits = [], []
    previous = None
    for run in best_run.tolist():
        k = int(run_k[run])
        lw = result.log_weights[run, :k]
        li = result.log_initial[run, :k] if result.log_initial is not None else None
        rows = held_out_posteriors(
            per_sequence, stats, result.log_transition[run, :k], li,
            lw - torch.logsumexp(lw, -1), pseudo_transition=pseudo_transition,
            pseudo_initial=pseudo_initial, weight_pseudo_count=weight_pseudo_count, floor=floor,
        )  # fmt: skip
        icc = intraclass_correlation(rows, groups)
        defined = icc[~icc.isnan()]
        out.append(float(defined.min()) if k > 1 and defined.numel() else math.nan)
        split = math.nan
        if previous is not None and k > 1:
            split = split_consistency(rows, previous, groups)
        splits.append(split)
        previous = rows
    return torch.tensor(out, dtype=torch.float64), torch.tensor(splits, dtype=torch.float64)


def _finish(
    stats: SufficientStatistics,
    result: EMResult,
    run: int,
    k: int,
    bics: torch.Tensor,
    icls: torch.Tensor,
    per_k: dict[int, dict[str, float]],
    method: str,
    criterion: str,
    vocabulary: tuple[Any, ...] | None,
) -> MixtureFit:
    """Slice the chosen run, order its clusters by size, map rows back to sequences."""
    lt = result.log_transition[run, :k]  # (k, A, A)
    lw = result.log_weights[run, :k]  # (k,)
    li = result.log_initial[run, :k] if result.log_initial is not None else None
    if method == "paper":
        z = result.assignments[:, run]  # (U,)
        resp_rows = F.one_hot(z, k).to(lt.dtype)
    else:
        joint = e_table(
            stats.counts, stats.first_counts, lt[None], None if li is None else li[None]
        )
        joint = joint[:, 0] + lw  # (U, k)
        resp_rows = (joint - torch.logsumexp(joint, -1, keepdim=True)).exp()
    # order clusters by decreasing size (ties: by index), a canonical labelling
    sizes = (resp_rows * stats.multiplicity[:, None]).sum(0)
    order = torch.sort(-sizes, stable=True).indices
    lt, lw, resp_rows = lt[order], lw[order], resp_rows[:, order]
    if li is not None:
        li = li[order]
    # renormalise weights in float64-safe log space (sliced from k_max slots)
    lw = lw - torch.logsumexp(lw, -1)
    model = MarkovChainMixture(
        log_transition=lt.contiguous(),
        log_weights=lw.contiguous(),
        log_initial=None if li is None else li.contiguous(),
        vocabulary=vocabulary,
        atol=1e-4 if lt.dtype == torch.float32 else 1e-6,
    )
    responsibilities = resp_rows[stats.inverse]  # (N, k)
    return MixtureFit(
        model=model,
        k=k,
        bic=float(bics[run]),
        icl=float(icls[run]),
        log_likelihood=float(result.log_likelihood[run]),
        assignments=responsibilities.argmax(-1),
        responsibilities=responsibilities,
        per_k=per_k,
        method=method,
        criterion=criterion,
        converged=bool(result.converged[run]),
        iterations=int(result.iterations[run]),
        num_distinct=stats.num_distinct,
    )
