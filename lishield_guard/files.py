"""Peek at input files without ever blocking: only regular files are read, a FIFO never is."""

from __future__ import annotations

import os
import stat

__all__ = ["read_head"]


def read_head(path: str | os.PathLike, n_bytes: int) -> bytes | None:
    """The first ``n_bytes`` of the regular file at ``path`` (or of a link to one).

    The file is opened non-blocking and checked with ``fstat`` before a byte is read, so a
    FIFO without a writer, a device or a socket never hangs the caller (a plain ``open`` of a
    FIFO waits for a writer forever).

    Parameters
    ----------
    path : str or os.PathLike
        The file.
    n_bytes : int
        How many bytes to read at most.

    Returns
    -------
    bytes or None
        None when ``path`` is not a regular file or cannot be opened or read (the reader that
        comes next says why, with its typed error).

    Examples
    --------
    >>> read_head("/dev/null", 16) is None
    True
    """
    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0)
    try:
        fd = os.open(path, flags)
    except OSError:
        return None
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            return None
        return os.read(fd, n_bytes)
    except OSError:
        return None
    finally:
        os.close(fd)
