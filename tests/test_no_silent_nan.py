"""A second new user's probe (stop 32): a plugin that returns NaN, a GNSS stream with no epoch in the IMU's
time, and a composed pipeline that reads GNSS: each was run without a word."""

import warnings

import numpy as np
import pytest

import fusionkit as fk
from fusionkit import sim
from fusionkit.errors import InputError, PluginError
from fusionkit.pipeline import Pipeline
from fusionkit.protocols import Correction, Corrector, Detector, SensorModel
from fusionkit.registry import Registry

NAN_RATE = Correction(np.array([np.nan, 0.0, 0.0]), 0)


def _with_corrector(name, returned):
    """A poisson-quat pipeline with one rate corrector ``name`` (registered for it alone) whose
    ``correct()`` returns ``returned`` on every sample."""

    class Returns(Corrector):
        mode = "rate"

        def correct(self, estimator, est_state, state, sample, flags, channel=None):
            return returned

    Returns.name = name
    reg = Registry()
    reg.register(Returns)
    return Pipeline({"estimator": "poisson-quat", "correctors": [name], "alignment": {"mode": "none"}}, registry=reg)


def test_a_plugin_that_returns_nan_is_named_not_passed_on():
    """A rate corrector returning a NaN correction made every later quaternion NaN, unflagged."""
    p = _with_corrector("test-nany", NAN_RATE)
    rec = sim.demo_recordings()[0].slice(0, 200)
    with pytest.raises(PluginError, match=r"not finite from sample 1 on: a plugin of this composition "
                                          r"\(poisson-quat, test-nany\)"):
        p.run(rec)


def test_a_gnss_stream_wholly_outside_the_imu_time_is_no_stream():
    """GNSS stamped in another time base (all epochs outside the IMU's): the epochs were dropped with a warning
    and ins-gnss / gst-gnss ran as if there were a stream (a free INS 5 km off after 480 s, no word), and the
    bench's metrics failed on the empty stream. Now the recording has no GNSS stream and they say they need one."""
    base = sim.simulate([sim.Rest(2.0), sim.Rotate((0, 0, 1), 1.0, 3.0)], rate=100.0, gnss_rate=10.0)
    g = base.gnss
    shifted = fk.Gnss(t=g.t + 1000.0, vel=g.vel, valid=g.valid, frame=g.frame, pos=g.pos)
    with pytest.warns(UserWarning, match=r"all \d+ GNSS epochs lie outside the IMU time .* no GNSS stream"):
        rec = fk.Recording(gyr=base.gyr, acc=base.acc, mag=base.mag, t=base.time, gnss=shifted, truth=base.truth)
    assert rec.gnss is None
    for name in ("gst-gnss", "ins-gnss"):
        with pytest.raises(InputError, match="needs a GNSS stream"):
            fk.make(name).run(rec)


def test_a_composed_pipeline_that_reads_gnss_needs_it():
    """``fusionkit describe gst-gnss --toml`` then ``fusionkit run`` on it: the composed pipeline lacked the
    preset's requires_gnss, ran without GNSS flagging every sample a gap, and was scored 6D (heading n/a)."""
    cfg = fk.make("gst-gnss").pipeline_config().model_dump()
    p = Pipeline(cfg)
    assert p.requires_gnss and not Pipeline(fk.make("gst").pipeline_config().model_dump()).requires_gnss
    r = sim.demo_recordings()[0].slice(0, 500)
    rec = fk.Recording(gyr=r.gyr, acc=r.acc, mag=r.mag, t=r.time)  # (the simulator's carry a GNSS stream)
    with pytest.raises(InputError, match=r"needs a GNSS stream .*: its gst-gnss corrector reads it"):
        p.run(rec)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fk.make("gst").run(rec, backend="reference")  # the autonomous one needs none


@pytest.mark.parametrize("returned, what", [(Correction(np.zeros(2), 0), r"a Correction whose rate has shape \(2,\)"),
                                            (np.zeros(3), "ndarray")])
def test_a_corrector_that_returns_the_wrong_thing_is_named(returned, what):
    """A rate corrector returning a rate of shape (2,) gave numpy's broadcast error, and a bare array numpy's
    '|=' on its .flags: neither named the plugin nor what it must return."""
    p = _with_corrector("test-wrong", returned)
    with pytest.raises(PluginError, match=rf"corrector 'test-wrong': correct\(\) returned {what}; it must return "
                                          r"Correction\(rate, flags\)"):
        p.run(sim.demo_recordings()[0].slice(0, 50))


@pytest.mark.parametrize("returned, what", [("yes", "str 'yes'"), (-1, "int -1"), (1.0, "float 1.0")])
def test_a_detector_that_returns_no_bitmask_is_named(returned, what):
    """A detector whose step() returned "yes" gave "invalid literal for int() with base 10: 'yes'" (a
    negative number numpy's OverflowError), in a pipeline and on its own: a PluginError naming the
    detector and what it must return, as for a corrector."""

    class Says(Detector):
        name = "test-says"
        flag = fk.Flag.MOTION

        def initial_state(self, dt):
            return np.zeros(1)

        def step(self, state, sample):
            return returned

    reg = Registry()
    reg.register(Says)
    rec = sim.demo_recordings()[0].slice(0, 50)
    message = (rf"detector 'test-says': step\(\) returned {what}; it must return its criteria bitmask, an int >= 0 "
               r"\(bit b: criteria_names\[b\]; 0: not fired\)")
    p = Pipeline({"estimator": "poisson-quat", "detectors": ["test-says"], "alignment": {"mode": "none"}}, registry=reg)
    with pytest.raises(PluginError, match=message):
        p.run(rec)
    with pytest.raises(PluginError, match=message):
        p.update(rec.gyr[0], rec.acc[0], dt=0.005)
    with pytest.raises(PluginError, match=message):
        Says().run(rec)


def test_a_detector_that_returns_a_comparison_fires_bit_0():
    """A detector's step() returning a comparison (numpy's bool: ``norm(g) > threshold``) is bit 0, as
    Python's bool is; the bitmask check of the stop refused it."""
    from fusionkit.detectors._run import checked_bits

    det = fk.get("motion")
    assert checked_bits(det, np.float64(2.0) > 1.0) == 1 and checked_bits(det, np.float64(0.0) > 1.0) == 0
    assert checked_bits(det, True) is True and checked_bits(det, np.uint32(5)) == 5


def test_the_offline_mode_warns_of_a_gap_once_at_the_recordings_index():
    """A 5 s gap gave six GapWarnings from the offline passes, half naming the reversed pass's sample index."""
    from fusionkit.types import GapWarning

    r = sim.demo_recordings()[1].slice(0, 3000)  # (12 s of rest, then turns)
    t = r.time.copy()
    t[2700:] += 5.0
    rec = fk.Recording(gyr=r.gyr, acc=r.acc, mag=r.mag, t=t)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = fk.make("recommended", offline=True).run(rec, backend="reference")  # (no compile for this test alone)
    gaps = [str(w.message) for w in caught if issubclass(w.category, GapWarning)]
    assert len(gaps) == 1 and "2700" in gaps[0], gaps
    # each pass restarts at the gap: the other one carries the samples next to it (the gap's own 5 s gave
    # the restarted pass 0.93 of full information, the weights were 0.48 / 0.52 on BROAD)
    w = res.diagnostics["backward_weight"]["inclination"]
    assert w[2698] < 0.05 and w[2701] > 0.95, (w[2698], w[2701])
    # a gap after the first sample: that sample's interval is a copy of the gap's, held too (it gave the forward
    # pass 0.81 of full information from one sample, the backward weight 0.003); each pass knows one sample there
    s = r.slice(0, 400)
    t = s.time.copy()
    t[1:] += 5.0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", GapWarning)
        first = fk.make("recommended", offline=True).run(fk.Recording(gyr=s.gyr, acc=s.acc, mag=s.mag, t=t),
                                                         backend="reference")
    assert 0.3 < first.diagnostics["backward_weight"]["inclination"][0] < 0.7


def test_a_stream_through_a_plugin_that_returns_nan_is_refused_too():
    """update() (the readable step, which a plugin without a kernel runs) passed the NaN on as run() did."""
    p = _with_corrector("test-nany-stream", NAN_RATE)
    g, a = np.array([0.01, 0.0, 0.0]), np.array([0.0, 0.0, 9.81])
    p.update(g, a, dt=0.01)  # the first sample: the correction enters the next propagation
    with pytest.raises(PluginError, match=r"not finite .* \(poisson-quat, test-nany-stream\)"):
        p.update(g, a, dt=0.01)


# -- a third probe (stop 33): a plugin that changed the user's recording, a sensor model returning the wrong thing


def _scaled_in_place(sample):
    """What the probe's plugins did: ``a = sample.acc; a *= 1.001`` (the sample's array changed in place)."""
    a = sample.acc
    a *= 1.001


class _EditsModel(SensorModel):
    name = "test-edits"

    def apply(self, state, sample, quat):
        _scaled_in_place(sample)
        return sample, 0


class _EditsCorrector(Corrector):
    name = "test-edits"
    mode = "rate"

    def correct(self, estimator, est_state, state, sample, flags):
        if sample.acc is not None:
            _scaled_in_place(sample)
        return Correction(None, 0)


class _EditsDetector(Detector):
    name = "test-edits"
    flag = fk.Flag.MOTION

    def initial_state(self, dt):
        return np.zeros(0)

    def step(self, state, sample):
        _scaled_in_place(sample)
        return 0


@pytest.mark.parametrize("cls, key, kind", [(_EditsModel, "models", "sensor model"),
                                            (_EditsCorrector, "correctors", "corrector"),
                                            (_EditsDetector, "detectors", "detector")])
def test_a_plugin_that_edits_its_sample_in_place_is_named_and_the_recording_kept(cls, key, kind):
    """A model, corrector or detector editing ``sample.acc`` in place changed the user's Recording (its
    rows were handed over as views: rec.acc came back 1.001 times larger, on the auto and reference
    backends) and update()'s caller's array. The plugins now get read-only views; writing into one is a
    PluginError naming the plugin, and nothing of the user's changes."""
    reg = Registry()
    reg.register(cls)
    rec = sim.demo_recordings()[0].slice(0, 30)
    acc0 = rec.acc.copy()
    p = Pipeline({"estimator": "poisson-quat", key: ["test-edits"], "alignment": {"mode": "none"}}, registry=reg)
    message = rf"{kind} 'test-edits' wrote into a read-only array, likely the sample it was given .*must not change"
    for backend in ("reference", "auto"):  # (auto: the reference, the plugin has no kernel)
        with pytest.raises(PluginError, match=message):
            p.run(rec, backend=backend)
        assert np.array_equal(rec.acc, acc0)
    a = rec.acc[0].copy()
    with pytest.raises(PluginError, match=message):
        p.update(rec.gyr[0], a, dt=0.01)
    assert np.array_equal(a, acc0[0])
    if cls is _EditsDetector:  # on its own too
        with pytest.raises(PluginError, match=message):
            cls().run(rec, backend="reference")
        assert np.array_equal(rec.acc, acc0)


def _with_model(name, apply):
    """A poisson-quat pipeline with one sensor model ``name`` (registered for it alone) whose ``apply``
    returns ``apply(sample)``."""

    class Returns(SensorModel):
        def apply(self, state, sample, quat):
            return apply(sample)

    Returns.name = name
    reg = Registry()
    reg.register(Returns)
    return Pipeline({"estimator": "poisson-quat", "models": [name], "correctors": ["gradient-descent"],
                     "alignment": {"mode": "none"}}, registry=reg)


@pytest.mark.parametrize("apply, what", [
    (lambda s: s, r"a Sample alone, not \(sample, flags\)"),
    (lambda s: (s._replace(gyr=np.zeros(2)), 0), r"\(sample, flags\) with sample.gyr of type ndarray, shape \(2,\)"),
    (lambda s: (s._replace(acc=list(s.acc)), 0), r"\(sample, flags\) with sample.acc of type list"),
    (lambda s: (s, None), r"\(sample, flags\) with flags None \(NoneType\)"),
    (lambda s: (s, 1.5), r"\(sample, flags\) with flags 1.5 \(float\)"),
    (lambda s: [s, 0, 0], r"list \["),
])
def test_a_sensor_model_that_returns_the_wrong_thing_is_named(apply, what):
    """A sensor model returning ``sample`` instead of ``(sample, flags)`` gave "too many values to unpack",
    a gyr of shape (2,) an IndexError from types._largest, an acc list an AttributeError ('tolist'), flags
    None or 1.5 a TypeError: none named the model. Now a PluginError says which and what it must return,
    as for a corrector; on run() and update()."""
    p = _with_model("test-wrong-model", apply)
    rec = sim.demo_recordings()[0].slice(0, 20)
    message = rf"sensor model 'test-wrong-model': apply\(\) returned {what}.*; it must return \(sample, flags\)"
    with pytest.raises(PluginError, match=message):
        p.run(rec)
    with pytest.raises(PluginError, match=message):
        p.update(rec.gyr[0], rec.acc[0], dt=0.01)


def test_every_numpy_write_into_a_read_only_sample_is_named():
    """numpy words a write into a read-only array several ways (``a.sort()``, ``np.put``, ``a.flat``): each
    is the plugin's write into its sample; a plugin's own error that mentions "read-only" is its own
    (review rev33d: the exact match of two messages let ``sample.acc.sort()`` through as a raw ValueError)."""
    from fusionkit.detectors._run import read_only, wrote_input

    class Named:
        name = "test-writes"

    a = read_only(np.arange(3.0))
    for write in (lambda: a.sort(), lambda: np.put(a, 0, 1.0), lambda: a.flat.__setitem__(0, 1.0),
                  lambda: a.__setitem__(0, 1.0), lambda: np.multiply(a, 2.0, out=a)):
        with pytest.raises(ValueError) as exc:
            write()
        with pytest.raises(PluginError, match="'test-writes' wrote into a read-only array"):
            wrote_input("sensor model", Named(), exc.value)
    assert wrote_input("sensor model", Named(), ValueError("my table is read-only, sorry")) is None


def test_model_reports_refuse_another_pipelines_state():
    """model_reports(state) zipped the models with the state's: another pipeline's state reported fewer
    models, or another model's layout, without a word (review rev33d)."""
    rec = sim.demo_recordings()[0].slice(0, 40)
    p = _with_model("test-report-model", lambda s: (s, 0))
    state = p.run(rec, backend="reference").diagnostics["state"]
    assert list(p.model_reports(state)) == ["test-report-model"]
    with pytest.raises(fk.InputError, match="one state per sensor model"):
        p.model_reports({**state, "mod": []})


def _debiased(sample):
    sample.gyr[:] -= 0.001  # the gyro corrected in place: a copy of its own, as before (review rev33c)
    return sample


@pytest.mark.parametrize("apply", [lambda s: [s, 0], lambda s: (s, np.False_), lambda s: (_debiased(s), np.int64(0))])
def test_what_a_sensor_model_may_return_and_change(apply):
    """A list (sample, flags), numpy's bool or int as flags, and a gyro corrected in place all ran before
    the return check and the read-only samples of the stop, and run still (review rev33c)."""
    p = _with_model("test-fine-model", apply)
    rec = sim.demo_recordings()[0].slice(0, 20)
    gyr0 = rec.gyr.copy()
    assert np.isfinite(p.run(rec, backend="reference").quat).all()
    assert np.array_equal(rec.gyr, gyr0)
