"""Ray connection helpers shared by sweeps and sharded clustering (the ``[ray]`` extra).

Example:
    >>> check_reachable("no-port")
    Traceback (most recent call last):
    ...
    torchhrc.errors.ModelError: expected a Ray address HOST:PORT (or 'local'), got 'no-port'
"""

from __future__ import annotations

import os
import socket
from typing import Any

from torchhrc.errors import ModelError

__all__ = ["check_reachable", "import_ray", "init_ray", "task_error"]


def import_ray() -> Any:
    """Import ray, or raise :class:`ModelError` naming the extra to install."""
    try:
        import ray
    except ImportError:
        raise ModelError(
            "Ray is not installed: pip install 'torchhrc[ray]' (or run without --ray)"
        ) from None
    return ray


def check_reachable(address: str, timeout: float = 5.0) -> None:
    """Raise :class:`ModelError` unless ``HOST:PORT`` (or ``ray://HOST:PORT``) accepts a TCP
    connection within ``timeout`` seconds: an unreachable cluster fails fast, in one line.
    """
    target = address.split("://", 1)[-1]
    host, sep, port = target.rpartition(":")
    if not sep or not port.isdigit():
        raise ModelError(f"expected a Ray address HOST:PORT (or 'local'), got {address!r}")
    try:
        with socket.create_connection((host or "127.0.0.1", int(port)), timeout=timeout):
            pass
    except OSError as error:
        raise ModelError(f"cannot reach the Ray cluster at {address}: {error}") from None


def init_ray(address: str = "local", *, num_cpus: int | None = None) -> bool:
    """Connect to Ray: ``"local"`` starts a local cluster, ``HOST:PORT`` joins one.

    Returns ``True`` when this call started the connection (the caller shuts it down), and
    ``False`` when Ray was already initialised in this process.

    Raises:
        ModelError: Ray is missing, or the address is malformed or unreachable.
    """
    ray = import_ray()
    if ray.is_initialized():
        return False
    if address == "local":
        ray.init(
            num_cpus=num_cpus or os.cpu_count() or 1,
            include_dashboard=False,
            log_to_driver=False,
            configure_logging=False,
        )
    else:
        check_reachable(address)
        ray.init(address=address, log_to_driver=False, configure_logging=False)
    return True


def task_error(error: BaseException) -> BaseException:
    """The exception a Ray task raised (Ray wraps it; ``error.cause`` holds the original)."""
    cause = getattr(error, "cause", None)
    return cause if isinstance(cause, Exception) else error
