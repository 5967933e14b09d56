"""What the policy commands (``simulate``, ``evaluate``, ``graph``) share: reading a model
by its suffix, reading a policy, and the argument checks.

Example:
    >>> positive_int("3")
    3
"""

from __future__ import annotations

import argparse
import errno
import os
from pathlib import Path
from typing import Any

from torchhrc.errors import ModelError

__all__ = [
    "MODEL_SUFFIXES",
    "POLICY_SUFFIXES",
    "add_fast",
    "add_model_and_policy",
    "check_new_file",
    "model_path",
    "non_negative_int",
    "policy_does_not_fit",
    "policy_path",
    "positive_int",
    "read_model",
    "read_policy",
]

MODEL_SUFFIXES = (".pomdp", ".pomdpx")
POLICY_SUFFIXES = (".policyx", ".policy", ".xml", ".safetensors")


def _int_at_least(text: str, low: int, kind: str) -> int:
    """``text`` as an integer of at least ``low``; the error names ``kind`` otherwise."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
    if value < low:
        raise argparse.ArgumentTypeError(f"expected {kind}, got {text!r}")
    return value


def positive_int(text: str) -> int:
    """An integer >= 1 (argparse type)."""
    return _int_at_least(text, 1, "a positive integer")


def non_negative_int(text: str) -> int:
    """An integer >= 0 (argparse type)."""
    return _int_at_least(text, 0, "a non-negative integer")


def model_path(text: str) -> str:
    """A ``.pomdp`` or ``.pomdpx`` path (argparse type)."""
    if Path(text).suffix.lower() not in MODEL_SUFFIXES:
        raise argparse.ArgumentTypeError(f"expected a .pomdp or .pomdpx file, got {text!r}")
    return text


def policy_path(text: str) -> str:
    """A ``.policyx`` (APPL) or ``.safetensors`` (torchhrc) path (argparse type)."""
    if Path(text).suffix.lower() not in POLICY_SUFFIXES:
        raise argparse.ArgumentTypeError(f"expected a .policyx or .safetensors file, got {text!r}")
    return text


def add_model_and_policy(parser: argparse.ArgumentParser) -> None:
    """The positional model and the ``--policy`` option of the policy commands."""
    parser.add_argument(
        "model",
        type=model_path,
        metavar="FILE.pomdp|FILE.pomdpx",
        help="the model (Cassandra .pomdp; APPL .pomdpx by its suffix)",
    )
    parser.add_argument(
        "--policy",
        "--policy-file",
        dest="policy",
        type=policy_path,
        required=True,
        metavar="POLICY",
        help="the policy: torchhrc's .safetensors or APPL's .policyx (as pomdpsol writes it)",
    )
    add_fast(parser)


def add_fast(parser: argparse.ArgumentParser | argparse._ArgumentGroup) -> None:
    """APPL's ``--fast`` (its faster, picky ``.pomdp`` parser), accepted so that APPL's
    command lines run as they are; it has no effect: torchhrc has one reader."""
    parser.add_argument(
        "--fast",
        action="store_true",
        help="accepted for APPL command lines (its faster, picky .pomdp parser); no effect: "
        "torchhrc has one reader",
    )


def read_model(path: str) -> Any:
    """The model of a ``.pomdp`` or ``.pomdpx`` file, sparse where a dense one would not fit
    (as ``torchhrc solve`` reads it)."""
    if Path(path).suffix.lower() == ".pomdpx":
        from torchhrc.io.pomdpx import read_pomdpx

        return read_pomdpx(path, sparse="auto")
    from torchhrc.io.cassandra import read_pomdp

    return read_pomdp(path, sparse="auto")


def read_policy(path: str) -> Any:
    """The :class:`~torchhrc.solvers.policy.AlphaVectorPolicy` of a policy file."""
    from torchhrc.io.policyx import load_policy

    if not os.path.exists(path):
        raise FileNotFoundError(errno.ENOENT, "No such file or directory", path)
    try:
        return load_policy(path)
    except ModelError:
        raise
    except ValueError as error:  # a malformed safetensors header, a bad tensor
        raise ModelError(f"cannot read policy {path}: {error}") from None


def policy_does_not_fit(error: ModelError, policy: str, model: str) -> ModelError:
    """``error`` (a policy that does not fit the model's states, actions or observed values)
    with both files named; other errors as they are."""
    text = str(error)
    if text.startswith(("expected policy", "a MOMDP policy")):
        return ModelError(f"the policy {policy} does not fit the model {model}: {text}")
    return error


def check_new_file(path: str, *, force: bool) -> None:
    """Refuse to overwrite ``path`` without ``force``; its folder must exist."""
    if os.path.exists(path) and not force:
        raise FileExistsError(errno.EEXIST, "file exists (use --force to overwrite)", path)
    folder = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(folder):
        raise FileNotFoundError(errno.ENOENT, "No such file or directory", folder)
