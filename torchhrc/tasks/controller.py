"""An online controller: a solved model acting in a loop against a real or simulated human.

Paper (section "Online estimation of human type"; Eq. 3): at each step the robot observes
the task state ``x'`` (and, when the task has one, a noisy signal ``o`` of the human),
updates its belief over the human types

    b'(y') = eta Z(x', y', a, o) sum_y Tx(x, y, a, x') Ty(x, y, a, x', y') b(y)

and takes the action of its policy at ``(x', b')``. :class:`Controller` does exactly that::

    controller.reset(prior)                   # belief over the types, start state
    a = controller.act(x0)                    # first action
    a = controller.act((x1, o1))              # later: the new state (and signal)
    controller.done                           # True once a terminal state is seen

The filter is given as a function, so one controller serves every model form: the factored
MOMDP (:meth:`Controller.from_model`, :meth:`Controller.from_momdp`; belief over ``Y``) and
the flat POMDP (:meth:`Controller.from_pomdp`; belief over ``S``, observation only).
Batched: ``x`` of shape ``(B,)`` runs ``B`` episodes at once (``reset(batch=B)``); plain
ints work for one episode.

Example:
    >>> import torch
    >>> from torchhrc.testing import random_momdp
    >>> from torchhrc.solvers import AlphaVectorPolicy
    >>> m = random_momdp(3, 2, 2, 1, seed=0)
    >>> blind = AlphaVectorPolicy.from_action_vectors(m.R, momdp=True)
    >>> c = Controller.from_momdp(m, blind)
    >>> c.reset()
    >>> a = c.act(0); a2 = c.act(1)
    >>> c.belief.shape, len(c.history), c.done
    (torch.Size([2]), 2, False)
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np
import torch

from torchhrc._checks import check_index
from torchhrc.errors import ModelError

if TYPE_CHECKING:
    from torchhrc.pomdp import MOMDP, POMDP
    from torchhrc.tasks.pipeline import LearnedModel

__all__ = ["Controller"]

#: ``filter(x, belief, action, x_next, observation) -> belief'`` (batched), or a
#: :class:`~torchhrc.pomdp.belief.BeliefUpdate` whose ``log_normalizer`` is ``-inf`` where the
#: observation is impossible.
Filter = Callable[[Any, torch.Tensor, torch.Tensor, Any, torch.Tensor], Any]
#: ``choose(x, belief) -> action`` (batched).
Chooser = Callable[[Any, torch.Tensor], torch.Tensor]


class Controller:
    """A robot acting online: belief filter + policy.

    Args:
        filter: ``filter(x, belief, action, x_next, observation) -> belief'``.
        choose: ``choose(x, belief) -> action``.
        prior: default initial belief ``(K,)``.
        x0: default start state (``None`` for a flat POMDP).
        names: optional action names (for :attr:`history`).
        start: ``(X, K)`` the initial belief given the first state seen, for a model whose
            first state is random (:attr:`~torchhrc.pomdp.MOMDP.initial`): after a
            :meth:`reset` without a prior, the first :meth:`act` starts from ``start[x]``.
        terminal: ``(X,)`` bool, the states that end an episode (:attr:`done`); default none.
        sizes: ``(X, O)``, the number of states and of signals, to check what :meth:`act`
            is given (``X`` is ``None`` for a flat POMDP); default: unchecked.
        state_names: ``(X,)`` names used in error messages.

    Most users build one with :meth:`from_model`.
    """

    def __init__(
        self,
        filter: Filter,
        choose: Chooser,
        prior: torch.Tensor,
        x0: int | None,
        names: tuple[str, ...] | None = None,
        start: torch.Tensor | None = None,
        terminal: torch.Tensor | None = None,
        sizes: tuple[int | None, int | None] | None = None,
        state_names: tuple[str, ...] | None = None,
    ) -> None:
        self._filter = filter
        self._choose = choose
        self._prior = prior
        self._x0 = x0
        self._start = start
        self._from_start = start is not None  # the next first act reads start[x]
        self.terminal = None if terminal is None else torch.as_tensor(terminal, dtype=torch.bool)
        self.names = names
        self._sizes = sizes
        self._state_names = state_names
        self.belief: torch.Tensor = prior.clone()
        self.state: torch.Tensor | None = None
        self.last_action: torch.Tensor | None = None
        self.history: list[tuple[Any, Any, torch.Tensor]] = []

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_momdp(cls, momdp: MOMDP, policy: Any) -> Controller:
        """A controller of a MOMDP and a policy with ``action(x, belief_y) -> a``."""
        from torchhrc.pomdp import split_initial
        from torchhrc.pomdp.belief import momdp_update

        # a random first x: the belief given the x seen (zeros where x has no mass)
        start = None if momdp.initial is None else split_initial(momdp.initial)[1]

        def filt(x: Any, b: torch.Tensor, a: torch.Tensor, x2: Any, o: torch.Tensor) -> Any:
            return momdp_update(momdp, x, b, a, x2, o, on_zero="ninf")

        def choose(x: Any, b: torch.Tensor) -> torch.Tensor:
            return policy.action(x, b)

        names = tuple(momdp.actions or ()) or None
        states = tuple(momdp.observed_states or ()) or None
        sizes = (momdp.num_observed, momdp.num_observations)
        return cls(filt, choose, momdp.b0, int(momdp.x0), names, start, _absorbing(momdp),
                   sizes, states)  # fmt: skip

    @classmethod
    def from_model(cls, model: LearnedModel) -> Controller:
        """The controller of a solved :class:`~torchhrc.tasks.pipeline.LearnedModel`.

        Raises:
            ModelError: the model has not been solved.
        """
        if model.policy is None:
            raise ModelError(
                "the model has no policy: solve it first "
                "(torchhrc.tasks.pipeline.solve_model or learn(solve=True))"
            )
        return cls.from_momdp(model.momdp, model.policy)

    @classmethod
    def from_pomdp(cls, pomdp: POMDP, policy: Any) -> Controller:
        """A controller of a flat POMDP (belief over its ``S`` states; ``act(o)``)."""
        from torchhrc.pomdp.belief import update

        def filt(x: Any, b: torch.Tensor, a: torch.Tensor, x2: Any, o: torch.Tensor) -> Any:
            return update(pomdp, b, a, o, on_zero="ninf")

        def choose(x: Any, b: torch.Tensor) -> torch.Tensor:
            return policy.action(b)

        return cls(filt, choose, pomdp.b0, None, tuple(pomdp.actions or ()) or None,
                   sizes=(None, pomdp.num_observations))  # fmt: skip

    # ------------------------------------------------------------------ loop
    def reset(self, prior: torch.Tensor | None = None, *, batch: int | None = None) -> None:
        """Start an episode.

        Args:
            prior: ``(K,)`` or ``(B, K)`` initial belief (default the model's ``b0``, or,
                for a model whose first state is random, the belief given the first state
                the next :meth:`act` sees).
            batch: run ``B`` episodes at once (the prior is repeated).

        Raises:
            ModelError: the prior is not a distribution over the model's ``K`` values, or
                ``batch`` is not a positive int.
        """
        p = self._prior if prior is None else torch.as_tensor(prior)
        K = self._prior.shape[-1]
        if p.shape[-1] != K or p.dim() > 2:
            raise ModelError(f"expected prior of shape (K={K},) or (B, K={K}), "
                             f"got {tuple(p.shape)}")  # fmt: skip
        p = p.to(self._prior.dtype)
        if (p < 0).any() or not torch.allclose(p.sum(-1), torch.ones((), dtype=p.dtype),
                                               atol=1e-6):  # fmt: skip
            raise ModelError("expected prior to be non-negative and sum to 1 over the last dim")
        if batch is not None:
            if isinstance(batch, bool) or not isinstance(batch, int) or batch < 1:
                raise ModelError(f"expected batch to be a positive int, got {batch!r}")
            p = p.expand(batch, K)
        self.belief = p.clone()
        self._from_start = self._start is not None and prior is None
        self.state = None
        self.last_action = None
        self.history = []

    @property
    def done(self) -> Any:
        """Whether the episode has ended: the last state seen by :meth:`act` is terminal
        (an absorbing, zero-reward state of the model; ``terminal`` of the constructor).

        ``False`` before the first :meth:`act` and for a flat POMDP; a bool for one
        episode, a ``(B,)`` bool tensor for a batch.
        """
        if self.state is None or self.terminal is None:
            if isinstance(self.state, torch.Tensor) and self.state.dim() > 0:
                return torch.zeros(self.state.shape, dtype=torch.bool)
            return False
        ended = self.terminal.to(self.state.device)[self.state]
        return bool(ended) if ended.dim() == 0 else ended

    def act(self, observation: Any) -> Any:
        """Update the belief with what the robot sees now and return its next action.

        Args:
            observation: the current task state ``x`` (an int or NumPy integer, or ``(B,)``
                integers as a tensor, array or list); for a task
                with a noisy human signal, the pair ``(x, o)``; for a flat POMDP, ``o``.
                At the first call after :meth:`reset` there is nothing to update: ``x`` is
                the start state (its signal, if any, is ignored).

        Returns:
            The robot action (int for an int ``x``, else an int64 tensor ``(B,)``).
            ``x`` or ``o`` of another type (a float, a bool, a string) raises ``TypeError``.

        Raises:
            ModelError: a state or signal out of the model's range, the
                observation is impossible under the belief (the human did something no
                type explains), or, for a random start, the first state has no mass.

        Example:
            >>> from torchhrc.testing import random_momdp
            >>> from torchhrc.solvers import AlphaVectorPolicy
            >>> m = random_momdp(3, 2, 2, 1, seed=0)
            >>> c = Controller.from_momdp(m, AlphaVectorPolicy.from_action_vectors(m.R, momdp=True))
            >>> c.reset(batch=2)
            >>> c.act(torch.tensor([0, 2])).shape
            torch.Size([2])
        """
        if isinstance(observation, tuple):
            x, o = observation
        elif self._x0 is None:
            x, o = None, observation
        else:
            x, o = observation, 0
        scalar = all(v is None or isinstance(v, (int, np.integer)) for v in (x, o))
        X, O = self._sizes if self._sizes is not None else (None, None)
        xt = None if x is None else check_index("x", x, X, what="the model's states")
        ot = check_index("o", o, O, what="the model's signals")
        if self.last_action is not None:
            updated = self._filter(self.state, self.belief, self.last_action, xt, ot)
            if hasattr(updated, "log_normalizer"):
                self._check_possible(updated.log_normalizer, xt, ot)
                updated = updated.belief
            self.belief = updated
        elif self._from_start and self._start is not None and xt is not None:
            belief = self._start[xt].to(self._prior.dtype)
            if bool((belief.sum(-1) <= 0).any()):
                raise ModelError(
                    f"the first state x = {x} has no mass under the model's random start "
                    "(initial): pass a prior to reset()"
                )
            if xt.dim() == 0 and self.belief.dim() == 2:  # one x for a batch of episodes
                belief = belief.expand(self.belief.shape).clone()
            self.belief = belief
        action = torch.as_tensor(self._choose(xt, self.belief), dtype=torch.long)
        self.state = xt
        self.last_action = action
        self.history.append((x, o, self.belief))
        return int(action) if scalar else action

    def _check_possible(
        self, log_normalizer: torch.Tensor, x: torch.Tensor | None, o: torch.Tensor
    ) -> None:
        impossible = torch.isneginf(log_normalizer)
        if not bool(impossible.any()):
            return
        i = tuple(torch.nonzero(impossible)[0].tolist()) if impossible.dim() else ()
        at = f"episode {i[0]}: " if i else ""

        def pick(t: torch.Tensor | None) -> Any:
            if t is None:
                return None
            return int(t.expand(impossible.shape)[i]) if t.dim() else int(t)

        a, x0, x1, o1 = (pick(self.last_action), pick(self.state), pick(x), pick(o))
        seen = (f"observation o = {o1}" if x1 is None
                else f"state x' = {self.state_name(x1)} (signal o = {o1})")  # fmt: skip
        raise ModelError(
            f"{at}after action {self.action_name(a)!r} in state x = {self.state_name(x0)}, "
            f"the {seen} has "
            "probability zero under every type the belief allows: the human did something "
            "the model does not explain. Check the state passed to act(), start a new episode "
            "with reset() (or reset(prior=...) to allow every type), or learn the model with "
            "a larger noise= so every legal human action keeps some probability"
        )

    def state_name(self, x: int | None) -> str:
        """``x`` and, when the model names its states, its name (for messages)."""
        if x is None or not self._state_names or not 0 <= x < len(self._state_names):
            return str(x)
        return f"{x} ({self._state_names[x]!r})"

    def action_name(self, action: int) -> str:
        """The name of ``action`` (its index when the model has no names)."""
        return self.names[action] if self.names else str(action)


def _absorbing(momdp: MOMDP) -> torch.Tensor | None:
    """``(X,)`` bool: states every action and type keeps, with zero reward (an episode's
    end, as APPL's terminal states); ``None`` for a batched model."""
    Tx, R = momdp.Tx, momdp.R
    if Tx.dim() != 4:
        return None
    X = Tx.shape[-1]
    stay = Tx.diagonal(dim1=1, dim2=3)  # (A, Y, X): P(x -> x)
    keeps = (stay > 1.0 - 1e-9).all(0).all(0)
    if R.dim() == 3:
        keeps = keeps & (R.abs() <= 1e-12).all(0).all(-1)
    return keeps.to(torch.bool).view(X)
