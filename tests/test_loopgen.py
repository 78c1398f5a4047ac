"""The compiled pipeline loop: generated per composition, cached on disk for the next process,
compiled in memory where a kernel cannot be imported by name; the one-sample step behind
``update()``; chunked runs at compiled speed equal to one run."""

import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

import fusionkit as fk
from fusionkit import _loopgen, sim
from fusionkit._numba import HAVE_NUMBA, njit
from fusionkit.protocols import Correction, Corrector, CorrectorKernel

pytestmark = pytest.mark.skipif(not HAVE_NUMBA, reason="numba is not installed")

DEG = np.pi / 180
# The disk-cache tests compile CONFIG into a fresh directory in every run, warm or cold, so it is the
# cheapest composition with a plugin kernel imported by name (the estimator's and the rest
# detector's): a third of the compile of one with two correctors (README, "Run the tests").
CONFIG = {"estimator": "poisson-quat", "detectors": ["rest"], "alignment": {"mode": "fixed", "duration": 1.0}}


@pytest.fixture(scope="module")
def rec():
    segs = [sim.Rest(2.0), sim.Rotate((0, 0, 1), 90 * DEG, 1.5), sim.Rotate((1, 0, 0), 40 * DEG, 1.0), sim.Rest(1.0)]
    return sim.simulate(segs, rate=100.0, noise=sim.Noise.mems(), seed=4)


@pytest.fixture(scope="module")
def cached_loop(tmp_path_factory, rec):
    """CONFIG's loop compiled once into a fresh cache directory: (the directory, the module's
    name). Shared by the cache tests: each compile of a loop costs seconds."""
    where = tmp_path_factory.mktemp("fusionkit-cache")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("FUSIONKIT_CACHE_DIR", str(where))
        mp.setattr(_loopgen, "_BUILT", {})
        fk.compose(CONFIG).run(rec, backend="numba")
        (mod,) = _loopgen._BUILT.values()
    return where, mod.__name__


def test_a_new_process_loads_the_loop_from_disk(cached_loop):
    """From disk, without numba's one-time compiler start (``_numba._load_overload_light``)."""
    where, name = cached_loop
    written = where / "loops" / f"loop_{name[len('_fusionkit_loop_'):]}.py"
    assert written.exists()
    code = textwrap.dedent(f"""
        import numpy as np, fusionkit as fk
        from fusionkit import _loopgen
        rec = fk.Recording(gyr=np.zeros((50, 3)), acc=np.tile([0, 0, 9.81], (50, 1)), mag=np.ones((50, 3)), rate=100.0)
        f = fk.compose({CONFIG!r})
        fast = f.run(rec, backend="numba")
        (mod,) = _loopgen._BUILT.values()
        # loaded without numba's compiler start (its typing and lowering registries), same numbers
        from numba.core.registry import cpu_target
        assert not cpu_target.target_context._registries
        assert np.abs(fast.quat - f.run(rec, backend="reference").quat).max() < 1e-9
        from numba import njit  # and numba still compiles what the process asks of it afterwards
        assert njit(lambda x: np.sum(x) * 2.0)(np.ones(3)) == 6.0
        print(mod.__name__, sum(mod.loop.stats.cache_hits.values()), sum(mod.loop.stats.cache_misses.values()))
    """)
    # numba's cache log on stdout: what was loaded, and what (if anything) was compiled instead
    env = {**os.environ, "FUSIONKIT_CACHE_DIR": str(where), "NUMBA_DEBUG_CACHE": "1"}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr + "\nnumba's cache log:\n" + out.stdout
    loaded, hits, misses = out.stdout.splitlines()[-1].split()
    assert loaded == name
    assert (hits, misses) == ("1", "0")


def test_a_changed_kernel_source_is_a_new_cache_entry(cached_loop, monkeypatch, rec):
    """The file's name hashes the kernels' source: an edited plugin is never served stale code.
    (The module is written when it is built; numba compiles it at its first call, not needed here.)"""
    where, name = cached_loop
    monkeypatch.setenv("FUSIONKIT_CACHE_DIR", str(where))
    monkeypatch.setattr(_loopgen, "_BUILT", {})
    layouts, build = [], _loopgen.get_compiled

    class Built(Exception):
        pass

    def capture(lay):
        layouts.append(lay)
        raise Built

    monkeypatch.setattr(_loopgen, "get_compiled", capture)
    with pytest.raises(Built):
        fk.compose(CONFIG).run(rec, backend="numba")
    assert build(layouts[0]).__name__ == name  # the same source: the entry on disk
    monkeypatch.setattr(_loopgen, "_BUILT", {})
    monkeypatch.setattr(_loopgen, "fusionkit_hash", lambda: "the hash of an edited fusionkit")
    edited = build(layouts[0]).__name__
    assert edited != name
    assert {p.stem for p in (where / "loops").glob("loop_*.py")} == {"loop_" + n[len("_fusionkit_loop_"):]
                                                                     for n in (name, edited)}


def test_a_kernel_that_cannot_be_imported_is_compiled_in_memory(rec):
    """A corrector whose kernel is a closure: the same generated source, compiled without the cache."""
    gain = 0.5

    @njit(cache=False)
    def pull(q, s, g0, g1, g2, a0, a1, a2, m0, m1, m2, acc_ok, mag_ok, flags, dt, p, rate):
        if acc_ok:  # a Mahony-like tilt pull: rate = gain * (acc x vertical in the body)
            n = np.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
            w, x, y, z = q[0], q[1], q[2], q[3]
            vx, vy, vz = 2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)
            rate[0] += p[0] * (a1 * vz - a2 * vy) / n
            rate[1] += p[0] * (a2 * vx - a0 * vz) / n
            rate[2] += p[0] * (a0 * vy - a1 * vx) / n
        return 0

    class Pull(Corrector):
        name = "test-pull"
        mode = "rate"

        def correct(self, estimator, est_state, state, sample, flags):
            rate = np.zeros(3)
            if sample.acc is not None:
                q = estimator.quat(est_state)
                v = fk.rotations.quat_to_matrix(q)[2]
                a = sample.acc / np.sqrt(sample.acc[0] ** 2 + sample.acc[1] ** 2 + sample.acc[2] ** 2)
                rate[:] = gain * np.array([a[1] * v[2] - a[2] * v[1], a[2] * v[0] - a[0] * v[2],
                                           a[0] * v[1] - a[1] * v[0]])
            return Correction(rate, 0)

        def kernel(self, estimator):
            return CorrectorKernel(pull, np.array([gain]), mode="rate")

    from fusionkit.pipeline import Pipeline
    from fusionkit.registry import Registry

    reg = Registry()
    reg.register(Pull)
    p = Pipeline({"estimator": "poisson-quat", "correctors": ["test-pull"], "alignment": {"mode": "none"}},
                 registry=reg)
    fast = p.run(rec, backend="numba")
    ref = p.run(rec, backend="reference")
    assert np.abs(fast.quat - ref.quat).max() < 1e-9
    assert any(m.__name__ == "_fusionkit_loop_memory" for m in _loopgen._BUILT.values())


@pytest.mark.parametrize("name", ["gradient-descent", "poisson", "recommended", "channel-dcm", "gst"])
def test_chunked_runs_are_compiled_and_equal_one_run(name, rec):
    f = fk.make(name)
    whole = f.run(rec, backend="numba")
    parts, state = [], None
    for lo, hi in ((0, 123), (123, 124), (124, 400), (400, len(rec))):
        r = f.run(rec.slice(lo, hi), backend="numba", state=state)
        assert r.diagnostics["backend"] == "numba"
        parts.append(r.quat)
        state = r.diagnostics["state"]
    assert np.abs(np.vstack(parts) - whole.quat).max() < 1e-9


@pytest.mark.parametrize("name", ["gradient-descent", "poisson", "recommended", "channel-dcm"])
def test_update_runs_compiled_and_state_round_trips(name, rec):
    """update() takes the compiled step; its state, read mid-stream and restored in a new filter,
    continues the same stream."""
    f = fk.make(name)
    ref = f.run(rec, backend="reference").quat
    g = fk.make(name)
    h = len(rec) // 2
    first = [g.update(rec.gyr[k], rec.acc[k], rec.mag[k], dt=float(rec.dt[k])) for k in range(h)]
    assert g._packed if hasattr(g, "_packed") else g._buffers  # the compiled stream is in use
    g2 = fk.make(name)
    g2.set_state(g.state)
    second = [g2.update(rec.gyr[k], rec.acc[k], rec.mag[k], dt=float(rec.dt[k])) for k in range(h, len(rec))]
    assert np.abs(np.array(first + second) - ref).max() < 1e-9


def test_step_reuses_its_workspace_and_takes_a_state_without_it(rec):
    """The compiled step takes its one-sample arrays from the stream's tail past the states
    (``STEP_WORK`` entries, written there, never into a state), and an ``S`` without that tail
    (fresh arrays) gives the same numbers."""
    f = fk.compose(CONFIG)
    for k in range(5):
        f.update(rec.gyr[k], rec.acc[k], rec.mag[k], dt=float(rec.dt[k]))
    step, S, P, O, q, states, _ = f._packed
    end = int(O[2 * len(states) - 1])  # the last state's end
    assert S.size == end + _loopgen.STEP_WORK
    bare, q2 = S[:end].copy(), np.empty(4)
    args = (*rec.gyr[5], *rec.acc[5], *rec.mag[5], float(rec.dt[5]), True)
    assert step(*args, S, P, O, q, *_loopgen.NO_GNSS) == step(*args, bare, P, O, q2, *_loopgen.NO_GNSS)
    assert np.array_equal(q, q2) and np.array_equal(S[:end], bare)
    assert np.array_equal(S[end:end + 3], rec.gyr[5])  # the sample went through the tail


@pytest.mark.parametrize("name", ["gradient-descent", "recommended"])
def test_update_backend_switched_mid_stream_takes_the_reference_path(name, rec):
    """After the compiled stream's fast path has run, update_backend='reference' is obeyed (the
    reference step runs; the numbers continue the same stream)."""
    f = fk.make(name)
    ref = f.run(rec, backend="reference").quat
    out = [f.update(rec.gyr[k], rec.acc[k], rec.mag[k], dt=float(rec.dt[k])) for k in range(300)]
    f.update_backend = "reference"
    calls = []
    step = f._step
    f._step = lambda *a: calls.append(1) or step(*a)
    out += [f.update(rec.gyr[k], rec.acc[k], rec.mag[k], dt=float(rec.dt[k])) for k in range(300, len(rec))]
    assert len(calls) == len(rec) - 300
    assert np.abs(np.array(out) - ref).max() < 1e-9



@njit(cache=False, cold=True)
def _rare(s):
    s[1] += 2.0 * s[0]


@njit(cache=False)
def _hot(s):
    s[0] += 1.0
    if s[0] >= 3.0:
        _rare(s)
    return s[1]


def test_a_cold_helper_stays_a_call_in_the_inlined_twin():
    """``njit(cold=True)`` (a per-segment path): the twins the loop inlines call it, compiled once,
    instead of copying it into every composition; what is computed is the same."""
    from fusionkit._numba import _COLD, inline_copy

    assert _rare in _COLD and _hot not in _COLD
    assert inline_copy(_rare) is _rare
    twin = inline_copy(_hot)
    assert twin is not _hot and twin.py_func.__globals__["_rare"] is _rare

    @njit(cache=False)
    def drive(s):
        for _ in range(4):
            twin(s)

    a, b = np.zeros(2), np.zeros(2)
    drive(a)
    for _ in range(4):
        _hot(b)
    assert a[1] == b[1] == 2.0 * 3.0 + 2.0 * 4.0
