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


_INLINED: dict = {}


def inline_copy(func):
    """An ``inline="always"`` twin of the njit function ``func``, in which every njit function
    it calls by a global name is such a twin too (recursively): compiled into a caller, the whole
    call tree becomes one function body, with no call, no argument marshalling and no reference
    counting of the arrays between a caller and its kernels. The pipeline's generated loop calls
    its plugins' kernels through these (:mod:`fusionkit._loopgen`); ``func`` itself is unchanged.
    Anything that is not a numba dispatcher is returned as it is."""
    if not HAVE_NUMBA or not isinstance(func, _nb.core.registry.CPUDispatcher):
        return func
    if func in _INLINED:
        return _INLINED[func]
    _INLINED[func] = func  # a function that reaches itself again is called, not inlined
    import types

    py = func.py_func
    glb = dict(py.__globals__)
    for name in py.__code__.co_names:
        if isinstance(glb.get(name), _nb.core.registry.CPUDispatcher):
            glb[name] = inline_copy(glb[name])
    twin = types.FunctionType(py.__code__, glb, py.__name__, py.__defaults__, py.__closure__)
    twin.__qualname__, twin.__module__ = py.__qualname__, py.__module__
    opts = {k: v for k, v in func.targetoptions.items() if k not in ("cache", "inline", "nopython")}
    _INLINED[func] = _nb.njit(inline="always", **opts)(twin)
    return _INLINED[func]


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
