"""The ``magnetic`` disturbance detector: detection, recovery on a new homogeneous field, no
recovery for a magnet carried along, kernel == reference, and the pipeline's reaction."""

import dataclasses

import numpy as np
import pytest

import fusionkit as fk
from fusionkit import sim
from fusionkit.benchmarking.metrics import broad_errors
from fusionkit.detectors.magnetic import MAG_SIZE, MagneticDetector, magnetic_step

DEG = np.pi / 180


@pytest.fixture(scope="module")
def rec():
    segs = [sim.Rest(3.0)] + [sim.Rotate((0.2, 0.1, 1), 180 * DEG * (-1) ** i, 3.0) for i in range(16)]
    return sim.simulate(segs, rate=100.0, noise=sim.Noise(gyr_noise=0.002, acc_noise=0.02, mag_noise=0.2), seed=2,
                        gnss_rate=None)


def test_kernel_equals_reference_on_random_fields():
    det = MagneticDetector(new_time=0.5)
    rng = np.random.default_rng(0)
    a, b = np.zeros(MAG_SIZE), np.zeros(MAG_SIZE)
    for k in range(3000):
        # a steady field with jumps to other fields, some consistent for a while
        base = 50.0 if (k // 200) % 3 else 65.0
        norm, dip = base + rng.normal(scale=0.5), 1.1 + 0.3 * ((k // 300) % 2) + rng.normal(scale=0.01)
        rate = abs(rng.normal(scale=0.5))
        ra = det.reference_step(a, norm, dip, rate, 0.01)
        rb = magnetic_step(b, norm, dip, rate, 0.01, *det.step_params())
        assert ra == rb, k
        np.testing.assert_allclose(a, b, atol=1e-12)


def test_detects_a_nearby_magnet_and_not_the_clean_field(rec):
    mag = rec.mag.copy()
    mag[800:1200] += [30.0, -20.0, 10.0]
    clean = fk.make("magnetic", kind="detector").run(rec)
    assert clean.onset_index is None
    res = fk.make("magnetic", kind="detector").run(dataclasses.replace(rec, mag=mag))
    assert res.fired[800:1200].mean() > 0.95 and not res.fired[:800].any() and not res.fired[1210:].any()


def test_a_new_homogeneous_field_becomes_the_reference_while_turning(rec):
    """A field that stays constant in the earth frame (another room) is accepted after new_time
    s of turning; a magnet carried along with the body (a constant offset in the body) is not,
    because its norm and dip against the vertical change as the body turns."""
    new_field = sim.simulate([sim.Rest(3.0)] + [sim.Rotate((0.2, 0.1, 1), 180 * DEG * (-1) ** i, 3.0)
                                                for i in range(16)], rate=100.0, seed=2, gnss_rate=None,
                             mag_field=(5.0, 30.0, -30.0))
    mag = rec.mag.copy()
    mag[1000:] = new_field.mag[1000:]
    res = fk.make("magnetic", kind="detector", new_time=10.0).run(dataclasses.replace(rec, mag=mag))
    assert res.fired[1000:1500].all()  # disturbed at first
    # accepted after new_time = 10 s of turning: about 13 s here, the rate is below new_min_rate
    # near each raised-cosine segment's ends
    assert res.fired[2000:2200].all() and not res.fired[2500:].any()
    carried = rec.mag.copy()
    carried[1000:] += [25.0, 0.0, 0.0]  # a magnet attached to the body
    res = fk.make("magnetic", kind="detector", new_time=10.0).run(dataclasses.replace(rec, mag=carried))
    assert res.fired[1000:].mean() > 0.6


def _relearned(det, evidence, relearn=True):
    """Turning at 1 rad/s, 100 Hz: 2 s of field A (norm 50), then (``relearn``) the reference learned again on
    field B (norm 60: a recalibration inside a disturbance) and B for 3 s, then A for 25 s. Both paths step
    together (states equal to 1e-12); returns the seconds A is disturbed before it is the reference again."""
    from fusionkit.detectors.magnetic import follow_field, k_follow_field

    a, b = np.zeros(MAG_SIZE), np.zeros(MAG_SIZE)
    fields = [(50.0, 200), (60.0, 300), (50.0, 2500)]
    k, back = 0, None
    for i, (norm, n) in enumerate(fields):
        if i == 1 and relearn:
            assert follow_field(a, norm, 1.1, det.config.norm_threshold, det.config.dip_threshold, evidence)
            assert k_follow_field(b, norm, 1.1, det.config.norm_threshold, det.config.dip_threshold, evidence)
        for _ in range(n):
            ra = det.reference_step(a, norm, 1.1, 1.0, 0.01)
            assert magnetic_step(b, norm, 1.1, 1.0, 0.01, *det.step_params()) == ra
            np.testing.assert_allclose(a, b, atol=1e-12)
            if i == 2 and back is None and ra != 1:  # (1: MAG_DISTURBED)
                back = k * 0.01
            k += 1
    return back - 5.0


def test_a_relearned_reference_yields_to_a_field_seen_longer():
    """``relearn_evidence``: a reference learned again at a recalibration inside a disturbance (field B, learned
    over 1 s and used for 2 s while turning) yields to the earth's field (A, consistent while turning) after those
    3 s, instead of new_time (20 s); with the option off, after new_time. A reference learned at the
    start keeps new_time either way, so a disturbance that lasts less than new_time stays rejected."""
    det = MagneticDetector()
    assert abs(_relearned(det, True) - 3.0) < 0.05  # its 1 s of learning and 2 s of use while turning
    assert abs(_relearned(MagneticDetector(relearn_evidence=False), False) - 20.0) < 0.05
    # no relearn: B is a disturbance against the reference learned at the start, A its end (never disturbed)
    a = np.zeros(MAG_SIZE)
    codes = [det.reference_step(a, norm, 1.1, 1.0, 0.01) for norm, n in ((50.0, 200), (60.0, 1500)) for _ in range(n)]
    assert all(c == 1 for c in codes[300:])  # 15 s of B: still disturbed


def test_a_relearned_reference_is_not_replaced_without_turning():
    """A reference learned again and never used while turning still has its second of learning as evidence (or,
    learned from one sample, ``init_time`` 0, the candidate's own second): a different field at rest (which cannot
    be told from a magnet carried along) stays disturbed, on both paths."""
    from fusionkit.detectors.magnetic import follow_field, k_follow_field

    for init_time in (1.0, 0.0):
        _relearned_at_rest(MagneticDetector(init_time=init_time), follow_field, k_follow_field)


def _relearned_at_rest(det, follow_field, k_follow_field):
    a, b = np.zeros(MAG_SIZE), np.zeros(MAG_SIZE)
    for norm, n, rate in ((50.0, 200, 1.0), (60.0, 200, 0.0), (75.0, 500, 0.0), (75.0, 50, 1.0)):
        if norm == 60.0:
            assert follow_field(a, norm, 1.1, 0.1, 0.17, True) and k_follow_field(b, norm, 1.1, 0.1, 0.17, True)
        codes = []
        for _ in range(n):
            codes.append(det.reference_step(a, norm, 1.1, rate, 0.01))
            assert magnetic_step(b, norm, 1.1, rate, 0.01, *det.step_params()) == codes[-1]
            np.testing.assert_allclose(a, b, atol=1e-12)
        if norm == 75.0:
            assert all(c == 1 for c in codes)  # 5 s at rest, then 0.5 s turning: under the 1 s it needs


def test_pipeline_withholds_the_disturbed_magnetometer(rec):
    """With the detector, a gradient-descent pipeline's heading ignores the magnet."""
    mag = rec.mag.copy()
    mag[800:1600] += [30.0, -20.0, 10.0]
    bad = dataclasses.replace(rec, mag=mag)
    base = {"estimator": "poisson-quat", "correctors": [{"name": "gradient-descent", "params": {"beta": 0.5}}],
            "alignment": {"mode": "fixed", "duration": 1.0, "heading": "auto"}}
    plain = fk.compose(base).run(bad)
    guarded = fk.compose({**base, "detectors": ["magnetic"]}).run(bad)
    def head(r):
        return np.sqrt(np.mean(broad_errors(r.quat, rec.truth)["heading"][800:1600] ** 2))

    assert head(guarded) < 0.3 * head(plain), (head(guarded), head(plain))
    assert (guarded.flags[810:1600] & fk.Flag.MAG_DISTURBED).all()


def _steps(det, pattern, rate=0.0):
    """Field B (norm 60) for 1 s (the reference), then ``pattern`` (norms) repeated for 90 s at ``rate``, both
    paths step for step (states equal to 1e-12); the codes after the first second."""
    a, b = np.zeros(MAG_SIZE), np.zeros(MAG_SIZE)
    norms = [60.0] * 100 + [pattern[k % len(pattern)] for k in range(9000)]
    codes = []
    for k, norm in enumerate(norms):
        ra = det.reference_step(a, norm, 1.1, rate, 0.01)
        assert magnetic_step(b, norm, 1.1, rate, 0.01, *det.step_params()) == ra
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-12)
        codes.append(ra)
    return np.array(codes[100:]), a


def test_a_reference_that_describes_nothing_is_learned_again():
    """``max_rejection`` (an option; 60 s here): a reference learned on a field that then never comes back (learned
    inside a disturbance, or against a vertical still wrong at a start in motion) while the sensor does not turn
    enough for the new-field test is learned again after 60 s of rejection; without it (the default), never. A
    sample the reference describes pays back twice its time (VQF's magRejectionFactor): rejected two samples in
    three, it is kept. Learned again as at the start: a reference relearned so keeps new_time (no evidence count)."""
    codes, s = _steps(MagneticDetector(max_rejection=60.0), [50.0])
    assert (codes[:6000] == 1).all() and (codes[6000:6100] == 2).all() and (codes[6100:] == 0).all()
    # (1: disturbed; 2: learning, 1 s; 0: used)
    assert abs(s[0] - 50.0) < 1e-6 and s[7] == 0.0  # the field it learned again; no evidence count (slot _EV)
    codes, _ = _steps(MagneticDetector(), [50.0])
    assert (codes == 1).all()
    codes, _ = _steps(MagneticDetector(max_rejection=60.0), [50.0, 50.0, 60.0])
    assert not (codes == 2).any()  # (2: learning) never learned again


def test_the_detector_plugin_learns_again_after_max_rejection():
    """The ``magnetic`` detector plugin's kernel with the clock firing equals its reference step for step: an
    earth-fixed field from 1 s to the end, the sensor turning at 10 deg/s (under new_min_rate)."""
    from fusionkit.sim import FieldPatch, SensorErrors

    segs = [sim.Rotate((0.1, 0.2, 1.0), 30 * DEG * (-1) ** i, 3.0) for i in range(5)]
    slow = sim.simulate(segs, rate=100.0, noise=sim.Noise(gyr_noise=0.002, acc_noise=0.02, mag_noise=0.2), seed=2,
                        gnss_rate=None, errors=SensorErrors(patches=(FieldPatch((20.0, -15.0, 10.0), 1.0, 100.0),)))
    det = fk.make("magnetic", kind="detector", max_rejection=5.0)
    ref, fast = (det.run(slow, backend=b) for b in ("reference", "numba"))
    np.testing.assert_array_equal(ref.fired, fast.fired)
    assert ref.fired[110:590].all() and not ref.fired[620:].any()  # learned again 5 s after the field changed


def _start_in_motion(det, rate_first, second):
    """Field A (norm 50, dip 0.6: the earth's field measured against a vertical still wrong) for 1 s at
    ``rate_first`` rad/s, then field ``second`` (norm, dip) for 30 s turning at 1 rad/s, both paths step for step
    (states equal to 1e-12); the seconds the second field is disturbed before it is used (None: never)."""
    a, b = np.zeros(MAG_SIZE), np.zeros(MAG_SIZE)
    back = None
    for k in range(3100):
        norm, dip, rate = (50.0, 0.6, rate_first) if k < 100 else (*second, 1.0)
        ra = det.reference_step(a, norm, dip, rate, 0.01)
        assert magnetic_step(b, norm, dip, rate, 0.01, *det.step_params()) == ra
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-12)
        if k >= 100 and back is None and ra == 0:  # (0: MAG_USE)
            back = (k - 100) * 0.01
    return back


def test_a_reference_learned_while_turning_yields_to_its_own_norm_at_another_dip():
    """``start_evidence`` (an option, off by default): a recording that starts in motion learns its first reference
    while the accelerometer's vertical is still a guess, so its dip may be wrong and its norm is not. Such a
    reference (its learning began turning at new_min_rate or more) is replaced by a field of its own norm consistent
    while turning for as long as it was learned and used while turning (here its 1 s of learning, then none): about
    1 s, against new_time (20 s) with the option off. A field of another norm (a disturbance) still needs new_time,
    and so does the same dip change after a start at rest, where the vertical is the accelerometer's."""
    det = MagneticDetector(start_evidence=True)
    assert abs(_start_in_motion(det, 1.0, (50.0, 1.1)) - 1.0) < 0.05
    assert abs(_start_in_motion(MagneticDetector(), 1.0, (50.0, 1.1)) - 20.0) < 0.05  # (the default: off)
    assert abs(_start_in_motion(det, 1.0, (60.0, 1.1)) - 20.0) < 0.05  # another norm: a disturbance
    assert abs(_start_in_motion(det, 0.0, (50.0, 1.1)) - 20.0) < 0.05  # learned at rest
    # the field taken is kept as one learned at rest: a later dip change at its norm needs new_time again
    a = np.zeros(MAG_SIZE)
    codes = [det.reference_step(a, 50.0, 0.6 if k < 100 or k >= 1300 else 1.1, 1.0, 0.01) for k in range(3200)]
    assert all(c == 1 for c in codes[1300:])  # (1: MAG_DISTURBED) 19 s turning in the first dip: still disturbed


def test_a_start_in_motion_takes_the_earths_dip_soon_after_the_vertical_is_known():
    """The isolating simulation of ``start_evidence``: a recording cut to start in the middle of a turn (2 rad/s)
    while the body accelerates horizontally (3 m/s^2 north for its first 1.5 s), so ``recommended``'s first magnetic
    reference is learned against a vertical 17 deg off and its dip is wrong. Once the vertical is known, the
    earth's field (the same norm) is rejected: with the option off (the default) for new_time (here until 30 s),
    with it on for about 5 s. Run without the bias in motion (``motion_bias_tau=None``), which with its default
    learns part of that tilt as a gyro bias and then keeps the inclination, and with it the magnetometer's
    heading, a few degrees off for tens of seconds (docs/generalisation.md, "Stop 31")."""
    from fusionkit.benchmarking.metrics import truth_errors
    from fusionkit.rotations import quat_to_matrix

    segs = [sim.Rest(1.0)] + [sim.Rotate((0.2, 0.1, 1), 180 * DEG * (-1) ** i, 3.0) for i in range(14)]
    rec = sim.simulate(segs, rate=100.0, noise=sim.Noise.mems(), seed=3, gnss_rate=None).slice(250, None)
    acc = rec.acc.copy()
    acc[:150] += np.einsum("nij,i->nj", quat_to_matrix(rec.truth[:150]), [0.0, 3.0, 0.0])  # (R^T a, body frame)
    rec = dataclasses.replace(rec, acc=acc)
    t = np.arange(len(rec)) / 100.0
    rms, rejected = {}, {}
    for evidence in (True, False):
        res = fk.make("recommended", motion_bias_tau=None, magnetic={"start_evidence": evidence}).run(rec)
        rms[evidence] = np.sqrt(np.mean(truth_errors(res.quat, "ENU", rec)["total"][t > 5.0] ** 2))
        rejected[evidence] = t[np.flatnonzero(res.flags & fk.Flag.MAG_DISTURBED)[[0, -1]]]
    assert rejected[True][1] < 11.0 < 29.0 < rejected[False][1], rejected  # (4.2-9.7 s and 4.2-29.9 s)
    assert rms[True] < 0.75 * rms[False], rms  # (1.50 against 2.74 deg on the development machine)
    # the provisional reference and its replacement, compiled, give the reference paths' numbers (mag-heading's
    # start_evidence slot, the ekf's)
    part = rec.slice(0, 1300)
    for f in (fk.make("recommended", motion_bias_tau=None, magnetic={"start_evidence": True}),
              fk.make("ekf", magnetic={"start_evidence": True})):
        ref, fast = (f.run(part, backend=b) for b in ("reference", "numba"))
        assert np.abs(fast.quat - ref.quat).max() < 1e-9
        np.testing.assert_array_equal(fast.flags, ref.flags)
        dist = np.flatnonzero(ref.flags & fk.Flag.MAG_DISTURBED)
        assert dist.size and dist[-1] < 1280, f  # disturbed, then the earth's field taken (9.7 s; the ekf: 12.7 s)


def test_a_disturbance_of_the_earths_norm_after_a_start_in_motion_is_why_start_evidence_is_off():
    """The cost of ``start_evidence`` (reviewer rev31): the recording cut in the middle of a turn as above, no
    linear acceleration (the first reference is right), then an earth-fixed field of the earth's norm and a dip
    23 deg shallower from 4 to 16 s. With the option on, the provisional reference yields to it within seconds and
    the earth's field after it is rejected for new_time; off (the default), it is rejected throughout."""
    from fusionkit.benchmarking.metrics import truth_errors
    from fusionkit.sim.sensors import KYIV_FIELD_ENU

    segs = [sim.Rest(1.0)] + [sim.Rotate((0.2, 0.1, 1), 180 * DEG * (-1) ** i, 3.0) for i in range(12)]
    kw = dict(rate=100.0, noise=sim.Noise.mems(), seed=3, gnss_rate=None)
    earth = np.array(KYIV_FIELD_ENU)  # the simulator's field (ENU, uT)
    n, h = np.linalg.norm(earth), np.linalg.norm(earth) * np.cos(45 * DEG)
    other = sim.simulate(segs, mag_field=(h * np.sin(40 * DEG), h * np.cos(40 * DEG), -n * np.sin(45 * DEG)), **kw)
    rec = sim.simulate(segs, **kw)
    mag = rec.mag.copy()
    mag[650:1850] = other.mag[650:1850]
    rec = dataclasses.replace(rec, mag=mag).slice(250, None)
    t = np.arange(len(rec)) / 100.0
    rms = {}
    for ev in (True, False):
        res = fk.make("recommended", magnetic={"start_evidence": ev}).run(rec)
        rms[ev] = np.sqrt(np.mean(truth_errors(res.quat, "ENU", rec)["total"][t > 5.0] ** 2))
    assert rms[False] < 1.5 < 10.0 < rms[True], rms  # (0.59 against 32.2 deg)



def test_soft_rejection_uses_a_consistent_field_once_the_clock_has_run_out():
    """``max_rejection_mode="soft"`` (an option; VQF's magMaxRejectionTime): the reference is never learned again;
    a disturbed field consistent while turning for 1 s is used (MAG_SOFT, 3), weighed by its departure, once the
    reference has rejected for max_rejection. The clock starts full when a reference starts being learned (one that
    has described nothing may not reject) and each sample it describes earns twice its time. Both paths step for
    step."""
    soft = MagneticDetector(max_rejection=5.0, max_rejection_mode="soft")
    codes, s = _steps(soft, [50.0], rate=1.0)  # the reference (60) never describes the field (50)
    assert not (codes == 2).any()  # (2: learning) never learned again
    assert (codes[:100] == 1).all() and (codes[100:1999] == 3).all()  # the candidate's first 1 s, then used
    assert (codes[2001:] == 0).all() and abs(s[0] - 50.0) < 1e-6  # after new_time (20 s turning) the new field
    codes, _ = _steps(soft, [50.0], rate=0.0)  # not turning: never consistent evidence, never used
    assert (codes == 1).all()
    # a reference that first describes its field for 10 s has earned 20 s - 5 s... capped: it rejects for 5 s
    det = MagneticDetector(max_rejection=5.0, max_rejection_mode="soft")
    a, b = np.zeros(MAG_SIZE), np.zeros(MAG_SIZE)
    out = []
    for k in range(1100 + 1000):
        norm = 60.0 if k < 1100 else 50.0
        ra = det.reference_step(a, norm, 1.1, 1.0, 0.01)
        assert magnetic_step(b, norm, 1.1, 1.0, 0.01, *det.step_params()) == ra
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-12)
        out.append(ra)
    out = np.array(out[1100:])
    assert (out[:500] == 1).all() and (out[500:] == 3).all()  # rejected for max_rejection (5 s), then used
    relearn = MagneticDetector(max_rejection=5.0)  # the default mode: learned again at the clock
    codes, _ = _steps(relearn, [50.0], rate=1.0)
    assert (codes == 2).any() and not (codes == 3).any()


def test_soft_rejection_in_mag_heading_and_the_ekf():
    """``recommended`` with the soft mode: a field fixed in the earth frame over 2-40 s, turning at 90 deg/s (the
    reference learned at rest before it), max_rejection 5 s: the disturbed samples are flagged MAG_DISTURBED, and
    after the clock those consistent for 1 s are used (the heading moves towards the disturbed field's, weighed by
    its departure); compiled equals reference. The ekf keeps such a sample out: its result is the one without the
    clock."""
    from fusionkit.sim import FieldPatch, SensorErrors

    segs = [sim.Rest(2.0)] + [sim.Rotate((0.1, 0.2, 1.0), 90 * DEG * (-1) ** i, 1.0) for i in range(12)]
    rec = sim.simulate(segs, rate=100.0, noise=sim.Noise(gyr_noise=0.002, acc_noise=0.02, mag_noise=0.2), seed=1,
                       gnss_rate=None, errors=SensorErrors(patches=(FieldPatch((20.0, 20.0, 0.0), 2.0, 40.0),)))
    soft = {"max_rejection": 5.0, "max_rejection_mode": "soft"}
    f = fk.make("recommended", magnetic=soft)
    ref, fast = (f.run(rec, backend=b) for b in ("reference", "numba"))
    assert np.abs(fast.quat - ref.quat).max() < 1e-9
    np.testing.assert_array_equal(fast.flags, ref.flags)
    hard = fk.make("recommended", magnetic={"max_rejection": None}).run(rec)
    dist = (ref.flags & fk.Flag.MAG_DISTURBED) != 0
    assert dist[300:1300].mean() > 0.95 and (hard.flags[300:1300] & fk.Flag.MAG_DISTURBED).all()
    moved = np.abs(fast.quat[1300] - hard.quat[1300]).max()
    assert moved > 1e-3, moved  # the soft samples moved the heading
    e_soft, e_none = (fk.make("ekf", magnetic=m).run(rec).quat for m in (soft, {"max_rejection": None}))
    np.testing.assert_array_equal(e_soft, e_none)


def test_the_soft_mode_needs_a_clock_and_follows_rejection():
    """Review rev32: ``max_rejection_mode="soft"`` without ``max_rejection`` was accepted and did nothing; and
    with mag-heading's ``rejection=False`` (disturbed samples used as any other) a soft sample was flagged and
    halved, weighed below a disturbed one. Now the first is a ConfigError and the second a sample like any other."""
    from fusionkit.errors import ConfigError
    from fusionkit.sim import FieldPatch, SensorErrors

    with pytest.raises(ConfigError, match="max_rejection_mode 'soft' needs max_rejection"):
        fk.make("recommended", magnetic={"max_rejection_mode": "soft"})
    segs = [sim.Rest(2.0)] + [sim.Rotate((0.1, 0.2, 1.0), 90 * DEG * (-1) ** i, 1.0) for i in range(8)]
    rec = sim.simulate(segs, rate=100.0, noise=sim.Noise(gyr_noise=0.002, acc_noise=0.02, mag_noise=0.2), seed=1,
                       gnss_rate=None, errors=SensorErrors(patches=(FieldPatch((20.0, 20.0, 0.0), 2.0, 9.0),)))
    for gain, backends in (("kalman", ("reference", "numba")), ("fixed", ("reference",))):  # (the fixed gain's
        # compiled loop would be a compile of its own for this test alone: the kalman one covers the kernel's branch)
        runs = [fk.make("recommended", mag_rejection=False, heading_gain=gain, magnetic=m).run(rec, backend=b)
                for m in ({"max_rejection": 2.0, "max_rejection_mode": "soft"}, {"max_rejection": None})
                for b in backends]
        for r in runs[1:]:
            assert np.abs(r.quat - runs[0].quat).max() < 1e-9
            np.testing.assert_array_equal(r.flags, runs[0].flags)
        assert not (runs[0].flags & fk.Flag.MAG_DISTURBED).any()
