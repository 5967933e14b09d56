"""Reading a ``.pomdpx`` element tree into its variables and tables: the
``_Reader`` (the document's elements, names, instances, ``<ProbTable>`` and
``<ValueTable>`` numbers, checked) and the ``_Table`` it yields per function."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from torchhrc.errors import ParseError
from torchhrc.io._budget import check_budget
from torchhrc.io.pomdpx.variables import PomdpxVariable, PomdpxVariables
from torchhrc.io.pomdpx.xml_tree import _line, _Node, _text
from torchhrc.pomdp.sparse import MAX_DENSE_ENTRIES

__all__: list[str] = []  # private parts; the public names are the package's

_ROW_TOL = 1e-4  # rows of a CondProb must sum to 1 within this (then renormalised exactly)

#: Bytes of a value named by ``<NumValues>``: its made-up name and the reader's lookup entry
#: (measured: 146 bytes a value for 3 million).
_NAME_BYTES = 160


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
        coordinates = entries > MAX_DENSE_ENTRIES and kind in ("transition", "observation")
        if entries > MAX_DENSE_ENTRIES and not coordinates:
            raise self.error(
                f"the table of {var!r} would have {entries:.3g} entries (more than "
                f"{MAX_DENSE_ENTRIES:.3g})",
                node,
            )
        if not coordinates:
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
        value_tag = "ValueTable" if kind == "reward" else "ProbTable"
        if coordinates:
            return self._coordinate_table(node, param, axes, var, value_tag)
        table = np.zeros(dims, dtype=np.float64)
        if not self._entries_batched(param, table, axes, kind, value_tag):
            for entry in param:
                if entry.tag != "Entry":
                    raise self.error(f"<Parameter>: expected <Entry>, got <{entry.tag}>", entry)
                self._entry(entry, table, axes, var, kind, value_tag)
        if kind != "reward":
            self._normalise(table, axes, var, node)
        return _Table(var=var, axes=tuple(axes), values=table, line=_line(node))

    def _coordinate_table(self, node: _Node, param: _Node, axes: list[str], var: str,
                          value_tag: str) -> _Table:  # fmt: skip
        """A CondProb too large to hold densely (a flat model of many states, as
        :func:`~torchhrc.io.pomdpx.write_pomdpx` writes a SparsePOMDP), read as its nonzeros:
        every ``<Entry>`` must name one value of each variable and give one probability.
        Where two entries name the same cell the later one wins (as APPL reads them); every
        parents' configuration must sum to 1 (renormalised within the tolerance)."""
        dims = [self.size(a) for a in axes]
        total = math.prod(dims)
        strides = [1] * len(axes)
        for k in range(len(axes) - 2, -1, -1):
            strides[k] = strides[k + 1] * dims[k + 1]
        lookups = [self.lookup[a] for a in axes]
        cells: list[int] = []
        chunks: list[np.ndarray] = []
        pending: list[str] = []
        for entry in param:
            if entry.tag != "Entry":
                raise self.error(f"<Parameter>: expected <Entry>, got <{entry.tag}>", entry)
            inst, value = entry.find("Instance"), entry.find(value_tag)
            if inst is None or value is None:
                missing = "Instance" if inst is None else value_tag
                raise self.error(f"<Entry> has no <{missing}>", entry)
            tokens = _text(inst).split()
            if len(tokens) != len(axes):
                raise self.error(f"<Instance>: expected {len(axes)} values ({' '.join(axes)}), "
                                 f"got {len(tokens)}", inst)  # fmt: skip
            cell = 0
            for tok, axis, lookup, stride, size in zip(tokens, axes, lookups, strides, dims):
                i = lookup.get(tok)
                if i is None and _is_index(tok) and int(tok) < size:
                    i = int(tok)
                if i is None:
                    if tok in ("*", "-"):
                        raise self.error(
                            f"the table of {var!r} has {total:.3g} cells (more than "
                            f"{MAX_DENSE_ENTRIES:.3g}), so it is read as its entries, each "
                            f"naming one value of every variable; {tok!r} spans {axis!r}",
                            inst,
                        )
                    raise self.error(f"<Instance>: {tok!r} is not a value of {axis!r}", inst)
                cell += i * stride
            numbers = _text(value).split()
            if len(numbers) != 1:
                raise self.error(f"<{value_tag}>: expected one probability for one cell, got "
                                 f"{len(numbers)} numbers", value)  # fmt: skip
            cells.append(cell)
            pending.append(numbers[0])
            if len(pending) >= _NUMBER_BLOCK and not _convert(pending, chunks):
                raise self.error(f"<{value_tag}>: a number that is not a number", node)
        if not _convert(pending, chunks):
            raise self.error(f"<{value_tag}>: a number that is not a number", node)
        vals = np.concatenate(chunks) if chunks else np.zeros(0)
        cell_arr = np.asarray(cells, dtype=np.int64)
        del cells, chunks
        if not np.isfinite(vals).all() or ((vals < 0) | (vals > 1 + _ROW_TOL)).any():
            raise self.error(f"<CondProb> of {var!r}: a probability outside [0, 1]", node)
        # the last entry of a cell wins: a stable sort by cell keeps the entries in order
        order = np.argsort(cell_arr, kind="stable")
        cell_arr, vals = cell_arr[order], vals[order]
        last = np.ones(cell_arr.size, dtype=bool)
        last[:-1] = cell_arr[1:] != cell_arr[:-1]
        keep = last & (vals != 0)
        cell_arr, vals = cell_arr[keep], vals[keep]
        width, rows_total = dims[-1], total // dims[-1]
        rows, cols = cell_arr // width, cell_arr % width
        del cell_arr
        self._charge(24 * rows.size, f"the nonzeros of {var!r} ({rows.size:.3g})", node)
        sums = np.bincount(rows, weights=vals, minlength=rows_total)
        drift = self._check_rows(sums.reshape(dims[:-1]), axes, var, node).reshape(-1)
        if drift.any():
            vals = np.where(drift[rows], vals / sums[rows], vals)
        return _Table(var=var, axes=tuple(axes), values=None, line=_line(node),
                      coo=(rows, cols, vals), shape=tuple(dims))  # fmt: skip

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
        drift = self._check_rows(sums, axes, var, node)
        if drift.any():
            table[drift] /= sums[drift][:, None]

    def _check_rows(self, sums: np.ndarray, axes: list[str], var: str, node: _Node) -> np.ndarray:
        """Raise unless every parents' configuration of a CondProb sums to 1 within the
        tolerance (``sums`` shaped as the parents' axes); return where a row drifts from 1
        and is to be renormalised (exact rows are kept bit for bit)."""
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
        return np.abs(sums - 1) > 1e-12

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
    """A parsed function: ``values`` over ``axes`` (parents, then the variable for a CondProb),
    or, for a CondProb too large to hold densely, its nonzeros ``coo = (rows, cols, probs)``
    (``rows`` the parents' configurations row-major, sorted; ``cols`` the variable's values)
    and ``values`` None."""

    var: str
    axes: tuple[str, ...]
    values: np.ndarray | None
    line: int
    coo: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
    shape: tuple[int, ...] = ()

    def __post_init__(self) -> None:
        if self.values is not None:
            self.shape = tuple(self.values.shape)

    @property
    def width(self) -> int:
        """The variable's number of values (the last axis)."""
        return int(self.shape[-1])

    @property
    def rows(self) -> int:
        """The parents' configurations (every axis but the last)."""
        return int(math.prod(self.shape[:-1]))

    def nonzeros(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(rows, cols, values)`` of the nonzero cells, sorted by row then column."""
        if self.coo is not None:
            return self.coo
        assert self.values is not None
        flat = self.values.reshape(-1, self.width)
        rows, cols = np.nonzero(flat)
        return rows, cols, flat[rows, cols]

    def row_counts(self) -> np.ndarray:
        """``(rows,)`` the nonzeros of each parents' configuration."""
        return np.bincount(self.nonzeros()[0], minlength=self.rows)
