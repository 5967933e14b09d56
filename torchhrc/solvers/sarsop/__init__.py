"""SARSOP (Kurniawati, Hsu & Lee 2008) with the MOMDP factoring (Ong et al. 2010).

SARSOP ("successive approximations of the reachable space under optimal policies") grows a
tree of beliefs reachable from ``b0``, sampling the parts an optimal policy would visit, and
keeps two bounds on the optimal value function ``V*``:

* the lower bound, a set of alpha vectors ``V_low(b) = max_n alphas[n] . b`` (each the value
  of a conditional plan), initialised by the blind policies ("always do ``a``") and improved
  by point-based backups of the sampled beliefs;
* the upper bound, the sawtooth interpolation over corner values and belief points
  (:class:`~torchhrc.solvers.upper_bound.SawtoothUpperBound`), initialised by the Fast
  Informed Bound (Hauskrecht 2000) and improved by Bellman backups at the sampled beliefs.

One iteration samples a path from ``b0`` (Algorithm "SamplePoints" of the paper): at belief
``b`` at depth ``t`` it stops when the predicted optimal value ``V_hat(b)`` (learned online by
binning beliefs on their upper bound and entropy) cannot raise the root's lower bound past the
target ``L`` and ``V_up(b) <= max(U, V_low(b) + eps * gamma^-t)``; otherwise it takes the
action with the highest upper bound ``a* = argmax_a Q_up(b, a)`` and the observation with the
largest weighted excess uncertainty
``o* = argmax_o P(o | b, a*) (V_up - V_low)(tau(b, a*, o)) - eps gamma^-(t+1)``, passing down
the targets ``L_t``, ``U_t`` solved from
``L' = R(b, a*) + gamma (P(o*) L_t + sum_{o != o*} P(o) V_low(tau(b, a*, o)))`` with
``L' = max(L, max_a Q_low(b, a))`` and ``U' = max(U, max_a Q_low(b, a) + eps gamma^-t)`` (and
the same with ``V_up`` for ``U_t``). A MOMDP with a random first observed value
(:attr:`~torchhrc.pomdp.MOMDP.initial`) has one root per first ``x`` (nodes ``0..R-1``, beliefs
``P(. | x)``); the bounds at the start are theirs weighted by ``P(x)``, and a trial enters the
root of largest weighted gap ``P(x) (V_up - V_low)`` with the targets of a step without reward
or discount (as APPL's SARSOP does for such files, e.g. ``TagAvoid.pomdpx``). The path is then
backed up leaf to root; a belief the trial reaches a second time (a cycle of the model) is also
backed up when reached, as APPL backs up every node a trial reaches. Tree nodes holding the same
belief share its cached evaluation. Dominated alpha vectors and alpha vectors that win at no
tree belief, unless they were the best at a child of an active tree belief at its last
evaluation (as APPL keeps the vectors best at the unexpanded children in its belief cache) or a
kept vector was built from them (so that the greedy policy of the written vectors keeps the
lower bound's value), redundant upper-bound points and belief nodes reached by sub-optimal
actions (``Q_up(b, a) < max_a' Q_low(b, a')``) are pruned.

One model interface: the solver asks the model only through
:class:`~torchhrc.solvers.forms.base.SolverModel` (children of beliefs with their
probabilities, rewards, the pieces of a backup, the initial bounds, the tree that stores
beliefs), picked once by :func:`~torchhrc.solvers.forms.as_solver_model`; it never tests
which form it holds. The forms: dense flat POMDP, MOMDP, sparse flat
(:mod:`torchhrc.solvers.forms`).

MOMDP (Ong et al. 2010): beliefs are ``(x, b_y)``; alpha vectors belong to one observed value
and live over ``Y``, and are stored grouped by ``x`` (one contiguous ``(N_x, Y)`` block each);
the upper-bound points too (per-``x`` point lists, and for ``Y <= 256`` a dense per-``x``
table), so bounding a belief at ``x`` touches only ``x``'s vectors and points, never the
whole sets. Every expansion only touches the next observed values reachable from ``x`` (see
:class:`~torchhrc.solvers.forms.momdp.MOMDPForm`, whose per-``x`` slices are built when
the search first reaches ``x``), so a factored backup costs about ``Y / S = 1 / X`` of the
flat one's flops. The initial bounds use the reachable-``x2`` FIB operator, never the flat
``(X Y) x (X Y)`` matrix. A flat POMDP is the same model with ``X = 1``.

Reproducibility and time: with a fixed ``max_iterations`` (or ``precision``) and a
``time_limit`` that is not reached, a solve is bit-identical run to run: the default FIB
initialisation stops on its tolerance (``init_tol``) or iteration cap, not on the clock
(``init_time_fraction`` of the limit is only a safety net; ``Solution.info["init"]`` says how
it stopped). ``time_limit`` is checked between iterations, at every step of a trial and
between the backups of its path, so one long trial does not overrun it; the solve stays
anytime and returns the bounds and policy reached so far.

Every tensor computation at a belief is batched over all ``(a, x2, o)`` children at once (one
expansion, one matrix product against all alpha vectors, one sawtooth evaluation against all
points); :attr:`SARSOPConfig.sweep_interval` also backs up all active tree beliefs of an
observed value together as one batched backup.

Batched models (leading batch dims) are not solved together: the tree search is sequential
per problem, so :func:`sarsop` raises for them; solve ``model`` per batch index.

Sparse flat models (:class:`~torchhrc.pomdp.SparsePOMDP`, e.g. RockSample(7, 8) read with
``read_pomdp(path, sparse=True)``: 12545 states, a dense ``T`` of 2e9 entries) take a sparse
form with the same algorithm (:class:`~torchhrc.solvers.forms.sparse.SparseForm`): ``T`` as
per-action CSR (:class:`~torchhrc.solvers.sparse_model.SparseFlatModel`), tree beliefs stored
by their support (:class:`~torchhrc.solvers.belief_tree.SparseBeliefTree`), each belief's
children formed and bounded only on the union of their supports, blind lower bound and
QMDP/FIB upper bound by sparse value iteration, alpha vectors dense ``(S,)``. Belief pruning
is one sparse product; the ``N^2 S`` pointwise-dominance test is skipped. On small models it
gives the same bounds and policy as the dense path (tested).

The package, one concept a module: :mod:`~torchhrc.solvers.sarsop.config` (the settings),
:mod:`~torchhrc.solvers.sarsop.search` (the solver's state, budget and loop, and
:func:`sarsop`), :mod:`~torchhrc.solvers.sarsop.alpha_set` (the lower bound's vectors),
:mod:`~torchhrc.solvers.sarsop.bins` (the ``V_hat`` predictor),
:mod:`~torchhrc.solvers.sarsop.bounds` (the bounds at a belief and its children),
:mod:`~torchhrc.solvers.sarsop.backup`, :mod:`~torchhrc.solvers.sarsop.trial` and
:mod:`~torchhrc.solvers.sarsop.pruning`.

Example:
    >>> from torchhrc.tasks.classic import tiger
    >>> sol = sarsop(tiger(), SARSOPConfig(time_limit=60.0, precision=0.5))
    >>> sol.info["stop_reason"], sol.upper - sol.lower <= 0.5, sol.policy.action(tiger().b0).item()
    ('precision', True, 0)
"""

from __future__ import annotations

from torchhrc.solvers.sarsop.config import LowerInit as LowerInit
from torchhrc.solvers.sarsop.config import SARSOPConfig
from torchhrc.solvers.sarsop.config import UpperInit as UpperInit
from torchhrc.solvers.sarsop.search import fib_corner_values, sarsop

__all__ = ["SARSOPConfig", "fib_corner_values", "sarsop"]
