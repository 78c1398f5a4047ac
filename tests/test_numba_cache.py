"""numba's disk cache never serves machine code compiled from sources that have changed since.

numba keys a cached function on its own file only, but the machine code it saves holds every
njit function it calls, compiled in: a cached function that calls a kernel from another module
kept serving the kernel's old code after the kernel's file changed (an edited plugin, an upgrade).
``fusionkit._numba.njit`` adds the source hash of the function's package (and fusionkit's) to the
cache's source stamp (``fusionkit/_numba.py``, "the disk cache's source stamp"). These tests copy
fusionkit into a temporary directory, add two tiny modules to it and a two-module plugin package
beside it, and run them in new processes before and after an edit of the callees.
"""

from __future__ import annotations

import io
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import fusionkit
from fusionkit import _numba
from fusionkit._numba import HAVE_NUMBA

pytestmark = pytest.mark.skipif(not HAVE_NUMBA, reason="numba is not installed")

CALLER = """
from fusionkit._numba import njit

from .{callee} import value


@njit
def through(x):
    return value(x)
"""

CALLEE = """
from fusionkit._numba import njit


@njit
def value(x):
    return x + {v}
"""

# A plugin kernel made with numba's own decorator, which fusionkit adopts (as a pipeline's loop does).
PLAIN = """
from numba import njit

from .b import value


@njit(cache=True)
def through(x):
    return value(x)
"""

# The callers are called, then report their result and whether numba loaded them from its disk
# cache or compiled them.
RUN = """
import json, fusionkit
from fusionkit import _cache_probe_a as f, _numba
from probe_plugin import a as p, plain
_numba.adopt(plain.through)
out = {"file": fusionkit.__file__}
for name, mod in (("fusionkit", f), ("plugin", p), ("plain", plain)):
    r = mod.through(1.0)
    st = mod.through.stats
    out[name] = [r, sum(st.cache_hits.values()), sum(st.cache_misses.values())]
print(json.dumps(out))
"""


def make_tree(base: Path) -> Path:
    """A copy of fusionkit with a caller and a callee module, and a plugin package that is the
    same pair outside fusionkit; every callee returns ``x + 1.0``."""
    src = base / "src"
    pkg = src / "fusionkit"
    shutil.copytree(Path(fusionkit.__file__).parent, pkg, ignore=shutil.ignore_patterns("__pycache__"))
    (pkg / "_cache_probe_a.py").write_text(CALLER.format(callee="_cache_probe_b"))
    (pkg / "_cache_probe_b.py").write_text(CALLEE.format(v="1.0"))
    plugin = src / "probe_plugin"
    plugin.mkdir()
    (plugin / "__init__.py").write_text("")
    (plugin / "a.py").write_text(CALLER.format(callee="b"))
    (plugin / "plain.py").write_text(PLAIN)
    (plugin / "b.py").write_text(CALLEE.format(v="1.0"))
    return src


def run(src: Path) -> dict:
    env = {**os.environ, "PYTHONPATH": str(src), "FUSIONKIT_CACHE_DIR": str(src.parent / "cache"),
           "XDG_CACHE_HOME": str(src.parent / "xdg")}  # numba's fallback directory too
    env.pop("NUMBA_CACHE_DIR", None)  # numba's cache in the copy's own __pycache__ directories
    env.pop("NUMBA_DISABLE_JIT", None)
    p = subprocess.run([sys.executable, "-c", RUN], env=env, cwd=src.parent, capture_output=True, text=True,
                       timeout=300)  # (not the repository: "-c" puts the working directory first)
    assert p.returncode == 0, p.stderr
    out = json.loads(p.stdout.strip().splitlines()[-1])
    assert Path(out["file"]).parent == src / "fusionkit"  # the copy, not the installed package
    return out


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """One tree through four new processes, which the two tests below read (each process costs
    over a second, most of it importing numba and fusionkit): a first run (compiles), the same
    sources again (loads), after a same-size edit of the callees (1.0 -> 2.0, the callers' files
    untouched), and after an edit of a fusionkit module none of the functions calls."""
    tree = make_tree(tmp_path_factory.mktemp("numba-cache"))
    out = {"first": run(tree), "warm": run(tree)}
    for callee in (tree / "fusionkit" / "_cache_probe_b.py", tree / "probe_plugin" / "b.py"):
        callee.write_text(CALLEE.format(v="2.0"))
    out["callees"] = run(tree)
    other = tree / "fusionkit" / "errors.py"
    other.write_text(other.read_text() + "\n# edited\n")
    out["other"] = run(tree)
    return out


def test_an_edited_callee_in_another_module_is_compiled_again(runs):
    """A same-size edit of the callees (1.0 -> 2.0), the callers' files untouched and their
    compiled code on disk: the next process computes with the new callee, in fusionkit and in a
    plugin package."""
    assert runs["warm"]["fusionkit"] == runs["warm"]["plugin"] == [2.0, 1, 0]  # on disk before the edit
    edited = runs["callees"]
    assert edited["fusionkit"][0] == 3.0, "fusionkit: stale machine code from numba's disk cache"
    assert edited["plugin"][0] == 3.0, "plugin: stale machine code from numba's disk cache"
    assert edited["plain"][0] == 3.0, "a plugin's numba.njit: stale machine code from numba's disk cache"
    assert edited["fusionkit"][2] == edited["plugin"][2] == edited["plain"][2] == 1  # compiled, not loaded


def test_an_edit_anywhere_in_fusionkit_recompiles_and_unchanged_sources_load(runs):
    """Unchanged sources: the next process loads from disk (a cache hit, no compile). An edit of
    any fusionkit module (one the functions do not call) invalidates fusionkit's entries and a
    plugin's (a plugin's kernels call fusionkit's)."""
    assert runs["first"]["fusionkit"] == runs["first"]["plugin"] == [2.0, 0, 1]
    warm = runs["warm"]
    assert warm["fusionkit"] == warm["plugin"] == warm["plain"] == [2.0, 1, 0]
    edited = runs["other"]  # after the callees' edit, whose compiled code the process before saved
    assert edited["fusionkit"] == edited["plugin"] == edited["plain"] == [3.0, 0, 1]


def test_every_cached_njit_function_is_stamped_with_its_sources():
    """The stamp is in place on the installed numba (a numba without the attribute it sets gets
    its disk cache turned off, never stale code)."""
    from fusionkit._kernels import validity_flags
    from fusionkit._sources import fusionkit_hash
    from fusionkit.correctors.dcm import _col

    for f in (validity_flags, _col):
        stamp = f._cache._cache_file._source_stamp
        assert isinstance(stamp, tuple) and stamp[1] == fusionkit_hash() != ""
        assert stamp[0] != stamp[1]  # numba's own, of the function's file
        assert f._cache._enabled


@pytest.mark.skipif(not HAVE_NUMBA, reason="numba's disk cache")
def test_a_called_twin_of_an_inlined_kernel_is_cached_and_stamped_like_the_kernel():
    """A loop built with ``FUSIONKIT_LOOP_INLINE=0`` (the test suite's setting) calls a twin of
    each ``inline="always"`` kernel: compiled once on disk, like the kernel, so a second process
    or another loop loads it instead of compiling it again, and stamped with the sources."""
    from fusionkit._kernels import qmul_entries
    from fusionkit._sources import fusionkit_hash

    assert qmul_entries.targetoptions["inline"] == "always"
    twin = _numba.call_copy(qmul_entries)
    assert twin is not qmul_entries and twin.targetoptions["inline"] == "never"
    assert twin._cache._enabled and twin._cache._cache_file._source_stamp[1] == fusionkit_hash()


def _probe_package(tmp_path, monkeypatch, **modules):
    """A package of its own in ``tmp_path`` (a name no other test imports), with an empty
    ``__init__`` and ``modules`` (module name -> source), on ``sys.path``: (its name, its directory)."""
    name = "probe_" + tmp_path.name.replace("-", "_")
    pkg = tmp_path / name
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    for mod, text in modules.items():
        (pkg / f"{mod}.py").write_text(text)
    monkeypatch.syspath_prepend(str(tmp_path))
    return name, pkg


def test_a_module_edited_after_its_package_was_hashed_turns_the_cache_off(tmp_path, monkeypatch):
    """A module of a package imported after an edit made once the package's hash was taken: the
    code in memory is not what the hash describes, so the package's functions neither load nor
    save (they compile, with the edited code)."""
    name, pkg = _probe_package(tmp_path, monkeypatch, b=CALLEE.format(v="1.0"), a=CALLER.format(callee="b"),
                               c=CALLEE.format(v="5.0"))
    import importlib

    from numba.core import config

    # numba reads NUMBA_CACHE_DIR again at each compile, and a function made meanwhile takes the cache
    # directory numba read last: read it again as soon as the variable is back, or a module imported
    # after this test (before its next compile) would cache beside its source instead of where the
    # suite's processes look (test_loopgen's new process then compiled instead of loading)
    try:
        with monkeypatch.context() as mp:
            mp.delenv("NUMBA_CACHE_DIR", raising=False)
            a = importlib.import_module(f"{name}.a")  # the package is hashed here
            assert a.through._cache._cache_file._source_stamp[1].endswith(_numba._snapshot(name)[0])
            (pkg / "c.py").write_text(CALLEE.format(v="7.0"))
            c = importlib.import_module(f"{name}.c")
            assert c.value(1.0) == 8.0 and a.through(1.0) == 2.0
            assert not a.through._cache._enabled and not c.value._cache._enabled
            assert sum(a.through.stats.cache_misses.values()) == 1
            assert not list(pkg.rglob("*.nbi"))  # nothing saved
    finally:  # (also when an assert above fails: the tests after this one keep the suite's cache directory)
        for m in [m for m in sys.modules if m == name or m.startswith(name + ".")]:
            del sys.modules[m]
        config.reload_config()
    assert config.CACHE_DIR == os.environ.get("NUMBA_CACHE_DIR", "")


def test_a_pipeline_loop_adopts_its_plugins_numba_functions(tmp_path, monkeypatch):
    """The generated loop links the compiled code of the functions it calls: a plugin's made with
    ``numba.njit(cache=True)`` (and what they call) get fusionkit's stamp when the loop is built."""
    from fusionkit import _loopgen

    name, _ = _probe_package(tmp_path, monkeypatch, b=CALLEE.format(v="1.0"),
                             est=PLAIN + "\n\n@njit(cache=True)\ndef to_quat(x, q):\n    q[0] = x[0]\n"
                             "\n\n@njit(cache=True)\ndef from_quat(q, x):\n    x[0] = q[0]\n")
    monkeypatch.setenv("FUSIONKIT_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setattr(_loopgen, "_BUILT", {})
    import importlib

    try:
        est = importlib.import_module(f"{name}.est")
        b = sys.modules[f"{name}.b"]
        assert not isinstance(est.through._cache._cache_file._source_stamp, tuple)  # numba's own
        _loopgen.get_compiled(_loopgen.Layout((est.through, est.to_quat, est.from_quat), True, (), 0, 4))
        for f in (est.through, est.to_quat, est.from_quat, b.value):  # b.value: what through calls
            assert f._cache._cache_file._source_stamp[1].endswith(_numba._snapshot(name)[0])
            assert isinstance(f._cache.load_overload, _numba._Light)
    finally:
        for m in [m for m in sys.modules if m == name or m.startswith(name + ".")]:
            del sys.modules[m]


def test_only_a_changed_or_new_source_file_of_the_package_counts_as_a_change(monkeypatch, tmp_path):
    """The check of the files against the package's hash: a file named by a relative path, an
    extension module or a file outside the package are no change; a source file of the package
    that was not hashed (a new module) or that differs is."""
    from fusionkit import _kernels

    monkeypatch.setattr(_numba, "_DIRTY", set())
    here = _kernels.__file__
    for path in (os.path.relpath(here), here[:-3] + ".cpython-311-x86_64-linux-gnu.so", str(tmp_path / "x.py")):
        _numba._check_file("fusionkit", path)
        assert not _numba._DIRTY, path
    _numba._check_file("fusionkit", os.path.join(os.path.dirname(here), "not_hashed_module.py"))
    assert _numba._DIRTY == {"fusionkit"}
    _numba._DIRTY.clear()
    digest, stats = _numba._snapshot("fusionkit")  # as if the file had been edited since it was hashed
    monkeypatch.setitem(_numba._SNAPSHOTS, "fusionkit", (digest, {**stats, os.path.abspath(here): (0, 0)}))
    _numba._check_file("fusionkit", here)
    assert _numba._DIRTY == {"fusionkit"}


def test_a_long_compile_says_so_on_stderr_once_for_the_outermost_function(tmp_path, monkeypatch, capsys):
    """The compile notice: with ``FUSIONKIT_COMPILE_NOTICE=1`` a load-or-compile longer than
    ``NOTICE_AFTER`` (here 0 s) prints a line when it becomes long and one when it is done, for the
    function called (``through``), not for what it compiles inside (``value``); with ``0``, and for a
    signature the process has already, nothing. (Not on a terminal and without the variable: nothing,
    so the suite's captured stderr stays as it was.)"""
    import importlib

    name, _ = _probe_package(tmp_path, monkeypatch, b=CALLEE.format(v="1.0"), a=CALLER.format(callee="b"))
    monkeypatch.setattr(_numba, "NOTICE_AFTER", 0.0)
    try:
        a = importlib.import_module(f"{name}.a")
        monkeypatch.setenv("FUSIONKIT_COMPILE_NOTICE", "1")
        assert a.through(1.0) == 2.0
        lines = capsys.readouterr().err.splitlines()
        assert len(lines) == 2, lines
        assert lines[0].startswith(f"fusionkit: compiling {name}.a.through for this machine (once")
        assert re.fullmatch(rf"fusionkit: compiled {name}\.a\.through in \d+ s", lines[1])
        assert a.through(2.0) == 3.0 and capsys.readouterr().err == ""  # (compiled already)
        monkeypatch.setenv("FUSIONKIT_COMPILE_NOTICE", "0")
        assert a.through(np.float32(1.0)) == 2.0 and capsys.readouterr().err == ""  # (a new signature, silent)
        monkeypatch.setenv("FUSIONKIT_COMPILE_NOTICE", "1")
        in_memory = _numba.njit(cache=False)(lambda x: x * 2.0)  # (no disk cache: a loop compiled in memory)
        assert in_memory(1.0) == 2.0
        lines = capsys.readouterr().err.splitlines()
        assert len(lines) == 2 and "<lambda> for this machine (in memory, no disk cache" in lines[0], lines
        closed = io.StringIO()
        closed.close()
        real, sys.stderr = sys.stderr, closed  # (a closed stderr: the compile goes on, silently)
        try:
            assert a.through(np.int64(1)) == 2.0
        finally:
            sys.stderr = real
        monkeypatch.delenv("FUSIONKIT_COMPILE_NOTICE", raising=False)
        assert not _numba._notice_wanted()  # (pytest's captured stderr is not a terminal)
    finally:
        for m in [m for m in sys.modules if m == name or m.startswith(name + ".")]:
            del sys.modules[m]


def test_the_compile_notice_without_a_thread_or_without_file_locks(tmp_path, monkeypatch, capsys):
    """No thread to be had: the compile goes on without the notice, and the next one has it again
    (the depth count back at 0). No ``fcntl`` (Windows): no compile lock, the notice still (rev26d)."""
    import importlib
    import threading

    monkeypatch.setattr(_numba, "NOTICE_AFTER", 0.0)
    monkeypatch.setenv("FUSIONKIT_COMPILE_NOTICE", "1")

    def no_thread(self):
        raise RuntimeError("can't start new thread")

    with monkeypatch.context() as mp:
        mp.setattr(threading.Timer, "start", no_thread)
        assert _numba.njit(cache=False)(lambda x: x - 1.0)(1.0) == 0.0
    assert capsys.readouterr().err == "" and getattr(_numba._NOTICE, "depth", 0) == 0
    name, _ = _probe_package(tmp_path, monkeypatch, b=CALLEE.format(v="1.0"), a=CALLER.format(callee="b"))
    monkeypatch.setitem(sys.modules, "fcntl", None)  # (import fcntl raises ImportError)
    try:
        a = importlib.import_module(f"{name}.a")
        assert a.through(1.0) == 2.0
        lines = capsys.readouterr().err.splitlines()
        assert len(lines) == 2 and lines[0].startswith(f"fusionkit: compiling {name}.a.through"), lines
    finally:
        for m in [m for m in sys.modules if m == name or m.startswith(name + ".")]:
            del sys.modules[m]
