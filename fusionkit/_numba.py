"""numba, when installed, with the settings every fusionkit kernel uses.

``fastmath`` stays off: it lets LLVM assume no NaN and compiles ``np.isnan`` checks away.
Without numba the decorator returns the plain Python function, and ``HAVE_NUMBA`` is False;
``backend="numba"`` then raises instead of falling back silently (see ``resolve_backend``).
"""

from __future__ import annotations

from .errors import ConfigError

try:  # pragma: no cover - exercised implicitly
    import numba as _nb

    HAVE_NUMBA = True
except ImportError:  # pragma: no cover
    _nb = None
    HAVE_NUMBA = False

BACKENDS = ("auto", "numba", "reference")


def njit(func=None, *, cache: bool = True, inline: str = "never"):
    """``numba.njit(cache=cache, fastmath=False, nogil=True, inline=inline)`` or the identity
    without numba. ``inline="always"`` inlines the function into its callers at numba's IR level
    (no call, no reference counting of the array arguments): for the small glue functions the
    pipeline chains its plugins' kernels with."""

    def wrap(f):
        if not HAVE_NUMBA:
            return f
        return _nb.njit(cache=cache, fastmath=False, nogil=True, inline=inline)(f)

    return wrap(func) if func is not None else wrap


def resolve_backend(backend: str, has_kernel: bool) -> str:
    """Pick the backend that will run: ``"numba"`` or ``"reference"``.

    ``"auto"`` takes numba when it is installed and every plugin of the run has a kernel;
    ``"numba"`` raises when that is not possible; ``"reference"`` always runs the readable path.
    """
    if backend not in BACKENDS:
        raise ConfigError(f"backend must be one of {BACKENDS}, got {backend!r}")
    if backend == "reference":
        return "reference"
    if backend == "numba":
        if not HAVE_NUMBA:
            raise ConfigError("backend='numba' was asked for but numba is not installed")
        if not has_kernel:
            raise ConfigError(
                "backend='numba' was asked for but a plugin of this run has no numba kernel; "
                "use backend='auto' or 'reference'"
            )
        return "numba"
    return "numba" if (HAVE_NUMBA and has_kernel) else "reference"
