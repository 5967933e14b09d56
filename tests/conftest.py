"""Shared test settings.

The suite runs with ``pytest -n 2`` on two cores: one torch thread per worker avoids
oversubscription, which makes small tensor work many times slower. Without xdist, an explicit
``OMP_NUM_THREADS`` is honoured (``.ci/run`` reruns the ``numeric`` tests with 2 threads, so
torch's sums are split the way a 2-thread user's are).

``numeric`` marker: the numerically sensitive tests, rerun by ``.ci/run`` under other BLAS
kernels (``OPENBLAS_CORETYPE``, ``MKL_ENABLE_INSTRUCTIONS``) and thread counts, where last
bits differ (``docs/testing.md``). A test module listed in ``NUMERIC_MODULES`` is marked
whole; a test elsewhere may carry ``@pytest.mark.numeric`` itself.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest
import torch

if "PYTEST_XDIST_WORKER" in os.environ or not os.environ.get("OMP_NUM_THREADS", "").isdigit():
    torch.set_num_threads(1)
else:
    torch.set_num_threads(max(1, int(os.environ["OMP_NUM_THREADS"])))

#: modules whose every test is ``numeric``: solver bounds and policies, EM and model selection
#: against references, the tasks' models and learning pipeline, the online experiment and
#: separation statistics, the environments' Monte Carlo checks. Chosen to rerun fast (their
#: CPU time, one rerun: about 2 minutes; docs/testing.md).
NUMERIC_MODULES = frozenset(
    {
        "tests/solvers/test_forms_regression.py",
        "tests/solvers/test_bounds.py",
        "tests/solvers/test_fib_exact.py",
        "tests/solvers/test_backup.py",
        "tests/solvers/test_backup_kernel.py",
        "tests/solvers/test_value_iteration.py",
        "tests/solvers/test_pruning.py",
        "tests/solvers/test_upper_bound.py",
        "tests/solvers/test_sawtooth_kernel.py",
        "tests/solvers/test_evaluate.py",
        "tests/solvers/sarsop/test_alpha_set.py",
        "tests/solvers/test_policy.py",
        "tests/solvers/test_pbvi.py",
        "tests/mixture/test_soft_em_reference.py",
        "tests/mixture/test_soft_em.py",
        "tests/mixture/test_hard_em.py",
        "tests/mixture/test_counts.py",
        "tests/mixture/test_likelihood.py",
        "tests/mixture/test_model.py",
        "tests/mixture/test_init.py",
        "tests/mixture/test_inference.py",
        "tests/tasks/test_classic.py",
        "tests/tasks/test_controller.py",
        "tests/tasks/test_hand_finishing.py",
        "tests/tasks/test_pipeline.py",
        "tests/tasks/test_place_and_drill_demos.py",
        "tests/tasks/test_place_and_drill_model.py",
        "tests/tasks/test_place_and_drill_simulate.py",
        "tests/experiments/test_online.py",
        "tests/experiments/test_separation.py",
        "tests/experiments/test_robustness.py",
        "tests/envs/test_env_tasks.py",
        "tests/envs/test_env_model.py",
        # belief updates and fitted observation models; sharded = in-memory statistics and
        # fits (issue 30 goal 4); the place-and-drill baselines and the hand-finishing MOMDP
        # (moved into tests/tasks/ by issue 32)
        "tests/pomdp/test_belief.py",
        "tests/pomdp/test_dense.py",
        "tests/pomdp/test_observation_fit.py",
        "tests/mixture/test_em.py",
        "tests/mixture/test_sharded.py",
        "tests/tasks/test_place_and_drill_cross_training.py",
        "tests/tasks/test_place_and_drill_hand_coded.py",
        "tests/tasks/test_hand_finishing_collaborative.py",
    }
)

_ROOT = Path(__file__).resolve().parent.parent


def pytest_configure(config: pytest.Config) -> None:
    # a moved or renamed test module would silently leave the CI reruns (issue 30)
    stale = sorted(m for m in NUMERIC_MODULES if not (_ROOT / m).is_file())
    if stale:
        raise pytest.UsageError(f"tests/conftest.py NUMERIC_MODULES names no file: {stale}")


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    for item in items:
        try:
            module = Path(str(item.path)).resolve().relative_to(_ROOT).as_posix()
        except ValueError:
            continue
        if module in NUMERIC_MODULES:
            item.add_marker(pytest.mark.numeric)
