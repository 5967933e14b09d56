"""``torchhrc simulate``: run a policy on a model and trace it (APPL's ``pomdpsim``).

Not to be confused with ``torchhrc simulate-demos`` (:mod:`torchhrc.commands.simulate_demos`),
which writes a simulated demonstration study. This command reads a model (``.pomdp`` or
``.pomdpx``) and a policy (``.safetensors`` or APPL's ``.policyx``), runs ``--episodes``
simulations at once on tensors (:func:`torchhrc.solvers.evaluate.evaluate_policy`) and prints
the discounted return of each and their mean with its 95 % CI (as ``torchhrc evaluate``).
``--trace FILE`` writes one JSON object a line for every step of every simulation:

``{"episode", "step", "state", "belief", "action", "reward", "observation"}``, plus ``"x"``
and ``"next_x"`` (the observed state before and after the step) for a MOMDP; ``state`` is
the true (hidden) state, ``belief`` the belief the action was chosen at, as ``{name: p}``
over its nonzero entries. A flat policy of a MOMDP (solved through ``to_pomdp()``) runs on
the flat model: its states and observations are named ``"x|y"`` and ``"x2|o"``, as
``to_pomdp()`` names them, and there is no ``"x"``. A simulation that reaches an absorbing
state (APPL's terminal states) has no more lines. The trace is written atomically when the
run ends.

Example:
    >>> import argparse
    >>> from torchhrc.commands import simulate
    >>> sub = argparse.ArgumentParser(prog="torchhrc").add_subparsers()
    >>> simulate.register(sub)
    >>> sub.choices["simulate"].parse_args(["m.pomdp", "--policy", "p.policyx"]).episodes
    10
"""

from __future__ import annotations

import argparse
import json
from typing import IO, Any

from torchhrc.commands._files import check_new_file
from torchhrc.commands.evaluate import add_simulation_options, print_report, report, run_simulations

__all__ = ["register", "run"]


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``simulate`` sub-command."""
    parser = subparsers.add_parser(
        "simulate",
        help="simulate a policy on a .pomdp/.pomdpx model and trace it (as APPL's pomdpsim)",
        description=(
            "Simulate a policy (.safetensors or APPL .policyx) on a model in Cassandra's "
            ".pomdp or APPL's .pomdpx format, all simulations stepped together on tensors; "
            "print each discounted return and their mean, and optionally write a trace of "
            "beliefs, actions and observations (JSON lines). For simulated demonstrations "
            "see simulate-demos."
        ),
    )
    add_simulation_options(parser, episodes=10)
    parser.add_argument(
        "--trace",
        "--output-file",
        dest="trace",
        metavar="FILE",
        default=None,
        help="write every step as a JSON line (--output-file as APPL, whose trace is text)",
    )
    parser.add_argument("--force", action="store_true", help="overwrite an existing trace")
    parser.set_defaults(func=run)


def _names(model: Any, field: str, size: int) -> list[str]:
    names = getattr(model, field, None)
    if names is not None and len(names) == size:
        return [str(n) for n in names]
    return [str(i) for i in range(size)]


class _Trace:
    """Writes the steps of :func:`evaluate_policy` as JSON lines to an open file."""

    def __init__(self, model: Any, out: IO[str]) -> None:
        self.out = out
        self.model = model
        self.factored = hasattr(model, "num_observed")
        self.hidden: list[str] | None = None

    def _hidden_names(self, width: int) -> list[str]:
        if self.hidden is None or len(self.hidden) != width:
            m = self.model
            if self.factored and width == m.num_hidden:
                self.hidden = _names(m, "hidden_states", width)
            elif self.factored:  # a flat policy of a MOMDP: the states (x, y) of to_pomdp()
                xs = _names(m, "observed_states", m.num_observed)
                ys = _names(m, "hidden_states", m.num_hidden)
                self.hidden = [f"{x}|{y}" for x in xs for y in ys]
            else:
                self.hidden = _names(m, "states", width)
        return self.hidden

    def __call__(self, step: Any) -> None:
        m = self.model
        actions = _names(m, "actions", m.num_actions)
        observations = _names(m, "observations", m.num_observations)
        hidden = self._hidden_names(step.belief.shape[-1])
        factored = self.factored and step.belief.shape[-1] == m.num_hidden
        if self.factored and not factored:  # to_pomdp()'s observations (x2, o), as x2 * O + o
            xs = _names(m, "observed_states", m.num_observed)
            observations = [f"{x}|{o}" for x in xs for o in observations]
        observed = _names(m, "observed_states", m.num_observed) if factored else None
        live = step.active.nonzero().squeeze(-1).tolist()
        beliefs = step.belief[live].double()
        x, y = step.x[live].tolist(), step.y[live].tolist()
        a, o = step.action[live].tolist(), step.observation[live].tolist()
        r, nx = step.reward[live].tolist(), step.next_x[live].tolist()
        for i, e in enumerate(live):
            b = beliefs[i]
            nz = (b > 0).nonzero().squeeze(-1).tolist()
            line: dict[str, Any] = {"episode": e, "step": step.step}
            if observed is not None:
                line["x"] = observed[x[i]]
            line["state"] = hidden[y[i]]
            line["belief"] = {hidden[j]: float(b[j]) for j in nz}
            line["action"] = actions[a[i]]
            line["reward"] = r[i]
            line["observation"] = observations[o[i]]
            if observed is not None:
                line["next_x"] = observed[nx[i]]
            self.out.write(json.dumps(line) + "\n")


def run(args: argparse.Namespace) -> int:
    """Simulate, print, and write the trace; return the exit status."""
    if args.trace is None:
        _, result, elapsed = run_simulations(args)
    else:
        check_new_file(args.trace, force=args.force)
        from torchhrc._atomic import atomic_write
        from torchhrc.commands._files import read_model

        def write(tmp: str) -> tuple[Any, Any, float]:
            with open(tmp, "w") as out:
                model = read_model(args.model)
                return run_simulations(args, _Trace(model, out), model=model)

        ran: list[tuple[Any, Any, float]] = []
        atomic_write(args.trace, lambda tmp: ran.append(write(tmp)))
        _, result, elapsed = ran[0]
    summary = report(args, result, elapsed)
    summary["returns"] = result.returns.tolist()
    summary["trace"] = args.trace
    if args.json:
        print(json.dumps(summary))
        return 0
    for e, value in enumerate(summary["returns"]):
        print(f"episode {e:4d}  return {value:.6g}")
    print_report(summary)
    if args.trace is not None:
        print(f"trace      {args.trace}")
    return 0
