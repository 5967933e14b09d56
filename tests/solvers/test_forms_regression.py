"""Bit-identity of deterministic SARSOP and PBVI solves across refactors of the model forms.

The expected numbers in ``data/forms_regression.json`` were recorded on the code before the
solvers were rewritten against one model interface (:mod:`torchhrc.solvers.forms`): with a
fixed ``max_iterations`` and a time limit never reached, a solve is deterministic, so the
same algorithm must give the very same floats (exact equality, not a tolerance) whatever
form (dense flat, MOMDP-factored, sparse flat) the model is held in.

Each SARSOP case is recorded twice: on the numpy path (``backup_kernel.load`` returning
``None``: the rows recorded before the compiled steps existed, unchanged) and with the compiled
steps of :mod:`torchhrc.solvers.backup_kernel` (key ``"<case>#compiled"``), whose sequential
sums may differ from BLAS's in the last bit (with several observed values, a MOMDP, the
compiled steps are the children's scores and sawtooth values of ``group_scores`` and
``group_upper``).

Regenerate (only when a change of the algorithm is intended, and say so in the commit)::

    PYTHONPATH=. python tests/solvers/test_forms_regression.py --write
"""

from __future__ import annotations

import hashlib
import json
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import torch

from torchhrc.solvers import PBVIConfig, SARSOPConfig, backup_kernel, pbvi, sarsop
from torchhrc.sparse import SparsePOMDP
from torchhrc.tasks.classic import rock_sample, rock_sample_momdp, rock_sample_sparse, tag, tiger
from torchhrc.testing import random_momdp, random_pomdp

DATA = Path(__file__).parent / "data" / "forms_regression.json"
LONG = 1e9  # a time limit never reached: solves stop on max_iterations


def _sarsop(build: Callable[[], Any], iterations: int, **kw: Any) -> Callable[[], Any]:
    return lambda: sarsop(
        build(), SARSOPConfig(time_limit=LONG, precision=1e-9, max_iterations=iterations, **kw)
    )


def _pbvi(build: Callable[[], Any], **kw: Any) -> Callable[[], Any]:
    return lambda: pbvi(build(), PBVIConfig(time_limit=LONG, precision=1e-9, **kw))


def _rmomdp() -> Any:
    return random_momdp(4, 3, 3, 3, static=False, discount=0.95, concentration=0.3, seed=4)


def _rmomdp_static() -> Any:
    return random_momdp(5, 3, 2, 3, static=True, discount=0.9, seed=7)


CASES: dict[str, Callable[[], Any]] = {
    "sarsop/tiger": _sarsop(tiger, 60),
    "sarsop/random_pomdp": _sarsop(lambda: random_pomdp(6, 3, 3, discount=0.9, seed=11), 40),
    "sarsop/rocksample44_dense": _sarsop(lambda: rock_sample(4, 4), 25),
    "sarsop/rocksample44_dense_sweep": _sarsop(lambda: rock_sample(4, 4), 12, sweep_interval=4),
    "sarsop/rocksample44_momdp": _sarsop(lambda: rock_sample_momdp(4, 4), 25),
    "sarsop/rocksample44_momdp_sweep": _sarsop(
        lambda: rock_sample_momdp(4, 4), 12, sweep_interval=4
    ),
    "sarsop/tag_dense": _sarsop(tag, 8),
    "sarsop/random_momdp": _sarsop(_rmomdp, 30),
    "sarsop/random_momdp_sweep": _sarsop(_rmomdp, 15, sweep_interval=3),
    "sarsop/random_momdp_static": _sarsop(_rmomdp_static, 20),
    "sarsop/rocksample44_sparse": _sarsop(lambda: rock_sample_sparse(4, 4), 25),
    "sarsop/rocksample44_sparse_sweep": _sarsop(
        lambda: rock_sample_sparse(4, 4), 12, sweep_interval=4
    ),
    "sarsop/tiger_sparse": _sarsop(lambda: SparsePOMDP.from_dense(tiger()), 40),
    # every child re-bounded at every backup (SARSOPConfig.lazy_upper=False)
    "sarsop/rocksample44_momdp_eager": _sarsop(
        lambda: rock_sample_momdp(4, 4), 25, lazy_upper=False
    ),
    "sarsop/rocksample44_sparse_eager": _sarsop(
        lambda: rock_sample_sparse(4, 4), 25, lazy_upper=False
    ),
    "pbvi/tiger": _pbvi(tiger, expansions=4),
    "pbvi/random_pomdp_qmdp": _pbvi(
        lambda: random_pomdp(6, 3, 3, discount=0.9, seed=11), expansions=3, upper_bound="qmdp"
    ),
    "pbvi/random_momdp": _pbvi(_rmomdp, expansions=3),
    "pbvi/random_momdp_flattened": _pbvi(_rmomdp, expansions=2, factored=False),
    "pbvi/rocksample44_momdp": _pbvi(
        lambda: rock_sample_momdp(4, 4), expansions=2, backups_per_expansion=5
    ),
}


def _digest(t: torch.Tensor | None) -> str | None:
    if t is None:
        return None
    return hashlib.sha256(t.detach().cpu().contiguous().numpy().tobytes()).hexdigest()[:16]


COMPILED = "#compiled"
KEYS = sorted(CASES) + [n + COMPILED for n in sorted(CASES) if n.startswith("sarsop/")]


def _record(key: str) -> dict[str, Any]:
    """The numbers of case ``key`` (``name`` on the numpy path, ``name#compiled`` with the
    compiled steps where the extension is built)."""
    name = key.removesuffix(COMPILED)
    load = backup_kernel.load
    if not key.endswith(COMPILED):
        backup_kernel.load = lambda: None  # type: ignore[assignment]
    try:
        sol = CASES[name]()
    finally:
        backup_kernel.load = load  # type: ignore[assignment]
    p = sol.policy
    return {
        "lower": sol.lower,
        "upper": sol.upper,
        "n_alphas": int(p.num_vectors),
        "history_lower": [h["lower"] for h in sol.history],
        "history_upper": [h["upper"] for h in sol.history],
        "alphas": _digest(p.alphas),
        "actions": _digest(p.actions.long()),
        "observed": _digest(None if p.observed is None else p.observed.long()),
    }


def _dumps(cases: dict[str, Any]) -> str:
    """One case a line (floats as ``repr``: exact round trip)."""
    lines = [f"{json.dumps(k)}: {json.dumps(v)}" for k, v in sorted(cases.items())]
    return "{\n" + ",\n".join(lines) + "\n}\n"


def _expected() -> dict[str, Any]:
    return json.loads(DATA.read_text())


@pytest.mark.parametrize("name", KEYS)
def test_bounds_bit_identical_to_recorded(name: str) -> None:
    if name.endswith(COMPILED) and backup_kernel.load() is None:
        pytest.skip("the compiled extension is not built (or TORCHHRC_NO_EXTENSION is set)")
    expected = _expected()[name]
    got = _record(name)
    # bounds first (the promise), then the policy itself
    for key in ("lower", "upper", "n_alphas", "history_lower", "history_upper"):
        assert got[key] == expected[key], key
    for key in ("alphas", "actions", "observed"):
        assert got[key] == expected[key], key


if __name__ == "__main__":
    torch.set_num_threads(1)
    if "--write" not in sys.argv:
        raise SystemExit("usage: test_forms_regression.py --write (records the expected numbers)")
    if backup_kernel.load() is None:
        raise SystemExit("build the extension first: python setup.py build_ext --inplace")
    out = {}
    for name in KEYS:
        out[name] = _record(name)
        print(name, out[name]["lower"], out[name]["upper"], out[name]["n_alphas"], flush=True)
    tmp = DATA.with_suffix(".tmp")
    tmp.write_text(_dumps(out))
    tmp.replace(DATA)
