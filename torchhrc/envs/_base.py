"""What every torchhrc environment shares: validation of the options, seeding, the horizon."""

from __future__ import annotations

import numpy as np
import torch

__all__: list[str] = []


def check_horizon(horizon: object) -> int | None:
    """``None`` or a positive int (the number of steps after which an episode is truncated)."""
    if horizon is None:
        return None
    if isinstance(horizon, bool) or not isinstance(horizon, (int, np.integer)) or horizon < 1:
        raise ValueError(f"expected horizon to be a positive int or None, got {horizon!r}")
    return int(horizon)


def check_render_mode(render_mode: object) -> str | None:
    """``None`` or ``"ansi"``, the one render mode the model environments offer."""
    if render_mode not in (None, "ansi"):
        raise ValueError(f"expected render_mode None or 'ansi', got {render_mode!r}")
    return render_mode  # type: ignore[return-value]


def check_probability(name: str, value: object, *, upper_open: bool = False) -> float:
    """A float in ``[0, 1]`` (``[0, 1)`` with ``upper_open``)."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.floating)):
        raise TypeError(f"expected {name} to be a float in [0, 1], got {value!r}")
    value = float(value)
    if not (0.0 <= value < 1.0 if upper_open else 0.0 <= value <= 1.0):
        bound = "[0, 1)" if upper_open else "[0, 1]"
        raise ValueError(f"expected {name} in {bound}, got {value}")
    return value


def check_type_probabilities(type_probabilities: object, num_types: int) -> torch.Tensor:
    """The distribution types are drawn from, ``(Y,)`` float64: uniform for ``None``, else
    the given one, which must have ``Y`` non-negative entries summing to 1 (to 1e-9)."""
    Y = num_types
    if type_probabilities is None:
        return torch.full((Y,), 1.0 / Y, dtype=torch.float64)
    probs = torch.as_tensor(type_probabilities, dtype=torch.float64)
    if probs.shape != (Y,) or (probs < 0).any() or abs(float(probs.sum()) - 1.0) > 1e-9:
        raise ValueError(
            f"expected type_probabilities of shape (Y={Y},), non-negative, summing to "
            f"1, got {list(type_probabilities)!r}"
        )
    return probs


def check_action(action: object, num_actions: int) -> int:
    """The action as an int in ``[0, A)``; a ValueError naming the range otherwise."""
    a = np.asarray(action)
    if a.shape != () or not np.issubdtype(a.dtype, np.integer) or not 0 <= int(a) < num_actions:
        raise ValueError(f"expected action to be an int in [0, {num_actions}), got {action!r}")
    return int(a)


def torch_generator(np_random: np.random.Generator) -> torch.Generator:
    """A ``torch.Generator`` seeded from gymnasium's ``np_random`` (deterministic in it)."""
    return torch.Generator().manual_seed(int(np_random.integers(0, 2**62)))


def check_unbatched(model: object) -> None:
    """Raise ValueError when ``model`` has batch dims (an env simulates one model)."""
    batch = tuple(getattr(model, "batch_shape", ()))
    if batch:
        raise ValueError(f"expected an unbatched model, got batch_shape {batch}")
