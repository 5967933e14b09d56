"""Leave-one-subject-out accuracy of the inferred human type (the paper's evaluation).

Paper (Nikolaidis et al., "Performance of Human Type Clustering"): for each subject, cluster
the sequences of all other subjects (Select-Best-Model), infer the held-out subject's type
from its sequences with the likelihood-weighted vote, and compare with the expert's label;
the paper reports an average accuracy of 96.5% on 18 subjects x 3 sequences.

Fold ``f`` (held-out subject ``s_f``):

1. ``fit = fit_mixture(all sequences but s_f's, k_min..k_max, restarts, method, seed)``;
2. name the clusters: the one-to-one map cluster -> label that agrees best with the
   training sequences' labels (an exact assignment problem, :func:`~torchhrc.metrics.
   match_clusters`), or each cluster's majority label (``matching="majority"``);
   a cluster left without a label (more clusters than labels) predicts no label;
3. ``p = infer_type(fit.model, s_f's sequences)``: the paper's vote (default) or the
   Bayesian posterior; the probability of a label is the sum of ``p`` over its clusters;
4. the prediction is the most probable label; accuracy = fraction of correct subjects.

The folds differ in their training data, so they are fitted one after the other (each fit
is itself one batched tensor program over all ``(k, restart)`` runs); progress goes to the
``progress`` callback and to ``logging`` (logger ``torchhrc.experiments.loo``).

Example:
    >>> from torchhrc.tasks.place_and_drill import simulate_study
    >>> from torchhrc.experiments.loo import leave_one_subject_out
    >>> demos = simulate_study(n_subjects=6, noise=0.0, seed=0)
    >>> leave_one_subject_out(demos, k_max=3, restarts=2, method="paper").accuracy
    1.0
"""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Callable, Hashable
from dataclasses import dataclass
from typing import Any, Literal

import torch

from torchhrc.data import Demonstrations
from torchhrc.errors import ModelError
from torchhrc.metrics import match_clusters

__all__ = ["FoldResult", "LeaveOneOutResult", "leave_one_subject_out"]

logger = logging.getLogger(__name__)

Inference = Literal["vote", "posterior"]
Matching = Literal["one_to_one", "majority"]


@dataclass(frozen=True)
class FoldResult:
    """One fold: the held-out subject and what the model trained without it predicts.

    Attributes:
        subject: the held-out subject.
        true_type: its ground-truth label.
        predicted_type: the most probable label, or ``None`` if the most probable cluster
            has no label (one-to-one matching with more clusters than labels).
        correct: ``predicted_type == true_type``.
        k: the number of clusters selected on the training subjects.
        cluster_probabilities: ``(k,)`` float64, ``P(type = cluster)`` from ``infer_type``.
        cluster_labels: ``(k,)`` the label of each cluster (``None`` if unmatched).
        cluster_sizes: ``(k,)`` training sequences assigned to each cluster.
        label_probabilities: label -> summed probability of its clusters.
    """

    subject: str
    true_type: str
    predicted_type: str | None
    correct: bool
    k: int
    cluster_probabilities: torch.Tensor
    cluster_labels: tuple[str | None, ...]
    cluster_sizes: tuple[int, ...]
    label_probabilities: dict[str | None, float]

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready record."""
        return {
            "subject": self.subject,
            "true_type": self.true_type,
            "predicted_type": self.predicted_type,
            "correct": self.correct,
            "k": self.k,
            "cluster_probabilities": self.cluster_probabilities.tolist(),
            "cluster_labels": list(self.cluster_labels),
            "cluster_sizes": list(self.cluster_sizes),
            "label_probabilities": {
                ("null" if k is None else k): v for k, v in self.label_probabilities.items()
            },
        }


@dataclass(frozen=True)
class LeaveOneOutResult:
    """Leave-one-subject-out accuracy and the per-subject predictions.

    Attributes:
        accuracy: fraction of subjects whose type is predicted correctly.
        folds: one :class:`FoldResult` per subject, in order of first appearance.
        method, inference, matching: the settings used.
    """

    accuracy: float
    folds: tuple[FoldResult, ...]
    method: str
    inference: str
    matching: str

    @property
    def subjects(self) -> tuple[str, ...]:
        """``(S,)`` the held-out subjects."""
        return tuple(f.subject for f in self.folds)

    @property
    def predictions(self) -> dict[str, str | None]:
        """subject -> predicted label."""
        return {f.subject: f.predicted_type for f in self.folds}

    @property
    def k_counts(self) -> dict[int, int]:
        """How many folds selected each ``k``."""
        return dict(sorted(Counter(f.k for f in self.folds).items()))

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready summary."""
        return {
            "accuracy": self.accuracy,
            "method": self.method,
            "inference": self.inference,
            "matching": self.matching,
            "k_counts": {str(k): v for k, v in self.k_counts.items()},
            "folds": [f.to_dict() for f in self.folds],
        }


def _subject_types(demos: Demonstrations) -> dict[str, str]:
    if demos.types is None:
        raise ModelError("leave-one-subject-out needs ground-truth types (the CSV's 'type' column)")
    labels: dict[str, str] = {}
    for subject, label, key in zip(demos.subjects, demos.types, demos.keys):
        if labels.setdefault(subject, label) != label:
            raise ModelError(
                f"subject {subject!r} has sequences labelled {labels[subject]!r} and "
                f"{label!r} (at {key}); expected one type per subject"
            )
    return labels


def _cluster_labels(
    train_types: tuple[str, ...], assignments: torch.Tensor, k: int, matching: Matching
) -> tuple[str | None, ...]:
    clusters = assignments.tolist()
    if matching == "one_to_one":
        mapping: dict[Hashable, Hashable] = match_clusters(train_types, clusters)
    else:
        votes: dict[int, Counter[str]] = {}
        for c, label in zip(clusters, train_types):
            votes.setdefault(c, Counter())[label] += 1
        # Ties go to the label first in sorted order (deterministic).
        mapping = {
            c: min(v.items(), key=lambda item: (-item[1], item[0]))[0] for c, v in votes.items()
        }
    return tuple(mapping.get(c) for c in range(k))  # type: ignore[misc]


def leave_one_subject_out(
    demonstrations: Demonstrations,
    *,
    k_min: int = 2,
    k_max: int = 10,
    restarts: int = 20,
    method: str = "soft",
    inference: Inference = "vote",
    matching: Matching = "one_to_one",
    seed: int = 0,
    progress: Callable[[int, int, FoldResult], None] | None = None,
    **fit_options: Any,
) -> LeaveOneOutResult:
    """Leave-one-subject-out type accuracy (see the module docstring for the protocol).

    Args:
        demonstrations: sequences of at least two subjects, with ``types`` (one per subject).
        k_min, k_max, restarts, method: passed to :func:`torchhrc.mixture.fit_mixture`
            (``method="paper"``: the paper's hard EM; ``"soft"``: the default method).
        inference: ``"vote"`` (the paper's likelihood-weighted vote over the subject's
            sequences) or ``"posterior"`` (Bayesian: sum of log-likelihoods + log prior).
        matching: ``"one_to_one"`` (best assignment, the default) or ``"majority"``.
        seed: the seed of every fold's fit (each fold reproducible on its own).
        progress: called as ``progress(fold, num_folds, result)`` after each fold.
        **fit_options: further keyword options of ``fit_mixture`` (e.g. ``pseudo_count``).

    Returns:
        :class:`LeaveOneOutResult`.

    Raises:
        ModelError: no types, a subject with two types, fewer than two subjects.
        ValueError: an unknown ``inference`` or ``matching``.
    """
    from torchhrc.mixture import fit_mixture, infer_type

    Demonstrations.check(demonstrations)
    if inference not in ("vote", "posterior"):
        raise ValueError(f"expected inference 'vote' or 'posterior', got {inference!r}")
    if matching not in ("one_to_one", "majority"):
        raise ValueError(f"expected matching 'one_to_one' or 'majority', got {matching!r}")
    labels = _subject_types(demonstrations)
    subjects = demonstrations.unique_subjects
    if len(subjects) < 2:
        raise ModelError(f"leave-one-subject-out needs at least 2 subjects, got {len(subjects)}")
    folds: list[FoldResult] = []
    for f, subject in enumerate(subjects):
        held_out = torch.tensor([s == subject for s in demonstrations.subjects])
        train = demonstrations.subset(~held_out)
        test = demonstrations.subset(held_out)
        fit = fit_mixture(
            train,
            k_min=k_min,
            k_max=k_max,
            restarts=restarts,
            method=method,
            seed=seed,
            **fit_options,
        )
        assert train.types is not None
        names = _cluster_labels(train.types, fit.assignments, fit.k, matching)
        scored = fit.model.prepare(test)  # the form the chains are over (fit.objects)
        probs = infer_type(fit.model, scored.sequences, scored.lengths, method=inference)
        probs = probs.detach().to(device="cpu", dtype=torch.float64)  # (k,)
        by_label: dict[str | None, float] = {}
        for name, p in zip(names, probs.tolist()):
            by_label[name] = by_label.get(name, 0.0) + p
        # Most probable label; ties broken by cluster order (first cluster of the label).
        predicted = max(by_label, key=lambda name: by_label[name])
        result = FoldResult(
            subject=subject,
            true_type=labels[subject],
            predicted_type=predicted,
            correct=predicted == labels[subject],
            k=fit.k,
            cluster_probabilities=probs,
            cluster_labels=names,
            cluster_sizes=tuple(torch.bincount(fit.assignments.cpu(), minlength=fit.k).tolist()),
            label_probabilities=by_label,
        )
        folds.append(result)
        logger.info(
            "fold %d/%d: subject %s, k = %d, true %s, predicted %s",
            f + 1,
            len(subjects),
            subject,
            fit.k,
            result.true_type,
            result.predicted_type,
        )
        if progress is not None:
            progress(f, len(subjects), result)
    accuracy = sum(r.correct for r in folds) / len(folds)
    return LeaveOneOutResult(
        accuracy=accuracy,
        folds=tuple(folds),
        method=method,
        inference=inference,
        matching=matching,
    )
