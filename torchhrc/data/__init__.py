"""Joint-action demonstrations: action vocabulary, padded sequences, CSV/JSON IO.

A demonstration is a sequence of steps, each the pair ``(actor, action)`` with ``actor`` in
``{"human", "robot"}``. The pair is the *symbol* of the step: a human ``wait`` and a robot
``wait`` are different symbols, so the alphabet is the paper's ``A = A_r ∪ A_h``
(Nikolaidis et al., section "Clustering of Human Types"). Symbols are numbered by the
vocabulary, and the ``N`` sequences are stored as one padded tensor::

    sequences: (N, L) int64   sequences[n, t] = symbol index of step t of sequence n
                              (0 beyond lengths[n]: padding, masked out)
    lengths:   (N,)   int64   number of steps of each sequence, every one >= 2
    mask:      (N, L) bool    mask[n, t] = t < lengths[n]

The CSV form (shared/DESIGN.md) has one row per step, header
``subject,sequence,step,actor,action[,type]``, steps ``0, 1, ...`` in order within each
(subject, sequence); the optional ``type`` is a ground-truth label used only for scoring.

The parts: :mod:`~torchhrc.data.vocabulary` (actors, steps, a vocabulary's checks and order),
:mod:`~torchhrc.data.demonstrations` (the container) and :mod:`~torchhrc.data.formats` (its
CSV and JSON forms).

Example:
    >>> from torchhrc.data import Demonstrations
    >>> demos = Demonstrations.from_lists([[("human", "place_A"), ("robot", "drill_A")]])
    >>> demos.symbol_names, demos.sequences.tolist(), demos.lengths.tolist()
    (('human:place_A', 'robot:drill_A'), [[0, 1]], [2])
"""

from torchhrc.data.demonstrations import Demonstrations
from torchhrc.data.formats import CSV_COLUMNS
from torchhrc.data.vocabulary import ACTORS, Step

__all__ = ["ACTORS", "CSV_COLUMNS", "Demonstrations", "Step"]
