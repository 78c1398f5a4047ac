"""numba, when installed, with the settings every fusionkit kernel uses.

``fastmath`` stays off: it lets LLVM assume no NaN and compiles ``np.isnan`` checks away.
Without numba the decorator returns the plain Python function, and ``HAVE_NUMBA`` is False;
``backend="numba"`` then raises instead of falling back silently (see ``resolve_backend``).
"""

from __future__ import annotations

import functools
import os
import sys
import threading
import time

from .errors import ConfigError

# numba writes an error message for every typing template it tries and rejects while it compiles
# (tens of thousands per composition), and with colorama installed it marks each one up through
# colorama's terminal set-up and tear-down: about a twentieth of a compile's time, for messages
# nobody reads. numba's own switch (read at its import; process-wide, and inherited by child
# processes) leaves its messages unmarked (plain text, no bold). Where numba was imported first,
# its colour scheme's markup is made a no-op instead. A user who chose numba's colours (either
# variable set) keeps them and the cost.
_USER_COLOURS = any(v in os.environ for v in ("NUMBA_COLOR_SCHEME", "NUMBA_DISABLE_ERROR_MESSAGE_HIGHLIGHTING"))
_NUMBA_FIRST = "numba" in sys.modules
if not _USER_COLOURS:
    os.environ["NUMBA_DISABLE_ERROR_MESSAGE_HIGHLIGHTING"] = "1"

try:  # pragma: no cover - exercised implicitly
    import numba as _nb

    HAVE_NUMBA = True
except ImportError:  # pragma: no cover
    _nb = None
    HAVE_NUMBA = False


def _unmark_numba_errors() -> None:
    """numba's error messages left unmarked where numba was imported before fusionkit (above)."""
    from numba.core import errors

    scheme = errors.termcolor()
    if hasattr(scheme, "_markup"):  # (numba's highlighting scheme; the no-op one has nothing to mark)
        scheme._markup = lambda msg, *args, **kwargs: msg


if HAVE_NUMBA and _NUMBA_FIRST and not _USER_COLOURS:
    _unmark_numba_errors()

BACKENDS = ("auto", "numba", "reference")


# -- numba's one-time start without all of scipy.linalg -----------------------------------------
#
# The first compile or cache load in a process makes numba import numba.np.arraymath, which checks
# that a BLAS is there by importing scipy.linalg.cython_blas: that imports all of scipy.linalg
# (and through scipy's array API layer numpy.f2py), a third or more of numba's start before a
# first result. The finder below imports the BLAS module alone for that check (scipy.linalg's
# package stands in for its parent while numba.np.arraymath runs, with the same search path), so
# the check finds the same module; scipy.linalg itself is imported by whoever uses it, and gets
# its cython_blas attribute then. Nothing changes when scipy.linalg is already imported, and any
# failure falls back to numba's own import.


class _LightBlasCheck:
    """A meta path finder for ``numba.np.arraymath`` (once) and, after it, ``scipy.linalg``."""

    def find_spec(self, name, path=None, target=None):
        if name == "numba.np.arraymath":
            return self._wrap(name, self._without_scipy_linalg)
        if name == "scipy.linalg" and "scipy.linalg.cython_blas" in sys.modules:
            return self._wrap(name, self._with_blas_attribute)
        return None

    def _wrap(self, name, run):
        import importlib.util

        sys.meta_path.remove(self)  # not asked again for this name while it is found
        try:
            spec = importlib.util.find_spec(name)
        finally:
            sys.meta_path.insert(0, self)
        if spec is None or spec.loader is None or not hasattr(spec.loader, "exec_module"):
            return spec
        inner = spec.loader

        class Loader:
            def create_module(self, spec):
                return inner.create_module(spec)

            def exec_module(self, module):
                run(inner, module)

        spec.loader = Loader()
        return spec

    def _without_scipy_linalg(self, inner, module) -> None:
        import importlib.util
        import types

        stub = None
        try:
            if "scipy.linalg" not in sys.modules:
                found = importlib.util.find_spec("scipy.linalg")
                if found is not None and found.submodule_search_locations:
                    stub = types.ModuleType("scipy.linalg")
                    stub.__path__ = list(found.submodule_search_locations)
                    sys.modules["scipy.linalg"] = stub
        except Exception:  # no scipy, or an unusual one: numba's own check decides
            stub = None
        try:
            inner.exec_module(module)
        finally:
            if stub is not None and sys.modules.get("scipy.linalg") is stub:
                del sys.modules["scipy.linalg"]
            if stub is None or "scipy.linalg.cython_blas" not in sys.modules:
                _remove_finder()

    def _with_blas_attribute(self, inner, module) -> None:
        _remove_finder()
        inner.exec_module(module)
        if not hasattr(module, "cython_blas"):
            module.cython_blas = sys.modules["scipy.linalg.cython_blas"]


def _remove_finder() -> None:
    sys.meta_path[:] = [f for f in sys.meta_path if not isinstance(f, _LightBlasCheck)]


if HAVE_NUMBA and "numba.np.arraymath" not in sys.modules and "scipy.linalg" not in sys.modules:
    sys.meta_path.insert(0, _LightBlasCheck())


def njit(func=None, *, cache: bool = True, inline: str = "never", forward_copies: bool = False,
         cold: bool = False):
    """``numba.njit(cache=cache, fastmath=False, nogil=True, inline=inline)`` or the identity
    without numba. ``inline="always"`` inlines the function into its callers at numba's IR level
    (no call, no reference counting of the array arguments): for the small glue functions the
    pipeline chains its plugins' kernels with. ``forward_copies``: compile with
    :func:`loop_compiler` (for a function that calls ``inline="always"`` kernels in a loop).
    ``cold``: a rare path (work done once per segment or once per run, not every sample) that
    :func:`inline_copy` keeps as a call (see there)."""

    def wrap(f):
        if not HAVE_NUMBA:
            return f
        extra = {"pipeline_class": loop_compiler()} if forward_copies else {}
        d = _light_load(_nb.njit(cache=cache, fastmath=False, nogil=True, inline=inline, **extra)(f))
        _no_integer_literals(d)
        if cold:
            _COLD.add(d)
        return d

    return wrap(func) if func is not None else wrap


# -- loading from numba's disk cache without its compiler's start -------------------------------


def _light_load(dispatcher):
    """``dispatcher`` (returned), its disk cache loading through :func:`_load_overload_light`."""
    cache = getattr(dispatcher, "_cache", None)
    if cache is not None and hasattr(cache, "_load_overload") and not isinstance(cache.load_overload, _Light):
        _stamp_sources(dispatcher, cache)  # (numba's Cache: cache=True, JIT enabled; once)
        cache.load_overload = _Light(_load_overload_light, cache)
        _lock_compiles(dispatcher, cache)
    elif cache is not None and not hasattr(cache, "_load_overload") and not getattr(dispatcher.compile,
                                                                                  "_fusionkit_notice", False):
        _wrap_compile(dispatcher, None, cached=False)  # (no disk cache, e.g. a loop compiled in memory: the notice)
    return dispatcher


def _wrap_compile(dispatcher, lock_path: str | None, cached: bool) -> None:
    """``dispatcher.compile`` for a signature the process has not got yet: the compile notice around it
    (:class:`_CompileNotice`; ``cached``: whether the function has a disk cache), and the function's lock
    file ``lock_path`` held while it loads or compiles (None: no lock; :func:`_lock_compiles`)."""
    inner = dispatcher.compile

    def compile(sig):
        from numba.core import sigutils

        if tuple(sigutils.normalize_signature(sig)[0]) in dispatcher.overloads:
            return inner(sig)
        with _CompileNotice(dispatcher.py_func, cached):  # (also while another process compiles it: the lock's wait)
            held = lock_path is not None and _acquire(lock_path)
            try:
                return inner(sig)
            finally:
                if held:
                    _release(lock_path)

    compile._fusionkit_notice = True
    dispatcher.compile = compile


# -- one compile of a function for every integer constant it is called with ---------------------
#
# An integer constant passed to an njit function from another (a module constant such as a state
# offset, a literal size) reaches numba's dispatcher typed as that value (``Literal[int](121)``), and
# the dispatcher compiles a specialisation for each value: a helper called with two offsets was
# compiled twice, with the same machine code but for the constant. fusionkit's functions never
# need an integer's value at compile time, so their dispatchers compile for the integer's type
# (``int64``) instead: one compile for every constant. Boolean constants keep their value: a rare
# path called with ``False`` is compiled without the branch it rules out (numba's dead-branch pruning).


def _no_integer_literals(dispatcher) -> None:
    if not HAVE_NUMBA or not hasattr(dispatcher, "get_call_template"):
        return
    from numba.core import types

    inner = dispatcher.get_call_template

    def unliteral(t):
        return types.unliteral(t) if isinstance(t, types.IntegerLiteral) else t

    def get_call_template(args, kws):
        return inner(tuple(unliteral(a) for a in args), {k: unliteral(v) for k, v in kws.items()})

    dispatcher.get_call_template = get_call_template


class _Light(functools.partial):
    """A cache's ``load_overload`` made by :func:`_light_load`."""


_ADOPTED: set = set()


def adopt(func) -> None:
    """Give an njit function made by numba's own decorator (a plugin's kernel, ``numba.njit(cache=True)``),
    and every njit function it calls by a global name, the disk cache of :func:`njit`'s functions:
    stamped with its packages' sources (below), loaded lightly, compiled under the lock. A
    generated loop that calls it links its compiled code, which numba's own stamp would let go
    stale. Code the function has loaded already in this process stays; anything that is not a
    numba dispatcher is left as it is."""
    if not HAVE_NUMBA or not isinstance(func, _nb.core.registry.CPUDispatcher) or func in _ADOPTED:
        return
    _ADOPTED.add(func)
    _light_load(func)
    py = func.py_func
    for name in py.__code__.co_names:
        adopt(py.__globals__.get(name))


# -- the disk cache's source stamp covers the packages, not the function's file alone ----------
#
# numba keys a cached function on its own file (the file's content hash; in older numba its
# modification time and size), but the machine code it saves has every njit function it calls compiled
# in, and the values of the other modules' globals it reads. An edit of a helper in another
# module (an edited plugin, an upgrade that leaves the caller's file as it was) left the caller's
# entry valid: the old code, silently. Every cached function made here is stamped with numba's
# stamp and the source hash of fusionkit (``fusionkit._sources``), and, for a function outside
# fusionkit (a plugin's kernel, a generated loop), of its own top-level package as well: an edit
# of any of their files makes every entry they stamp stale, and numba compiles and saves it again
# (overwriting the old entry, as for an edit of the function's own file).
#
# A package is hashed once per process, when its first cached function is made (during its
# import), so the hash describes the code the process runs. A module of it whose file is not what
# was hashed (edited after that, before the module was imported) makes the code in memory a mix
# that no hash describes: the package's functions, and with fusionkit's every function, then
# neither load from nor save to the disk cache in this process (each load checks the files of the
# modules imported since, one ``os.stat`` per file and process).

_SNAPSHOTS: dict = {}  # top-level package -> (source hash, {file: (st_mtime_ns, st_size)})
_SEEN: dict = {}  # top-level package -> the size of sys.modules when its modules were checked
_CHECKED: set = set()  # the files of imported modules checked so far
_DIRTY: set = set()  # packages with a file changed since their hash was taken
_ROOTS: dict = {}  # top-level package -> the directory its hashed files are in


def _top(py_func) -> str:
    return (getattr(py_func, "__module__", None) or "").partition(".")[0]


def _snapshot(top: str):
    if not top:
        return None, {}
    if top not in _SNAPSHOTS:
        from ._sources import fusionkit_snapshot, source_snapshot

        try:
            _SNAPSHOTS[top] = fusionkit_snapshot() if top == "fusionkit" else source_snapshot(top)
        except (OSError, ValueError):  # a file that cannot be read: no disk cache for the package
            _SNAPSHOTS[top] = (None, {})
            _DIRTY.add(top)
    return _SNAPSHOTS[top]


def _package_stamp(module: str) -> str:
    """What a cached function of ``module`` adds to numba's stamp: fusionkit's source hash, and
    outside fusionkit its own top-level package's after it."""
    top = module.partition(".")[0]
    digest = _snapshot("fusionkit")[0] or ""
    return digest if top == "fusionkit" else f"{digest}:{_snapshot(top)[0] or ''}"


def _check_file(top: str, path) -> None:
    """Mark ``top`` changed when the file ``path`` of one of its modules is not as it was hashed
    (or is a source file of its directory that was not there)."""
    stats = _snapshot(top)[1]
    if not stats or not isinstance(path, str) or not path.endswith(".py"):
        return  # no source was hashed (a zip, a frozen application: numba's own stamp), an extension module
    path = os.path.abspath(path)
    known = stats.get(path)
    if known is None:
        if top not in _ROOTS:
            _ROOTS[top] = os.path.commonpath(list(stats)) if len(stats) > 1 else os.path.dirname(next(iter(stats)))
        if not path.startswith(_ROOTS[top] + os.sep):
            return  # not in the package's directory, not hashed: numba's own stamp covers it
    try:
        st = os.stat(path)
        same = known == (st.st_mtime_ns, st.st_size)
    except OSError:
        same = False
    if not same:
        _DIRTY.add(top)


def _unchanged(top: str) -> bool:
    """Whether every imported module of the package ``top`` is as it was when it was hashed."""
    if top in _DIRTY:
        return False
    if not top:
        return True
    if _SEEN.get(top) != len(sys.modules):
        _SEEN[top] = len(sys.modules)
        for name, mod in list(sys.modules.items()):
            if name == top or name.startswith(top + "."):
                path = getattr(mod, "__file__", None)
                if path and path not in _CHECKED:
                    _CHECKED.add(path)
                    _check_file(top, path)
    return top not in _DIRTY


def _stamp_sources(dispatcher, cache) -> None:
    """Add the packages' source hashes to ``cache``'s stamp (:func:`_package_stamp`); a numba
    that keeps its stamp elsewhere gets its disk cache turned off, never a stale entry."""
    top = _top(dispatcher.py_func)
    try:
        index = cache._cache_file
        own = index._source_stamp
        index._source_stamp = (own, _package_stamp(dispatcher.py_func.__module__ or ""))
        if own != cache._impl.locator.get_source_stamp():  # the file changed since numba read it
            _DIRTY.add(top)
    except (AttributeError, TypeError, OSError):
        cache.disable()
        return
    _check_file(top, dispatcher.py_func.__code__.co_filename)  # (a module reloaded after an edit)


# -- one compile of a function at a time across processes ----------------------------------------
#
# Two processes that need the same uncompiled function at once (pytest's workers starting on the
# same filter, two scripts after an upgrade) would each compile it, and the disk cache would serve
# only the one that comes later. A compile of a cached function takes a lock file beside its cache
# entry (``<function>.lock``): a process that finds the lock held waits, then finds the other's
# result in the disk cache (numba's dispatcher looks there first) and loads it. A function that is
# compiled already in the process takes no lock; a lock that cannot be made (no ``fcntl``, a
# read-only cache) or is held for longer than :data:`LOCK_WAIT` seconds (a process stopped while
# compiling still holds it only until it exits) is not waited for: the process compiles as it would
# without it.

LOCK_WAIT = 600.0
_HELD: dict = {}  # lock path -> [file descriptor, depth]: a compile that reaches its own function again
_HELD_LOCK = threading.Lock()  # (its entries are shared by the threads of the process)


def _lock_compiles(dispatcher, cache) -> None:
    """Make ``dispatcher.compile`` hold the function's lock file while it loads or compiles a
    signature the process has not got yet (with the compile notice: :func:`_wrap_compile`)."""
    try:
        import fcntl  # noqa: F401  (POSIX only)

        path = os.path.join(cache._cache_path, cache._impl.filename_base + ".lock")
    except (ImportError, AttributeError, TypeError):  # (no fcntl, e.g. Windows: no lock, the notice still)
        path = None
    _wrap_compile(dispatcher, path, cached=True)


# -- a line on the terminal while numba compiles ---------------------------------------------------
#
# A filter's first run on a machine (or after an upgrade) waits for numba to compile its loop: a few
# seconds for a small preset, half a minute for ``recommended`` inlined, with nothing to show for it.
# Every later process loads the machine code from the disk cache in well under a second. A load or
# compile that takes longer than :data:`NOTICE_AFTER` seconds says so on stderr, once when it starts to
# be long and once when it is done (the outermost function only: the kernels a loop compiles inside it
# are part of its line). Where: on an interactive terminal, as the progress bar (``progress=None``);
# ``FUSIONKIT_COMPILE_NOTICE=1`` always (a notebook, a log), ``0`` never.

NOTICE_AFTER = 2.0
_NOTICE = threading.local()


def _notice_wanted() -> bool:
    flag = os.environ.get("FUSIONKIT_COMPILE_NOTICE", "")
    if flag in ("0", "1"):
        return flag == "1"
    try:
        return sys.stderr is not None and sys.stderr.isatty()
    except (AttributeError, ValueError):  # a replaced or closed stderr
        return False


class _CompileNotice:
    """The notice above around one load-or-compile of ``func`` (a timer thread that prints after
    :data:`NOTICE_AFTER` seconds; cancelled when the compile ends sooner)."""

    def __init__(self, func, cached: bool = True):
        self.func, self.cached, self.timer, self.said = func, cached, None, False

    def __enter__(self):
        depth = getattr(_NOTICE, "depth", 0)
        _NOTICE.depth = depth + 1
        if depth == 0 and _notice_wanted():
            self.t0 = time.monotonic()
            timer = threading.Timer(NOTICE_AFTER, self._say)
            timer.daemon = True
            try:
                timer.start()
                self.timer = timer
            except RuntimeError:  # no thread to be had (a limit, the interpreter ending): the compile alone
                pass
        return self

    def _name(self) -> str:
        mod = getattr(self.func, "__module__", "") or ""
        if mod.startswith("_fusionkit_loop_"):
            return "the pipeline's loop"
        return f"{mod}.{getattr(self.func, '__qualname__', '?')}"

    def _say(self) -> None:
        self.said = True
        why = ("once: later runs load it from the disk cache" if self.cached else
               "in memory, no disk cache: every process compiles it")
        _tell(f"fusionkit: compiling {self._name()} for this machine ({why}) ...")

    def __exit__(self, *exc):
        _NOTICE.depth -= 1
        if self.timer is not None:
            self.timer.cancel()
            self.timer.join()  # (a line being printed is finished first)
            if self.said:
                _tell(f"fusionkit: compiled {self._name()} in {time.monotonic() - self.t0:.0f} s")
        return False


def _tell(line: str) -> None:
    """``line`` on stderr; nothing where there is none or it is closed (the compile goes on)."""
    err = sys.stderr
    if err is None:
        return
    try:
        print(line, file=err, flush=True)
    except (OSError, ValueError):
        pass


def _acquire(path: str) -> bool:
    """Take the lock file ``path`` (re-entrant within the process); False when it is not taken."""
    import fcntl
    import time

    with _HELD_LOCK:  # (threads of one process share its entries: read and count them as one step)
        entry = _HELD.get(path)
        if entry is not None:
            entry[1] += 1
            return True
    try:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
    except OSError:
        return False
    end = time.monotonic() + LOCK_WAIT
    while True:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            break
        except BlockingIOError:
            if time.monotonic() > end:
                os.close(fd)
                return False
            time.sleep(0.05)
        except OSError:  # a file system without locks
            os.close(fd)
            return False
    _HELD[path] = [fd, 1]
    return True


def _release(path: str) -> None:
    import fcntl

    with _HELD_LOCK:
        entry = _HELD[path]
        entry[1] -= 1
        if entry[1] != 0:
            return
        del _HELD[path]
    fcntl.flock(entry[0], fcntl.LOCK_UN)
    os.close(entry[0])


def _load_overload_light(cache, sig, target_context):
    """numba's ``Cache.load_overload`` without its ``target_context.refresh()``.

    That refresh is numba's one-time start of its compiler in a process: it imports and installs
    every typing and lowering registry (numba's implementations of the builtins, numpy, cffi,
    unicode, typed containers ...), a third of a new process's first result. Loading machine code
    from the cache needs none of it: the code is compiled and linked already; what it calls at run
    time is numba's runtime (NRT, started here) and the C helpers numba registers when it makes
    its context. A cache miss returns None and the dispatcher compiles, and the compiler does the
    full refresh itself (as does numba's own load for any other function); a failure here falls
    back to numba's own load. When a source file changed while the process ran (:func:`_unchanged`,
    "the disk cache's source stamp" above), the cache is turned off instead: the dispatcher
    compiles, and saves nothing.
    """
    top = _top(getattr(cache, "_py_func", None))
    if not (_unchanged("fusionkit") and _unchanged(top)):  # sources changed while the process ran
        cache.disable()
        return None
    try:
        from numba.core.runtime import nrt

        nrt.rtsys.initialize(target_context)
        with cache._guard_against_spurious_io_errors():
            return cache._load_overload(sig, target_context)
    except Exception:  # an unexpected numba: its own path
        return type(cache).load_overload(cache, sig, target_context)


# -- a loop that calls inlined kernels keeps their array arguments without reference counting ---
#
# numba inlines an ``inline="always"`` call at its IR level by binding each parameter to the
# caller's variable, ``x.1 = x``. Lowered, that copy of an array is a reference count increment
# and, where ``x.1`` dies, a decrement: calls into numba's runtime that its pruning pass removes
# only when the kernel has one exit. A kernel with an early ``return`` or a loop keeps them, each
# sample, and each call there makes the compiler save and reload every floating-point value live
# across it. The pass below (run right after the inlining) reads every such copy of a variable
# that is assigned once, before any loop (the function's entry block), as that variable itself:
# the same array object in every place, so the values computed are the same, without the copies.

_LOOP_COMPILER: list = []


def loop_compiler():
    """numba's nopython pipeline with :class:`ForwardCopies` after its inlining pass (built once)."""
    if not _LOOP_COMPILER:
        from numba.core import ir
        from numba.core.analysis import compute_cfg_from_blocks
        from numba.core.compiler import CompilerBase, DefaultPassBuilder
        from numba.core.compiler_machinery import FunctionPass, register_pass
        from numba.core.ir_utils import replace_vars
        from numba.core.untyped_passes import InlineInlinables

        @register_pass(mutates_CFG=False, analysis_only=False)
        class ForwardCopies(FunctionPass):
            """Replace ``a = b`` (``a`` assigned once, ``b`` assigned once in the entry block,
            which no loop returns to) by reading ``b`` wherever ``a`` is read; chains resolved."""

            _name = "fusionkit_forward_copies"

            def __init__(self):
                FunctionPass.__init__(self)

            def run_pass(self, state):
                blocks = state.func_ir.blocks
                entry = min(blocks)
                if list(compute_cfg_from_blocks(blocks).predecessors(entry)):
                    return False
                ndef: dict = {}
                for blk in blocks.values():
                    for st in blk.body:
                        if isinstance(st, ir.Assign):
                            ndef[st.target.name] = ndef.get(st.target.name, 0) + 1
                fixed = {st.target.name: st.target for st in blocks[entry].body
                         if isinstance(st, ir.Assign) and ndef[st.target.name] == 1}
                copies = {st.target.name: st.value.name for blk in blocks.values() for st in blk.body
                          if isinstance(st, ir.Assign) and isinstance(st.value, ir.Var)
                          and ndef[st.target.name] == 1 and st.target.name != st.value.name}
                repl = {}
                for a in copies:
                    r, seen = a, set()
                    while r in copies and r not in seen:
                        seen.add(r)
                        r = copies[r]
                    if r in fixed and r != a:
                        repl[a] = fixed[r]
                if not repl:
                    return False
                for blk in blocks.values():
                    blk.body = [st for st in blk.body if not (
                        (isinstance(st, ir.Assign) and st.target.name in repl)
                        or (isinstance(st, ir.Del) and st.value in repl))]
                replace_vars(blocks, repl)
                return True

        class LoopCompiler(CompilerBase):
            def define_pipelines(self):
                pm = DefaultPassBuilder.define_nopython_pipeline(self.state)
                pm.add_pass_after(ForwardCopies, InlineInlinables)
                pm.finalize()
                return [pm]

        _LOOP_COMPILER.append(LoopCompiler)
    return _LOOP_COMPILER[0]


# -- numba's inliner copies the inlined function's IR block by block -------------------------
#
# ``InlineWorker.inline_ir`` (numba.core.inline_closurecall) deep-copies the callee's IR twice per
# call site, each block with its own ``copy.deepcopy``. Every block refers to the function's one
# scope, which holds every variable of the function, so each block's copy copies the whole scope
# again: a copy quadratic in the function's size (for a generated loop, most of numba's inlining
# time). The shim below gives the blocks of one IR one shared memo inside ``inline_ir``, which is
# ``copy.deepcopy(blocks)`` of the whole: the blocks of a copy share one copied scope, as the
# blocks of the function they come from do. Installed at the first compile of a process (it
# imports numba's inliner, which numba's compiler imports anyway).
#
# The second of the two copies is the callee's IR "unmutated", returned to the caller of
# ``inline_ir``, and numba's two callers (the inlining passes for ``inline="always"`` functions and
# for overloads, the first through ``inline_function``) discard it: the shim hands back a block of
# the first copy as it is, instead of a copy of it. Only where those four functions have the source
# this was checked against (:data:`_NUMBA_SOURCES`; no other numba code calls ``inline_ir``); elsewhere
# both copies are made, as numba does.


def _install_linear_inline_copy() -> None:
    from numba.core import inline_closurecall as icc
    from numba.core import ir

    if isinstance(icc.copy, _BlockCopy) or not hasattr(icc.InlineWorker, "inline_ir"):
        return
    shim = _BlockCopy(icc.copy, ir.Block)
    inner = NUMBA_ORIGINAL.setdefault("inline_ir", icc.InlineWorker.inline_ir)
    shim.once = _copy_once_checked()

    def inline_ir(self, *args, **kwargs):
        shim.memos, shim.made = {}, {}
        try:
            return inner(self, *args, **kwargs)
        finally:
            shim.memos = shim.made = None

    icc.copy = shim
    icc.InlineWorker.inline_ir = inline_ir


def _copy_once_checked() -> bool:
    """Whether numba's ``inline_ir``, ``inline_function`` and the two passes that call them have
    the sources the single copy was checked against."""
    from numba.core import inline_closurecall as icc
    from numba.core import typed_passes, untyped_passes

    return (_same_source(NUMBA_ORIGINAL.get("inline_ir", icc.InlineWorker.inline_ir))
            and _same_source(getattr(icc.InlineWorker, "inline_function", None))
            and _same_source(getattr(untyped_passes.InlineInlinables, "_do_work", None))
            and _same_source(getattr(typed_passes.InlineOverloads, "_run_inliner", None)))


class _BlockCopy:
    """The ``copy`` module as numba's inliner sees it: ``deepcopy`` of a block inside
    ``inline_ir`` shares one memo with the other blocks of its scope."""

    def __init__(self, real, block_type):
        self._real, self._block, self.memos, self.made, self.once = real, block_type, None, None, False

    def __getattr__(self, name):
        return getattr(self._real, name)

    def deepcopy(self, x, memo=None):
        if memo is None and self.memos is not None and isinstance(x, self._block):
            if self.once and id(x.scope) in self.made:  # a block of the first copy: the discarded second copy
                return x
            entry = self.memos.get(id(x.scope))
            if entry is None:  # the scope kept with its memo, so its id is not reused meanwhile
                entry = self.memos[id(x.scope)] = (x.scope, {})
            y = self._real.deepcopy(x, entry[1])
            self.made[id(y.scope)] = y.scope  # (kept: its id not reused meanwhile)
            return y
        return self._real.deepcopy(x, memo)


# -- numba's SSA reconstruction visits every block once per variable it repairs -------------
#
# ``numba.core.ssa._run_ssa`` repairs each variable assigned more than once ("violator") by two
# rewrites over every block of the function: fresh names for its definitions, then each use
# re-associated with the definition that reaches it (phi nodes inserted where needed). A block
# that does not mention the variable comes out of both rewrites as it went in, yet is visited, so
# the pass costs (violators) x (statements): in an inlined loop, where each kernel brings its own
# violators and the function holds every kernel's statements, it was the largest single item of
# the compile (about a quarter of the front end's time for ``recommended``). The version below
# gives each violator's two rewrites only the blocks that mention it (a phi node may also go into
# a block that does not: that block is then copied with the phi in front), in the function's
# block order, with numba's own handlers: the same statements, names and phi nodes, in the same
# order, as numba's pass (tests/test_numba_ssa.py compares the two on the kernels' IR). Installed
# only where numba's functions have the source it was checked against (:data:`_NUMBA_SOURCES`).


NUMBA_ORIGINAL: dict = {}  # numba's functions that fusionkit's replace (the inliner's, the two passes below), by name


def _run_ssa_local(blocks):
    """``numba.core.ssa._run_ssa`` with each violator's rewrites on the blocks that mention it."""
    from numba.core import ir, ssa
    from numba.core.analysis import compute_cfg_from_blocks

    if not blocks:
        return {}
    cfg = compute_cfg_from_blocks(blocks)
    df_plus = ssa._iterated_domfronts(cfg)
    violators = ssa._find_defs_violators(blocks, cfg)
    cache_list_vars = ssa._CacheListVars()
    where: dict = {v: [] for v in violators}
    for label, blk in blocks.items():
        named = set()
        for stmt in blk.body:
            named.update(v.name for v in stmt.list_vars())
        for name in named.intersection(where):
            where[name].append(label)
    blocks = dict(blocks)
    for varname in violators:
        sub = {label: blocks[label] for label in where[varname]}
        states = ssa._make_states(blocks)
        states["varname"] = varname
        states["defmap"] = defmap = ssa.defaultdict(list)
        sub = ssa._run_block_rewrite(sub, states, ssa._FreshVarHandler())
        states = ssa._make_states(blocks)
        states.update(varname=varname, defmap=defmap, phimap=ssa.defaultdict(list), cfg=cfg,
                      phi_locations=ssa._compute_phi_locations(df_plus, defmap))
        sub = ssa._run_block_rewrite(sub, states, ssa._FixSSAVars(cache_list_vars))
        for label, philist in states["phimap"].items():
            blk = sub.get(label)
            if blk is None:  # a phi where the variable is not named: the block, copied
                old = blocks[label]
                blk = sub[label] = ir.Block(scope=old.scope, loc=old.loc)
                blk.body = list(old.body)
            blk.body = philist + blk.body
        blocks.update(sub)  # (keys kept in their places: the function's block order)
    if compute_cfg_from_blocks(blocks) != cfg:
        from numba.core import errors

        raise errors.CompilerError("CFG mutated in SSA pass")
    return blocks


# The sources of the numba functions fusionkit's replacements stand in for or rely on, as checked
# (numba 0.68.1; tests/test_numba_ssa.py, tests/test_numba_compile.py): another numba whose sources
# differ keeps its own.
_NUMBA_SOURCES = {"_run_ssa": "c497422bcf049990", "_fix_ssa_vars": "3f183045a5355bf4",
                  "_fresh_vars": "4a4d13bc0ec57cfb", "compute_live_map": "713c4c094977e93b",
                  # the inliner's single copy (above) and the call-typing memo (below)
                  "inline_ir": "26fd2b7600c9d929", "inline_function": "1b53f183258e659d",
                  "_do_work": "5e0a1f246f0fcb5d", "_run_inliner": "cfaed222e938f558",
                  "get_call_type": "6559c167bfc0ad36"}


def _same_source(func) -> bool:
    """Whether numba's ``func`` has the source the replacement was checked against."""
    import hashlib
    import inspect

    try:
        digest = hashlib.sha256(inspect.getsource(func).encode()).hexdigest()[:16]
    except (OSError, TypeError):
        return False
    return digest == _NUMBA_SOURCES.get(func.__name__)


def _install_local_ssa() -> None:
    from numba.core import ssa

    needed = ("_iterated_domfronts", "_find_defs_violators", "_CacheListVars", "_make_states",
              "_run_block_rewrite", "_FreshVarHandler", "_FixSSAVars", "_compute_phi_locations")
    if ssa._run_ssa is _run_ssa_local or not all(hasattr(ssa, n) for n in needed):
        return
    if all(_same_source(getattr(ssa, n)) for n in ("_run_ssa", "_fix_ssa_vars", "_fresh_vars")):
        NUMBA_ORIGINAL.setdefault("_run_ssa", ssa._run_ssa)
        ssa._run_ssa = _run_ssa_local


# -- numba's liveness analysis unions sets of names -------------------------------------------
#
# ``numba.core.analysis.compute_live_map`` (run by every ``PostProcessor``, several times per
# compile on the whole function) first finds, for each block, every variable defined or used on
# some path to it, as a ``set`` of names that each block passes on to its successors: in a long
# function most blocks carry most of its names, so the sets' unions cost (blocks) x (variables).
# The version below runs the same two fix-points (definitions reaching each block, then
# liveness pushed backwards where a definition reaches) on integers used as bit sets, one bit
# per name, and returns the same sets: the least fix-point of the same equations, which does not
# depend on how it is reached (tests/test_numba_ssa.py compares the two on the kernels' IR).


def _live_map_bits(cfg, blocks, var_use_map, var_def_map):
    """``numba.core.analysis.compute_live_map`` on bit sets: the variables live at each block's entry."""
    index: dict = {}

    def bits(names) -> int:
        b = 0
        for name in names:
            i = index.get(name)
            if i is None:
                i = index[name] = len(index)
            b |= 1 << i
        return b

    topo = cfg.topo_order()
    use = {k: bits(v) for k, v in var_use_map.items()}
    dfn = {k: bits(v) for k, v in var_def_map.items()}
    succ = {k: [s for s, _ in cfg.successors(k)] for k in topo}
    pred = {k: [p for p, _ in cfg.predecessors(k)] for k in topo}
    reach: dict = {}
    changed = True
    while changed:  # the definitions (and uses) reaching each block's entry, forwards
        changed = False
        for k in topo:
            v = reach.get(k, 0) | dfn[k] | use[k]
            if v != reach.get(k):
                reach[k], changed = v, True
            for s in succ[k]:
                w = reach.get(s, 0) | v
                if w != reach.get(s):
                    reach[s], changed = w, True
    live = {k: use[k] for k in blocks}
    changed = True
    while changed:  # what is used before it is defined, backwards where a definition reaches
        changed = False
        for k in reversed(topo):
            v = live[k]
            for p in pred[k]:
                w = live[p] | (v & reach.get(p, 0) & ~dfn[p])
                if w != live[p]:
                    live[p], changed = w, True
    names = list(index)
    out = {}
    for k, v in live.items():
        s = set()
        while v:
            low = v & -v
            s.add(names[low.bit_length() - 1])
            v ^= low
        out[k] = s
    return out


def _install_live_map_bits() -> None:
    from numba.core import analysis, ir_utils

    if analysis.compute_live_map is _live_map_bits or not _same_source(analysis.compute_live_map):
        return
    NUMBA_ORIGINAL.setdefault("compute_live_map", analysis.compute_live_map)
    for mod in (analysis, ir_utils):
        if getattr(mod, "compute_live_map", None) is not None:
            mod.compute_live_map = _live_map_bits


# -- numba types a call of a function or an operator from scratch each time --------------------
#
# ``BaseFunction.get_call_type`` (numba.core.types.functions) resolves a call, ``a + b`` on two
# floats or ``math.sqrt(x)``, by trying the function's typing templates in order until one accepts
# the argument types, building an error message for every one that does not; nothing is kept, so
# the kernels' thousands of scalar operations on the same few types repeat the same search: about
# a tenth of a compile. The version below keeps each successful resolution, keyed on the function
# type, the typing context, the target, the argument types (literal values included) and the
# number of templates (a template registered later is a new search); a failure is not kept and
# raises as before. The signature kept is the one numba returned, and numba has recorded its
# implementation key then (lowering reads it by the signature's arguments). Installed only where
# numba's function has the source this was checked against (:data:`_NUMBA_SOURCES`).


def _install_call_memo() -> None:
    from numba.core.target_extension import get_local_target
    from numba.core.types import functions

    if getattr(functions.BaseFunction.get_call_type, "_fusionkit_memo", False):
        return
    inner = NUMBA_ORIGINAL.setdefault("get_call_type", functions.BaseFunction.get_call_type)
    if not _same_source(inner):
        return
    memo: dict = {}

    def get_call_type(self, context, args, kws):
        """numba's ``BaseFunction.get_call_type``, each successful resolution kept (above)."""
        try:
            key = (self, context, get_local_target(context), tuple(args), tuple(sorted(kws.items())),
                   len(self.templates))
            sig = memo.get(key)
        except TypeError:  # (an unhashable type: resolved as numba does)
            return inner(self, context, args, kws)
        if sig is None:
            sig = inner(self, context, args, kws)
            if sig is not None:
                memo[key] = sig
        return sig

    get_call_type._fusionkit_memo = True
    functions.BaseFunction.get_call_type = get_call_type


if HAVE_NUMBA:
    from numba.core import event as _event

    class _FirstCompile(_event.Listener):
        done = False

        def on_start(self, event):
            if not self.done:  # (kept registered: removing it while numba broadcasts would skip the next one)
                self.done = True
                for install in (_install_linear_inline_copy, _install_local_ssa, _install_live_map_bits,
                                _install_call_memo):
                    try:
                        install()
                    except Exception:  # an unexpected numba: its own pass
                        pass

        def on_end(self, event):
            pass

    FIRST_COMPILE = _FirstCompile()  # (its ``done``: the tests install again after restoring numba's passes)
    _event.register("numba:compile", FIRST_COMPILE)


_INLINED: dict = {}

# Functions marked ``njit(cold=True)``: rare paths that an inlined kernel keeps calling. Inlining
# copies a function's whole call tree into every loop that composes its kernel, and numba's
# compile time grows with the copied code, not with how often it runs: a per-segment least-squares
# fit or a once-per-run alignment end would be compiled again into every composition, for no run
# time (a call where the work is hundreds of operations, once in many samples, costs nothing
# measurable). Kept as calls, they are compiled once, to numba's disk cache, and shared.
_COLD: set = set()


def inline_copy(func):
    """An ``inline="always"`` twin of the njit function ``func``, in which every njit function
    it calls by a global name is such a twin too (recursively): compiled into a caller, the whole
    call tree becomes one function body, with no call, no argument marshalling and no reference
    counting of the arrays between a caller and its kernels. The pipeline's generated loop calls
    its plugins' kernels through these (:mod:`fusionkit._loopgen`); ``func`` itself is unchanged.
    Anything that is not a numba dispatcher is returned as it is, and so is a function marked
    ``njit(cold=True)``: its callers' twins call it (compiled once, cached on disk)."""
    if not HAVE_NUMBA or not isinstance(func, _nb.core.registry.CPUDispatcher) or func in _COLD:
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


# -- a test session's loops call their kernels -------------------------------------------------
#
# Inlining every kernel makes each composition's loop one large body, and numba's front end
# (typing, lowering) grows with it: 10-30 s of CPU per composition, paid again for every
# composition, where a loop that calls its kernels costs 1-3 s and the kernels, compiled once
# each, are shared through numba's disk cache. With fastmath off, the two compute the same
# numbers (a call or an inlined body evaluates the same operations in the same order); only the
# speed differs. ``FUSIONKIT_LOOP_INLINE=0`` (the test suite's setting, tests/conftest.py) makes
# the generated loops call their kernels; the loop's source names the choice, so the two kinds of
# loop are separate cache entries and a session's loops never serve a user's run.

LOOP_INLINE = os.environ.get("FUSIONKIT_LOOP_INLINE", "1").strip() != "0"

_CALLED: dict = {}


def call_copy(func):
    """What a loop built with ``LOOP_INLINE`` off calls instead of :func:`inline_copy`'s twin:
    ``func`` itself, or, for a function declared ``inline="always"`` (which numba would inline
    into any caller), a dispatcher of the same Python function compiled as a call (cached on disk
    like ``func`` would be)."""
    if not HAVE_NUMBA or not isinstance(func, _nb.core.registry.CPUDispatcher):
        return func
    if func.targetoptions.get("inline", "never") == "never":
        return func
    if func not in _CALLED:
        opts = {k: v for k, v in func.targetoptions.items() if k not in ("inline", "nopython")}
        cache = not isinstance(getattr(func, "_cache", None), _nb.core.caching.NullCache)
        _CALLED[func] = _light_load(_nb.njit(cache=cache, **{**opts, "inline": "never"})(func.py_func))
        _no_integer_literals(_CALLED[func])
    return _CALLED[func]


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
