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
  EM with Dirichlet smoothing (:mod:`.soft_em`); the BIC also counts the ``k - 1`` free
  mixture weights (and ``k (A - 1)`` first-symbol parameters when ``initial=True``), and
  ``l`` is the marginal log-likelihood.

``criterion="icl"`` uses the integrated completed likelihood ``ICL = BIC - H(r)`` (Biernacki,
Celeux, Govaert 2000), ``H`` the entropy of the responsibilities (0 for hard EM).

Example:
    >>> import torch
    >>> from torchhrc.mixture import fit_mixture
    >>> seqs = torch.tensor([[0, 1, 0, 1]] * 6 + [[0, 0, 0, 0]] * 4)
    >>> fit = fit_mixture((seqs, torch.full((10,), 4), 2), k_min=1, k_max=3, restarts=3)
    >>> fit.k, fit.assignments.tolist()
    (2, [0, 0, 0, 0, 0, 0, 1, 1, 1, 1])
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Literal

import torch
import torch.nn.functional as F

from torchhrc.errors import ModelError
from torchhrc.mixture._em import EMResult, e_table
from torchhrc.mixture.counts import SufficientStatistics, check_sequences, sufficient_statistics
from torchhrc.mixture.hard_em import hard_em, partition_counts, partition_sizes
from torchhrc.mixture.init import kmeans_pp_init, random_init
from torchhrc.mixture.model import MarkovChainMixture
from torchhrc.mixture.soft_em import SoftStatistics, m_step, soft_em

__all__ = ["MixtureFit", "bic", "fit_mixture", "num_free_parameters"]

Method = Literal["soft", "paper"]
Criterion = Literal["bic", "icl"]


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
        per_k: ``k -> {"bic", "icl", "log_likelihood"}`` of the best run of every k.
        method: ``"soft"`` or ``"paper"``; criterion: ``"bic"`` or ``"icl"``.
        converged: whether the selected run converged before ``max_iterations``.
        iterations: EM iterations of the selected run.
        num_distinct: distinct sequences (by transition counts) the EM worked on.
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


def _soft_initial_parameters(
    stats: SufficientStatistics,
    z: torch.Tensor,
    cluster_mask: torch.Tensor,
    pseudo_count: float,
    weight_pseudo_count: float,
    dtype: torch.dtype,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
    """Smoothed M-step from a hard partition ``z (U, R)``."""
    R, K = cluster_mask.shape
    A = stats.num_symbols
    flat_counts, flat_init = partition_counts(stats, z, K, dtype)  # chunked, (R*K, ...)
    counts = flat_counts.view(R, K, A, A)
    init_counts = flat_init.view(R, K, A) if flat_init is not None else None
    expected = SoftStatistics(
        counts=counts,
        initial_counts=init_counts,
        sizes=partition_sizes(z, stats.multiplicity, K).to(dtype),
        log_likelihood=counts.new_zeros(R),
        entropy=counts.new_zeros(R),
        assignments=z,
    )
    uniform = counts.new_full((R, K, A, A), -math.log(A))
    uniform_init = (
        counts.new_full((R, K, A), -math.log(A)) if stats.first_counts is not None else None
    )
    return m_step(expected, uniform, uniform_init, cluster_mask, pseudo_count, weight_pseudo_count)


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


def _support_parameters(stats: SufficientStatistics) -> int:
    """Free parameters of one chain on the observed support: ``sum_a max(s_a - 1, 0)``.

    ``s_a`` = number of distinct successors of ``a`` seen anywhere in the data.
    """
    A = stats.num_symbols
    seen = ((stats.counts * stats.multiplicity[:, None]).sum(0) > 0).view(A, A)
    return int((seen.sum(-1) - 1).clamp_min(0).sum())


def fit_mixture(
    data: Any,
    *,
    k_min: int = 2,
    k_max: int = 10,
    restarts: int = 20,
    method: Method = "soft",
    criterion: Criterion = "bic",
    unit: Literal["auto", "sequence", "subject"] = "auto",
    parameters: Literal["auto", "full", "support"] = "auto",
    seed: int | None = None,
    generator: torch.Generator | None = None,
    pseudo_count: float = 0.1,
    weight_pseudo_count: float = 1.0,
    max_iterations: int | None = None,
    short_iterations: int = 5,
    tol: float = 1e-6,
    floor: float = 1e-10,
    initial: bool = False,
    dtype: torch.dtype = torch.float64,
    progress: Callable[[int, int], None] | None = None,
    ray: bool | str | None = None,
) -> MixtureFit:
    """Cluster sequences into human types and choose their number (Select-Best-Model).

    Args:
        data: a :class:`torchhrc.data.Demonstrations`, a tuple ``(sequences (N, L) int64,
            lengths (N,) int64, num_symbols)``, or a corpus in shards
            (:class:`torchhrc.corpus.ShardedCorpus`: CSV or Parquet files), whose shards are
            reduced to their distinct units one by one (or as Ray tasks, ``ray=``) and merged
            exactly: the same fit as the corpus in memory.
        k_min, k_max: the range of k (``1 <= k_min <= k_max``).
        restarts: EM runs per k (the paper's numOfIterations, 20).
        method: ``"soft"`` (k-means++ + smoothed soft EM, the default) or ``"paper"``
            (random init + hard EM, exactly the paper's algorithm).
        criterion: ``"bic"`` (the paper's) or ``"icl"``.
        unit: what gets one cluster label: ``"sequence"`` (the paper) or ``"subject"`` (all
            demonstrations of a subject share one type, their evidence adds up; needs a
            ``Demonstrations``). ``"auto"``: ``"subject"`` for ``"soft"`` when subject ids
            are known, else ``"sequence"``. The BIC's ``n`` is the number of units.
        parameters: the BIC's parameter count: ``"full"`` (the paper's ``k A (A - 1)``)
            or ``"support"`` (only transitions observed somewhere in the data are free:
            ``k sum_a (s_a - 1)``, ``s_a`` the distinct successors of ``a``). ``"auto"``:
            ``"full"`` for ``"paper"``, ``"support"`` for ``"soft"``.
        seed, generator: randomness (one of them; default seed 0). Same seed, same result.
        pseudo_count: Dirichlet pseudo-count on transitions (``"soft"`` only).
        weight_pseudo_count: pseudo-count on cluster sizes (``"soft"`` only).
        max_iterations: EM iteration cap (default 100 for ``"paper"``, 200 for ``"soft"``).
        short_iterations: ``"soft"`` runs the em-EM strategy (Biernacki, Celeux, Govaert
            2003): every restart runs this many iterations, then the best restart of each k
            (by log-likelihood) runs to convergence.
        tol: relative log-likelihood change that stops soft EM.
        floor: probability that stands for 0 in the paper's E-step (see :mod:`.hard_em`).
        initial: also model each cluster's first-symbol distribution.
        dtype: float dtype of the computation (float32 halves time and memory on big data).
        progress: ``progress(iteration, runs_still_running)`` after every EM iteration.
        ray: with a sharded corpus, reduce each shard in a Ray task: ``True`` or ``"local"``
            (a local cluster, unless Ray is already initialised) or ``"HOST:PORT"``.

    Returns:
        :class:`MixtureFit`.

    Raises:
        TypeError, ValueError, ModelError: invalid data or options (the message names them).

    Example:
        >>> import torch
        >>> seqs = torch.tensor([[0, 1, 0, 1]] * 5 + [[0, 0, 0, 0]] * 5)
        >>> fit_mixture((seqs, torch.full((10,), 4), 2), k_min=1, k_max=2, restarts=2).k
        2
    """
    # a ShardedCorpus (or its merged CorpusStatistics): statistics computed shard by shard
    sharded = callable(getattr(data, "statistics", None))
    if not sharded:
        sequences, lengths, A, vocabulary = _unpack(data)
    elif ray is not None and not isinstance(ray, (bool, str)):
        raise TypeError(f"expected ray to be a bool or an address string, got {ray!r}")
    for name, value in (("k_min", k_min), ("k_max", k_max), ("restarts", restarts)):
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise ValueError(f"expected {name} to be a positive int, got {value!r}")
    if k_max < k_min:
        raise ValueError(f"expected k_min <= k_max, got k_min = {k_min}, k_max = {k_max}")
    if method not in ("soft", "paper"):
        raise ValueError(f"expected method 'soft' or 'paper', got {method!r}")
    if criterion not in ("bic", "icl"):
        raise ValueError(f"expected criterion 'bic' or 'icl', got {criterion!r}")
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
    gen = _generator(seed, generator)
    if sharded:
        by = unit if unit != "auto" else ("subject" if method == "soft" else "sequence")
        corpus = data.statistics(unit=by, initial=initial, dtype=dtype, ray=ray)
        stats, vocabulary, A = corpus.stats, corpus.vocabulary, corpus.stats.num_symbols
    else:
        groups = _groups(data, unit, method)
        stats = sufficient_statistics(
            sequences, lengths, A, initial=initial, groups=groups, dtype=dtype
        )
    device = stats.counts.device
    ks = torch.arange(k_min, k_max + 1, device=device)
    run_k = ks.repeat_interleave(restarts)  # (R,): run r = (k index) * restarts + restart
    K = k_max
    cluster_mask = torch.arange(K, device=device) < run_k.unsqueeze(-1)  # (R, K)

    result: EMResult
    per_group = restarts
    if method == "paper":
        lt0, z0 = random_init(stats, cluster_mask, generator=gen, dtype=dtype)
        li0 = None
        if initial:
            li0 = lt0.new_full((run_k.shape[0], K, A), -math.log(A))
        result = hard_em(
            stats,
            lt0,
            cluster_mask,
            assignments=z0,
            log_initial=li0,
            floor=floor,
            max_iterations=100 if max_iterations is None else max_iterations,
            progress=progress,
        )
    else:
        z0 = kmeans_pp_init(stats, cluster_mask, generator=gen)
        lt0, lw0, li0 = _soft_initial_parameters(
            stats, z0, cluster_mask, pseudo_count, weight_pseudo_count, dtype
        )
        options = dict(pseudo_count=pseudo_count, weight_pseudo_count=weight_pseudo_count, tol=tol)
        cap = 200 if max_iterations is None else max_iterations
        if restarts > 1:  # em-EM: short runs for every restart, then the best of each k
            short = soft_em(
                stats,
                lt0,
                lw0,
                cluster_mask,
                log_initial=li0,
                max_iterations=min(short_iterations, cap),
                progress=progress,
                details=False,  # only the log-likelihoods and parameters are kept
                **options,
            )
            ll = torch.nan_to_num(short.log_likelihood, nan=-math.inf).view(len(ks), restarts)
            keep = torch.arange(len(ks), device=device) * restarts + ll.argmax(-1)  # (num_k,)
            lt0, lw0 = short.log_transition[keep], short.log_weights[keep]
            li0 = short.log_initial[keep] if short.log_initial is not None else None
            run_k, cluster_mask, per_group = run_k[keep], cluster_mask[keep], 1
        result = soft_em(
            stats,
            lt0,
            lw0,
            cluster_mask,
            log_initial=li0,
            max_iterations=cap,
            progress=progress,
            **options,
        )

    if parameters == "auto":
        parameters = "full"
    n_params = num_free_parameters(run_k.to(dtype), A, method=method, initial=initial)
    if parameters == "support":
        full_chain = A * (A - 1)
        n_params = n_params - run_k.to(dtype) * (full_chain - _support_parameters(stats))
    n = stats.num_units
    bics = bic(result.log_likelihood, n_params, n)  # (R,)
    icls = bics - result.entropy
    score = bics if criterion == "bic" else icls
    score = torch.nan_to_num(score, nan=-math.inf)
    grouped = score.view(len(ks), per_group)
    best_run = torch.arange(len(ks), device=device) * per_group + grouped.argmax(-1)
    chosen = int(best_run[grouped.max(-1).values.argmax()])
    per_k = {
        int(ks[i]): {
            "bic": float(bics[best_run[i]]),
            "icl": float(icls[best_run[i]]),
            "log_likelihood": float(result.log_likelihood[best_run[i]]),
        }
        for i in range(len(ks))
    }
    return _finish(
        stats,
        result,
        chosen,
        int(run_k[chosen]),
        bics,
        icls,
        per_k,
        method,
        criterion,
        vocabulary,
    )


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
