"""The accelerometer's lever arm: the simulator's ``lever_arm`` (rigid-body kinematics) and the
``lever-arm`` sensor model (fusionkit/models/lever_arm.py) that learns it online."""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np
import pytest

import fusionkit as fk
from fusionkit import sim
from fusionkit.benchmarking.metrics import rms_errors
from fusionkit.models.lever_arm import BEST, CONF, LEVER, STATE, STD, lever_arm_apply
from fusionkit.protocols import Sample
from fusionkit.rotations import quat_to_matrix
from fusionkit.sim import Rest, Rotate, SensorErrors, Translate
from fusionkit.testing import assert_reports_equal

R_TRUE = np.array([0.15, 0.03, -0.05])


def _hand_held(lever_arm=tuple(R_TRUE), **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the scenario's GNSS stream: one epoch past the end
        return sim.scenario("hand-held", lever_arm=lever_arm, **kw)


def _model_states(rec, acc=None, gyr=None, kernel=True, **params):
    """The model alone over a recording: the state and the corrected accelerometer (NaN where
    the sample has none) after every sample; ``kernel``: its numba kernel, else the reference."""
    m = fk.make("lever-arm", kind="model", **params)
    s = m.initial_state(rec.nominal_dt)
    acc = rec.acc if acc is None else acc
    gyr = rec.gyr if gyr is None else gyr
    states, out = np.empty((len(rec), STATE)), np.full((len(rec), 3), np.nan)
    q, kern = np.array([1.0, 0.0, 0.0, 0.0]), m.kernel()
    for k in range(len(rec)):
        g_ok, a_ok = bool(np.isfinite(gyr[k]).all()), bool(np.isfinite(acc[k]).all())
        if kernel:
            v = np.concatenate([gyr[k] if g_ok else np.zeros(3), acc[k] if a_ok else np.zeros(3), np.zeros(3)])
            kern.apply(s, v, g_ok, a_ok, False, q, float(rec.dt[k]), kern.params)
            res = v[3:6] if a_ok else None
        else:
            res = m.apply(s, Sample(gyr[k], acc[k] if a_ok else None, None, float(rec.dt[k])), q)[0].acc
        states[k] = s
        if res is not None:
            out[k] = res
    return states, out


def test_simulated_lever_arm_is_the_rigid_body_acceleration():
    """The simulator's lever-arm term is the second derivative of the sensor's position ``R r``
    (finite differences of the true orientation), seen in the body; the centre's own motion and
    every other sample are unchanged."""
    segs = [Rest(0.5), Rotate((1, 2, 0), 2.0, 1.0), Translate((1, 0, 0), 0.3, 1.0), Rest(0.5)]
    r = (0.2, -0.1, 0.05)
    rate = 1000.0
    plain = sim.simulate(segs, rate=rate, sampling="point", gnss_rate=None, errors=SensorErrors())
    lever = sim.simulate(segs, rate=rate, sampling="point", gnss_rate=None, errors=SensorErrors(lever_arm=r))
    pos = quat_to_matrix(plain.truth) @ np.array(r)  # the sensor's position from the centre, ENU
    acc_e = (pos[2:] - 2.0 * pos[1:-1] + pos[:-2]) * rate**2
    expected = np.einsum("nji,nj->ni", quat_to_matrix(plain.truth[1:-1]), acc_e)
    diff = lever.acc - plain.acc
    assert np.abs(diff).max() > 1.0  # the term is there (m/s^2)
    assert np.abs(diff[1:-1] - expected).max() < 1e-3 * np.abs(diff).max()  # the differences' own error
    assert np.array_equal(lever.gyr, plain.gyr) and np.array_equal(lever.truth, plain.truth)
    # interval means (the default sampling) average the same term
    mean = sim.simulate(segs, rate=rate, gnss_rate=None, errors=SensorErrors(lever_arm=r)).acc
    assert np.abs(mean - lever.acc)[1:].max() < 0.05
    with pytest.raises(fk.errors.InputError, match="lever_arm"):
        SensorErrors(lever_arm=(0.1, np.nan, 0.0))


def test_lever_arm_model_recovers_the_lever_arm():
    """Turns by hand about many axes, 15 cm / 3 cm / -5 cm: the fit is applied once confident
    and is within 3 % of |r|; it is not applied before ten high-pass time constants."""
    rec = _hand_held()
    st, acc = _model_states(rec)
    assert st[-1, CONF] == 1.0 and st[-1, STD] < 0.02
    assert np.linalg.norm(st[-1, LEVER:LEVER + 3] - R_TRUE) < 0.03 * np.linalg.norm(R_TRUE)
    early = np.arange(len(rec)) * rec.nominal_dt < 10.0  # ten hp_tau: the noise estimate is not trusted yet
    assert not st[early, CONF].any()
    assert np.array_equal(acc[early], rec.acc[early])  # unconfident: the sample passes unchanged


def test_lever_arm_model_estimates_nothing_without_a_lever_arm_or_rotation():
    """r = 0: the fit is ~0 (under 5 mm). A pure translation (no rotation: nothing to learn from)
    is never confident and leaves every sample unchanged."""
    st, _ = _model_states(_hand_held(lever_arm=(0.0, 0.0, 0.0)))
    assert np.linalg.norm(st[-1, BEST:BEST + 3]) < 0.005
    segs = [Rest(2.0)] + [Translate(d, 0.4, 1.0) for d in ((1, 0, 0), (0, 1, 0), (0, 0, 1), (-1, 0, 0))] * 4
    trans = sim.simulate(segs + [Rest(2.0)], rate=200.0, noise=sim.Noise.mems(), gnss_rate=None)
    st, acc = _model_states(trans)
    assert not st[:, CONF].any()
    assert np.array_equal(acc, trans.acc)


def test_lever_arm_model_follows_a_changed_grip():
    """The lever arm changes from 15 cm along x to 12 cm along y after 20 s: the forgetting
    (30 s) learns the new one (within 1.5 cm 60 s later)."""
    a, b = _hand_held(), _hand_held(lever_arm=(0.0, 0.12, 0.0))
    k = int(20.0 * a.rate)
    rec = fk.Recording(gyr=np.concatenate([a.gyr, b.gyr[1:], b.gyr[1:]]), rate=a.rate,
                       acc=np.concatenate([a.acc[:k], b.acc[k:], b.acc[1:], b.acc[1:]]))
    st, _ = _model_states(rec)
    assert np.linalg.norm(st[k - 1, LEVER:LEVER + 3] - R_TRUE) < 0.03
    assert st[-1, CONF] == 1.0 and np.linalg.norm(st[-1, LEVER:LEVER + 3] - (0.0, 0.12, 0.0)) < 0.015


def test_lever_arm_kernel_equals_reference():
    """The kernel gives the reference's state and corrected sample to 1e-9 on every sample,
    with an invalid gyro sample and a missing accelerometer sample in the stream."""
    rec = _hand_held(rate=100.0).slice(0, 1600)
    gyr, acc = rec.gyr.copy(), rec.acc.copy()
    gyr[700] = np.nan
    acc[900:903] = np.nan
    ref, ref_acc = _model_states(rec, acc=acc, gyr=gyr, kernel=False)
    fast, fast_acc = _model_states(rec, acc=acc, gyr=gyr)
    inf = np.isinf(ref)  # the standard deviation before there is any
    assert np.array_equal(inf, np.isinf(fast))
    assert np.abs(np.where(inf, 0.0, fast) - np.where(inf, 0.0, ref)).max() < 1e-9
    assert np.array_equal(np.isnan(ref_acc), np.isnan(fast_acc))
    assert np.nanmax(np.abs(fast_acc - ref_acc)) < 1e-9
    assert ref[-1, CONF] == 1.0  # it did get confident (the correction was compared too)
    assert fk.make("lever-arm", kind="model").kernel().apply is lever_arm_apply
    m = fk.make("lever-arm", kind="model")  # its report reads the state alone: the same from either state
    assert_reports_equal(m.report(fast[-1]), m.report(ref[-1]))


def _corrected(rec):
    """The recording with the model's corrected accelerometer (what composing it does: it reads
    only the IMU's samples)."""
    _, acc = _model_states(rec)
    return dataclasses.replace(rec, acc=np.where(np.isnan(acc), rec.acc, acc))


def test_the_model_removes_the_lever_arms_inclination_error():
    """``recommended`` 6D, 30 cm: once the model is confident (the last 10 s of 30) the
    inclination error is that of the same motion without a lever arm (within 0.01 deg), and
    0.03 deg better than without the model; with no lever arm it costs nothing (0.002 deg). The
    bias in motion is off: the Kalman bias filter learns along different paths on the three
    recordings (0.27 deg with the model, 0.30 clean), which would hide the lever arm's part; so is
    the adaptive time constant (its statistics see the lever arm before the model is confident:
    0.166 with the model against 0.096 clean)."""
    rec, clean = _hand_held(lever_arm=(0.3, 0.06, -0.1)), _hand_held(lever_arm=(0.0, 0.0, 0.0))
    f = fk.make("recommended", use_mag=False, motion_bias_tau=None, tau_adapt=False)
    last = rec.movement & (np.arange(len(rec)) * rec.nominal_dt >= 20.0)
    e = {name: rms_errors(f.run(r, backend="numba"), rec, mask=last)["inclination"]
         for name, r in (("base", rec), ("model", _corrected(rec)), ("clean", clean))}
    assert e["model"] < e["base"] - 0.03
    assert abs(e["model"] - e["clean"]) < 0.01
    whole = [rms_errors(f.run(r, backend="numba"), rec)["inclination"] for r in (clean, _corrected(clean))]
    assert abs(whole[1] - whole[0]) < 0.002


def test_lever_arm_reports_the_simulated_lever_arm():
    """``diagnostics["models"]["lever-arm"]`` of ``recommended`` with the model (``hand-held``,
    15 cm / 3 / -5 cm, 15 s at 100 Hz, reference path): the lever arm in m and body axes within 3%
    of ``|r|`` (the documented accuracy), each axis within four of its standard deviations, which
    are below ``max_std`` (2 cm), confident and applied; after 2 s not yet (NaN, inf)."""
    rec = _hand_held(rate=100.0).slice(0, 1500)
    f = fk.make("recommended", use_mag=False, lever_arm=True)
    res = f.run(rec, backend="reference")
    rep = res.diagnostics["models"]["lever-arm"]
    err = rep["lever_arm_m"] - R_TRUE
    assert np.linalg.norm(err) < 0.03 * np.linalg.norm(R_TRUE)
    assert (np.abs(err) < 4.0 * rep["std_m"]).all() and (rep["std_m"] <= rep["std_max_m"] + 1e-15).all()
    assert rep["std_max_m"] < 0.02 and rep["confident"] is True and rep["applied"] is True
    assert list(res.diagnostics["models"]) == ["lever-arm"]  # (use_mag=False: no mag-calibration)
    early = f.run(rec.slice(0, 200), backend="reference").diagnostics["models"]["lever-arm"]
    assert np.isnan(early["lever_arm_m"]).all() and early["std_max_m"] == np.inf and early["applied"] is False


def test_recommended_composes_the_model():
    """``lever_arm=True`` puts the model in front of ``recommended``: the same output as the
    model's corrected recording fed to ``recommended`` (reference path, once it is confident)."""
    rec = _hand_held(rate=100.0).slice(0, 1500)
    f = fk.make("recommended", use_mag=False, lever_arm=True)
    assert [m.name for m in f.models] == ["lever-arm"]  # (use_mag=False: no mag-calibration in front)
    assert "lever-arm" not in [m.name for m in fk.make("recommended").models]
    res = f.run(rec, backend="reference")
    assert res.diagnostics["state"]["mod"][0][CONF] == 1.0
    plain = fk.make("recommended", use_mag=False).run(_corrected(rec), backend="reference")
    assert np.abs(res.quat - plain.quat).max() < 1e-12
