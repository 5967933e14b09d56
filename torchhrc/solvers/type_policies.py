"""A lower bound for static-type MOMDPs from the per-type MDP policies.

Where the hidden value never changes (the human type of the paper), following the optimal
policy of one type's MDP needs only the observed ``x``, so its value under every true type is
achievable from any belief: a set of alpha vectors that bounds the optimal value from below
and is often far tighter than the blind-policy bound (:mod:`torchhrc.solvers.blind`). Use it
as SARSOP's ``lower_bound_init``.

Example:
    >>> from torchhrc.testing import random_momdp
    >>> model = random_momdp(4, 2, 3, 2, static=True, seed=0)
    >>> type_policy_lower_bound(model).alphas.shape
    torch.Size([8, 2])
"""

from __future__ import annotations

import torch

from torchhrc.errors import ModelError
from torchhrc.pomdp import MOMDP
from torchhrc.solvers.policy import AlphaVectorPolicy
from torchhrc.solvers.value_iteration import policy_evaluation, value_iteration

__all__ = ["type_policy_lower_bound"]


def type_policy_lower_bound(model: MOMDP) -> AlphaVectorPolicy:
    """Lower-bound alpha vectors of a static-type MOMDP from its per-type MDP policies.

    For each type ``y`` let ``pi_y`` be the optimal policy of the MDP ``(Tx[:, :, y], R[..., y])``.
    Following ``pi_y`` needs only ``x``, so its value under every true type ``y2``,
    ``V^{pi_y}_{y2}(x)`` (exact policy evaluation), is achievable from ``(x, b)``: the vector
    ``alpha_{y, x} = (V^{pi_y}_{y2}(x))_{y2}`` with action ``pi_y(x)`` is a valid lower bound
    (the value of a conditional plan). SARSOP starts from these ``Y * X`` vectors instead of
    the blind policies, which on this task are far below (waiting forever costs every step).

    Args:
        model: an unbatched MOMDP with ``Ty is None``.

    Returns:
        A MOMDP :class:`~torchhrc.solvers.policy.AlphaVectorPolicy` with ``Y * X`` vectors.
    """
    if model.Ty is not None or model.batch_shape != torch.Size([]):
        raise ModelError("type_policy_lower_bound needs an unbatched MOMDP with a static type")
    T = model.Tx.permute(2, 0, 1, 3)  # (Y, A, X, X)
    R = model.R.permute(2, 0, 1)  # (Y, A, X)
    Y, X = T.shape[0], T.shape[-1]
    policies = value_iteration(T, R, model.discount).policy  # (Y, X)
    # values[y, y2, x] = value of following pi_y when the true type is y2
    values = policy_evaluation(T.unsqueeze(0), R.unsqueeze(0), model.discount,
                               policies.unsqueeze(1).expand(Y, Y, X))  # fmt: skip
    alphas = values.permute(0, 2, 1).reshape(Y * X, Y)
    observed = torch.arange(X).repeat(Y)
    return AlphaVectorPolicy(alphas, policies.reshape(Y * X), observed=observed)
