"""The variables of a ``.pomdpx`` file, grouped as the reader combines them into
indices (:class:`PomdpxVariable`, :class:`PomdpxVariables`)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

__all__ = ["PomdpxVariable", "PomdpxVariables"]


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
