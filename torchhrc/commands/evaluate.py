"""``torchhrc evaluate``: the mean discounted reward of a policy and its 95 % CI (``pomdpeval``).

Reads the model (``.pomdp`` or ``.pomdpx``, as ``torchhrc solve`` does) and the policy
(torchhrc's ``.safetensors`` or APPL's ``.policyx``), runs ``--episodes`` simulations at once
on tensors (:func:`torchhrc.solvers.evaluate.evaluate_policy`: every step advances all of
them together), and prints the mean discounted reward, its standard error and the 95 %
confidence interval ``mean +- 1.96 std / sqrt(N)``, widened by the bound on the rewards
beyond the horizon. The horizon is ``--horizon`` steps (APPL's ``--simLen``), by default
enough for that bound to be below ``--tail`` (1e-3). A simulation that reaches an absorbing
state (every action stays there with reward 0, APPL's terminal states) stops early. With
``--json`` one JSON object is printed with the keys ``mean``, ``std_error``, ``ci_low``,
``ci_high``, ``truncation``, ``episodes``, ``horizon``, ``seed``, ``time_s`` and
``simulations_per_s``.

Example:
    >>> import argparse
    >>> from torchhrc.commands import evaluate
    >>> sub = argparse.ArgumentParser(prog="torchhrc").add_subparsers()
    >>> evaluate.register(sub)
    >>> sub.choices["evaluate"].parse_args(["m.pomdp", "--policy", "p.policyx"]).episodes
    1000
"""

from __future__ import annotations

import argparse
import json
import time
from typing import Any

from torchhrc.commands._files import add_model_and_policy, positive_int

__all__ = ["add_simulation_options", "register", "run", "run_simulations"]


def _tail(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not 0 < value < float("inf"):
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}")
    return value


def _at_least_two(text: str) -> int:
    value = positive_int(text)
    if value < 2:
        raise argparse.ArgumentTypeError(f"expected at least 2 (for the CI), got {text!r}")
    return value


def add_simulation_options(parser: argparse.ArgumentParser, *, episodes: int) -> None:
    """The options ``simulate`` and ``evaluate`` share."""
    add_model_and_policy(parser)
    parser.add_argument(
        "--episodes",
        "--simNum",
        dest="episodes",
        type=_at_least_two,
        default=episodes,
        help=f"number of simulations, all stepped together (--simNum as APPL) ({episodes})",
    )
    parser.add_argument(
        "--horizon",
        "--simLen",
        dest="horizon",
        type=positive_int,
        default=None,
        help="steps per simulation (--simLen as APPL; default: until the discounted tail "
        "is below --tail)",
    )
    parser.add_argument(
        "--tail",
        type=_tail,
        default=1e-3,
        help="bound on the rewards beyond the default horizon (1e-3)",
    )
    parser.add_argument(
        "--seed",
        "--srand",
        dest="seed",
        type=int,
        default=0,
        help="random seed (0; --srand as APPL, whose default is the clock)",
    )
    parser.add_argument("--json", action="store_true", help="print one JSON object")


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``evaluate`` sub-command."""
    parser = subparsers.add_parser(
        "evaluate",
        help="mean discounted reward of a policy and its 95%% CI (as APPL's pomdpeval)",
        description=(
            "Evaluate a policy (.safetensors or APPL .policyx) on a model in Cassandra's "
            ".pomdp or APPL's .pomdpx format: run N simulations at once on tensors and print "
            "the mean discounted reward with its 95 % confidence interval."
        ),
    )
    add_simulation_options(parser, episodes=1000)
    parser.set_defaults(func=run)


def run_simulations(
    args: argparse.Namespace, on_step: Any = None, *, model: Any = None
) -> tuple[Any, Any, float]:
    """Read the files (the model unless given), simulate; return ``(model, result, seconds)``."""
    from torchhrc.commands._files import policy_does_not_fit, read_model, read_policy
    from torchhrc.errors import ModelError
    from torchhrc.solvers.evaluate import evaluate_policy

    model = read_model(args.model) if model is None else model
    if args.horizon is None and not float(model.discount) < 1.0:
        raise ModelError(
            f"{args.model} has discount {float(model.discount):g}: give --horizon (the default "
            "horizon bounds the discounted tail, which needs discount < 1)"
        )
    policy = read_policy(args.policy)
    start = time.perf_counter()
    try:
        result = evaluate_policy(
            model,
            policy,
            episodes=args.episodes,
            horizon=args.horizon,
            tail_tolerance=args.tail,
            seed=args.seed,
            on_step=on_step,
        )
    except ModelError as error:
        raise policy_does_not_fit(error, args.policy, args.model) from None
    return model, result, time.perf_counter() - start


def report(args: argparse.Namespace, result: Any, elapsed: float) -> dict[str, Any]:
    """The summary of a run, as ``--json`` prints it."""
    return {
        "mean": result.mean,
        "std_error": result.std_error,
        "ci_low": result.ci_low,
        "ci_high": result.ci_high,
        "truncation": result.truncation,
        "episodes": args.episodes,
        "horizon": result.horizon,
        "seed": args.seed,
        "time_s": elapsed,
        "simulations_per_s": args.episodes / elapsed if elapsed > 0 else None,
    }


def print_report(summary: dict[str, Any]) -> None:
    """The summary as aligned lines."""
    print(f"mean       {summary['mean']:.6g}")
    print(f"ci95       [{summary['ci_low']:.6g}, {summary['ci_high']:.6g}]")
    print(f"std_error  {summary['std_error']:.4g}")
    print(f"episodes   {summary['episodes']}")
    print(f"horizon    {summary['horizon']} (tail <= {summary['truncation']:.3g})")
    print(f"time_s     {summary['time_s']:.3f}")


def run(args: argparse.Namespace) -> int:
    """Evaluate and print; return the exit status."""
    _, result, elapsed = run_simulations(args)
    summary = report(args, result, elapsed)
    if args.json:
        print(json.dumps(summary))
    else:
        print_report(summary)
    return 0
