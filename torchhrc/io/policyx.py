"""Alpha-vector policies on disk: APPL's ``.policyx`` XML and safetensors.

APPL SARSOP (Kurniawati, Hsu, Lee 2008; Ong et al. 2010) writes its policies as::

    <?xml version="1.0" encoding="ISO-8859-1"?>
    <Policy version="0.1" type="value" model="NAME" ...>
    <AlphaVector vectorLength="Y" numObsValue="X" numVectors="N">
    <Vector action="a" obsValue="x">v_1 ... v_Y </Vector>
    ...
    </AlphaVector> </Policy>

``vectorLength`` is the length of each vector (``S`` for a flat POMDP, ``Y`` for a MOMDP),
``numObsValue`` the number of observed values ``X`` (1 for a flat POMDP), ``obsValue`` the
observed value a vector belongs to. ``<SparseVector action=".." obsValue="..">`` with
``<Entry>index value</Entry>`` children is read too. Policies map to
:class:`~torchhrc.solvers.policy.AlphaVectorPolicy` (``alphas (N, S | Y)``, ``actions (N,)``,
``observed (N,)`` or ``None``).

The safetensors form stores ``alphas``, ``actions`` and (MOMDP) ``observed`` with metadata
``{"format": "torchhrc.AlphaVectorPolicy", "version": "1"}``. Writes are atomic; malformed
files raise :class:`~torchhrc.errors.ParseError` with file and line.

Example:
    >>> import torch, tempfile, os
    >>> from torchhrc.solvers.policy import AlphaVectorPolicy
    >>> p = AlphaVectorPolicy(torch.tensor([[1.0, -2.0]], dtype=torch.float64), torch.tensor([1]))
    >>> path = write_policyx(p, os.path.join(tempfile.mkdtemp(), "p.policyx"))
    >>> read_policyx(path).alphas
    tensor([[ 1., -2.]], dtype=torch.float64)
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any
from xml.parsers import expat

import numpy as np
import torch

from torchhrc._atomic import atomic_write_bytes
from torchhrc.errors import ModelError, ParseError

__all__ = [
    "format_policyx",
    "load_policy",
    "read_policy_safetensors",
    "read_policyx",
    "save_policy",
    "write_policy_safetensors",
    "write_policyx",
]

_FORMAT = "torchhrc.AlphaVectorPolicy"


def _policy_class() -> Any:
    # solvers sit above io in the layer order only for this class; import lazily
    from torchhrc.solvers.policy import AlphaVectorPolicy

    return AlphaVectorPolicy


def _check_policy(policy: object) -> None:
    cls = _policy_class()
    if not isinstance(policy, cls):
        raise TypeError(f"expected an AlphaVectorPolicy, got {type(policy).__name__}")


def _xml_escape(text: str) -> str:
    return (
        text.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;").replace('"', "&quot;")
    )


def format_policyx(policy: Any, *, model: str = "model", num_observed: int | None = None) -> str:
    """The ``.policyx`` text of an :class:`AlphaVectorPolicy`.

    Args:
        policy: flat (``observed is None``) or MOMDP policy.
        model: the ``model`` attribute (the problem file's name, as APPL writes it).
        num_observed: ``numObsValue`` for a MOMDP policy (default ``max(observed) + 1``).

    Returns:
        The XML text; values written with ``repr`` precision (exact round trip).

    Example:
        >>> import torch
        >>> from torchhrc.solvers.policy import AlphaVectorPolicy
        >>> p = AlphaVectorPolicy(torch.zeros(1, 2, dtype=torch.float64), torch.tensor([0]))
        >>> format_policyx(p).splitlines()[2]
        '<AlphaVector vectorLength="2" numObsValue="1" numVectors="1">'
    """
    _check_policy(policy)
    alphas = policy.alphas.detach().double().cpu().numpy()
    actions = policy.actions.cpu().tolist()
    N, L = alphas.shape
    if policy.observed is None:
        observed = [0] * N
        X = 1
    else:
        observed = policy.observed.cpu().tolist()
        X = num_observed if num_observed is not None else (max(observed) + 1 if N else 1)
        if N and max(observed) >= X:
            raise ModelError(f"num_observed = {X} but a vector belongs to x = {max(observed)}")
    lines = [
        '<?xml version="1.0" encoding="ISO-8859-1"?>',
        f'<Policy version="0.1" type="value" model="{_xml_escape(model)}" '
        'xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance" '
        'xsi:noNamespaceSchemaLocation="policyx.xsd">',
        f'<AlphaVector vectorLength="{L}" numObsValue="{X}" numVectors="{N}">',
    ]
    for n in range(N):
        values = " ".join(repr(float(v)) for v in alphas[n])
        lines.append(f'<Vector action="{actions[n]}" obsValue="{observed[n]}">{values} </Vector>')
    lines.append("</AlphaVector> </Policy>")
    return "\n".join(lines) + "\n"


def write_policyx(
    policy: Any,
    path: str | os.PathLike[str],
    *,
    model: str = "model",
    num_observed: int | None = None,
) -> Path:
    """Write ``policy`` as APPL ``.policyx`` XML, atomically. See :func:`format_policyx`.

    Example:
        >>> import torch, tempfile, os
        >>> from torchhrc.solvers.policy import AlphaVectorPolicy
        >>> p = AlphaVectorPolicy(torch.zeros(1, 2, dtype=torch.float64), torch.tensor([0]))
        >>> write_policyx(p, os.path.join(tempfile.mkdtemp(), "p.policyx")).suffix
        '.policyx'
    """
    text = format_policyx(policy, model=model, num_observed=num_observed)
    return atomic_write_bytes(path, text.encode("iso-8859-1", errors="xmlcharrefreplace"))


class _Handler:
    """expat callbacks collecting the vectors with their line numbers."""

    def __init__(self, parser: Any, path: str) -> None:
        self.parser = parser
        self.path = path
        self.stack: list[str] = []
        self.header: dict[str, str] | None = None
        self.header_line = 0
        self.vectors: list[tuple[dict[str, str], list[str], int]] = []
        self.entries: list[str] = []
        self.text: list[str] = []
        self.current: tuple[dict[str, str], int] | None = None
        self.saw_policy = False

    def error(self, reason: str, line: int | None = None) -> ParseError:
        return ParseError(
            reason,
            path=self.path,
            line=self.parser.CurrentLineNumber if line is None else line,
            column=None if line is not None else self.parser.CurrentColumnNumber + 1,
        )

    def entity_declaration(self, *args: object) -> None:
        raise self.error("entity declarations are not allowed")

    def start(self, tag: str, attrs: dict[str, str]) -> None:
        parent = self.stack[-1] if self.stack else None
        expected = {
            None: ("Policy",),
            "Policy": ("AlphaVector",),
            "AlphaVector": ("Vector", "SparseVector"),
            "SparseVector": ("Entry",),
        }.get(parent, ())
        if tag not in expected:
            where = f"inside <{parent}>" if parent else "at the top level"
            raise self.error(f"unexpected element <{tag}> {where}")
        self.stack.append(tag)
        if tag == "Policy":
            self.saw_policy = True
        elif tag == "AlphaVector":
            if self.header is not None:
                raise self.error("more than one <AlphaVector> element")
            self.header = attrs
            self.header_line = self.parser.CurrentLineNumber
        elif tag in ("Vector", "SparseVector"):
            self.current = (attrs, self.parser.CurrentLineNumber)
            self.text = []
            self.entries = []
        elif tag == "Entry":
            self.text = []

    def end(self, tag: str) -> None:
        self.stack.pop()
        if tag == "Vector":
            attrs, line = self.current  # type: ignore[misc]
            self.vectors.append(({**attrs, "__kind": "dense"}, "".join(self.text).split(), line))
        elif tag == "Entry":
            self.entries.append("".join(self.text))
        elif tag == "SparseVector":
            attrs, line = self.current  # type: ignore[misc]
            self.vectors.append(({**attrs, "__kind": "sparse"}, self.entries, line))

    def data(self, text: str) -> None:
        if self.stack and self.stack[-1] in ("Vector", "Entry"):
            self.text.append(text)
        elif text.strip():
            raise self.error(f"unexpected text {text.strip()[:20]!r}")


def _int_attr(h: _Handler, attrs: dict[str, str], name: str, line: int, tag: str) -> int:
    if name not in attrs:
        raise h.error(f"<{tag}> lacks the attribute {name!r}", line)
    value = attrs[name]
    if not (value.isascii() and value.isdigit()):
        raise h.error(f"<{tag}> attribute {name}={value!r} is not a non-negative integer", line)
    return int(value)


def read_policyx(path: str | os.PathLike[str], *, momdp: bool | None = None) -> Any:
    """Read an APPL ``.policyx`` file into an :class:`AlphaVectorPolicy`.

    Args:
        path: the file.
        momdp: whether to keep ``observed`` (a MOMDP policy); default: when
            ``numObsValue > 1``.

    Returns:
        :class:`~torchhrc.solvers.policy.AlphaVectorPolicy` in float64.

    Raises:
        ParseError: malformed XML or inconsistent counts (file and line in the message).

    Example:
        >>> import torch, tempfile, os
        >>> from torchhrc.solvers.policy import AlphaVectorPolicy
        >>> p = AlphaVectorPolicy(torch.eye(2, dtype=torch.float64), torch.tensor([0, 1]),
        ...                       observed=torch.tensor([0, 2]))
        >>> read_policyx(write_policyx(p, os.path.join(tempfile.mkdtemp(), "m.policyx"))).observed
        tensor([0, 2])
    """
    path_str = os.fspath(path)
    try:
        data = Path(path_str).read_bytes()
    except OSError as e:
        raise ParseError(f"cannot read file: {e.strerror}", path=path_str) from None
    parser = expat.ParserCreate()
    h = _Handler(parser, path_str)
    parser.StartElementHandler = h.start
    parser.EndElementHandler = h.end
    parser.CharacterDataHandler = h.data
    parser.EntityDeclHandler = h.entity_declaration
    try:
        parser.Parse(data, True)
    except expat.ExpatError as e:
        raise ParseError(
            f"malformed XML: {expat.ErrorString(e.code)}",
            path=path_str,
            line=e.lineno,
            column=e.offset + 1,
        ) from None
    if h.header is None:
        raise ParseError("no <AlphaVector> element", path=path_str, line=1)
    hl = h.header_line
    L = _int_attr(h, h.header, "vectorLength", hl, "AlphaVector")
    X = _int_attr(h, h.header, "numObsValue", hl, "AlphaVector")
    N = _int_attr(h, h.header, "numVectors", hl, "AlphaVector")
    if L < 1 or X < 1:
        raise h.error("vectorLength and numObsValue must be positive", hl)
    if len(h.vectors) != N:
        raise h.error(f"numVectors = {N} but the file holds {len(h.vectors)} vectors", hl)
    alphas = np.zeros((N, L))
    actions = np.zeros(N, dtype=np.int64)
    observed = np.zeros(N, dtype=np.int64)
    for n, (attrs, content, line) in enumerate(h.vectors):
        kind = "Vector" if attrs["__kind"] == "dense" else "SparseVector"
        actions[n] = _int_attr(h, attrs, "action", line, kind)
        observed[n] = _int_attr(h, attrs, "obsValue", line, kind) if "obsValue" in attrs else 0
        if observed[n] >= X:
            raise h.error(f"obsValue {observed[n]} out of range [0, {X})", line)
        try:
            if attrs["__kind"] == "dense":
                if len(content) != L:
                    raise h.error(f"expected {L} values (vectorLength), found {len(content)}", line)
                alphas[n] = np.array(content, dtype=np.float64)
            else:
                for entry in content:
                    parts = entry.split()
                    if len(parts) != 2:
                        raise h.error(f"<Entry> must hold 'index value', got {entry!r}", line)
                    i = int(parts[0])
                    if not 0 <= i < L:
                        raise h.error(f"<Entry> index {i} out of range [0, {L})", line)
                    alphas[n, i] = float(parts[1])
        except ValueError as e:
            raise h.error(f"bad number in vector {n}: {e}", line) from None
        if not np.isfinite(alphas[n]).all():
            raise h.error(f"vector {n} has non-finite values", line)
    keep_observed = (X > 1) if momdp is None else momdp
    cls = _policy_class()
    try:
        return cls(
            alphas=torch.from_numpy(alphas),
            actions=torch.from_numpy(actions),
            observed=torch.from_numpy(observed) if keep_observed else None,
        )
    except (ModelError, TypeError) as e:
        raise ParseError(str(e), path=path_str) from None


def write_policy_safetensors(policy: Any, path: str | os.PathLike[str]) -> Path:
    """Write ``policy`` as safetensors (``alphas``, ``actions``, ``observed``), atomically.

    Example:
        >>> import torch, tempfile, os
        >>> from torchhrc.solvers.policy import AlphaVectorPolicy
        >>> p = AlphaVectorPolicy(torch.ones(1, 3, dtype=torch.float64), torch.tensor([2]))
        >>> f = write_policy_safetensors(p, os.path.join(tempfile.mkdtemp(), "p.safetensors"))
        >>> read_policy_safetensors(f).actions
        tensor([2])
    """
    from safetensors.torch import save

    _check_policy(policy)
    tensors = {
        "alphas": policy.alphas.detach().cpu().contiguous(),
        "actions": policy.actions.detach().cpu().to(torch.int64).contiguous(),
    }
    if policy.observed is not None:
        tensors["observed"] = policy.observed.detach().cpu().to(torch.int64).contiguous()
    data = save(tensors, metadata={"format": _FORMAT, "version": "1"})
    return atomic_write_bytes(path, data)


def read_policy_safetensors(path: str | os.PathLike[str]) -> Any:
    """Read a policy written by :func:`write_policy_safetensors`.

    Raises:
        ParseError: not a safetensors file, or not a torchhrc policy.

    Example:
        >>> import torch, tempfile, os
        >>> from torchhrc.solvers.policy import AlphaVectorPolicy
        >>> p = AlphaVectorPolicy(torch.ones(2, 2, dtype=torch.float64), torch.tensor([0, 1]))
        >>> f = write_policy_safetensors(p, os.path.join(tempfile.mkdtemp(), "p.safetensors"))
        >>> read_policy_safetensors(f).num_vectors
        2
    """
    from safetensors import SafetensorError
    from safetensors.torch import load

    path_str = os.fspath(path)
    try:
        data = Path(path_str).read_bytes()
    except OSError as e:
        raise ParseError(f"cannot read file: {e.strerror}", path=path_str) from None
    try:
        tensors = load(data)
    except (SafetensorError, ValueError, RuntimeError) as e:
        raise ParseError(f"not a safetensors file ({e})", path=path_str) from None
    missing = [k for k in ("alphas", "actions") if k not in tensors]
    if missing:
        raise ParseError(f"not a torchhrc policy: missing {missing}", path=path_str)
    cls = _policy_class()
    try:
        return cls(
            alphas=tensors["alphas"], actions=tensors["actions"], observed=tensors.get("observed")
        )
    except (ModelError, TypeError) as e:
        raise ParseError(str(e), path=path_str) from None


def save_policy(policy: Any, path: str | os.PathLike[str], **kwargs: Any) -> Path:
    """Write ``policy`` as ``.policyx`` or ``.safetensors`` by the file's suffix.

    Example:
        >>> import torch, tempfile, os
        >>> from torchhrc.solvers.policy import AlphaVectorPolicy
        >>> p = AlphaVectorPolicy(torch.ones(1, 2, dtype=torch.float64), torch.tensor([0]))
        >>> load_policy(save_policy(p, os.path.join(tempfile.mkdtemp(), "p.policyx"))).actions
        tensor([0])
    """
    suffix = Path(path).suffix.lower()
    if suffix in (".policyx", ".policy", ".xml"):
        return write_policyx(policy, path, **kwargs)
    if suffix == ".safetensors":
        return write_policy_safetensors(policy, path)
    raise ValueError(f"expected a .policyx or .safetensors path, got {os.fspath(path)!r}")


def load_policy(path: str | os.PathLike[str], **kwargs: Any) -> Any:
    """Read a ``.policyx`` or ``.safetensors`` policy by the file's suffix.

    Example:
        >>> load_policy("p.txt")
        Traceback (most recent call last):
        ...
        ValueError: expected a .policyx or .safetensors path, got 'p.txt'
    """
    suffix = Path(path).suffix.lower()
    if suffix in (".policyx", ".policy", ".xml"):
        return read_policyx(path, **kwargs)
    if suffix == ".safetensors":
        return read_policy_safetensors(path)
    raise ValueError(f"expected a .policyx or .safetensors path, got {os.fspath(path)!r}")
