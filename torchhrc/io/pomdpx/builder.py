"""Assembling a ``.pomdpx`` file's tables into a model: the ``_Builder`` combines the
``_Table``s into dense tensors by broadcasting or into the
sparse forms by expanding nonzero successors, with the names of the flat form."""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from typing import Any

import numpy as np
import torch

from torchhrc._host import as_host
from torchhrc.errors import ModelError
from torchhrc.io.pomdpx.reader import _Reader, _Table
from torchhrc.io.pomdpx.variables import PomdpxVariable, PomdpxVariables
from torchhrc.pomdp import MOMDP, POMDP
from torchhrc.pomdp.sparse import SparsePOMDP
from torchhrc.pomdp.sparse_momdp import SparseMOMDP

__all__: list[str] = []  # private parts; the public names are the package's

#: Peak bytes a nonzero of the sparse forms costs while it is expanded (its row, value and
#: probability, one index per variable, the re-indexing), per variable of the expansion.
_ENTRY_BYTES = 48


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
            and bool((t.row_counts() == 1).all())
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
        if table.values is None:
            raise ModelError(
                f"the table of {table.var!r} is held as its nonzeros (too large to "
                "hold densely): the model can be read in the sparse form only"
            )
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
        if t.values is None or any(self.r.observation[o].values is None for o in obs):
            raise ModelError("a reward that depends on the next state or observation through "
                             "a table held as its nonzeros (too large to hold densely) is not "
                             "supported")  # fmt: skip
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
            n = t.width
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
            nz_rows, nz_cols, nz_vals = t.nonzeros()
            indptr = np.zeros(t.rows + 1, dtype=np.int64)
            np.cumsum(np.bincount(nz_rows, minlength=t.rows), out=indptr[1:])
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
            p = p * nz_vals[pos]
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

    def transition_nonzeros(self) -> float:
        """The flat ``T``'s nonzeros, estimated from the tables (:meth:`_entries`)."""
        return self._entries([self.r.transition[n] for n in self.xc + self.yc])

    def _entries(self, tables: list[_Table]) -> float:
        """The nonzeros an expansion over ``tables`` from every ``(a, s)`` row makes, estimated
        as ``A S`` times each table's mean nonzeros per row (exact for tables whose rows have
        the same count, as a model's usually have)."""
        n = float(self.A * self.S)
        for t in tables:
            n *= t.nonzeros()[0].size / max(t.rows, 1)
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
        if t.values is None:  # held as its nonzeros: read as changing (the sparse forms hold
            return False  # either; only a dense MOMDP's Ty = None needs to know)
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
        t = torch.from_numpy(np.ascontiguousarray(a))
        if device is None or torch.device(device).type == "cpu":
            return as_host(t, dtype)  # (numpy's conversion: torchhrc._host)
        return t.to(dtype=dtype, device=device)

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
