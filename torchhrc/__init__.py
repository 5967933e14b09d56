"""torchhrc: learn human types from joint-action demonstrations and plan robot policies.

Implements Nikolaidis, Gu, Ramakrishnan, Shah, "Efficient Model Learning for Human-Robot
Collaborative Tasks": clustering of demonstrations into human types (mixture of Markov
chains), a reward per type by inverse reinforcement learning, and a MOMDP solved with
point-based solvers (PBVI, SARSOP), all batched on PyTorch tensors.
"""

from __future__ import annotations

from torchhrc.errors import ModelError, ParseError, TorchHRCError
from torchhrc.pomdp import MOMDP, POMDP

__version__ = "0.1.0"

__all__ = [
    "MOMDP",
    "POMDP",
    "ModelError",
    "ParseError",
    "TorchHRCError",
    "__version__",
]
