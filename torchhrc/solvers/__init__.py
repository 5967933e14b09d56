"""POMDP and MOMDP solvers behind one protocol: ``solve(model, config) -> Solution``.

The configuration's type picks the solver (as POMDPs.jl's ``solve(solver, problem)``)::

    QMDPConfig   -> qmdp    (Littman et al. 1995; upper bound, fast)
    FIBConfig    -> fib     (Hauskrecht 2000; tighter upper bound)
    PBVIConfig   -> pbvi    (Pineau, Gordon, Thrun 2003)
    SARSOPConfig -> sarsop  (Kurniawati, Hsu, Lee 2008; with the MOMDP factoring of Ong et al.)

New solvers register with :func:`register_solver`. Also here: MDP value iteration, the bound
vectors (QMDP, FIB, blind), the point-based backup kernel, pruning, the alpha-vector policy
and Monte Carlo evaluation.

Example:
    >>> from torchhrc.tasks.classic import tiger
    >>> solution = solve(tiger(), PBVIConfig(time_limit=10, expansions=4))
    >>> solution.lower <= solution.upper
    True
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from torchhrc.solvers.backup import BackupResult, momdp_point_backup, point_backup
from torchhrc.solvers.blind import blind_policy, blind_vectors
from torchhrc.solvers.evaluate import EvaluationResult, evaluate_policy
from torchhrc.solvers.fib import FIBConfig, fib, fib_policy, fib_vectors
from torchhrc.solvers.forms import has_form
from torchhrc.solvers.pbvi import PBVIConfig, pbvi
from torchhrc.solvers.policy import AlphaVectorPolicy
from torchhrc.solvers.policy_graph import PolicyGraph, controller_value, policy_graph
from torchhrc.solvers.pruning import prune_by_beliefs, prune_dominated
from torchhrc.solvers.qmdp import QMDPConfig, qmdp, qmdp_policy, qmdp_vectors
from torchhrc.solvers.sarsop import SARSOPConfig, sarsop
from torchhrc.solvers.solution import Solution
from torchhrc.solvers.sparse_model import SparseFlatModel, sparse_blind_policy, sparse_blind_vectors
from torchhrc.solvers.type_policies import type_policy_lower_bound
from torchhrc.solvers.value_iteration import MDPSolution, policy_evaluation, value_iteration

__all__ = [
    "AlphaVectorPolicy",
    "BackupResult",
    "EvaluationResult",
    "FIBConfig",
    "MDPSolution",
    "PBVIConfig",
    "PolicyGraph",
    "QMDPConfig",
    "SARSOPConfig",
    "Solution",
    "SparseFlatModel",
    "blind_policy",
    "blind_vectors",
    "controller_value",
    "evaluate_policy",
    "fib",
    "fib_policy",
    "fib_vectors",
    "momdp_point_backup",
    "pbvi",
    "point_backup",
    "policy_evaluation",
    "policy_graph",
    "prune_by_beliefs",
    "prune_dominated",
    "qmdp",
    "qmdp_policy",
    "qmdp_vectors",
    "register_solver",
    "sarsop",
    "solve",
    "sparse_blind_policy",
    "sparse_blind_vectors",
    "type_policy_lower_bound",
    "value_iteration",
]

SolverFunction = Callable[[Any, Any], Solution]

#: config type -> solver function ``(model, config) -> Solution``.
_SOLVERS: dict[type, SolverFunction] = {
    QMDPConfig: qmdp,
    FIBConfig: fib,
    PBVIConfig: pbvi,
    SARSOPConfig: sarsop,
}


def register_solver(config_type: type, function: SolverFunction) -> None:
    """Make :func:`solve` dispatch configs of ``config_type`` to ``function(model, config)``.

    Example:
        >>> register_solver(QMDPConfig, qmdp)  # (already registered)
    """
    if not isinstance(config_type, type):
        raise TypeError(f"expected config_type to be a class, got {config_type!r}")
    if not callable(function):
        raise TypeError(f"expected function to be callable, got {function!r}")
    _SOLVERS[config_type] = function


def solve(model: Any, config: Any) -> Solution:
    """Solve ``model`` with the solver that ``config``'s type names.

    Args:
        model: whatever :func:`~torchhrc.solvers.forms.as_solver_model` accepts: an unbatched
            :class:`~torchhrc.pomdp.POMDP` or :class:`~torchhrc.pomdp.MOMDP`, a
            :class:`~torchhrc.pomdp.SparsePOMDP`, :class:`~torchhrc.pomdp.SparseMOMDP`
            or :class:`~torchhrc.solvers.sparse_model.SparseFlatModel`, a
            :class:`~torchhrc.solvers.forms.SolverModel`, or an instance of a type added with
            :func:`~torchhrc.solvers.forms.register_form` (every built-in solver takes it
            through its solver form; a registered solver is handed the model as it is).
        config: a solver configuration (``QMDPConfig``, ``FIBConfig``, ``PBVIConfig``,
            ``SARSOPConfig`` or a registered type).

    Returns:
        :class:`Solution` with ``policy``, ``lower``, ``upper`` (bounds on the optimal value
        at the initial belief) and ``history``.

    Raises:
        TypeError: ``config``'s type has no registered solver, or ``model`` of no known type.

    Example:
        >>> from torchhrc.tasks.classic import tiger
        >>> round(solve(tiger(), QMDPConfig()).upper, 6)
        189.0
    """
    if not has_form(model):
        raise TypeError(
            "expected model to be a POMDP, MOMDP, SparsePOMDP, SparseMOMDP, SparseFlatModel, "
            f"a SolverModel or a type added with register_form, got {type(model).__name__}"
        )
    for config_type in type(config).__mro__:
        if config_type in _SOLVERS:
            return _SOLVERS[config_type](model, config)
    known = ", ".join(sorted(t.__name__ for t in _SOLVERS))
    raise TypeError(
        f"no solver for config of type {type(config).__name__}; expected one of {known}"
    )
