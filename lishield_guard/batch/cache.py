"""One evidence cache for batch tools: opt-in, keyed by what produced an entry.

An entry's key is derived from the function that computed it (module and name), the source
file it was computed from (absolute path, size, modification time), the settings passed to it
(their ``repr``), the run's own settings and a hash of the library's source code and shipped
data files (decision weights, their card, the default config). Editing the code, retraining
the weights or changing a setting makes new keys; nothing is bumped by hand. A cache without
a folder (the ``--no-cache`` case) computes every time and stores nothing. Entries are written
atomically (a temporary file, then a rename), so a cancelled run leaves no half-written entry.
"""

from __future__ import annotations

import hashlib
import os
import pickle
from collections.abc import Callable
from pathlib import Path
from typing import Any

from lishield_guard.data_files import data_digest

__all__ = ["EvidenceCache", "code_version"]


def code_version() -> str:
    """Hash of the library's source (every module but the command shells) and of its shipped
    data (`data_files.data_digest`): an entry is only reused by the code and the weights that
    made it."""
    root = Path(__file__).resolve().parent.parent
    h = hashlib.sha1()
    for f in sorted(root.rglob("*.py")):
        rel = f.relative_to(root).as_posix()
        if rel.startswith("commands/"):
            continue
        h.update(rel.encode())
        h.update(f.read_bytes())
    h.update(data_digest().encode())
    return h.hexdigest()[:12]


def _digest(*parts: Any) -> str:
    return hashlib.sha1(repr(parts).encode()).hexdigest()[:20]


class EvidenceCache:
    """Per-file results of pure functions, in one folder (or nowhere).

    Parameters
    ----------
    folder : str, Path or None
        Where entries live; None turns the cache off.
    *settings
        What every entry of this run depends on beyond its own arguments (a config): part of
        every key, by ``repr``.
    """

    def __init__(self, folder: str | Path | None, *settings: Any) -> None:
        self.folder = None if folder is None else os.fspath(folder)
        if self.folder:
            os.makedirs(self.folder, exist_ok=True)
        self.base = _digest(*settings, code_version())

    def key(self, fn: Callable, source: str, *args: Any) -> str:
        """Entry key of ``fn`` on file ``source`` with extra arguments ``args``: the entry's
        file name is ``<fn name>-<key>.pkl``."""
        st = os.stat(source)
        return fn.__name__ + "-" + _digest(f"{fn.__module__}.{fn.__qualname__}",
                                           os.path.abspath(source), st.st_size, st.st_mtime_ns,
                                           args, self.base)

    def get(self, fn: Callable, source: str, *args: Any,
            compute: Callable[[], Any] | None = None) -> tuple[Any, bool]:
        """``(value, hit)``: the stored value of ``fn`` on ``source``, or ``compute()``'s.

        ``compute`` defaults to ``fn(source, *args)``; pass a function that returns None to
        only look up (None is never stored, so a miss stays a miss).
        """
        path = os.path.join(self.folder, self.key(fn, source, *args) + ".pkl") \
            if self.folder else None
        if path and os.path.exists(path):
            try:
                with open(path, "rb") as fh:
                    value = pickle.load(fh)
                if value is not None:
                    return value, True
            except Exception:  # noqa: BLE001 - a corrupt entry is recomputed
                pass
        value = compute() if compute is not None else fn(source, *args)
        if path and value is not None:
            tmp = f"{path}.{os.getpid()}.tmp"
            with open(tmp, "wb") as fh:
                pickle.dump(value, fh, protocol=pickle.HIGHEST_PROTOCOL)
            os.replace(tmp, path)
        return value, False
