"""Contract checks for plugin authors: ``fusionkit.testing.check_plugin(MyPlugin)`` in one test.

Each check raises ``AssertionError`` with a message saying which rule broke. They run on a
seeded simulated recording (:mod:`fusionkit.sim`) and take a few seconds.

Rules for every plugin: a name and a kind, subclassing that kind's protocol class and
implementing its abstract methods (a ``Plugin`` that only says ``kind = "filter"`` has no
``run``), a ``Config`` that rejects unknown keys and documents every field (description and
unit), default construction works. Filters: one unit quaternion per input sample, ``run`` equals
a loop of ``update``, a run split in two with the state carried over equals one run, a NaN
sample raises ``InputError`` naming it (``nan_policy="raise"``) or is held and flagged
(``"skip"``), a wrong shape raises ``InputError``, and the numba backend (when the filter has
one) matches the reference to 1e-9. Estimators: the state round-trips a quaternion, the
quaternion stays unit norm over steps of propagation, and the kernel matches the reference.
Detectors: one criteria value per sample and kernel == reference. Correctors and sensor models:
they run inside a pipeline with finite unit output, and the pipeline compiled with their kernel
(when they have one) matches the reference to 1e-9; a sensor model's ``report()`` is a dict, the
same from both paths (:func:`assert_reports_equal`). Estimators, detectors, sensor models and
correctors leave the arrays they are given unchanged (one that edited a sample in place changed
the user's recording).
"""

from __future__ import annotations

import inspect
import re
from typing import Any

import numpy as np

from ._numba import HAVE_NUMBA
from .config import PluginConfig
from .errors import ConfigError, InputError, PluginError
from .protocols import Corrector, Detector, Estimator, Filter, Plugin, Sample, SensorModel, plugin_class_problem
from .registry import default_registry
from .types import Flag, Recording

__all__ = ["check_plugin", "contract_recording", "assert_reports_equal"]

TOL = 1e-9


def contract_recording(seed: int = 0, rate: float = 100.0) -> Recording:
    """A short seeded recording: 3 s rest, rotations about three axes, a translation, rest."""
    from . import sim

    segs = [sim.Rest(3.0), sim.Rotate((0, 0, 1), 1.2, 1.0), sim.Rotate((1, 0, 0), -0.7, 0.8),
            sim.Translate((1, 1, 0), 0.3, 1.0), sim.Rotate((0, 1, 0), 0.9, 0.7), sim.Rest(0.5)]
    return sim.simulate(segs, rate=rate, noise=sim.Noise.mems(), seed=seed, name="contract")


def _resolve(plugin) -> type[Plugin]:
    if isinstance(plugin, str):
        return default_registry().get(plugin)
    if isinstance(plugin, Plugin):
        return type(plugin)
    return plugin


def check_plugin(plugin, params: dict[str, Any] | None = None, rec: Recording | None = None,
                 within: Any = None) -> None:
    """Check a plugin class (or registered name) against its kind's contract.

    ``within`` (correctors and sensor models): the pipeline config (a dict or ``PipelineConfig``,
    e.g. a preset's ``pipeline_config()``) to check the plugin in, instead of the smallest pipeline
    it runs in; its entry of the plugin's name takes ``params``. Each pipeline composition is a
    compile of its own (seconds): a test suite that compiles a preset anyway checks the plugins the
    preset composes in it at no compile of their own."""
    cls = _resolve(plugin)
    params = params or {}
    _check_common(cls, params)
    rec = rec or contract_recording()
    before = _arrays(rec)
    try:
        if issubclass(cls, Filter):
            _check_filter(cls, params, rec)
        elif issubclass(cls, Estimator):
            _check_estimator(cls(**params))
        elif issubclass(cls, Detector):
            _check_detector(cls(**params), rec)
        elif issubclass(cls, Corrector):
            _check_corrector(cls, params, rec, within)
        elif issubclass(cls, SensorModel):
            _check_model(cls, params, rec, within)
    except PluginError as exc:  # the pipeline's read-only samples: a plugin that wrote into one, as this rule
        if "wrote into a read-only array" not in str(exc):
            raise
        raise AssertionError(f"{cls.name}: it changes the sample it is given: {exc}") from exc
    changed = [k for k, a in _arrays(rec).items() if not np.array_equal(a, before[k], equal_nan=True)]
    assert not changed, f"{cls.name}: the recording's {', '.join(changed)} changed: a plugin must not change its input"


def _arrays(rec: Recording) -> dict[str, np.ndarray]:
    """Copies of the recording's sensor arrays (to tell whether a plugin changed them)."""
    return {k: np.array(getattr(rec, k)) for k in ("gyr", "acc", "mag") if getattr(rec, k) is not None}


def _assert_unchanged(name: str, what: str, given: Sample, kept: Sample) -> None:
    """The arrays of ``given`` (a plugin's input sample after its call) equal ``kept`` (copies made
    before): a plugin editing its sample in place changed the user's recording."""
    for k in ("gyr", "acc", "mag"):
        a, b = getattr(given, k), getattr(kept, k)
        if a is not None:
            assert np.array_equal(a, b, equal_nan=True), f"{name}: {what} changed sample.{k} in place ({b} -> {a})"


def _copied(sample: Sample) -> Sample:
    return sample._replace(**{k: np.array(getattr(sample, k)) for k in ("gyr", "acc", "mag")
                              if getattr(sample, k) is not None})


def _within(within, key: str, name: str, params: dict[str, Any]) -> dict[str, Any]:
    """``within`` as a pipeline config dict, its ``key`` entry named ``name`` given ``params``."""
    from .pipeline import Pipeline

    cfg = Pipeline.Config.model_validate(within).model_dump() if isinstance(within, dict) else within.model_dump()
    found = [e for e in cfg[key] if e["name"] == name]
    assert len(found) == 1, f"{name}: the pipeline to check it in has {len(found)} {key} of that name, not one"
    found[0]["params"] = dict(params)
    return cfg


def _check_common(cls, params) -> None:
    problem = plugin_class_problem(cls)  # (a Plugin that only said kind="filter", with no run(), passed)
    assert problem is None, problem
    assert issubclass(cls.Config, PluginConfig), f"{cls.__name__}.Config must subclass PluginConfig"
    for fname, f in cls.Config.model_fields.items():
        assert f.description, f"{cls.name}: config field {fname!r} has no description"
        extra = f.json_schema_extra if isinstance(f.json_schema_extra, dict) else {}
        assert "unit" in extra, f"{cls.name}: config field {fname!r} has no unit (use fusionkit.config.param)"
    try:
        cls(**params, no_such_parameter_xyz=1)
    except ConfigError as exc:
        assert "no_such_parameter_xyz" in str(exc), f"{cls.name}: the error does not name the unknown key: {exc}"
    else:
        raise AssertionError(f"{cls.name}: an unknown parameter was accepted")
    cls(**params)


def _assert_unit_quats(name, q, n) -> None:
    assert q.shape == (n, 4), f"{name}: quat has shape {q.shape}, expected ({n}, 4)"
    assert np.isfinite(q).all(), f"{name}: non-finite quaternion at sample {int(np.argmin(np.isfinite(q).all(1)))}"
    err = np.abs(np.linalg.norm(q, axis=1) - 1.0).max()
    assert err < 1e-6, f"{name}: quaternions are not unit norm (max deviation {err:.2e})"


def _check_filter(cls, params, rec) -> None:
    n = len(rec)
    f = cls(**params)
    res = f.run(rec, backend="reference")
    _assert_unit_quats(cls.name, res.quat, n)
    assert res.flags.shape == (n,), f"{cls.name}: flags has shape {res.flags.shape}, expected ({n},)"

    streaming = getattr(cls, "streaming", True)
    # run == a loop of update
    g = cls(**params)
    if not streaming:
        g = None
    dt = rec.dt
    mag = rec.mag
    if g is not None:
        extra = [{}] * n
        if "gnss" in inspect.signature(g.update).parameters:  # GNSS-aided filters take the latest epoch
            from .detectors.gnss_gap import gnss_sample_rows

            extra = [{"gnss": row} for row in gnss_sample_rows(rec)]
        for path in ("auto", "reference"):  # the compiled one-sample step where there is one, and the reference
            g.reset()
            if hasattr(g, "update_backend"):
                g.update_backend = path
            elif path == "reference":
                break
            streamed = np.array([g.update(rec.gyr[k], rec.acc[k], None if mag is None else mag[k], dt[k],
                                          **extra[k]) for k in range(n)])
            d = np.abs(streamed - res.quat).max()
            assert d < TOL, f"{cls.name}: run() and a loop of update() differ by {d:.2e} (update_backend {path!r})"

    # split run with the state carried over == one run (every streaming filter can be chunked)
    if streaming:
        assert "state" in inspect.signature(f.run).parameters, (
            f"{cls.name}: run() takes no state=, so a long recording cannot be processed in chunks")
        h = n // 2
        first = f.run(rec.slice(0, h), backend="reference")
        second = f.run(rec.slice(h, None), backend="reference", state=first.diagnostics["state"])
        d = np.abs(np.vstack([first.quat, second.quat]) - res.quat).max()
        assert d < TOL, f"{cls.name}: a split run differs from one run by {d:.2e}"

    # numba == reference, on every sample
    if HAVE_NUMBA:
        try:
            fast = f.run(rec, backend="numba")
        except ConfigError:
            fast = None  # the filter has no kernel
        if fast is not None:
            d = np.abs(fast.quat - res.quat).max()
            assert d < TOL, f"{cls.name}: numba and reference differ by {d:.2e}"
            assert np.array_equal(fast.flags, res.flags), f"{cls.name}: numba and reference flags differ"

    # bad input
    bad = rec.acc.copy()
    bad[77] = np.nan
    nan_rec = Recording(gyr=rec.gyr, acc=bad, mag=rec.mag, rate=rec.rate, t=rec.t, gnss=rec.gnss)
    if "nan_policy" in cls.Config.model_fields:
        try:
            cls(**{**params, "nan_policy": "raise"}).run(nan_rec)
        except InputError as exc:
            assert re.search(r"acc\[77\]", str(exc)), f"{cls.name}: the NaN error does not name acc[77]: {exc}"
        else:
            raise AssertionError(f"{cls.name}: a NaN sample did not raise with nan_policy='raise'")
        out = cls(**{**params, "nan_policy": "skip"}).run(nan_rec)
        _assert_unit_quats(cls.name + " (nan_policy='skip')", out.quat, n)
        assert out.flags[77] & Flag.ACC_INVALID, f"{cls.name}: the NaN sample was not flagged ACC_INVALID"
    try:
        f.run("not a recording")  # type: ignore[arg-type]
    except InputError:
        pass
    else:
        raise AssertionError(f"{cls.name}: run() accepted a str instead of a Recording")
    if not streaming:
        return
    try:
        f.update(np.zeros(2), np.zeros(3), None, 0.01)
    except InputError as exc:
        assert "(3,)" in str(exc), f"{cls.name}: the shape error does not state the expected shape: {exc}"
    else:
        raise AssertionError(f"{cls.name}: update() accepted a gyr of shape (2,)")


def _check_estimator(est: Estimator) -> None:
    rng = np.random.default_rng(1)
    q0 = rng.normal(size=4)
    q0 /= np.linalg.norm(q0)
    x = est.initial_state(q0)
    q = est.quat(x)
    assert min(np.abs(q - q0).max(), np.abs(q + q0).max()) < 1e-12, f"{est.name}: state does not round-trip {q0}"
    k = est.kernel()
    y = x.copy()
    out = np.empty(4)
    for i in range(500):
        w = rng.normal(scale=2.0, size=3)
        given = w.copy()
        est.propagate(x, given, 0.01)
        assert np.array_equal(given, w), f"{est.name}: propagate() changed the rate it was given in place"
        q = est.quat(x)
        # (only the initial round trip was checked: one whose quaternion drifted off unit norm passed)
        err = abs(float(np.linalg.norm(q)) - 1.0)
        assert err < 1e-6, f"{est.name}: quat() is off unit norm by {err:.2e} after {i + 1} steps of propagate()"
        if k is not None and HAVE_NUMBA:
            k.propagate(y, w[0], w[1], w[2], 0.01, k.params)
    if k is not None and HAVE_NUMBA:
        k.to_quat(y, out)
        d = np.abs(out - est.quat(x)).max()
        assert d < TOL, f"{est.name}: kernel and reference differ by {d:.2e}"


def _check_detector(det: Detector, rec: Recording) -> None:
    ref = det.run(rec, backend="reference")
    assert ref.criteria.shape == (len(rec),), f"{det.name}: criteria has shape {ref.criteria.shape}"
    if det.kernel() is not None and HAVE_NUMBA:
        fast = det.run(rec, backend="numba")
        assert np.array_equal(fast.criteria, ref.criteria), f"{det.name}: kernel and reference criteria differ"
    s = det.initial_state(rec.nominal_dt)
    kept = Sample(rec.gyr[0].copy(), rec.acc[0].copy(), None, rec.nominal_dt)
    given = _copied(kept)
    bits = det.step(s, given)
    assert isinstance(bits, (int, np.integer)), f"{det.name}: step() must return an int bitmask"
    _assert_unchanged(det.name, "step()", given, kept)


def _check_model(cls, params, rec, within=None) -> None:
    """A sensor model in a pipeline: the kernel equals the reference on every sample, states too."""
    from .pipeline import Pipeline

    model = cls(**params)  # its own input, called directly: unchanged
    s = model.initial_state(rec.nominal_dt)
    q = np.array([1.0, 0.0, 0.0, 0.0])
    mag = rec.mag
    for k in range(min(len(rec), 20)):
        kept = Sample(rec.gyr[k].copy(), rec.acc[k].copy(), None if mag is None else mag[k].copy(), rec.nominal_dt)
        given = _copied(kept)
        model.apply(s, given, q)
        _assert_unchanged(cls.name, "apply()", given, kept)
    if within is not None:
        p = Pipeline(_within(within, "models", cls.name, params))
    else:
        p = Pipeline({"estimator": "poisson-quat", "models": [{"name": cls.name, "params": params}],
                      "correctors": ["gradient-descent"], "alignment": {"mode": "fixed", "duration": 1.0}})
    res = p.run(rec, backend="reference")
    _assert_unit_quats(cls.name + " in a pipeline", res.quat, len(rec))
    assert isinstance(res.diagnostics.get("models"), dict), f"{cls.name}: no diagnostics['models'] in its pipeline"
    if all(m.kernel() is not None for m in p.models) and HAVE_NUMBA:
        fast = p.run(rec, backend="numba")
        d = np.abs(fast.quat - res.quat).max()
        assert d < TOL, f"{cls.name}: kernel and reference differ by {d:.2e} in a pipeline"
        assert np.array_equal(fast.flags, res.flags), f"{cls.name}: kernel and reference flags differ"
        for a, b in zip(fast.diagnostics["state"]["mod"], res.diagnostics["state"]["mod"]):
            assert np.allclose(a, b, rtol=0, atol=TOL, equal_nan=True), f"{cls.name}: kernel and reference states differ"
        assert_reports_equal(fast.diagnostics["models"], res.diagnostics["models"], what=f"{cls.name}: the reports")


def assert_reports_equal(a: dict, b: dict, tol: float = TOL, what: str = "reports") -> None:
    """Two :meth:`~fusionkit.protocols.SensorModel.report` dicts (or ``diagnostics["models"]``, a
    dict of them) are the same: the same keys, numbers and arrays within ``tol`` (NaN equal to NaN,
    an infinity to itself), anything else (a bool, a string, None) equal. What the compiled and
    the reference paths report must agree as their states do (1e-9)."""
    assert isinstance(a, dict) and isinstance(b, dict), f"{what}: not dicts ({type(a).__name__}, {type(b).__name__})"
    assert a.keys() == b.keys(), f"{what}: different keys ({sorted(a)} against {sorted(b)})"
    for k in a:
        x, y, at = a[k], b[k], f"{what}[{k!r}]"
        if isinstance(x, dict):
            assert_reports_equal(x, y, tol, at)
        elif x is None or isinstance(x, (str, bool, np.bool_)):
            assert x == y, f"{at}: {x!r} against {y!r}"
        else:
            assert np.shape(x) == np.shape(y), f"{at}: shapes {np.shape(x)} and {np.shape(y)}"
            assert np.allclose(x, y, rtol=0, atol=tol, equal_nan=True), f"{at}: {x} against {y} (beyond {tol:g})"


def _check_corrector(cls, params, rec, within=None) -> None:
    from .pipeline import Pipeline
    from .registry import default_registry

    if within is not None:
        p = Pipeline(_within(within, "correctors", cls.name, params))
        _check_corrector_in(cls, p, rec)
        return
    detectors = []
    if cls.requires_flag:  # a registered detector that sets the flag it acts on
        reg = default_registry()
        found = [n for n in reg.names("detector") if reg.get(n, "detector").flag & cls.requires_flag]
        assert found, f"{cls.name}: no registered detector sets {cls.requires_flag!r}, which it requires"
        detectors = [found[0]]
    estimator = "poisson-quat"
    if cls.state_layout:  # it works on the estimator's state: a registered estimator with that layout
        reg = default_registry()
        found = [n for n in reg.names("estimator") if reg.get(n, "estimator").state_layout == cls.state_layout]
        assert found, f"{cls.name}: no registered estimator has the state layout {cls.state_layout!r} it needs"
        estimator = found[0]
    p = Pipeline({"estimator": estimator, "correctors": [{"name": cls.name, "params": params}],
                  "detectors": detectors, "alignment": {"mode": "fixed", "duration": 1.0}})
    _check_corrector_in(cls, p, rec)


def _check_corrector_in(cls, p, rec) -> None:
    """The pipeline ``p``, which composes corrector ``cls``: finite unit output, and its compiled
    loop (when every plugin has a kernel) equals the reference on every sample, states too."""
    res = p.run(rec, backend="reference")
    _assert_unit_quats(cls.name + " in a pipeline", res.quat, len(rec))
    (c,) = [c for c in p.correctors if c.name == cls.name]
    kernel = c.kernel(p.estimator)
    if kernel is not None and HAVE_NUMBA:
        assert kernel.mode == cls.mode, f"{cls.name}: its kernel's mode {kernel.mode!r} is not its mode {cls.mode!r}"
        fast = p.run(rec, backend="numba")
        d = np.abs(fast.quat - res.quat).max()
        assert d < TOL, f"{cls.name}: kernel and reference differ by {d:.2e} in a pipeline"
        assert np.array_equal(fast.flags, res.flags), f"{cls.name}: kernel and reference flags differ"
        for a, b in zip(fast.diagnostics["state"]["cor"], res.diagnostics["state"]["cor"]):
            same = np.allclose(a, b, rtol=0, atol=TOL, equal_nan=True)
            assert same, f"{cls.name}: kernel and reference states differ"
