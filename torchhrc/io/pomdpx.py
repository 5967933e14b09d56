"""APPL's factored ``.pomdpx`` XML format (Ong et al. 2010): reader and writer.

The format of APPL SARSOP (``doc/POMDPX/PomdpxFileFormat-v1.0.pdf`` and ``pomdpx.xsd`` in
https://github.com/AdaCompNUS/sarsop): a POMDP as a dynamic Bayesian network over named
variables.

Reading (:func:`read_pomdpx`), covered as APPL accepts it:

* ``<StateVar vnamePrev vnameCurr fullyObs>``, ``<ObsVar>``, ``<ActionVar>``, ``<RewardVar>``,
  each with ``<ValueEnum>`` names or ``<NumValues>`` (APPL's implicit names ``s0 s1 ...``,
  ``o0 ...``, ``a0 ...`` are accepted in instances, as are 0-based numbers);
* ``<InitialStateBelief>``, ``<StateTransitionFunction>``, ``<ObsFunction>`` (``<CondProb>``)
  and ``<RewardFunction>`` (``<Func>``, several summed), ``<Parameter type="TBL">`` tables:
  an ``<Entry>``'s ``<Instance>`` has one token per parent and (for a ``CondProb``) the
  variable; a value name fixes it, ``*`` means "every value, the same numbers", ``-`` means
  "every value, numbers listed" (row-major over the ``-`` positions); ``<ProbTable>identity``
  (one ``-`` parent and a ``-`` variable of the same size) and ``uniform`` (``1 / |var|``);
  later entries override earlier ones; cells no entry covers are 0;
* the DBN APPL solves: an observed (``fullyObs="true"``) variable depends on the action and
  the previous slice, a hidden one also on observed variables of the current slice;
  observations depend on the action and the current slice; rewards on the action, both slices
  and observations (reduced to the expected ``R[a, s]``). ``type="DD"`` (decision diagrams)
  is not supported (a :class:`~torchhrc.errors.ParseError` says so), as in APPL.

Several variables form one index, row-major in declaration order (the first varies slowest):
observed state variables give ``x``, hidden ones ``y``, action variables ``a``, observation
variables ``o``; a value's name is its variables' value names joined by ``","``.
:func:`read_pomdpx_variables` returns the variables and decodes an index. A model with
an observed variable is returned as a :class:`~torchhrc.pomdp.MOMDP`
(``Tx (A, X, Y, X)``, ``Ty (A, X, Y, X, Y)`` or ``None`` when every hidden variable keeps its
value, ``Z (A, X, Y, O)``, ``R (A, X, Y)``; an initial belief spread over several ``x`` as its
``initial (X, Y)``, APPL's ``TagAvoid.pomdpx``), or as a
:class:`~torchhrc.sparse_momdp.SparseMOMDP` when its dense ``Tx``/``Ty`` would be too large;
otherwise as a flat
:class:`~torchhrc.pomdp.POMDP` over ``s = x * Y + y`` (names ``"x|y"``; observations
``x2 * O + o`` when some variable is observed, as :meth:`~torchhrc.pomdp.MOMDP.to_pomdp`,
unless ``x`` is a function of the actions taken: one initial ``x`` and deterministic observed
variables that depend on no hidden one), or as a
:class:`~torchhrc.sparse.SparsePOMDP` when the dense tensors would be too large
(RockSample(7, 8): ``Ty`` would hold 2e9 entries). Tables are parsed with numpy and combined
by broadcasting (dense forms) or by expanding the nonzero successors of every ``(a, s)``
(sparse form); no Python loop runs over states. XML is parsed by expat with document type
declarations and entities refused (no entity expansion, no external fetch). Any malformed
input raises :class:`~torchhrc.errors.ParseError` with the file, line, element and reason.

Writing (:func:`write_pomdpx`): a :class:`MOMDP` as two state variables ``x`` (observed) and
``y`` (hidden), a :class:`POMDP` as one hidden state variable, one observation, action and
reward variable, each function a full table (a random start: ``x_0`` with ``P(x)`` and
``y_0 | x_0``)::

    x_1 | action x_0 y_0            Tx  (A, X, Y, X)
    y_1 | action x_0 y_0 [x_1]      Ty  (A, X, Y[, X], Y); "identity" on y_0 when static
    obs | action x_1 y_1            Z   (A, X, Y, O)
    reward(action x_0 y_0)          R   (A, X, Y)

``x_1`` is a parent of ``y_1`` only when ``Ty`` depends on it (where ``x_1`` is reachable).
Checked with APPL SARSOP's ``pomdpsol``: Tiger and RockSample(4, 4) written this way solve to
the same values as their flat ``.pomdp`` files; a flat POMDP (``state_1 | action state_0``,
``obs | action state_1``, ``reward(action state_0)``) too (Tiger: 19.3711 / 19.3721).

Example:
    >>> from torchhrc.testing import random_momdp
    >>> m = random_momdp(2, 3, 2, 2, seed=0)
    >>> text = format_pomdpx(m)
    >>> '<StateVar vnamePrev="x_0" vnameCurr="x_1" fullyObs="true">' in text
    True
    >>> bool((read_pomdpx(text).Tx == m.Tx).all())
    True
"""

from __future__ import annotations

import itertools
import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal
from xml.etree import ElementTree
from xml.parsers import expat

import numpy as np
import torch

from torchhrc.errors import ModelError, ParseError
from torchhrc.io._atomic import atomic_write_bytes
from torchhrc.io._budget import check_budget, resolve_budget
from torchhrc.io._gc import gc_paused
from torchhrc.pomdp import MOMDP, POMDP, split_initial
from torchhrc.sparse import MAX_DENSE_ENTRIES, SparsePOMDP
from torchhrc.sparse_momdp import SparseMOMDP

__all__ = [
    "AUTO_SPARSE_ENTRIES",
    "AUTO_SPARSE_MOMDP_ENTRIES",
    "PomdpxVariable",
    "PomdpxVariables",
    "format_pomdpx",
    "parse_pomdpx",
    "read_pomdpx",
    "read_pomdpx_variables",
    "write_pomdpx",
]

#: ``read_pomdpx(..., sparse="auto")`` reads a model sparsely when a dense tensor (``Tx``, ``Ty``
#: and ``Z`` of the MOMDP form, then ``T (A, S, S)`` and ``Z`` of the flat form) would have more
#: entries than this (``torchhrc solve`` with SARSOP uses it).
AUTO_SPARSE_ENTRIES = MAX_DENSE_ENTRIES

#: ``read_pomdpx(..., sparse="auto")`` keeps a MOMDP's transitions as their nonzeros (a
#: :class:`~torchhrc.sparse_momdp.SparseMOMDP`) when its dense ``Tx`` or ``Ty`` would have more
#: entries than this (10^7, 80 MB in float64). Measured on RockSample(6, 6) as a MOMDP (a dense
#: ``Ty`` of 6.2e7 entries): read in 1.0 instead of 3.6 CPU-s, peak memory 443 instead of
#: 1,222 MB, and a tighter gap after 10 CPU-s of SARSOP (1.82 against 1.94).
AUTO_SPARSE_MOMDP_ENTRIES = 10_000_000

_ROW_TOL = 1e-4  # rows of a CondProb must sum to 1 within this (then renormalised exactly)

#: Bytes of memory a byte of the file takes as XML elements (measured: a 6 MB RockSample(6,
#: 6) file peaked 127 MB above the process, tables included).
_XML_BYTES = 20
#: Bytes of a value named by ``<NumValues>``: its made-up name and the reader's lookup entry
#: (measured: 146 bytes a value for 3 million).
_NAME_BYTES = 160
#: Peak bytes a nonzero of the sparse forms costs while it is expanded (its row, value and
#: probability, one index per variable, the re-indexing), per variable of the expansion.
_ENTRY_BYTES = 48


# ================================================================================ variables


@dataclass(frozen=True)
class PomdpxVariable:
    """One variable of a ``.pomdpx`` file.

    Attributes:
        name: ``vnameCurr`` of a state variable, ``vname`` otherwise.
        values: the value names (APPL's ``s0 s1 ...`` / ``o0 ...`` / ``a0 ...`` for
            ``<NumValues>``).
        previous: ``vnamePrev`` of a state variable, else ``None``.
        observed: ``fullyObs="true"`` (state variables).
        enumerated: the values were given by ``<ValueEnum>`` (not ``<NumValues>``).
    """

    name: str
    values: tuple[str, ...]
    previous: str | None = None
    observed: bool = False
    enumerated: bool = True

    @property
    def size(self) -> int:
        return len(self.values)


@dataclass(frozen=True)
class PomdpxVariables:
    """The variables of a ``.pomdpx`` file, grouped as the model combines them.

    Each group forms one index, row-major over its variables in declaration order (the first
    varies slowest): ``observed`` gives ``x`` (a MOMDP's observed part), ``hidden`` gives
    ``y``, the flat state is ``s = x * Y + y``; ``actions`` give ``a``, ``observations`` give
    ``o``.

    Example:
        >>> v = PomdpxVariables(observed=(PomdpxVariable("pos", ("l", "r")),),
        ...                     hidden=(PomdpxVariable("r0", ("bad", "good")),
        ...                             PomdpxVariable("r1", ("bad", "good"))))
        >>> v.decode("hidden", 2), v.encode("hidden", {"r0": "good", "r1": "bad"})
        ({'r0': 'good', 'r1': 'bad'}, 2)
    """

    observed: tuple[PomdpxVariable, ...] = ()
    hidden: tuple[PomdpxVariable, ...] = ()
    actions: tuple[PomdpxVariable, ...] = ()
    observations: tuple[PomdpxVariable, ...] = ()
    rewards: tuple[str, ...] = ()

    def _group(self, group: str) -> tuple[PomdpxVariable, ...]:
        if group == "states":
            return self.observed + self.hidden
        if group not in ("observed", "hidden", "actions", "observations"):
            raise ValueError(
                "expected group to be 'observed', 'hidden', 'states', 'actions' or "
                f"'observations', got {group!r}"
            )
        return getattr(self, group)

    def size(self, group: str) -> int:
        """The number of combined values of ``group`` (1 for an empty group)."""
        return math.prod(v.size for v in self._group(group))

    def decode(self, group: str, index: int) -> dict[str, str]:
        """``{variable name: value name}`` of the combined ``index`` of ``group``."""
        variables = self._group(group)
        if not 0 <= index < self.size(group):
            raise ValueError(f"expected index in [0, {self.size(group)}), got {index}")
        out = {}
        for v in reversed(variables):
            index, k = divmod(index, v.size)
            out[v.name] = v.values[k]
        return dict(reversed(list(out.items())))

    def encode(self, group: str, values: Mapping[str, str]) -> int:
        """The combined index of ``group`` for ``{variable name: value name}``."""
        index = 0
        for v in self._group(group):
            if v.name not in values:
                raise ValueError(f"expected a value for variable {v.name!r}")
            if values[v.name] not in v.values:
                raise ValueError(f"{values[v.name]!r} is not a value of {v.name!r}: {v.values}")
            index = index * v.size + v.values.index(values[v.name])
        return index


# ================================================================================ XML tree


class _Node:
    """An XML element with its 1-based line (expat tree; ElementTree drops lines)."""

    __slots__ = ("attrib", "children", "line", "parts", "tag")

    def __init__(self, tag: str, attrib: dict[str, str], line: int) -> None:
        self.tag = tag
        self.attrib = attrib
        self.line = line
        self.children: list[_Node] = []
        self.parts: list[str] = []

    @property
    def text(self) -> str:
        return "".join(self.parts)

    def find(self, tag: str) -> _Node | None:
        return next((c for c in self.children if c.tag == tag), None)

    def __iter__(self) -> Any:
        return iter(self.children)

    def __len__(self) -> int:
        return len(self.children)


def _text(node: Any) -> str:
    """The text of an element (a :class:`_Node` or an ``ElementTree`` element)."""
    return node.text or ""


def _line(node: Any) -> int | None:
    """The 1-based line of a :class:`_Node`; None for an ``ElementTree`` element."""
    return getattr(node, "line", None)


class _Refused(Exception):
    def __init__(self, reason: str, line: int) -> None:
        self.reason, self.line = reason, line


def _parse_xml(data: bytes | str, path: str) -> _Node:
    """The element tree of ``data``; DTDs and entity declarations are refused."""
    parser = expat.ParserCreate("utf-8" if isinstance(data, str) else None)
    parser.buffer_text = True
    root = _Node("", {}, 0)
    stack = [root]

    def start(tag: str, attrib: dict[str, str]) -> None:
        node = _Node(tag, attrib, parser.CurrentLineNumber)
        stack[-1].children.append(node)
        stack.append(node)

    def end(tag: str) -> None:
        stack.pop()

    def chars(text: str) -> None:
        stack[-1].parts.append(text)

    def refuse(*_: Any) -> None:
        raise _Refused(
            "document type declarations and entities are not allowed", parser.CurrentLineNumber
        )

    parser.StartElementHandler = start
    parser.EndElementHandler = end
    parser.CharacterDataHandler = chars
    parser.StartDoctypeDeclHandler = refuse
    parser.EntityDeclHandler = refuse
    parser.ExternalEntityRefHandler = refuse  # type: ignore[assignment]
    try:
        parser.Parse(data, True)
    except _Refused as e:
        raise ParseError(e.reason, path=path, line=e.line) from None
    except expat.ExpatError as e:
        raise ParseError(
            f"malformed XML: {expat.ErrorString(e.code)}",
            path=path,
            line=e.lineno,
            column=e.offset + 1,
        ) from None
    if not root.children:
        raise ParseError("no XML element", path=path)
    return root.children[0]


_REFUSED_MARKUP = (b"<!DOCTYPE", b"<!ENTITY")


def _parse_xml_fast(data: bytes | str) -> Any:
    """The root element parsed by ``ElementTree``'s C builder (no line numbers), or None when
    the document must go through :func:`_parse_xml` (a document type declaration or an entity
    to refuse, or malformed XML: that path reports the line)."""
    raw = data.encode("utf-8") if isinstance(data, str) else data
    if any(marker in raw for marker in _REFUSED_MARKUP):
        return None
    parser = ElementTree.XMLParser(encoding="utf-8" if isinstance(data, str) else None)
    try:
        parser.feed(raw)
        return parser.close()
    except ElementTree.ParseError:
        return None


# ================================================================================ reader


def _is_index(token: str) -> bool:
    return token.isdigit()


class _Reader:
    """Interprets the element tree; every error is a :class:`ParseError`."""

    def __init__(self, root: _Node, path: str, budget: float = math.inf) -> None:
        self.path = path
        self.root = root
        self.budget = budget
        self.held = 0.0  # bytes of the value names and tables allocated so far
        # name -> (kind, variable); kinds: action, prev, curr, obs, reward
        self.kind: dict[str, str] = {}
        self.var: dict[str, PomdpxVariable] = {}
        self.lookup: dict[str, dict[str, int]] = {}

    def error(self, reason: str, node: _Node | None) -> ParseError:
        return ParseError(reason, path=self.path, line=None if node is None else _line(node))

    # ------------------------------------------------------------------ document

    def read(self) -> None:
        root = self.root
        if root.tag != "pomdpx":
            raise self.error(f"expected the root element <pomdpx>, got <{root.tag}>", root)
        sections: dict[str, list[_Node]] = {}
        allowed = {
            "Description",
            "Discount",
            "Variable",
            "InitialStateBelief",
            "StateTransitionFunction",
            "ObsFunction",
            "RewardFunction",
        }
        for child in root:
            if child.tag not in allowed:
                what = "is not supported" if child.tag.startswith("Terminal") else "is unknown"
                raise self.error(f"<{child.tag}> {what} (expected one of {sorted(allowed)})", child)
            sections.setdefault(child.tag, []).append(child)
        for tag in (
            "Discount",
            "Variable",
            "InitialStateBelief",
            "StateTransitionFunction",
            "RewardFunction",
        ):
            if tag not in sections:
                raise self.error(f"<pomdpx> has no <{tag}>", root)
        for tag in ("Discount", "Variable"):
            if len(sections[tag]) > 1:
                raise self.error(f"<{tag}> appears more than once", sections[tag][1])
        self.discount = self._discount(sections["Discount"][0])
        self._variables(sections["Variable"][0])
        self.belief = self._functions(sections["InitialStateBelief"], "belief")
        self.transition = self._functions(sections["StateTransitionFunction"], "transition")
        self.observation = self._functions(sections.get("ObsFunction", []), "observation")
        self.rewards = self._functions(sections["RewardFunction"], "reward")
        self._check_coverage(sections)

    def _discount(self, node: _Node) -> float:
        text = _text(node).strip()
        try:
            value = float(text)
        except ValueError:
            raise self.error(f"<Discount>: expected a number, got {text!r}", node) from None
        if not 0 < value <= 1:
            raise self.error(f"<Discount>: expected a value in (0, 1], got {text}", node)
        return value

    # ------------------------------------------------------------------ variables

    def _values(self, node: _Node, prefix: str) -> tuple[tuple[str, ...], bool]:
        enum, num = node.find("ValueEnum"), node.find("NumValues")
        if enum is not None and num is not None:
            raise self.error(f"<{node.tag}> has both <ValueEnum> and <NumValues>", node)
        if enum is not None:
            names = tuple(_text(enum).split())
            if not names:
                raise self.error(f"<{node.tag}>: empty <ValueEnum>", enum)
            if len(set(names)) != len(names):
                dup = next(n for n in names if names.count(n) > 1)
                raise self.error(f"<{node.tag}>: value {dup!r} appears twice in <ValueEnum>", enum)
            return names, True
        if num is not None:
            text = _text(num).strip()
            if not text.isdigit() or int(text) < 1:
                raise self.error(f"<NumValues>: expected a positive integer, got {text!r}", num)
            count = int(text)
            if count > MAX_DENSE_ENTRIES:
                raise self.error(f"<NumValues>: {count} values are too many", num)
            self._charge(_NAME_BYTES * count, f"<NumValues>{count}</NumValues>: the names of "
                         f"{count:.3g} values", num)  # fmt: skip
            return tuple(f"{prefix}{i}" for i in range(count)), False
        raise self.error(f"<{node.tag}> has neither <ValueEnum> nor <NumValues>", node)

    def _charge(self, need: float, what: str, node: _Node | None) -> None:
        """Count ``need`` bytes against the budget, with what the reader holds already."""
        total = self.held + need
        if total > self.budget:
            so_far = f" (with the {self.held:.3g} bytes read before it)" if self.held else ""
            check_budget(total, self.budget, what + so_far, path=self.path,
                         line=None if node is None else _line(node))  # fmt: skip
        self.held = total

    def _declare(self, name: str | None, kind: str, var: PomdpxVariable, node: _Node) -> None:
        if not name or len(name.split()) != 1:
            raise self.error(f"<{node.tag}>: expected a variable name, got {name!r}", node)
        if name in self.kind or name == "null":
            raise self.error(f"variable name {name!r} is declared twice", node)
        self.kind[name] = kind
        self.var[name] = var
        self.lookup[name] = {v: i for i, v in enumerate(var.values)}

    def _variables(self, node: _Node) -> None:
        observed, hidden, actions, observations, rewards = [], [], [], [], []
        for child in node:
            if child.tag == "StateVar":
                prev, curr = child.attrib.get("vnamePrev"), child.attrib.get("vnameCurr")
                flag = child.attrib.get("fullyObs", "false").strip().lower()
                if flag not in ("true", "false", "1", "0"):
                    raise self.error(
                        f"<StateVar>: fullyObs must be true or false, got {flag!r}", child
                    )
                values, enumerated = self._values(child, "s")
                var = PomdpxVariable(
                    str(curr),
                    values,
                    previous=prev,
                    observed=flag in ("true", "1"),
                    enumerated=enumerated,
                )
                self._declare(prev, "prev", var, child)
                self._declare(curr, "curr", var, child)
                (observed if var.observed else hidden).append(var)
            elif child.tag in ("ObsVar", "ActionVar"):
                obs = child.tag == "ObsVar"
                values, enumerated = self._values(child, "o" if obs else "a")
                var = PomdpxVariable(str(child.attrib.get("vname")), values, enumerated=enumerated)
                self._declare(child.attrib.get("vname"), "obs" if obs else "action", var, child)
                (observations if obs else actions).append(var)
            elif child.tag == "RewardVar":
                name = child.attrib.get("vname")
                self._declare(name, "reward", PomdpxVariable(str(name), ("reward",)), child)
                rewards.append(str(name))
            else:
                what = "is not supported" if child.tag.startswith("Terminal") else "is unknown"
                raise self.error(f"<{child.tag}> in <Variable> {what}", child)
        if not observed and not hidden:
            raise self.error("<Variable> declares no <StateVar>", node)
        if not actions:
            raise self.error("<Variable> declares no <ActionVar>", node)
        if not rewards:
            raise self.error("<Variable> declares no <RewardVar>", node)
        self.variables = PomdpxVariables(
            observed=tuple(observed),
            hidden=tuple(hidden),
            actions=tuple(actions),
            observations=tuple(observations),
            rewards=tuple(rewards),
        )

    def size(self, name: str) -> int:
        return self.var[name].size

    # ------------------------------------------------------------------ functions

    def _functions(self, sections: list[_Node], kind: str) -> dict[str, _Table]:
        element = "Func" if kind == "reward" else "CondProb"
        out: dict[str, _Table] = {}
        for section in sections:
            if len(section) == 0:
                raise self.error(f"<{section.tag}> has no <{element}>", section)
            for node in section:
                if node.tag != element:
                    raise self.error(
                        f"<{section.tag}>: expected <{element}>, got <{node.tag}>", node
                    )
                table = self._table(node, kind)
                key = table.var if kind != "reward" else f"{table.var}#{len(out)}"
                if key in out:
                    raise self.error(f"a second <CondProb> for {table.var!r}", node)
                out[key] = table
        return out

    def _names(self, node: _Node, tag: str) -> list[str]:
        child = node.find(tag)
        if child is None:
            raise self.error(f"<{node.tag}> has no <{tag}>", node)
        names = _text(child).split()
        if not names:
            raise self.error(f"<{node.tag}>: empty <{tag}>", child)
        return names

    def _table(self, node: _Node, kind: str) -> _Table:
        var_names = self._names(node, "Var")
        var_node = node.find("Var")
        if len(var_names) != 1:
            raise self.error(f"<Var>: expected one variable, got {' '.join(var_names)!r}", var_node)
        var = var_names[0]
        expected = {
            "belief": ("prev", "curr"),
            "transition": ("curr",),
            "observation": ("obs",),
            "reward": ("reward",),
        }[kind]
        if self.kind.get(var) not in expected:
            what = {
                "belief": "a state variable",
                "transition": "a vnameCurr state variable",
                "observation": "an observation variable",
                "reward": "a reward variable",
            }
            got = "undeclared" if var not in self.kind else f"a {self.kind[var]} variable"
            raise self.error(f"<Var>: {var!r} is {got}, expected {what[kind]}", var_node)
        if kind == "belief":
            var = str(self.var[var].previous)
        parent_node = node.find("Parent")
        parents = self._names(node, "Parent")
        if parents == ["null"]:
            if kind != "belief":
                raise self.error(
                    "<Parent>null</Parent> is allowed in <InitialStateBelief> only", parent_node
                )
            parents = []
        allowed = {
            "belief": ("prev",),
            "transition": ("action", "prev", "curr"),
            "observation": ("action", "curr"),
            "reward": ("action", "prev", "curr", "obs"),
        }[kind]
        for p in parents:
            if p not in self.kind:
                raise self.error(f"<Parent>: {p!r} is not a declared variable", parent_node)
            if self.kind[p] not in allowed:
                raise self.error(
                    f"<Parent>: {p!r} (a {self.kind[p]} variable) cannot be a parent of {var!r}; "
                    f"allowed: {', '.join(allowed)} variables",
                    parent_node,
                )
            if kind == "transition" and self.kind[p] == "curr":
                me, other = self.var[var], self.var[p]
                if me.observed or other.observed is False:
                    raise self.error(
                        f"<Parent>: {p!r} is in the current slice; only a hidden variable may "
                        "depend on an observed variable of the current slice (APPL's MOMDP)",
                        parent_node,
                    )
        if len(set(parents)) != len(parents) or var in parents:
            raise self.error("<Parent>: a variable appears twice", parent_node)
        axes = parents if kind == "reward" else [*parents, var]
        dims = [self.size(a) for a in axes]
        entries = math.prod(dims)
        if entries > MAX_DENSE_ENTRIES:
            raise self.error(
                f"the table of {var!r} would have {entries:.3g} entries (more than "
                f"{MAX_DENSE_ENTRIES:.3g})",
                node,
            )
        self._charge(8 * entries, f"the table of {var!r} ({' x '.join(map(str, dims))}: "
                     f"{entries:.3g} cells)", node)  # fmt: skip
        param = node.find("Parameter")
        if param is None:
            raise self.error(f"<{node.tag}> has no <Parameter>", node)
        ptype = param.attrib.get("type", "TBL").strip()
        if ptype == "DD":
            raise self.error(
                'the decision-diagram parameter type="DD" is not supported; write the function '
                'as type="TBL" tables',
                param,
            )
        if ptype != "TBL":
            raise self.error(f'<Parameter type="{ptype}"> is not supported (expected TBL)', param)
        table = np.zeros(dims, dtype=np.float64)
        value_tag = "ValueTable" if kind == "reward" else "ProbTable"
        if not self._entries_batched(param, table, axes, kind, value_tag):
            for entry in param:
                if entry.tag != "Entry":
                    raise self.error(f"<Parameter>: expected <Entry>, got <{entry.tag}>", entry)
                self._entry(entry, table, axes, var, kind, value_tag)
        if kind != "reward":
            self._normalise(table, axes, var, node)
        return _Table(var=var, axes=tuple(axes), values=table, line=_line(node))

    def _entries_batched(
        self, param: Any, table: np.ndarray, axes: list[str], kind: str, value_tag: str
    ) -> bool:
        """Fill ``table`` from the ``<Entry>`` elements of ``param`` in one numpy pass.

        Each entry names a block of cells: its ``*`` and ``-`` tokens span their axes, the
        other tokens fix theirs. The cells of every entry and the index of each cell's number
        are gathered in Python (one dict lookup per token), the numbers of all entries are
        converted at once, and where entries overlap the later one wins (as the per-entry
        assignment of :meth:`_entry`). Returns False, leaving ``table`` untouched, for anything
        that path handles or reports (``identity`` / ``uniform`` tables, an unknown value, a
        wrong count, a bad number, a probability out of range, an unexpected element): the
        caller then runs :meth:`_entry` per entry, which raises the precise error.
        """
        sizes = [self.size(a) for a in axes]
        strides = [1] * len(axes)
        for k in range(len(axes) - 2, -1, -1):
            strides[k] = strides[k + 1] * sizes[k + 1]
        lookups = [self.lookup[a] for a in axes]
        patterns: dict[tuple[str, ...], tuple[np.ndarray, np.ndarray, int]] = {}
        bases: dict[tuple[str, ...], list[int]] = {}  # per pattern: base cell of each entry
        starts: dict[tuple[str, ...], list[int]] = {}  # per pattern: its first number's index
        orders: dict[tuple[str, ...], list[int]] = {}  # per pattern: the entries' ordinals
        # the numbers converted 2^16 strings at a time: a list of every number's string (5.1M
        # on a RockSample(5, 7) MOMDP written with one hidden variable) took 600 MB at once,
        # and one conversion per entry cost 3 us each (TagAvoid: 4,133 entries)
        chunks: list[np.ndarray] = []
        pending: list[str] = []
        total = 0
        for ordinal, entry in enumerate(param):
            if entry.tag != "Entry":
                return False
            inst, value = entry.find("Instance"), entry.find(value_tag)
            if inst is None or value is None:
                return False
            tokens = _text(inst).split()
            if len(tokens) != len(axes):
                return False
            base = 0
            key = []
            for tok, lookup, stride, size in zip(tokens, lookups, strides, sizes):
                if tok == "*" or tok == "-":
                    key.append(tok)
                    continue
                i = lookup.get(tok)
                if i is None:
                    if not (_is_index(tok) and int(tok) < size):
                        return False
                    i = int(tok)
                base += i * stride
                key.append("")
            pattern = tuple(key)
            if pattern not in patterns:
                patterns[pattern] = self._pattern(pattern, sizes, strides)
                bases[pattern], starts[pattern], orders[pattern] = [], [], []
            numbers = _text(value).split()
            if len(numbers) != patterns[pattern][2]:
                return False  # also "identity" and "uniform"
            pending += numbers
            if len(pending) >= _NUMBER_BLOCK:
                if not _convert(pending, chunks):
                    return False
            bases[pattern].append(base)
            starts[pattern].append(total)
            orders[pattern].append(ordinal)
            total += len(numbers)
        if not patterns:
            return True
        if not _convert(pending, chunks):
            return False
        numbers_all = np.concatenate(chunks)
        del chunks
        if not np.isfinite(numbers_all).all():
            return False
        if kind != "reward" and ((numbers_all < 0) | (numbers_all > 1 + _ROW_TOL)).any():
            return False
        cells, vals = [], []
        for pattern, (offsets, value_index, _) in patterns.items():
            b = np.asarray(bases[pattern], dtype=np.int64)[:, None]
            st = np.asarray(starts[pattern], dtype=np.int64)[:, None]
            cells.append((b + offsets[None, :]).reshape(-1))
            vals.append(numbers_all[(st + value_index[None, :]).reshape(-1)])
        del numbers_all
        cell = np.concatenate(cells)
        del cells
        val = np.concatenate(vals)
        del vals
        if np.bincount(cell, minlength=table.size).max(initial=0) <= 1:
            table.reshape(-1)[cell] = val  # no cell named twice (the usual file): no sort
            return True
        # the last entry covering a cell wins: sort by (cell, ordinal), keep each cell's last
        order = np.concatenate([
            np.repeat(np.asarray(orders[p], dtype=np.int64), patterns[p][0].size)
            for p in patterns
        ])  # fmt: skip
        idx = np.lexsort((order, cell))
        cell, val = cell[idx], val[idx]
        last = np.ones(cell.size, dtype=bool)
        last[:-1] = cell[1:] != cell[:-1]
        table.reshape(-1)[cell[last]] = val[last]
        return True

    @staticmethod
    def _pattern(
        pattern: tuple[str, ...], sizes: list[int], strides: list[int]
    ) -> tuple[np.ndarray, np.ndarray, int]:
        """For an instance whose tokens are ``pattern`` (``"*"``, ``"-"`` or ``""`` for a fixed
        value): the cell offsets it spans ``(n,)`` (row-major over its ``*``/``-`` axes), the
        index of each cell's number among the entry's numbers ``(n,)`` (row-major over the
        ``-`` axes, the same number across a ``*`` axis), and how many numbers it lists."""
        offsets = np.zeros(1, dtype=np.int64)
        value_index = np.zeros(1, dtype=np.int64)
        count = 1
        for tok, size, stride in zip(pattern, sizes, strides):
            if not tok:
                continue
            r = np.arange(size, dtype=np.int64)
            offsets = (offsets[:, None] + r[None, :] * stride).reshape(-1)
            if tok == "-":
                value_index = (value_index[:, None] * size + r[None, :]).reshape(-1)
                count *= size
            else:
                value_index = np.repeat(value_index, size)
        return offsets, value_index, count

    def _entry(
        self, entry: _Node, table: np.ndarray, axes: list[str], var: str, kind: str, value_tag: str
    ) -> None:
        inst_node = entry.find("Instance")
        if inst_node is None:
            raise self.error("<Entry> has no <Instance>", entry)
        tokens = _text(inst_node).split()
        if len(tokens) != len(axes):
            raise self.error(
                f"<Instance> {' '.join(tokens)!r} has {len(tokens)} tokens, expected "
                f"{len(axes)} ({' '.join(axes) or 'the variable'})",
                inst_node,
            )
        index: list[Any] = []
        shape: list[int] = []  # of the values, over the sliced axes
        dashes: list[int] = []
        for k, (tok, axis) in enumerate(zip(tokens, axes)):
            if tok in ("*", "-"):
                index.append(slice(None))
                shape.append(self.size(axis) if tok == "-" else 1)
                if tok == "-":
                    dashes.append(k)
            elif tok in self.lookup[axis]:
                index.append(self.lookup[axis][tok])
            elif _is_index(tok) and int(tok) < self.size(axis):
                index.append(int(tok))
            else:
                raise self.error(f"<Instance>: {tok!r} is not a value of {axis!r}", inst_node)
        value_node = entry.find(value_tag)
        if value_node is None:
            raise self.error(f"<Entry> has no <{value_tag}>", entry)
        text = _text(value_node).strip()
        keyword = text.lower()
        n = math.prod(shape) if shape else 1
        if keyword == "identity" and kind != "reward":
            if tokens[-1] != "-" or len(dashes) != 2:
                raise self.error(
                    "identity needs exactly one '-' parent and '-' for the variable, got "
                    f"<Instance> {' '.join(tokens)!r}",
                    value_node,
                )
            size = self.size(var)
            if self.size(axes[dashes[0]]) != size:
                raise self.error(
                    f"identity: {axes[dashes[0]]!r} has {self.size(axes[dashes[0]])} values, "
                    f"{var!r} has {size}",
                    value_node,
                )
            values = np.eye(size).reshape(shape)
        elif keyword == "uniform" and kind != "reward":
            if tokens[-1] == "*":
                shape[-1] = self.size(var)
            elif tokens[-1] != "-":
                raise self.error(
                    f"uniform needs '-' or '*' for the variable {var!r}, got {tokens[-1]!r}",
                    value_node,
                )
            values = np.full(shape, 1.0 / self.size(var))
        else:
            words = text.split()
            if len(words) != n:
                raise self.error(
                    f"<{value_tag}> has {len(words)} numbers, expected {n} for <Instance> "
                    f"{' '.join(tokens)!r}",
                    value_node,
                )
            try:
                values = np.array(words, dtype=np.float64).reshape(shape)
            except ValueError:
                bad = next(w for w in words if not _is_float(w))
                raise self.error(f"<{value_tag}>: {bad!r} is not a number", value_node) from None
            if not np.isfinite(values).all():
                raise self.error(f"<{value_tag}> has a non-finite number", value_node)
            if kind != "reward" and ((values < 0).any() or (values > 1 + _ROW_TOL).any()):
                bad = values[(values < 0) | (values > 1 + _ROW_TOL)].flat[0]
                raise self.error(
                    f"<{value_tag}>: probability {bad:g} is outside [0, 1]", value_node
                )
        table[tuple(index)] = values

    def _normalise(self, table: np.ndarray, axes: list[str], var: str, node: _Node) -> None:
        sums = table.sum(-1)
        bad = np.abs(sums - 1) > _ROW_TOL
        if bad.any():
            where = np.unravel_index(int(np.flatnonzero(bad)[0]), sums.shape)
            inst = " ".join(self.var[a].values[i] for a, i in zip(axes[:-1], where))
            total = float(sums[where])
            raise self.error(
                f"<CondProb> of {var!r}: the probabilities for {inst or 'the variable'!r} sum "
                f"to {total:.6g}, expected 1" + (" (no <Entry> covers them)" if total == 0 else ""),
                node,
            )
        drift = np.abs(sums - 1) > 1e-12  # renormalise drifts, keep exact rows bit for bit
        if drift.any():
            table[drift] /= sums[drift][:, None]

    def _check_coverage(self, sections: dict[str, list[_Node]]) -> None:
        names = {
            "belief": [str(v.previous) for v in self._states()],
            "transition": [v.name for v in self._states()],
            "observation": [v.name for v in self.variables.observations],
        }
        tags = {
            "belief": "InitialStateBelief",
            "transition": "StateTransitionFunction",
            "observation": "ObsFunction",
        }
        for kind, required in names.items():
            have = getattr(self, kind)
            missing = [n for n in required if n not in have]
            if missing:
                node = sections.get(tags[kind], [self.root])[0]
                raise self.error(f"<{tags[kind]}> has no <CondProb> for {missing[0]!r}", node)
        # the initial belief's parents must not form a cycle
        state = dict.fromkeys(self.belief, 0)

        def visit(name: str) -> None:
            if state[name] == 2:
                return
            if state[name] == 1:
                table = self.belief[name]
                raise ParseError(
                    f"<InitialStateBelief>: the parents of {name!r} form a cycle",
                    path=self.path,
                    line=table.line,
                )
            state[name] = 1
            for p in self.belief[name].axes[:-1]:
                visit(p)
            state[name] = 2

        for name in self.belief:
            visit(name)

    def _states(self) -> tuple[PomdpxVariable, ...]:
        return self.variables.observed + self.variables.hidden


#: number strings converted to floats at once by the batched table path (bounds the list of
#: strings held at a time)
_NUMBER_BLOCK = 1 << 16


def _convert(pending: list[str], chunks: list[np.ndarray]) -> bool:
    """Append ``pending``'s numbers to ``chunks`` as one float array and empty it; False if
    one is not a number."""
    try:
        chunks.append(np.array(pending, dtype=np.float64))
    except ValueError:
        return False
    pending.clear()
    return True


def _is_float(word: str) -> bool:
    try:
        float(word)
    except ValueError:
        return False
    return True


@dataclass
class _Table:
    """A parsed function: ``values`` over ``axes`` (parents, then the variable for a CondProb)."""

    var: str
    axes: tuple[str, ...]
    values: np.ndarray
    line: int


# ================================================================================ assembly


class _Builder:
    """Combines the tables into model tensors (dense by broadcasting, sparse by expansion)."""

    def __init__(self, r: _Reader) -> None:
        self.r = r
        v = r.variables
        self.act = [a.name for a in v.actions]
        self.xp = [str(s.previous) for s in v.observed]
        self.yp = [str(s.previous) for s in v.hidden]
        self.xc = [s.name for s in v.observed]
        self.yc = [s.name for s in v.hidden]
        self.ob = [o.name for o in v.observations]
        self.A = v.size("actions")
        self.X = v.size("observed")
        self.Y = v.size("hidden")
        self.S = self.X * self.Y
        self.O = v.size("observations")
        self.reveal = bool(self.xc)  # the flat observations carry x2 (see set_initial_x)

    def set_initial_x(self, b0: np.ndarray) -> None:
        """Decide whether the flat observations must carry the observed part ``x2``.

        They need not when ``x`` is a function of the actions taken: the initial belief is on
        one ``x`` and every observed variable moves deterministically, depending only on the
        action and observed variables (RockSample's robot). Seeing ``x2`` then adds nothing,
        and the flat model keeps ``O`` observations instead of ``X * O`` (RockSample(11, 11):
        a dense ``Z`` of 8e6 instead of 9.8e8 entries).
        """
        if not self.xc:
            return
        one_x = self._first_xs(b0) == 1
        observed_prev = set(self.xp)
        deterministic = all(
            all(a in self.act or a in observed_prev for a in t.axes[:-1])
            and bool((np.count_nonzero(t.values, axis=-1) == 1).all())
            for t in (self.r.transition[n] for n in self.xc)
        )
        self.reveal = not (one_x and deterministic)

    @property
    def flat_observations(self) -> int:
        return self.O * (self.X if self.reveal else 1)

    def size(self, name: str) -> int:
        return self.r.size(name)

    def place(self, table: _Table, layout: list[str]) -> np.ndarray:
        """``table.values`` transposed and reshaped to broadcast against ``layout``."""
        axes = list(table.axes)
        perm = sorted(range(len(axes)), key=lambda i: layout.index(axes[i]))
        values = table.values.transpose(perm)
        return values.reshape([self.size(n) if n in axes else 1 for n in layout])

    def product(self, tables: list[_Table], layout: list[str], expand: bool = True) -> np.ndarray:
        """The product of ``tables`` over the full ``layout`` (dense), multiplied at the
        tables' broadcast shape; ``expand=False`` returns it at that shape (size 1 on the
        variables no table names, one dim per variable of ``layout``)."""
        shape = [self.size(n) for n in layout]
        out = None
        for t in tables:
            value = self.place(t, layout)
            out = value if out is None else out * value
        if out is None:
            return np.ones(shape if expand else [1] * len(layout))
        return np.array(np.broadcast_to(out, shape), dtype=np.float64) if expand else out

    def _grouped(self, table: np.ndarray, groups: list[list[str]]) -> np.ndarray | None:
        """``table`` (one dim per variable of the concatenated ``groups``, at its broadcast
        shape) with each group's variables merged into one dim, of size 1 where no variable
        of the group is named; None when a group is named only in part (it cannot stay
        broadcast once merged)."""
        dims, i = [], 0
        for group in groups:
            part = table.shape[i : i + len(group)]
            i += len(group)
            if all(n == 1 for n in part):
                dims.append(1)
            elif list(part) == [self.size(n) for n in group]:
                dims.append(int(np.prod(part)))
            else:
                return None
        return table.reshape(dims)

    # ------------------------------------------------------------------ pieces

    def initial_belief(self) -> np.ndarray:
        """``(S,)`` the joint initial belief over ``(x, y)``."""
        return self.product(list(self.r.belief.values()), self.xp + self.yp).reshape(-1)

    def expected_reward(self, transitions: Any = None) -> np.ndarray:
        """``(A, S)``: ``R[a, s]``, expected over ``s2`` and ``o`` where a reward needs them."""
        layout = self.act + self.xp + self.yp
        R = np.zeros([self.size(n) for n in layout])
        later = []
        for t in self.r.rewards.values():
            if all(self.r.kind[a] in ("action", "prev") for a in t.axes):
                R = R + self.place(t, layout)
            else:
                later.append(t)
        R = R.reshape(self.A, self.S)
        if later:
            rows, _, p, value = transitions if transitions is not None else self.transitions()
            flat = R.reshape(-1)
            for t in later:
                flat += np.bincount(
                    rows, weights=p * self._reward_given_next(t, value), minlength=flat.size
                )
        return R

    def _reward_given_next(self, t: _Table, value: Any) -> np.ndarray:
        """``(M,)`` the reward of ``t`` per transition entry, expected over observations;
        ``value(name)`` gives a variable's value per entry."""
        obs = [a for a in t.axes if self.r.kind[a] == "obs"]
        if not obs:
            return t.values[tuple(value(a) for a in t.axes)]
        out = None
        for combo in itertools.product(*(range(self.size(o)) for o in obs)):
            given = dict(zip(obs, combo))
            weight = t.values[tuple(given[a] if a in given else value(a) for a in t.axes)]
            for o in obs:
                cpt = self.r.observation[o]
                weight = (
                    weight
                    * cpt.values[tuple(given[a] if a in given else value(a) for a in cpt.axes)]
                )
            out = weight if out is None else out + weight
        return out

    def _expand(
        self, layout: list[str], tables: list[_Table]
    ) -> tuple[np.ndarray, dict[str, np.ndarray], np.ndarray, Any]:
        """Start from every row ``0 .. prod(layout sizes) - 1`` (row-major over ``layout``) and
        expand each over the nonzero values of every table's variable, in order.

        A table is read as CSR over its parent configurations, so a row costs its number of
        nonzero successors, never the variable's size. Returns the row of every entry, the
        expanded variables' values, the probabilities and ``value(name)``, any variable's
        value per entry (a layout variable is decoded from the row).
        """
        sizes = {n: self.size(n) for n in layout}
        strides = {}
        stride = 1
        for n in reversed(layout):
            strides[n] = stride
            stride *= sizes[n]
        grid_shape = [sizes[n] for n in layout]
        rows = np.arange(stride, dtype=np.int64)
        new: dict[str, np.ndarray] = {}
        grid = True  # rows is still the full grid (no row was dropped or repeated)

        def value(name: str) -> np.ndarray:
            if name in new:
                return new[name]
            return (rows // strides[name]) % sizes[name]

        p = np.ones(len(rows))
        for t in tables:
            n = t.values.shape[-1]
            config_strides = {}
            c = 1
            for a in reversed(t.axes[:-1]):
                config_strides[a] = c
                c *= self.size(a)
            on_grid = [a for a in t.axes[:-1] if a not in new]
            if grid and on_grid:  # broadcast a small table of the layout parents' configs
                acc = np.zeros([1] * len(layout), dtype=np.int64)
                for a in on_grid:
                    shape = [1] * len(layout)
                    shape[layout.index(a)] = sizes[a]
                    acc = acc + (np.arange(sizes[a]) * config_strides[a]).reshape(shape)
                config = np.broadcast_to(acc, grid_shape).reshape(-1)
            else:
                config = np.zeros(len(rows), dtype=np.int64)
                for a in on_grid:
                    config = config + value(a) * config_strides[a]
            for a in t.axes[:-1]:
                if a in new:
                    config = config + new[a] * config_strides[a]
            flat = t.values.reshape(-1, n)
            nz_rows, nz_cols = np.nonzero(flat)
            indptr = np.zeros(flat.shape[0] + 1, dtype=np.int64)
            np.cumsum(np.bincount(nz_rows, minlength=flat.shape[0]), out=indptr[1:])
            start = indptr[config]
            count = indptr[config + 1] - start
            del config
            if (count == 1).all():  # one successor per row: no re-indexing
                pos = start
            else:
                grid = False
                keep = np.repeat(np.arange(len(rows)), count)
                pos = start[keep] + (
                    np.arange(len(keep)) - np.repeat(np.cumsum(count) - count, count)
                )
                rows = rows[keep]
                new = {name: v[keep] for name, v in new.items()}
                p = p[keep]
            new[t.var] = nz_cols[pos]
            p = p * flat[nz_rows[pos], nz_cols[pos]]
        return rows, new, p, value

    def transitions(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, Any]:
        """Nonzeros of ``T``: rows ``a * S + s``, next states ``s2``, probabilities, and
        ``value(name)`` per entry."""
        tables = [self.r.transition[n] for n in self.xc + self.yc]
        rows, new, p, value = self._expand(self.act + self.xp + self.yp, tables)
        s2 = np.zeros(len(rows), dtype=np.int64)
        for n in self.xc + self.yc:
            s2 = s2 * self.size(n) + new[n]
        return rows, s2, p, value

    def observations(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Nonzeros of the flat ``Z``: rows ``a * S + s2``, flat observations, probabilities."""
        tables = [self.r.observation[n] for n in self.ob]
        rows, new, p, _ = self._expand(self.act + self.xc + self.yc, tables)
        o = np.zeros(len(rows), dtype=np.int64)
        for n in self.ob:
            o = o * self.size(n) + new[n]
        if self.reveal:  # the observed part of the next state is seen: o_flat = x2 * O + o
            o = (rows % self.S) // self.Y * self.O + o
        return rows, o, p

    # ------------------------------------------------------------------ memory

    def _entries(self, tables: list[_Table]) -> float:
        """The nonzeros an expansion over ``tables`` from every ``(a, s)`` row makes, estimated
        as ``A S`` times each table's mean nonzeros per row (exact for tables whose rows have
        the same count, as a model's usually have)."""
        n = float(self.A * self.S)
        for t in tables:
            k = t.values.shape[-1]
            n *= np.count_nonzero(t.values) / max(t.values.size // max(k, 1), 1)
        return n

    def form_bytes(self, form: str, static: bool = True) -> tuple[float, str]:
        """Estimated peak bytes of building ``form`` (``"momdp"``, ``"sparse_momdp"``,
        ``"dense"`` or ``"sparse"``) from the tables, and what they hold (for a message).

        Dense tensors at 10 bytes a cell (measured: a dense ``Ty`` of 6.2e7 cells peaked at
        1.1 times its 8 bytes a cell), expansions at :data:`_ENTRY_BYTES` a nonzero, the
        rewards and the initial belief, and the made-up state names of the sparse form."""
        A, S = self.A, self.S
        t_tables = [self.r.transition[n] for n in self.xc + self.yc]
        z_tables = [self.r.observation[n] for n in self.ob]
        n_t = self._entries(t_tables) * len(t_tables)
        n_z = self._entries(z_tables) * len(z_tables)
        small = 8.0 * (A * S + S)
        if form == "momdp":
            tx, ty, z, _ = self.momdp_sizes()
            cells = tx + ty + z
            return 10.0 * cells + small, f"the dense Tx, Ty and Z ({cells:.3g} cells)"
        if form == "sparse_momdp":
            z = A * S * self.O
            return (_ENTRY_BYTES * n_t + 10.0 * z + small,
                    f"the transitions' nonzeros (about {n_t:.3g}) and the dense Z ({z:.3g} "
                    "cells)")  # fmt: skip
        if form == "dense":
            cells = A * S * S + A * S * self.flat_observations
            return (10.0 * cells + _ENTRY_BYTES * (n_t + n_z) + small,
                    f"the dense T (A={A}, S={S}, S) and Z ({cells:.3g} cells)")  # fmt: skip
        names = 64 * S  # (a str and its pointer)
        return (_ENTRY_BYTES * (n_t + n_z) + small + names,
                f"the nonzeros of T and Z (about {n_t + n_z:.3g}) and the names of "
                f"{S} states")  # fmt: skip

    # ------------------------------------------------------------------ forms

    def momdp_sizes(self) -> tuple[int, int, int, bool]:
        """``(Tx, Ty, Z)`` entries and whether every hidden variable keeps its value."""
        static = all(self._keeps_value(self.r.transition[n]) for n in self.yc)
        ty = 0 if static else self.A * self.X * self.Y * self.X * self.Y
        return self.A * self.X * self.Y * self.X, ty, self.A * self.S * self.O, static

    def _keeps_value(self, t: _Table) -> bool:
        prev = str(self.r.var[t.var].previous)
        if prev not in t.axes:
            return False
        k = t.axes.index(prev)
        n = self.size(t.var)
        shape = [1] * len(t.axes)
        shape[k] = shape[-1] = n
        eye = np.eye(n).reshape(shape)
        return bool((t.values == eye).all())

    def momdp(
        self, b0: np.ndarray, static: bool, dtype: torch.dtype, device: torch.device | str | None
    ) -> MOMDP:
        A, X, Y = self.A, self.X, self.Y
        layout = self.act + self.xp + self.yp + self.xc
        Tx = self.product([self.r.transition[n] for n in self.xc], layout).reshape(A, X, Y, X)
        t = _tensor_factory(dtype, device)
        Ty = None
        if not static:
            # kept at its tables' shape and expanded as a view: APPL's TagAvoid gives the
            # target's move without the robot's next cell, and a dense Ty would be 30 MB
            groups = [self.act, self.xp, self.yp, self.xc, self.yc]
            layout = [n for group in groups for n in group]
            tables = [self.r.transition[n] for n in self.yc]
            compact = self._grouped(self.product(tables, layout, expand=False), groups)
            if compact is None:
                Ty = t(self.product(tables, layout).reshape(A, X, Y, X, Y))
            else:
                Ty = t(compact).expand(A, X, Y, X, Y)
        R = self.expected_reward().reshape(A, X, Y)
        Z, x0, hidden, names = self._momdp_parts(b0)
        return MOMDP(
            Tx=t(Tx),
            Ty=Ty,
            Z=t(Z),
            R=t(R),
            x0=x0,
            b0=t(hidden),
            discount=self.r.discount,
            initial=self._initial(b0, t),
            **names,
        )

    def _initial(self, b0: np.ndarray, t: Any) -> torch.Tensor | None:
        """The joint ``(X, Y)`` initial belief as a tensor when it spreads over several
        ``x`` (a random start, :attr:`~torchhrc.pomdp.MOMDP.initial`), else None."""
        return t(b0.reshape(self.X, self.Y)) if self._first_xs(b0) > 1 else None

    def _first_xs(self, b0: np.ndarray) -> int:
        """How many observed values the joint initial belief ``b0 (S,)`` gives mass."""
        return int(np.count_nonzero(b0.reshape(self.X, self.Y).sum(-1) > 0))

    def _momdp_parts(
        self, b0: np.ndarray
    ) -> tuple[np.ndarray, int, np.ndarray, dict[str, tuple[str, ...]]]:
        """What the dense and sparse MOMDP share: ``Z (A, X, Y, O)``, ``x0`` (the observed
        value with the most initial mass), the hidden belief there ``(Y,)``, and the names."""
        layout = self.act + self.xc + self.yc + self.ob
        Z = self.product([self.r.observation[n] for n in self.ob], layout)
        b = b0.reshape(self.X, self.Y)
        x0 = int(b.sum(-1).argmax())
        hidden = b[x0] if abs(b[x0].sum() - 1) <= 1e-12 else b[x0] / b[x0].sum()
        v = self.r.variables
        names = {
            "observed_states": _group_names(v.observed),
            "hidden_states": _group_names(v.hidden),
            "actions": _group_names(v.actions),
            "observations": _group_names(v.observations),
        }
        return Z.reshape(self.A, self.X, self.Y, self.O), x0, hidden, names

    def sparse_momdp(self, b0: np.ndarray, dtype: torch.dtype) -> SparseMOMDP:
        """The MOMDP with ``Tx Ty`` as its nonzeros (expanded as the flat sparse ``T``), ``Z``
        and ``R`` dense (CPU)."""
        A, X, Y, S = self.A, self.X, self.Y, self.S
        rows, s2, p, value = self.transitions()
        R = self.expected_reward((rows, s2, p, value)).reshape(A, X, Y)
        s = rows % S
        index = np.stack([rows // S, s // Y, s % Y, s2 // Y, s2 % Y], axis=1)
        t = _tensor_factory(dtype, "cpu")
        Z, x0, hidden, names = self._momdp_parts(b0)
        return SparseMOMDP(
            transitions=(torch.from_numpy(index), torch.from_numpy(p)),
            Z=t(Z),
            R=t(R),
            x0=x0,
            b0=t(hidden),
            discount=self.r.discount,
            initial=self._initial(b0, t),
            **names,
        )

    def flat(
        self, b0: np.ndarray, sparse: bool, dtype: torch.dtype, device: torch.device | str | None
    ) -> POMDP | SparsePOMDP:
        A, S = self.A, self.S
        O_flat = self.flat_observations
        rows, s2, p, value = self.transitions()
        R = self.expected_reward((rows, s2, p, value))
        z_rows, z_o, z_p = self.observations()
        v = self.r.variables
        states, observations = _flat_names(v, sparse, self.reveal)
        actions = _group_names(v.actions)
        if sparse:

            def coo(
                r: np.ndarray, c: np.ndarray, q: np.ndarray
            ) -> tuple[torch.Tensor, torch.Tensor]:
                index = np.stack([r // S, r % S, c], axis=1)
                return torch.from_numpy(index), torch.from_numpy(q)

            return SparsePOMDP(
                transitions=coo(rows, s2, p),
                observations_=coo(z_rows, z_o, z_p),
                R=torch.from_numpy(R).to(dtype),
                b0=torch.from_numpy(b0).to(dtype),
                discount=self.r.discount,
                states=states,  # type: ignore[arg-type]
                actions=actions or tuple(str(i) for i in range(A)),
                observations=observations,  # type: ignore[arg-type]
            )
        T = np.bincount(rows * S + s2, weights=p, minlength=A * S * S)
        Z = np.bincount(z_rows * O_flat + z_o, weights=z_p, minlength=A * S * O_flat)
        t = _tensor_factory(dtype, device)
        return POMDP(
            T=t(T.reshape(A, S, S)),
            Z=t(Z.reshape(A, S, O_flat)),
            R=t(R),
            b0=t(b0),
            discount=self.r.discount,
            states=states,
            actions=actions,
            observations=observations,
        )


def _tensor_factory(dtype: torch.dtype, device: torch.device | str | None):  # type: ignore[no-untyped-def]
    def make(a: np.ndarray) -> torch.Tensor:
        return torch.from_numpy(np.ascontiguousarray(a)).to(dtype=dtype, device=device)

    return make


def _joined(variables: Sequence[PomdpxVariable]) -> list[str]:
    if len(variables) == 1:
        return list(variables[0].values)
    return [",".join(t) for t in itertools.product(*(v.values for v in variables))]


def _group_names(variables: Sequence[PomdpxVariable]) -> tuple[str, ...] | None:
    """Combined value names, ``None`` when the group is empty or all its sizes were counts."""
    if not variables or not any(v.enumerated for v in variables):
        return None
    names = tuple(_joined(variables))
    return names if len(set(names)) == len(names) else None


def _flat_names(v: PomdpxVariables, required: bool, reveal: bool) -> tuple[Any, Any]:
    """Flat state names ``"x|y"`` (or one part) and observation names ``"x|o"`` (or ``o``);
    indices as strings when ``required`` (a sparse model) and the names are not distinct."""
    states = observations = None
    if required or any(s.enumerated for s in v.observed + v.hidden):
        if v.observed and v.hidden:
            ys = _joined(v.hidden)
            states = tuple(f"{x}|{y}" for x in _joined(v.observed) for y in ys)
        else:
            states = tuple(_joined(v.observed + v.hidden))
    obs = _joined(v.observations) if v.observations else ["o0"]
    if required or any(o.enumerated for o in v.observations):
        if reveal:
            observations = tuple(f"{x}|{o}" for x in _joined(v.observed) for o in obs)
        else:
            observations = tuple(obs)
    out = []
    for names in (states, observations):
        if names is not None and len(set(names)) != len(names):
            names = tuple(str(i) for i in range(len(names))) if required else None
        out.append(names)
    return out[0], out[1]


def _read_source(source: str | os.PathLike[str]) -> tuple[bytes | str, str]:
    if isinstance(source, os.PathLike) or (isinstance(source, str) and "<" not in source):
        path = os.fspath(source)
        try:
            with open(path, "rb") as f:
                return f.read(), path
        except OSError as e:
            raise ParseError(f"cannot read file: {e.strerror}", path=path) from None
    if not isinstance(source, str):
        raise TypeError(f"expected a path or the file's text, got {type(source).__name__}")
    return source, "<string>"


def read_pomdpx_variables(source: str | os.PathLike[str]) -> PomdpxVariables:
    """The variables of a ``.pomdpx`` file (a path or the XML text), grouped as
    :func:`read_pomdpx` combines them (see :class:`PomdpxVariables`).

    Example:
        >>> from torchhrc.testing import random_momdp
        >>> v = read_pomdpx_variables(format_pomdpx(random_momdp(2, 3, 2, 2, seed=0)))
        >>> [x.name for x in v.observed], [y.name for y in v.hidden], v.size("hidden")
        (['x_1'], ['y_1'], 3)
    """
    data, path = _read_source(source)

    def variables(root: Any) -> PomdpxVariables:
        reader = _Reader(root, path)
        if root.tag != "pomdpx":
            raise reader.error(f"expected the root element <pomdpx>, got <{root.tag}>", root)
        node = root.find("Variable")
        if node is None:
            raise reader.error("<pomdpx> has no <Variable>", root)
        reader._variables(node)
        return reader.variables

    root = _parse_xml_fast(data)
    if root is not None:
        try:
            return variables(root)
        except ParseError:
            pass
    return variables(_parse_xml(data, path))  # errors with their line


def read_pomdpx(
    source: str | os.PathLike[str],
    *,
    sparse: bool | Literal["auto"] = "auto",
    momdp: bool = True,
    dtype: torch.dtype = torch.float64,
    device: torch.device | str | None = None,
    memory_budget: float | None = None,
) -> POMDP | MOMDP | SparseMOMDP | SparsePOMDP:
    """Read a ``.pomdpx`` file (a path, or the XML text itself); see the module docstring.

    Args:
        source: a path (``str`` without ``<``, or ``os.PathLike``) or the XML text.
        sparse: ``True``: a flat :class:`~torchhrc.sparse.SparsePOMDP`; ``False``: a dense
            model (:class:`ParseError` when a tensor would exceed
            :data:`~torchhrc.sparse.MAX_DENSE_ENTRIES`, 2e8 entries); ``"auto"``: dense when
            every dense tensor is within :data:`AUTO_SPARSE_ENTRIES` (by default the same
            2e8) and a MOMDP's ``Tx`` and ``Ty`` within :data:`AUTO_SPARSE_MOMDP_ENTRIES`
            (1e7), else sparse (a MOMDP's transitions as a
            :class:`~torchhrc.sparse_momdp.SparseMOMDP` when its ``Z`` fits).
        momdp: return a :class:`~torchhrc.pomdp.MOMDP` when the file has an observed
            (``fullyObs="true"``) state variable and the dense ``Tx``, ``Ty`` (unless
            static) and ``Z`` fit, a :class:`~torchhrc.sparse_momdp.SparseMOMDP` when only
            ``Z`` fits (either with :attr:`~torchhrc.pomdp.MOMDP.initial` when the initial
            belief spreads over several observed values); ``False``: always flat.
        dtype, device: of the returned tensors (a sparse model stays on the CPU).
        memory_budget: bytes the read may take (default ``None``: the machine's available
            memory, ``MemAvailable``; ``math.inf``: no limit). Checked before each
            allocation of the model's size: the XML elements (about 20 bytes a byte of the
            file) before parsing, each ``<NumValues>``'s names and each table as it is
            declared, the chosen form's tensors (dense at 10 bytes a cell, nonzeros of the
            sparse forms as estimated from the tables) before it is built; ``"auto"``
            picks a sparse form when the dense one would not fit.

    Returns:
        :class:`~torchhrc.pomdp.MOMDP`, :class:`~torchhrc.sparse_momdp.SparseMOMDP`,
        :class:`~torchhrc.pomdp.POMDP` or :class:`~torchhrc.sparse.SparsePOMDP`.

    Raises:
        ParseError: the file is malformed, a table is inconsistent (wrong number of values, a
            row not summing to 1, an unknown value), the DBN is not one APPL solves, the
            model is too large for ``sparse=False`` (file, line, element and reason), or it
            would take more than ``memory_budget`` (the message gives the cells, the bytes
            and the budget).

    Example:
        >>> from torchhrc.testing import random_momdp
        >>> m = read_pomdpx(format_pomdpx(random_momdp(2, 3, 2, 2, seed=0)))
        >>> type(m).__name__, m.num_observed, m.num_hidden
        ('MOMDP', 2, 3)
    """
    budget = resolve_budget(memory_budget)
    data, path = _read_source(source)
    return parse_pomdpx(data, path=path, sparse=sparse, momdp=momdp, dtype=dtype, device=device,
                        memory_budget=budget)  # fmt: skip


def parse_pomdpx(
    text: str | bytes,
    *,
    path: str = "<string>",
    sparse: bool | Literal["auto"] = "auto",
    momdp: bool = True,
    dtype: torch.dtype = torch.float64,
    device: torch.device | str | None = None,
    memory_budget: float | None = None,
) -> POMDP | MOMDP | SparseMOMDP | SparsePOMDP:
    """Parse the text of a ``.pomdpx`` file (``path`` is used in error messages only); see
    :func:`read_pomdpx`.

    Example:
        >>> from torchhrc.testing import random_pomdp
        >>> parse_pomdpx(format_pomdpx(random_pomdp(3, 2, 2, seed=0))).num_states
        3
    """
    if sparse not in (True, False, "auto"):
        raise ValueError(f"expected sparse to be True, False or 'auto', got {sparse!r}")
    budget = resolve_budget(memory_budget)
    check_budget(_XML_BYTES * len(text), budget, f"the XML elements of {len(text)} bytes of "
                 "text", path=path)  # fmt: skip
    # ElementTree's C builder first (no line numbers); a file it cannot read or that turns out
    # malformed is read again through the expat tree, whose errors carry the line
    with gc_paused():  # the elements are many, freed by reference counting (see _gc)
        root = _parse_xml_fast(text)
        if root is not None:
            try:
                return _parse_tree(root, path, sparse, momdp, dtype, device, budget)
            except ParseError:
                pass
        return _parse_tree(_parse_xml(text, path), path, sparse, momdp, dtype, device, budget)


def _parse_tree(
    root: Any,
    path: str,
    sparse: bool | Literal["auto"],
    momdp: bool,
    dtype: torch.dtype,
    device: torch.device | str | None,
    budget: float = math.inf,
) -> POMDP | MOMDP | SparseMOMDP | SparsePOMDP:
    reader = _Reader(root, path, budget)
    reader.read()
    b = _Builder(reader)
    b0 = b.initial_belief()
    limit = AUTO_SPARSE_ENTRIES if sparse == "auto" else MAX_DENSE_ENTRIES

    def fits(form: str) -> bool:
        return reader.held + b.form_bytes(form)[0] <= budget

    def check(form: str) -> None:  # the form's estimate with the tables held, or refused
        need, what = b.form_bytes(form)
        if reader.held + need > budget:
            check_budget(reader.held + need, budget, f"{what}, with the tables read "
                         f"({reader.held:.3g} bytes),", path=path)  # fmt: skip

    if momdp and sparse is not True and b.xc:
        tx, ty, z, static = b.momdp_sizes()
        dense_limit = min(AUTO_SPARSE_MOMDP_ENTRIES, limit) if sparse == "auto" else limit
        if max(tx, ty) <= dense_limit and z <= limit and (sparse is False or fits("momdp")):
            check("momdp")  # a random first x gives `initial`
            return _wrap(lambda: b.momdp(b0, static, dtype, device), path)
        if z <= limit and sparse == "auto":  # Tx Ty kept as its nonzeros
            check("sparse_momdp")
            return _wrap(lambda: b.sparse_momdp(b0, dtype), path)
    b.set_initial_x(b0)
    dense = max(b.A * b.S * b.S, b.A * b.S * b.flat_observations)
    if sparse is False and dense > MAX_DENSE_ENTRIES:
        raise ParseError(
            f"the dense T (A={b.A}, S={b.S}, S) would have {b.A * b.S * b.S:.3g} entries "
            f"(more than {MAX_DENSE_ENTRIES:.3g}); read it with sparse=True or 'auto'",
            path=path,
        )
    use_sparse = sparse is True or (sparse == "auto" and (dense > limit or not fits("dense")))
    check("sparse" if use_sparse else "dense")
    return _wrap(lambda: b.flat(b0, use_sparse, dtype, device), path)


def _wrap(build: Any, path: str) -> Any:
    try:
        return build()
    except ModelError as e:  # the tables were checked; this is a safety net
        raise ParseError(f"the model is invalid: {e}", path=path) from None


# ================================================================================ writer


def _values(t: torch.Tensor) -> str:
    flat = t.detach().double().cpu().numpy().reshape(-1)
    return " ".join("0" if v == 0 else "1" if v == 1 else repr(float(v)) for v in flat)


def _escape(text: str) -> str:
    return text.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")


def _enum(names: tuple[str, ...] | None, count: int) -> str:
    if names is not None and all(n.isidentifier() for n in names):
        return f"<ValueEnum>{' '.join(names)}</ValueEnum>"
    return f"<NumValues>{count}</NumValues>"


def _cond_prob(var: str, parents: str, instance: str, table: str) -> str:
    return (
        f'<CondProb><Var>{var}</Var><Parent>{parents}</Parent><Parameter type="TBL">'
        f"<Entry><Instance>{instance}</Instance><ProbTable>{table}</ProbTable></Entry>"
        "</Parameter></CondProb>"
    )


def _header(discount: float, description: str) -> list[str]:
    return [
        '<?xml version="1.0" encoding="ISO-8859-1"?>',
        '<pomdpx version="1.0" id="torchhrc" '
        'xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance" '
        'xsi:noNamespaceSchemaLocation="pomdpx.xsd">',
        f"<Description>{_escape(description)}</Description>",
        f"<Discount>{discount!r}</Discount>",
    ]


def _reward(parents: str, instance: str, R: torch.Tensor) -> list[str]:
    return [
        "<RewardFunction>",
        f'<Func><Var>reward</Var><Parent>{parents}</Parent><Parameter type="TBL">'
        f"<Entry><Instance>{instance}</Instance><ValueTable>{_values(R)}</ValueTable></Entry>"
        "</Parameter></Func>",
        "</RewardFunction>",
        "</pomdpx>",
    ]


def _format_pomdp(model: POMDP, description: str) -> str:
    A, S, O = model.num_actions, model.num_states, model.num_observations
    lines = [
        *_header(model.discount, description),
        "<Variable>",
        '<StateVar vnamePrev="state_0" vnameCurr="state_1" fullyObs="false">'
        f"{_enum(model.states, S)}</StateVar>",
        f'<ObsVar vname="obs">{_enum(model.observations, O)}</ObsVar>',
        f'<ActionVar vname="action">{_enum(model.actions, A)}</ActionVar>',
        '<RewardVar vname="reward"/>',
        "</Variable>",
        "<InitialStateBelief>",
        _cond_prob("state_0", "null", "-", _values(model.b0)),
        "</InitialStateBelief>",
        "<StateTransitionFunction>",
        _cond_prob("state_1", "action state_0", "- - -", _values(model.T)),
        "</StateTransitionFunction>",
        "<ObsFunction>",
        _cond_prob("obs", "action state_1", "- - -", _values(model.Z)),
        "</ObsFunction>",
    ]
    return "\n".join(lines + _reward("action state_0", "- -", model.R.expand(A, S))) + "\n"


def format_pomdpx(model: MOMDP | POMDP, *, description: str = "written by torchhrc") -> str:
    """The ``.pomdpx`` text of an unbatched :class:`MOMDP` or :class:`POMDP`.

    Args:
        model: the MOMDP (observed ``x_0/x_1`` and hidden ``y_0/y_1``) or flat POMDP (one
            hidden ``state_0/state_1``), no batch dims.
        description: the ``<Description>`` text.

    Returns:
        The XML text.

    Raises:
        ModelError: the model has batch dims.

    Example:
        >>> from torchhrc.testing import random_momdp
        >>> format_pomdpx(random_momdp(2, 2, 1, 1, seed=0)).count("<CondProb>")
        5
    """
    if not isinstance(model, (MOMDP, POMDP)):
        raise TypeError(f"expected a MOMDP or POMDP, got {type(model).__name__}")
    if len(model.batch_shape):
        raise ModelError(f"write one problem at a time: got batch shape {tuple(model.batch_shape)}")
    if isinstance(model, POMDP):
        return _format_pomdp(model, description)
    A, X, Y, O = model.num_actions, model.num_observed, model.num_hidden, model.num_observations
    mass = torch.zeros(X, dtype=torch.float64)  # P(x)
    mass[model.x0] = 1.0
    hidden = _cond_prob("y_0", "null", "-", _values(model.b0))
    if model.initial is not None:  # a random start: P(x), and P(y | x) (uniform at no mass)
        mass, given = split_initial(model.initial.double())
        given = torch.where(mass[:, None] > 0, given, 1.0 / Y)
        hidden = _cond_prob("y_0", "x_0", "- -", _values(given))
    lines = [
        *_header(model.discount, description),
        "<Variable>",
        '<StateVar vnamePrev="x_0" vnameCurr="x_1" fullyObs="true">'
        f"{_enum(model.observed_states, X)}</StateVar>",
        '<StateVar vnamePrev="y_0" vnameCurr="y_1" fullyObs="false">'
        f"{_enum(model.hidden_states, Y)}</StateVar>",
        f'<ObsVar vname="obs">{_enum(model.observations, O)}</ObsVar>',
        f'<ActionVar vname="action">{_enum(model.actions, A)}</ActionVar>',
        '<RewardVar vname="reward"/>',
        "</Variable>",
        "<InitialStateBelief>",
        _cond_prob("x_0", "null", "-", _values(mass)),
        hidden,
        "</InitialStateBelief>",
        "<StateTransitionFunction>",
        _cond_prob("x_1", "action x_0 y_0", "- - - -", _values(model.Tx)),
    ]
    if model.Ty is None:
        lines.append(_cond_prob("y_1", "y_0", "- -", "identity"))
    else:
        Ty = model.Ty
        # Does Ty depend on x_1 where x_1 is reachable (Tx > 0)? If not, drop that parent.
        reachable = model.Tx > 0  # (A, X, Y, X2)
        pick = reachable.double().argmax(-1)  # a reachable x2 per (a, x, y)
        rows = Ty.gather(-2, pick[..., None, None].expand(A, X, Y, 1, Y))  # (A, X, Y, 1, Y)
        same = (Ty == rows).all(-1) | ~reachable
        if bool(same.all()):
            lines.append(_cond_prob("y_1", "action x_0 y_0", "- - - -", _values(rows[..., 0, :])))
        else:
            lines.append(_cond_prob("y_1", "action x_0 y_0 x_1", "- - - - -", _values(Ty)))
    lines += [
        "</StateTransitionFunction>",
        "<ObsFunction>",
        _cond_prob("obs", "action x_1 y_1", "- - - -", _values(model.Z)),
        "</ObsFunction>",
    ]
    return "\n".join(lines + _reward("action x_0 y_0", "- - -", model.R)) + "\n"


def write_pomdpx(
    model: MOMDP | POMDP, path: str | os.PathLike[str], *, description: str = "written by torchhrc"
) -> Path:
    """Write ``model`` as ``.pomdpx`` XML, atomically. See :func:`format_pomdpx`.

    Example:
        >>> import os, tempfile
        >>> from torchhrc.testing import random_momdp
        >>> path = os.path.join(tempfile.mkdtemp(), "m.pomdpx")
        >>> write_pomdpx(random_momdp(2, 2, 1, 1, seed=0), path).suffix
        '.pomdpx'
    """
    text = format_pomdpx(model, description=description)
    return atomic_write_bytes(path, text.encode("iso-8859-1", errors="xmlcharrefreplace"))
