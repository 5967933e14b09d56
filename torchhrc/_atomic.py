"""Atomic file writes, internal: a temporary file in the target's folder, then ``os.replace``.

The one helper behind every file the library writes (models, policies, demonstrations,
reports, plots): a reader sees the old file or the new one, never half of one, and a write
that fails leaves the old file as it was and no temporary file behind. The new file gets the
usual ``0o666 & ~umask`` permissions (``mkstemp`` would leave ``0o600``), and its contents
are flushed to the disk (``fsync``) before it replaces the old one.

Example:
    >>> import tempfile, os
    >>> p = atomic_write_text(os.path.join(tempfile.mkdtemp(), "x.txt"), "hi\\n")
    >>> p.read_text()
    'hi\\n'
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable
from pathlib import Path

__all__ = ["atomic_write", "atomic_write_bytes", "atomic_write_text"]


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def atomic_write(path: str | os.PathLike[str], write: Callable[[str], object]) -> Path:
    """Write ``path`` atomically: ``write(tmp)`` fills a temporary file, which replaces ``path``.

    Args:
        path: the file to write (its folder must exist).
        write: called with the temporary file's path (a ``str``, in the folder of ``path``);
            it writes the whole contents there (``savefig``, safetensors' ``save_file``, or
            an ``open``). What it returns is ignored.

    Returns:
        ``path`` as a :class:`~pathlib.Path`.

    Raises:
        Whatever ``write`` or the file system raises; ``path`` is then left as it was.

    Example:
        >>> import tempfile, os
        >>> from pathlib import Path
        >>> p = atomic_write(os.path.join(tempfile.mkdtemp(), "x.txt"),
        ...                  lambda tmp: Path(tmp).write_text("hi"))
        >>> p.read_text()
        'hi'
    """
    target = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    os.close(fd)
    try:
        write(tmp)
        fd = os.open(tmp, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, target)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return target


def atomic_write_bytes(path: str | os.PathLike[str], data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically (see :func:`atomic_write`).

    Example:
        >>> import tempfile, os
        >>> p = atomic_write_bytes(os.path.join(tempfile.mkdtemp(), "x.txt"), b"hi")
        >>> p.read_bytes()
        b'hi'
    """

    def write(tmp: str) -> None:
        with open(tmp, "wb") as handle:
            handle.write(data)

    return atomic_write(path, write)


def atomic_write_text(path: str | os.PathLike[str], text: str) -> Path:
    """Write ``text`` to ``path`` atomically, UTF-8 encoded, line ends as they are in ``text``.

    Example:
        >>> import tempfile, os
        >>> p = atomic_write_text(os.path.join(tempfile.mkdtemp(), "x.csv"), "a,b\\r\\n")
        >>> p.read_bytes()
        b'a,b\\r\\n'
    """
    return atomic_write_bytes(path, text.encode("utf-8"))
