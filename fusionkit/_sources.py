"""Hashes of the source code a piece of code comes from: cache keys that an edit invalidates.

Two caches use them: the benchmark's result cache (a fixed plugin must be re-run) and the disk
cache of generated pipeline loops (an edited kernel must be recompiled, not loaded stale).
"""

from __future__ import annotations

import functools
import hashlib
import importlib
import os
import sys
from pathlib import Path

__all__ = ["source_files", "source_hash", "fusionkit_hash"]


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


def source_hash(top: str) -> str | None:
    """sha256 over the files of ``top`` (each one's path within it, then its bytes); None when it
    has no source to read. Not memoised: a plugin edited and reloaded in a process hashes anew."""
    files = source_files(top)
    if not files:
        return None
    root = Path(os.path.commonpath(files)) if len(files) > 1 else files[0].parent
    h = hashlib.sha256()
    for f in files:
        h.update(str(f.relative_to(root)).encode())  # a renamed file is a change too
        h.update(f.read_bytes())
    return h.hexdigest()


@functools.lru_cache(maxsize=1)
def fusionkit_hash() -> str:
    """:func:`source_hash` of fusionkit itself, once per process."""
    return source_hash("fusionkit") or ""
