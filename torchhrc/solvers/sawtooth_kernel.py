"""Compiled inner loop of the sawtooth upper bound (CPU): one pass over points sorted by gain.

The sawtooth correction at a (possibly unnormalised) belief ``b`` is (Hauskrecht 2000;
Smith & Simmons 2004; Kurniawati, Hsu & Lee 2008)::

    corr(b) = min(0, min_i g_i * r_i(b)),   r_i(b) = min_{y in supp b_i} b(y) / b_i(y)

with the gains ``g_i = v_i - b_i . c`` (only points with ``g_i < 0`` can lower the bound).
Two exact bounds let the loop skip most of the work without changing the result:

* ``r_i(b) <= m(b) / s_i`` where ``m(b) = sum_y b(y)`` and ``s_i = sum_y b_i(y)`` (a minimum
  of ratios is at most the ratio of the sums), so ``g_i r_i(b) >= k_i m(b)`` with the key
  ``k_i = g_i / s_i``. Points visited in increasing key order: once ``k_i m(b)`` reaches the
  best term so far, no later point can lower it, and the scan over points stops.
* ``r_i`` only decreases while a point's support is scanned, so ``g_i r_i`` only increases;
  once it reaches the best term the point is abandoned (a zero of ``b`` on the support, the
  usual case for a point of another region of the belief space, ends it at once).

Every term that is kept is the same product ``g_i * min_k (b(y_k) * (1 / b_i(y_k)))`` as a
full evaluation, so the result equals the exhaustive minimum bit for bit. APPL evaluates its
sawtooth the same way, over the points' sparse supports with early termination
(``FullObsUBInitializer`` / ``SawtoothUpperBound::getValue`` in its public source); the key
order and the stop on it are this module's.

The loop is C (``_sawtooth.c``, built by ``pip install``: a CPython extension with no
dependency beyond Python's headers); :func:`_corrections` below is the same loop in Python,
the reference of the tests, and :func:`_corrections_np` the same minimum in whole-array
numpy, the fallback where the extension was not built (no C compiler at install time: a
warning says so once). ``TORCHHRC_NO_EXTENSION=1`` forces the fallback.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Callable

import numpy as np

__all__ = ["sawtooth_corrections", "support_signature", "support_signatures"]

_SLACK = 1.0 + 1e-12  # the key bound with room for the round-off of the products


def _corrections(*args: np.ndarray) -> None:
    """The loop of ``_sawtooth.c`` in Python: the arguments of :func:`sawtooth_corrections`
    in their order (``local`` an empty array when not given), then ``out (R,)``.

    Runs in float64 whatever the storage's dtype, as the C loop does."""
    beliefs, rows, order, idx, inv, off, wid, gain, key, local, _sig, out = args
    # (the signatures only let the compiled loop skip points whose term is 0)
    beliefs, inv, gain, key = (np.asarray(a, dtype=np.float64) for a in (beliefs, inv, gain, key))
    C = beliefs.shape[1]
    mapped = local.shape[0] > 0
    for q in range(rows.shape[0]):
        row = rows[q]
        mass = 0.0
        for c in range(C):
            mass += beliefs[row, c]
        best = 0.0
        for t in range(order.shape[0]):
            j = order[t]
            if key[t] * mass * _SLACK >= best:
                break  # no later point has a lower bound on its term
            g = gain[j]
            r = np.inf
            for e in range(off[j], off[j] + wid[j]):
                y = idx[e]
                if mapped:
                    y = local[y]
                    if y >= C:  # outside the given columns: b(y) = 0
                        r = 0.0
                        break
                v = beliefs[row, y] * inv[e]
                if v < r:
                    r = v
                    if g * r >= best:
                        break
            term = g * r
            if term < best:
                best = term
        out[q] = best


#: Elements of the ``(rows, support entries)`` block :func:`_corrections_np` forms at a time.
_BLOCK = 1 << 20


def _corrections_np(*args: np.ndarray) -> None:
    """The loop of ``_sawtooth.c`` as whole-array numpy (the fallback where the extension was
    not built): the arguments of :func:`_corrections`, the same floats.

    Every candidate point's ratio ``r_i = min_y b(y) / b_i(y)`` is taken over its whole
    support at once (``np.minimum.reduceat`` over the products ``b(y) * inv``, the loop's
    products), for a block of rows at a time; the loop's early stops skip only terms that
    cannot be the minimum, so the minimum is the loop's. The signatures are not needed.
    On Hallway (60 states) a call took 1 ms against the Python loop's 8 ms, and SARSOP's 60
    iterations 2.3 CPU-s (0.33 with the extension); with the Python loop the default 10 s
    ran out at iteration 37.
    """
    beliefs, rows, order, idx, inv, off, wid, gain, _key, local, _sig, out = args
    beliefs = np.asarray(beliefs, dtype=np.float64)
    C = beliefs.shape[1]
    width = wid[order]  # (P,) every support is nonempty
    first = np.cumsum(width) - width  # (P,) where each point's entries start among them
    # the entries of the candidate points, end to end in the order of ``order``
    entries = np.repeat(off[order] - first, width) + np.arange(int(width.sum()))
    cols = idx[entries]
    outside = None
    if local.shape[0] > 0:  # hidden values to columns; C or more: not given (b = 0)
        cols = local[cols]
        outside = cols >= C
        cols = np.where(outside, 0, cols)
    factor = np.asarray(inv, dtype=np.float64)[entries]
    g = np.asarray(gain, dtype=np.float64)[order]
    step = max(1, _BLOCK // max(cols.shape[0], 1))
    for start in range(0, rows.shape[0], step):
        block = beliefs[rows[start : start + step]][:, cols] * factor  # (R', E')
        if outside is not None:
            block[:, outside] = 0.0
        terms = g * np.minimum.reduceat(block, first, axis=1)  # (R', P)
        best = terms.min(axis=1)
        out[start : start + step] = np.where(best < 0.0, best, 0.0)


_KERNEL: Callable[..., None] | None = None
_NO_MAP = np.empty(0, dtype=np.int64)
_FIRST = np.zeros(1, dtype=np.int64)  # one support, from entry 0 (support_signature)
_FIRST.flags.writeable = False
# the dtypes the extension takes, argument by argument (``out`` aside)
_DTYPES = (np.float64, np.int64, np.int64, np.int64, np.float64, np.int64, np.int64,
           np.float64, np.float64, np.int64, np.int64)  # fmt: skip


def _kernel() -> Callable[..., None]:
    """The compiled loop, or the Python one (with a warning) where it was not built."""
    global _KERNEL
    if _KERNEL is None:
        if os.environ.get("TORCHHRC_NO_EXTENSION", "") not in ("", "0"):
            _KERNEL = _corrections_np
        else:
            try:
                from torchhrc.solvers._sawtooth import corrections
            except ImportError:
                warnings.warn(
                    "torchhrc's compiled sawtooth loop (torchhrc/solvers/_sawtooth.c) is not "
                    "built, so SARSOP's upper bound runs in numpy, several times slower: "
                    "reinstall with a C compiler present (pip install -e .), or build it in "
                    "place with python setup.py build_ext --inplace",
                    RuntimeWarning,
                    stacklevel=3,
                )
                _KERNEL = _corrections_np
            else:
                _KERNEL = corrections
    return _KERNEL


def support_signatures(idx: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """``(n,)`` int64 support signatures: bit ``y % 64`` set for every hidden value ``y`` of a
    support, the supports given end to end in ``idx (E,)`` from ``starts (n,)`` (each
    nonempty).

    A point whose signature has a bit that a row's lacks covers a hidden value where the row
    is 0, so its sawtooth term is 0: the compiled loops skip it.

    Example:
        >>> support_signatures(np.array([0, 2, 65]), np.array([0, 2])).tolist()
        [5, 2]
    """
    bits = np.left_shift(np.int64(1), idx.astype(np.int64, copy=False) & 63)
    return np.bitwise_or.reduceat(bits, starts)


def support_signature(idx: np.ndarray) -> int:
    """The support signature of one support ``idx (w,)`` (:func:`support_signatures`), as a
    Python int in int64's range; a loop over plain ints for a narrow support (a point of a
    small model: the array calls cost more than its few bits).

    Example:
        >>> support_signature(np.array([0, 2, 65]))
        7
    """
    if idx.size > 16:
        return int(support_signatures(idx, _FIRST)[0])
    s = 0
    for y in idx.tolist():
        s |= 1 << (y & 63)
    return s - (1 << 64) if s >> 63 else s  # bit 63 set: the int64's negative value


def sawtooth_corrections(
    beliefs: np.ndarray,
    rows: np.ndarray,
    order: np.ndarray,
    idx: np.ndarray,
    inv: np.ndarray,
    off: np.ndarray,
    wid: np.ndarray,
    gain: np.ndarray,
    key: np.ndarray,
    local: np.ndarray | None = None,
    sig: np.ndarray | None = None,
) -> np.ndarray:
    """``(R,)`` sawtooth corrections ``min(0, min_i g_i min_y b(y) / b_i(y))`` of some rows.

    Args:
        beliefs: ``(B, C)`` float64 non-negative weights, C-contiguous.
        rows: ``(R,)`` int64 the rows of ``beliefs`` to evaluate.
        order: ``(P',)`` int64 the candidate points, by increasing ``key`` (only ``key < 0``).
        idx: ``(E,)`` int64 the points' supports (hidden values) end to end: point ``j``'s
            are entries ``off[j]`` to ``off[j] + wid[j]``. inv: ``(E,)`` float64
            ``1 / b_i(y)`` on the supports, entry by entry.
        off: ``(cap,)`` int64 where each point's support starts in ``idx`` and ``inv``.
        wid: ``(cap,)`` int64 support widths. gain: ``(cap,)`` the gains ``g_i``.
        key: ``(P',)`` the keys ``g_i / s_i`` of the points of ``order`` (see the module
            docstring), increasing.
        local: optional ``(Y,)`` int64 map from hidden value to column of ``beliefs``, ``C``
            (or more) where the column is not given (``b = 0`` there); without it the columns
            are the hidden values themselves.
        sig: optional ``(cap,)`` int64 the points' support signatures (bit ``y % 64`` set for
            each hidden value ``y`` of the support, :func:`support_signatures`): the compiled
            loop skips a point that covers a hidden value the row does not (its term is 0),
            with the same result.

    Returns:
        ``(R,)`` float64 corrections (``<= 0``).

    Example:
        >>> import numpy as np
        >>> b = np.array([[0.2, 0.8]])  # one query; one point b_1 = (0.4, 0.6) with gain -1
        >>> idx, inv, g = np.array([0, 1]), np.array([1 / 0.4, 1 / 0.6]), np.array([-1.0])
        >>> one = np.array([0])  # the row, the point, its offset
        >>> sawtooth_corrections(b, one, one, idx, inv, one, np.array([2]), g, g)
        array([-0.5])
    """
    out = np.empty(rows.shape[0], dtype=np.float64)
    if rows.shape[0] == 0:
        return out
    if order.shape[0] == 0:
        out.fill(0.0)
        return out
    args = (beliefs, rows, order, idx, inv, off, wid, gain, key,
            _NO_MAP if local is None else local, _NO_MAP if sig is None else sig)  # fmt: skip
    kernel = _kernel()
    try:  # the arrays of a float64 bound go as they are (the extension checks them)
        kernel(*args, out)
    except TypeError:  # a float32 bound, or strided arrays: the loop runs on float64 copies
        kernel(*(np.ascontiguousarray(a, dtype=d) for a, d in zip(args, _DTYPES)), out)
    return out
