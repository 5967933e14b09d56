"""``torchhrc convert``: ``.pomdp`` to ``.pomdpx`` and back (APPL's ``pomdpconvert``, both ways).

Reads the input by its suffix (:func:`torchhrc.io.cassandra.read_pomdp` or
:func:`torchhrc.io.pomdpx.read_pomdpx`) and writes the output by its suffix
(:func:`torchhrc.io.pomdpx.write_pomdpx` or :func:`torchhrc.io.cassandra.write_pomdp`),
atomically. A ``.pomdpx`` MOMDP (observed state variables) written as ``.pomdp`` becomes the
flat POMDP over the joint states ``(x, y)``; a ``.pomdp`` written as ``.pomdpx`` has one
hidden state variable, its functions full tables, or one ``<Entry>`` per nonzero where the
model is read sparse (too large to hold densely; APPL's ``pomdpsol`` reads either). Without
``OUT`` the output is the input with the other suffix (``Hallway.pomdp`` ->
``Hallway.pomdpx``, as ``pomdpconvert`` names it). An existing output is kept unless
``--force``.

Example:
    >>> import argparse
    >>> from torchhrc.commands import convert
    >>> sub = argparse.ArgumentParser(prog="torchhrc").add_subparsers()
    >>> convert.register(sub)
    >>> sub.choices["convert"].parse_args(["m.pomdp"]).output
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from torchhrc.commands._files import check_new_file, model_path, read_model

__all__ = ["register", "run"]


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``convert`` sub-command."""
    parser = subparsers.add_parser(
        "convert",
        help="convert a model between .pomdp and .pomdpx (as APPL's pomdpconvert, both ways)",
        description=(
            "Convert a model between Cassandra's .pomdp format and APPL's .pomdpx format "
            "(chosen by the suffixes); a .pomdpx MOMDP becomes the flat POMDP over its "
            "joint states. A model too large to hold densely is written with one entry per "
            "nonzero."
        ),
    )
    parser.add_argument(
        "input", type=model_path, metavar="IN.pomdp|IN.pomdpx", help="the model to read"
    )
    parser.add_argument(
        "output",
        type=model_path,
        nargs="?",
        default=None,
        metavar="OUT.pomdpx|OUT.pomdp",
        help="the file to write (default: IN with the other suffix)",
    )
    parser.add_argument("--force", action="store_true", help="overwrite an existing file")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.set_defaults(func=run)


def _flat(model: Any) -> Any:
    """The flat model of a MOMDP form (a flat one as it is)."""
    if hasattr(model, "to_sparse_pomdp"):
        return model.to_sparse_pomdp()
    if hasattr(model, "to_pomdp"):
        return model.to_pomdp()
    return model


def run(args: argparse.Namespace) -> int:
    """Read, write; return the exit status."""
    from torchhrc.errors import ModelError
    from torchhrc.io.cassandra import write_pomdp
    from torchhrc.io.pomdpx import write_pomdpx
    from torchhrc.pomdp import MOMDP, POMDP
    from torchhrc.pomdp.sparse import SparsePOMDP

    source = Path(args.input)
    output = args.output
    if output is None:
        other = ".pomdpx" if source.suffix.lower() == ".pomdp" else ".pomdp"
        output = str(source.with_suffix(other))
    if Path(output).resolve() == source.resolve():
        raise ModelError(f"the output {output} is the input; give another OUT")
    check_new_file(output, force=args.force)
    model = read_model(args.input)
    if Path(output).suffix.lower() == ".pomdpx":
        # a dense model as full tables, a sparse one as one entry per nonzero (a sparse
        # MOMDP as its flat sparse POMDP)
        kept = model if isinstance(model, (POMDP, MOMDP, SparsePOMDP)) else _flat(model)
        written = write_pomdpx(kept, output, description=f"converted from {source.name}")
    else:
        written = write_pomdp(_flat(model), output, comment=f"converted from {source.name}")
    summary = {
        "input": args.input,
        "output": str(written),
        "model": type(model).__name__,
        "states": getattr(model, "num_states", None),
        "actions": model.num_actions,
        "observations": model.num_observations,
    }
    if args.json:
        print(json.dumps(summary))
    else:
        print(f"wrote {written} ({summary['model']}, {model.num_actions} actions, "
              f"{model.num_observations} observations)")  # fmt: skip
    return 0
