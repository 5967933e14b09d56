"""Mixture of Markov chains: clustering demonstrations into human types.

The paper's section "Clustering of Human Types" (Nikolaidis et al.): each human type is a
transition matrix over the joint actions; hard EM (Cluster-Transition-Matrices) assigns
sequences to types, and Select-Best-Model picks the number of types by BIC. This package
adds soft EM with Dirichlet smoothing and k-means++ initialisation (the default), runs every
``(k, restart)`` pair as one batched tensor program, infers the type of a new subject, and
offers a Pyro version of the model. A corpus too large for memory is clustered from its
shards (:class:`ShardedCorpus`: each shard reduced to its distinct rows, the merge exact),
and with ``ray=`` the E-steps run on a Ray cluster (:class:`RayEStep`).

Example:
    >>> import torch
    >>> from torchhrc.mixture import fit_mixture, infer_type
    >>> seqs = torch.tensor([[0, 1, 0, 1]] * 5 + [[0, 0, 0, 0]] * 5)
    >>> fit = fit_mixture((seqs, torch.full((10,), 4), 2), k_min=1, k_max=3, restarts=2)
    >>> probs = infer_type(fit.model, seqs[:2], torch.tensor([4, 4]))
    >>> fit.k, probs.argmax().item() == fit.assignments[0].item()
    (2, True)
"""

from __future__ import annotations

from torchhrc.mixture.consistency import cluster_consistency, intraclass_correlation
from torchhrc.mixture.counts import (
    SufficientStatistics,
    cluster_counts,
    sufficient_statistics,
    transition_counts,
)
from torchhrc.mixture.hard_em import hard_em
from torchhrc.mixture.inference import infer_type
from torchhrc.mixture.init import kmeans_pp_init, random_init
from torchhrc.mixture.likelihood import (
    count_log_likelihood,
    mixture_log_likelihood,
    sequence_log_likelihood,
)
from torchhrc.mixture.model import MarkovChainMixture
from torchhrc.mixture.ray_estep import RayEStep
from torchhrc.mixture.refine import refine_partition
from torchhrc.mixture.selection import (
    ClusterConfig,
    MixtureFit,
    bic,
    fit_mixture,
    num_free_parameters,
    partition_chains,
)
from torchhrc.mixture.sharded import (
    CorpusStatistics,
    ShardedCorpus,
    ShardStatistics,
    shard_statistics,
)
from torchhrc.mixture.soft_em import soft_em

__all__ = [
    "ClusterConfig",
    "CorpusStatistics",
    "MarkovChainMixture",
    "MixtureFit",
    "RayEStep",
    "ShardStatistics",
    "ShardedCorpus",
    "SufficientStatistics",
    "bic",
    "cluster_consistency",
    "cluster_counts",
    "count_log_likelihood",
    "fit_mixture",
    "hard_em",
    "infer_type",
    "intraclass_correlation",
    "kmeans_pp_init",
    "mixture_log_likelihood",
    "num_free_parameters",
    "partition_chains",
    "random_init",
    "refine_partition",
    "sequence_log_likelihood",
    "shard_statistics",
    "soft_em",
    "sufficient_statistics",
    "transition_counts",
]
