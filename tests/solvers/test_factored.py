"""Tests of torchhrc.solvers._factored's linear solve: the exact fixed points of the blind
policies, by numpy's LAPACK on the CPU and torch's elsewhere."""

from __future__ import annotations

import pytest
import torch

from torchhrc.solvers._factored import Expectation, _batched_solve
from torchhrc.testing import random_pomdp


def test_a_system_solved_by_hand() -> None:
    """``(I - 0.5 T) alpha = R`` with ``T = [[0.5, 0.5], [0, 1]]``, ``R = (1, 0)``: the second
    state keeps 0, so ``0.75 alpha_0 = 1``; a second system (``R = (0, 1)``) in the same batch:
    ``alpha_1 = 1 / 0.5 = 2`` and ``0.75 alpha_0 - 0.25 * 2 = 0``, ``alpha_0 = 2 / 3``."""
    T = torch.tensor([[0.5, 0.5], [0.0, 1.0]], dtype=torch.float64)
    lhs = (torch.eye(2, dtype=torch.float64) - 0.5 * T).expand(2, 2, 2)  # a stride-0 batch
    rhs = torch.tensor([[[1.0], [0.0]], [[0.0], [1.0]]], dtype=torch.float64)
    out = _batched_solve(lhs, rhs)
    assert out.shape == (2, 2, 1) and out.dtype == torch.float64
    torch.testing.assert_close(out[..., 0], torch.tensor([[4 / 3, 0.0], [2 / 3, 2.0]],
                                                         dtype=torch.float64))  # fmt: skip


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_numpy_and_torch_solve_alike(dtype: torch.dtype) -> None:
    """The numpy path (CPU, no autograd) against torch's (taken when a gradient is asked for)
    on a batch of random well-conditioned systems; the gradient path still differentiates."""
    g = torch.Generator().manual_seed(0)
    lhs = torch.rand(3, 4, 6, 6, generator=g, dtype=dtype) + 6 * torch.eye(6, dtype=dtype)
    rhs = torch.rand(3, 4, 6, 1, generator=g, dtype=dtype)
    fast = _batched_solve(lhs, rhs)
    grad = lhs.clone().requires_grad_(True)
    slow = _batched_solve(grad, rhs)
    assert slow.requires_grad and fast.dtype == dtype
    tol = 1e-12 if dtype == torch.float64 else 1e-5
    torch.testing.assert_close(fast, slow.detach(), rtol=tol, atol=tol)
    torch.testing.assert_close(lhs @ fast, rhs, rtol=tol * 10, atol=tol * 10)
    slow.sum().backward()
    assert grad.grad is not None and torch.isfinite(grad.grad).all()


def test_a_singular_system_raises_torchs_error() -> None:
    lhs = torch.zeros(2, 3, 3, dtype=torch.float64)
    with pytest.raises(torch.linalg.LinAlgError, match=r"[Ss]ingular"):
        _batched_solve(lhs, torch.ones(2, 3, 1, dtype=torch.float64))


def test_the_blind_fixed_point_is_the_iterations_limit() -> None:
    """``alpha_a = R_a + gamma T_a alpha_a`` per action, solved exactly, against 3,000 plain
    iterations of the same equation (an independent reference: no linear algebra)."""
    model = random_pomdp(7, 3, 2, discount=0.9, seed=4)
    exact = Expectation(model).solve_fixed_point(model.R, 0.9)
    assert exact is not None
    alpha = torch.zeros_like(model.R)
    for _ in range(3000):
        alpha = model.R + 0.9 * torch.einsum("ast,at->as", model.T, alpha)
    torch.testing.assert_close(exact, alpha, rtol=1e-10, atol=1e-10)
