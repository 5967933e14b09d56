"""``torchhrc graph``: draw a policy as a graph of beliefs and observations (APPL's ``polgraph``).

Reads the model (``.pomdp`` or ``.pomdpx``) and the policy (``.safetensors`` or APPL's
``.policyx``) and builds :func:`torchhrc.solvers.policy_graph.policy_graph`: from the initial
belief, each node is a belief with the policy's action there (and, for a MOMDP, the observed
state and the belief over the hidden type), each edge an observation (and next observed
state) with its probability; equal beliefs are one node, so a policy that revisits its
beliefs draws as a finite-state controller. ``--depth`` bounds the edges from the root
(APPL: ``--graph-max-depth``), ``--min-prob`` drops less likely edges (APPL:
``--graph-min-prob``), ``--max-nodes`` bounds the size. Writes ``--out FILE.dot`` (Graphviz
DOT, as polgraph's ``--policy-graph``) and, with ``--image FILE.png|FILE.svg``, a drawing
made with matplotlib (no Graphviz needed). With ``--json``: ``nodes``, ``edges``, ``closed``,
``dot``, ``image``.

Example:
    >>> import argparse
    >>> from torchhrc.commands import graph
    >>> sub = argparse.ArgumentParser(prog="torchhrc").add_subparsers()
    >>> graph.register(sub)
    >>> args = ["m.pomdp", "--policy", "p.policyx", "--out", "g.dot", "--depth", "3"]
    >>> sub.choices["graph"].parse_args(args).depth
    3
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from torchhrc.commands._files import (
    add_model_and_policy,
    check_new_file,
    non_negative_int,
    policy_does_not_fit,
    positive_int,
    read_model,
    read_policy,
)
from torchhrc.errors import ModelError, TorchHRCError

__all__ = ["register", "run"]


def _probability(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not 0.0 <= value <= 1.0:
        raise argparse.ArgumentTypeError(f"expected a probability in [0, 1], got {text!r}")
    return value


def _dot_path(text: str) -> str:
    if Path(text).suffix.lower() != ".dot":
        raise argparse.ArgumentTypeError(f"expected a .dot path, got {text!r}")
    return text


def _image_path(text: str) -> str:
    if Path(text).suffix.lower() not in (".png", ".svg"):
        raise argparse.ArgumentTypeError(f"expected a .png or .svg path, got {text!r}")
    return text


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``graph`` sub-command."""
    parser = subparsers.add_parser(
        "graph",
        help="draw a policy as a graph of beliefs, actions and observations (as APPL's polgraph)",
        description=(
            "Draw the policy graph of a policy (.safetensors or APPL .policyx) on a model in "
            "Cassandra's .pomdp or APPL's .pomdpx format: nodes are the beliefs reached from "
            "the initial belief with the policy's action (a MOMDP's observed state and type "
            "belief shown), edges the observations with their probability. Writes DOT and "
            "optionally a PNG or SVG drawing (matplotlib)."
        ),
    )
    add_model_and_policy(parser)
    parser.add_argument(
        "--out",
        "--policy-graph",
        dest="out",
        type=_dot_path,
        required=True,
        metavar="FILE.dot",
        help="the DOT file to write (--policy-graph as APPL)",
    )
    parser.add_argument(
        "--image",
        type=_image_path,
        default=None,
        metavar="FILE.png|FILE.svg",
        help="also draw the graph to a PNG or SVG file (matplotlib)",
    )
    parser.add_argument(
        "--depth",
        "--graph-max-depth",
        dest="depth",
        type=non_negative_int,
        default=None,
        help="the most edges from the root (--graph-max-depth as APPL; default: no limit)",
    )
    parser.add_argument(
        "--min-prob",
        "--graph-min-prob",
        dest="min_prob",
        type=_probability,
        default=0.0,
        help="the least probability of an edge drawn (--graph-min-prob as APPL) (0)",
    )
    parser.add_argument(
        "--max-branch",
        "--graph-max-branch",
        dest="max_branch",
        type=positive_int,
        default=None,
        help="the most edges out of a node, the most probable kept (--graph-max-branch as "
        "APPL; default: no limit)",
    )
    parser.add_argument(
        "--max-nodes", type=positive_int, default=200, help="the most nodes drawn (200)"
    )
    parser.add_argument("--force", action="store_true", help="overwrite existing files")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Build the graph, write DOT (and the image); return the exit status."""
    from torchhrc._atomic import atomic_write_bytes
    from torchhrc.solvers.policy_graph import policy_graph

    check_new_file(args.out, force=args.force)
    if args.image is not None:
        check_new_file(args.image, force=args.force)
    model = read_model(args.model)
    policy = read_policy(args.policy)
    try:
        graph = policy_graph(
            model,
            policy,
            depth=args.depth,
            min_prob=args.min_prob,
            max_branch=getattr(args, "max_branch", None),
            max_nodes=args.max_nodes,
        )
    except ModelError as error:
        raise policy_does_not_fit(error, args.policy, args.model) from None
    dot = graph.to_dot()
    image, image_bytes = None, b""
    if args.image is not None:  # drawn before any file is written: a failure leaves none
        try:
            image_bytes = _render(graph, args.image)
        except ImportError as error:  # matplotlib missing: the message names the extra
            raise TorchHRCError(str(error)) from None
    atomic_write_bytes(args.out, dot.encode())
    if args.image is not None:
        image = str(atomic_write_bytes(args.image, image_bytes))
    summary = {
        "nodes": len(graph.nodes),
        "edges": len(graph.edges),
        "closed": graph.closed,
        "dot": args.out,
        "image": image,
    }
    if args.json:
        print(json.dumps(summary))
        return 0
    print(f"nodes      {summary['nodes']}")
    print(f"edges      {summary['edges']}")
    cut = (
        "every node expanded, no edge dropped"
        if graph.closed
        else "cut by --depth, --min-prob, --max-branch or --max-nodes"
    )
    print(f"closed     {str(graph.closed).lower()} ({cut})")
    print(f"dot        {args.out}")
    if image is not None:
        print(f"image      {image}")
    return 0


def _render(graph: object, path: str) -> bytes:
    """The drawing's bytes (rendered in a temporary folder)."""
    import tempfile

    from torchhrc.solvers.policy_graph import draw_policy_graph

    with tempfile.TemporaryDirectory() as folder:
        tmp = Path(folder) / ("graph" + Path(path).suffix.lower())
        draw_policy_graph(graph, tmp)  # type: ignore[arg-type]
        return tmp.read_bytes()
