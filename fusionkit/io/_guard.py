"""One error for any file a reader cannot read: an :class:`~fusionkit.errors.InputError` naming
the file, whatever the parser underneath raised (h5py's ``OSError`` for a truncated HDF5 file,
pyulog's exceptions for a damaged log, ``UnicodeDecodeError`` for a non-UTF-8 CSV, ...)."""

from __future__ import annotations

import functools
from pathlib import Path

from ..errors import FusionkitError, InputError


def file_errors(kind: str):
    """Decorate a reader ``f(path, ...)``: any exception but a FusionkitError becomes an
    ``InputError("NAME: cannot read this KIND file: Type: message")``, chained to the original."""

    def wrap(read):
        @functools.wraps(read)
        def guarded(path, *args, **kwargs):
            try:
                return read(path, *args, **kwargs)
            except FusionkitError:
                raise
            except Exception as exc:  # a damaged or foreign file, whatever the parser raises
                msg = str(exc).splitlines()[0] if str(exc) else ""
                raise InputError(f"{Path(path).name}: cannot read this {kind} file: "
                                 f"{type(exc).__name__}{': ' + msg if msg else ''}") from exc

        return guarded

    return wrap
