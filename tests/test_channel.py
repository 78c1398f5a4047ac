"""The pipeline's channel (:class:`fusionkit.types.Channel`): a corrector publishes a named
quantity, a later one reads it, in the same sample, on both paths. ``recommended``'s use of it:
``inertial-tilt`` publishes what its inclination error is, ``mag-heading`` (``inclination_noise``,
``heading_inclination_noise``) counts it in a magnetometer heading's variance, where the heading read
in the levelled frame turns by ``tan(dip)`` times the inclination error about the field's axis."""

import math

import numpy as np
import pytest

import fusionkit as fk
from fusionkit.benchmarking.metrics import rms_errors
from fusionkit.correctors import tilt as T
from fusionkit.errors import ConfigError
from fusionkit.pipeline import _CHAN
from fusionkit.sim import Noise, Rest, Rotate, Translate, simulate
from fusionkit.sim.sensors import KYIV_FIELD_ENU
from fusionkit.types import CHANNEL_SIZE, Channel

from conftest import backend_quats

DEG = math.pi / 180.0


def _translation(dip, seed=2):
    """``fusionkit demo``'s translation (six 0.5 m pushes along the axes, a turn; 200 Hz, MEMS noise)
    in a field of the demo's strength with dip ``dip`` (deg): benchmarks/tilt_heading_coupling.py."""
    axes = ((1, 0, 0), (0, 1, 0), (0, 0, 1), (-1, 0, 0), (0, -1, 0), (0, 0, -1))
    segs = [Rest(12.0)] + [Translate(d, 0.5, 1.5) for d in axes] + [Rotate((0, 0, 1), 30 * DEG, 2.0), Rest(5.0)]
    b = float(np.linalg.norm(KYIV_FIELD_ENU))
    field = np.array([0.0, b * math.cos(dip * DEG), -b * math.sin(dip * DEG)])
    return simulate(segs, rate=200.0, noise=Noise.mems(), seed=seed, name="translation", mag_field=field)


@pytest.fixture(scope="module")
def steep():
    return _translation(68.0)


@pytest.mark.parametrize("split", [False, True])
def test_reference_equals_numba(steep, split):
    """With the heading reading the tilt's channel: reference == numba to 1e-9 on every sample, also
    across a split run (the channel is part of the run state)."""
    f = fk.make("recommended", heading_inclination_noise=True)
    out = backend_quats(f, steep.slice(0, 5000), 2600 if split else None)
    assert np.abs(out["numba"] - out["reference"]).max() < 1e-9


def test_the_tilt_publishes_its_inclination_error(steep):
    """inertial-tilt with tau_adapt writes its gyro part, time constant and let-through tilt into the
    channel when a corrector reads it; without tau_adapt, or with no reader (``recommended``'s default:
    mag-heading without ``inclination_noise``), nothing (the channel stays 0, 'nothing known')."""
    f = fk.make("recommended", heading_inclination_noise=True)
    st = f.run(steep.slice(0, 3000)).diagnostics["state"]
    ch = st["align"][_CHAN:_CHAN + CHANNEL_SIZE]
    (i,) = [k for k, c in enumerate(f.correctors) if c.name == "inertial-tilt"]
    x = st["cor"][i]
    assert ch[Channel.INCLINATION_VARIANCE] == x[T._IVAR] > 0.0
    assert ch[Channel.INCLINATION_TIME] == x[T._TAU] > 0.0
    assert 0.0 < np.linalg.norm(ch[Channel.LET_THROUGH:Channel.LET_THROUGH + 3]) < 10 * DEG
    st = fk.make("recommended", tau_adapt=False).run(steep.slice(0, 3000)).diagnostics["state"]
    assert not st["align"][_CHAN:_CHAN + CHANNEL_SIZE].any()
    for backend in ("numba", "reference"):
        st = fk.make("recommended").run(steep.slice(0, 300), backend=backend).diagnostics["state"]
        assert not st["align"][_CHAN:_CHAN + CHANNEL_SIZE].any(), backend


# the inclination as it was when these were measured: with tau_max_parallel and the rest's pin (the defaults
# since) less of a push's onset gets through, and the channel's gain shrinks with what it models (heading RMS
# off / on, deg: steep dip 0.184 / 0.176, east push 0.181 / 0.174, north push 0.127 / 0.121), so the channel is
# tested where its effect is well above the rest
LET_THROUGH = {"tau_max_parallel": False, "bias_sigma_rest": None}


def test_the_coupling_at_a_steep_dip_shrinks(steep):
    """At a dip of 68 deg the heading read in the levelled frame follows the inclination's let-through
    (tan 68 = 2.5 times it): counting it in the heading's variance lowers the 9D heading error over
    the motion; at a dip of 0 there is no coupling and it changes nothing."""
    on = fk.make("recommended", heading_inclination_noise=True, **LET_THROUGH)
    off = fk.make("recommended", **LET_THROUGH)
    h_on, h_off = (rms_errors(f.run(steep), steep)["heading"] for f in (on, off))
    assert h_on < 0.95 * h_off
    flat = _translation(0.0)
    assert rms_errors(on.run(flat), flat)["heading"] == pytest.approx(rms_errors(off.run(flat), flat)["heading"],
                                                                        abs=0.002)


def test_only_a_push_across_the_field_counts():
    """The let-through tilt is about ``up x`` the acceleration: a push along the field's horizontal
    direction (north) changes the dip, not the heading, and the heading's variance must not count
    it; a push across it (east) turns the heading by tan(dip) times the tilt, and does count."""
    out = {}
    for name, ax in (("east", (1, 0, 0)), ("north", (0, 1, 0))):
        back = tuple(-a for a in ax)
        rec = simulate([Rest(12.0)] + [Translate(ax, 0.5, 1.5), Translate(back, 0.5, 1.5)] * 3 + [Rest(5.0)],
                       rate=200.0, noise=Noise.mems(), seed=0, name=name)
        out[name] = [rms_errors(fk.make("recommended", heading_inclination_noise=on, **LET_THROUGH).run(rec),
                                rec)["heading"]
                     for on in (False, True)]
    (e_off, e_on), (n_off, n_on) = out["east"], out["north"]
    assert e_on < 0.95 * e_off
    assert abs(n_on - n_off) < 0.3 * (e_off - e_on)


def _pipeline(correctors):
    return fk.compose({"estimator": {"name": "poisson-quat"}, "correctors": correctors,
                       "alignment": {"mode": "none", "initial_quat": (1.0, 0.0, 0.0, 0.0)}})


def test_a_reader_before_its_publisher_is_refused():
    """mag-heading (inclination_noise) reads what inertial-tilt publishes: put before it, it would
    read the previous sample's value; two publishers of one quantity are ambiguous. Alone, it reads
    0 (nothing known); without inclination_noise it reads nothing, so any order is its own."""
    tilt = {"name": "inertial-tilt", "params": {"tau_adapt": True}}
    head = {"name": "mag-heading", "params": {"gain": "kalman", "inclination_noise": True}}
    with pytest.raises(ConfigError, match="INCLINATION_VARIANCE.*put the publisher first"):
        _pipeline([head, tilt])
    with pytest.raises(ConfigError, match="both publish"):
        _pipeline([tilt, tilt, head])
    _pipeline([tilt, head])
    _pipeline([head])
    _pipeline([{"name": "mag-heading", "params": {"gain": "kalman"}}, tilt])


def test_only_what_a_configuration_publishes_counts():
    """inertial-tilt publishes only with tau_adapt: without it two of them (a composition the
    pipeline took before the channel) are not two publishers, and a reader before one is not reading
    what it publishes. Two that publish are ambiguous only to a reader of the quantity."""
    plain = {"name": "inertial-tilt", "params": {"tau_adapt": False}}
    adapt = {"name": "inertial-tilt", "params": {"tau_adapt": True}}
    head = {"name": "mag-heading", "params": {"gain": "kalman", "inclination_noise": True}}
    _pipeline([plain, plain])
    _pipeline([head, plain])
    _pipeline([adapt, adapt])
    with pytest.raises(ConfigError, match="both publish"):
        _pipeline([adapt, adapt, head])
    with pytest.raises(ConfigError, match="put the publisher first"):
        _pipeline([head, adapt])


def test_bias_and_rate_correctors_get_the_channel_on_both_paths():
    """The channel reaches every corrector mode, not only factor ones: a bias corrector that publishes
    (the time since the start, as INCLINATION_TIME) and a rate corrector after it that turns the
    estimate by what it reads; reference == compiled (the kernels take ``ch`` after their parameters),
    also across a split run, and the reader reads 0 without the publisher."""
    from fusionkit._numba import njit
    from fusionkit.pipeline import Pipeline
    from fusionkit.protocols import BiasCorrector, Correction, Corrector, CorrectorKernel
    from fusionkit.registry import Registry

    t_idx = int(Channel.INCLINATION_TIME)

    @njit(cache=False)
    def clock(s, b, g0, g1, g2, a0, a1, a2, m0, m1, m2, acc_ok, mag_ok, flags, dt, p, ch):
        ch[t_idx] += dt
        return 0

    @njit(cache=False)
    def spin(q, s, g0, g1, g2, a0, a1, a2, m0, m1, m2, acc_ok, mag_ok, flags, dt, p, rate, ch):
        rate[2] += p[0] * ch[t_idx]
        return 0

    class Clock(BiasCorrector):
        name = "test-clock"
        publishes = (Channel.INCLINATION_TIME,)

        def update_bias(self, state, bias, sample, flags, channel=None):
            channel[t_idx] += sample.dt
            return 0

        def kernel(self, estimator):
            return CorrectorKernel(clock, np.zeros(1), mode="bias")

    class Spin(Corrector):
        name = "test-spin"
        mode = "rate"
        reads = (Channel.INCLINATION_TIME,)

        def correct(self, estimator, est_state, state, sample, flags, channel=None):
            return Correction(np.array([0.0, 0.0, 1e-3 * channel[t_idx]]), 0)

        def kernel(self, estimator):
            return CorrectorKernel(spin, np.array([1e-3]), mode="rate")

    reg = Registry()
    reg.register(Clock)
    reg.register(Spin)
    rec = _translation(68.0).slice(0, 1500)

    def make(names):
        return Pipeline({"estimator": "poisson-quat", "correctors": names, "alignment": {"mode": "none"}},
                        registry=reg)

    both = make(["test-clock", "test-spin"])
    out = backend_quats(both, rec)
    assert np.abs(out["numba"] - out["reference"]).max() < 1e-12
    split = backend_quats(both, rec, 700)
    assert np.abs(split["numba"] - out["numba"]).max() < 1e-12
    assert np.abs(split["reference"] - out["numba"]).max() < 1e-12
    alone = backend_quats(make(["test-spin"]), rec)
    assert np.abs(alone["numba"] - alone["reference"]).max() < 1e-12
    # 7.5 s of a rate growing as 1e-3 t: about 0.028 rad about z more than the spin alone (which reads 0)
    turn = 2 * np.arccos(np.clip(np.abs(np.sum(out["numba"][-1] * alone["numba"][-1])), 0, 1))
    assert 0.02 < turn < 0.04
    # the order that counts is the one they run in: bias correctors before the propagation, then the state
    # and rate correctors, then the factor ones; a bias corrector listed after its reader still runs first
    late = backend_quats(make(["test-spin", "test-clock"]), rec)
    assert np.abs(late["numba"] - out["numba"]).max() < 1e-12

    class Early(BiasCorrector):  # a bias corrector that reads what a factor corrector publishes
        name = "test-early"
        reads = (Channel.INCLINATION_TIME,)

        def update_bias(self, state, bias, sample, flags, channel=None):
            return 0

    reg.register(Early)
    reg.register(T.InertialTilt)
    with pytest.raises(ConfigError, match="test-early.*put the publisher first"):
        Pipeline({"estimator": "poisson-quat", "alignment": {"mode": "none"},
                  "correctors": [{"name": "inertial-tilt", "params": {"tau_adapt": True}}, "test-early"]}, registry=reg)


def test_the_pipeline_tells_a_publisher_what_is_read():
    """``Corrector.channel_read``: the pipeline sets it to what of a corrector's publications a later
    corrector reads (inertial-tilt skips writing the rest); outside a pipeline it is None and the
    corrector writes everything it publishes."""
    def tilt_of(f):
        (c,) = [c for c in f.correctors if c.name == "inertial-tilt"]
        return c

    read = tilt_of(fk.make("recommended", heading_inclination_noise=True))
    assert Channel.INCLINATION_VARIANCE in read.channel_read and read._publishing()
    unread = tilt_of(fk.make("recommended"))
    assert unread.channel_read == () and not unread._publishing()
    alone = type(unread)(unread.config)
    assert alone.channel_read is None and alone._publishing()
