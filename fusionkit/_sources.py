"""Hashes of the source code a piece of code comes from: cache keys that an edit invalidates.

Three caches use them: the benchmark's result cache (a fixed plugin must be re-run), the disk
cache of generated pipeline loops and numba's disk cache of every cached function (an edited
kernel must be recompiled, not loaded stale: ``fusionkit._numba``'s source stamp).
"""

from __future__ import annotations

import functools
import hashlib
import importlib
import os
import sys
from pathlib import Path

__all__ = ["source_files", "source_hash", "source_snapshot", "fusionkit_hash", "fusionkit_snapshot"]


def source_files(top: str) -> list[Path]:
    """The ``.py`` files of the top-level module or package ``top`` (empty if it has none)."""
    mod = sys.modules.get(top)
    if mod is None:
        try:
            mod = importlib.import_module(top)
        except ImportError:
            return []
    paths = list(getattr(mod, "__path__", []) or [])
    if paths:
        return sorted(f for d in paths for f in Path(d).rglob("*.py"))
    file = getattr(mod, "__file__", None)
    return [Path(file)] if file else []


def source_snapshot(top: str) -> tuple[str | None, dict[str, tuple[int, int]]]:
    """:func:`source_hash` of ``top`` and, for each file hashed, its ``(st_mtime_ns, st_size)``
    taken before it was read: a later ``os.stat`` that differs says the file changed since."""
    files = source_files(top)
    if not files:
        return None, {}
    root = Path(os.path.commonpath(files)) if len(files) > 1 else files[0].parent
    h = hashlib.sha256()
    stats = {}
    for f in files:
        st = f.stat()
        stats[os.path.abspath(f)] = (st.st_mtime_ns, st.st_size)
        h.update(str(f.relative_to(root)).encode())  # a renamed file is a change too
        h.update(f.read_bytes())
    return h.hexdigest(), stats


def source_hash(top: str) -> str | None:
    """sha256 over the files of ``top`` (each one's path within it, then its bytes); None when it
    has no source to read. Not memoised: a plugin edited and reloaded in a process hashes anew."""
    return source_snapshot(top)[0]


@functools.lru_cache(maxsize=1)
def fusionkit_snapshot() -> tuple[str | None, dict[str, tuple[int, int]]]:
    """:func:`source_snapshot` of fusionkit itself, once per process (at its first cached numba
    function, during ``import fusionkit``: see ``fusionkit._numba``)."""
    return source_snapshot("fusionkit")


def fusionkit_hash() -> str:
    """:func:`source_hash` of fusionkit itself, once per process."""
    return fusionkit_snapshot()[0] or ""
