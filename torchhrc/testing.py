"""Random model generators for tests and benchmarks.

Rows of every stochastic tensor are Dirichlet draws (``concentration`` controls how peaked
they are; ``sparsity`` zeroes a random fraction of entries, keeping at least one per row, so
models with impossible transitions and observations are exercised too). Every generator
takes ``seed`` or ``generator`` and is deterministic given it.

Example:
    >>> from torchhrc.testing import random_pomdp
    >>> m = random_pomdp(4, 2, 3, batch_shape=(5,), seed=0)
    >>> tuple(m.T.shape), tuple(m.Z.shape)
    ((5, 2, 4, 4), (5, 2, 4, 3))
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

from torchhrc.pomdp import MOMDP, POMDP

__all__ = ["random_belief", "random_momdp", "random_pomdp", "random_simplex"]


def _generator(seed: int | None, generator: torch.Generator | None) -> torch.Generator:
    if generator is not None and seed is not None:
        raise ValueError("pass either seed or generator, not both")
    if generator is not None:
        return generator
    g = torch.Generator()
    g.manual_seed(0 if seed is None else int(seed))
    return g


def random_simplex(
    shape: Sequence[int],
    *,
    concentration: float = 1.0,
    sparsity: float = 0.0,
    dtype: torch.dtype = torch.float64,
    device: torch.device | str | None = None,
    seed: int | None = None,
    generator: torch.Generator | None = None,
) -> torch.Tensor:
    """Random probability vectors along the last dim of ``shape`` (Dirichlet rows).

    Args:
        shape: the output shape ``(..., N)``; each ``[..., :]`` row sums to 1.
        concentration: symmetric Dirichlet concentration (small = peaked rows).
        sparsity: fraction of entries set to zero (at least one entry per row survives).
        dtype, device: of the output.
        seed, generator: the randomness (default seed 0).

    Returns:
        ``shape`` tensor of probabilities.

    Example:
        >>> p = random_simplex((2, 3), seed=1)
        >>> p.shape, bool(torch.allclose(p.sum(-1), torch.ones(2, dtype=torch.float64)))
        (torch.Size([2, 3]), True)
    """
    if concentration <= 0:
        raise ValueError(f"expected concentration > 0, got {concentration}")
    if not 0.0 <= sparsity < 1.0:
        raise ValueError(f"expected sparsity in [0, 1), got {sparsity}")
    g = _generator(seed, generator)
    shape = tuple(int(s) for s in shape)
    # torch's Gamma sampler takes no generator: draw a seed from ``g`` and sample under a
    # forked global RNG, so the result depends on ``g`` only.
    sub_seed = int(torch.randint(2**62, (1,), generator=g).item())
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(sub_seed)
        conc = torch.full(shape, float(concentration), dtype=torch.float64)
        gamma = torch.distributions.Gamma(conc, 1.0).sample().clamp_min(1e-300)
    if sparsity > 0:
        keep = torch.rand(shape, generator=g, dtype=torch.float64) >= sparsity
        first = torch.randint(shape[-1], (*shape[:-1], 1), generator=g)
        keep.scatter_(-1, first, True)
        gamma = gamma * keep
    probs = gamma / gamma.sum(-1, keepdim=True)
    return probs.to(dtype=dtype, device=device)


def random_belief(
    shape: Sequence[int],
    *,
    dtype: torch.dtype = torch.float64,
    device: torch.device | str | None = None,
    seed: int | None = None,
    generator: torch.Generator | None = None,
) -> torch.Tensor:
    """Uniformly random beliefs of ``shape (..., S)`` (flat Dirichlet(1) rows).

    Example:
        >>> random_belief((3, 4), seed=0).shape
        torch.Size([3, 4])
    """
    return random_simplex(shape, dtype=dtype, device=device, seed=seed, generator=generator)


def random_pomdp(
    num_states: int,
    num_actions: int,
    num_observations: int,
    *,
    batch_shape: Sequence[int] = (),
    discount: float = 0.95,
    concentration: float = 1.0,
    sparsity: float = 0.0,
    dtype: torch.dtype = torch.float64,
    device: torch.device | str | None = None,
    seed: int | None = None,
    generator: torch.Generator | None = None,
) -> POMDP:
    """A random POMDP with Dirichlet rows and standard-normal rewards.

    Args:
        num_states, num_actions, num_observations: ``S``, ``A``, ``O``.
        batch_shape: leading batch dims of every tensor.
        discount: the discount factor.
        concentration: Dirichlet concentration of the rows of ``T``, ``Z`` and ``b0``.
        sparsity: fraction of zero entries in ``T`` and ``Z`` (see :func:`random_simplex`).
        dtype, device: of the tensors.
        seed, generator: the randomness (default seed 0).

    Returns:
        :class:`POMDP` with ``T (*batch_shape, A, S, S)``, ``Z (*batch_shape, A, S, O)``,
        ``R (*batch_shape, A, S)``, ``b0 (*batch_shape, S)``.

    Example:
        >>> random_pomdp(3, 2, 2, seed=0).num_states
        3
    """
    g = _generator(seed, generator)
    batch = tuple(int(b) for b in batch_shape)
    S, A, O = int(num_states), int(num_actions), int(num_observations)
    kw = dict(dtype=dtype, device=device, generator=g, concentration=concentration)
    T = random_simplex((*batch, A, S, S), sparsity=sparsity, **kw)  # type: ignore[arg-type]
    Z = random_simplex((*batch, A, S, O), sparsity=sparsity, **kw)  # type: ignore[arg-type]
    R = torch.randn((*batch, A, S), generator=g, dtype=torch.float64).to(dtype=dtype, device=device)
    b0 = random_simplex((*batch, S), **kw)  # type: ignore[arg-type]
    return POMDP(T=T, Z=Z, R=R, b0=b0, discount=discount)


def random_momdp(
    num_observed: int,
    num_hidden: int,
    num_actions: int,
    num_observations: int,
    *,
    static: bool = True,
    batch_shape: Sequence[int] = (),
    discount: float = 0.95,
    concentration: float = 1.0,
    sparsity: float = 0.0,
    dtype: torch.dtype = torch.float64,
    device: torch.device | str | None = None,
    seed: int | None = None,
    generator: torch.Generator | None = None,
) -> MOMDP:
    """A random MOMDP with Dirichlet rows; ``static=True`` gives ``Ty = None``.

    Args:
        num_observed, num_hidden, num_actions, num_observations: ``X``, ``Y``, ``A``, ``O``.
        static: the hidden value never changes (``Ty is None``, the paper's human type).
        batch_shape: leading batch dims.
        discount, concentration, sparsity, dtype, device, seed, generator: as
            :func:`random_pomdp`.

    Returns:
        :class:`MOMDP` with ``Tx (*batch, A, X, Y, X)``, ``Ty (*batch, A, X, Y, X, Y)`` or
        ``None``, ``Z (*batch, A, X, Y, O)``, ``R (*batch, A, X, Y)``, ``b0 (*batch, Y)``,
        ``x0 = 0``.

    Example:
        >>> m = random_momdp(3, 2, 2, 4, static=False, seed=0)
        >>> tuple(m.Ty.shape)
        (2, 3, 2, 3, 2)
    """
    g = _generator(seed, generator)
    batch = tuple(int(b) for b in batch_shape)
    X, Y, A, O = int(num_observed), int(num_hidden), int(num_actions), int(num_observations)
    kw = dict(dtype=dtype, device=device, generator=g, concentration=concentration)
    Tx = random_simplex((*batch, A, X, Y, X), sparsity=sparsity, **kw)  # type: ignore[arg-type]
    Ty = (
        None if static else random_simplex((*batch, A, X, Y, X, Y), sparsity=sparsity, **kw)  # type: ignore[arg-type]
    )
    Z = random_simplex((*batch, A, X, Y, O), sparsity=sparsity, **kw)  # type: ignore[arg-type]
    R = torch.randn((*batch, A, X, Y), generator=g, dtype=torch.float64).to(
        dtype=dtype, device=device
    )
    b0 = random_simplex((*batch, Y), **kw)  # type: ignore[arg-type]
    return MOMDP(Tx=Tx, Ty=Ty, Z=Z, R=R, x0=0, b0=b0, discount=discount)
