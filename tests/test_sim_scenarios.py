"""The simulator's scenarios: each builds the recording that isolates one sensor error, with
noise, and the error shows in it the way the plugin tested on it will see it."""

from __future__ import annotations

import numpy as np
import pytest

from fusionkit import sim
from fusionkit.benchmarking.timing import sensor_lags
from fusionkit.errors import InputError
from fusionkit.rotations import quat_conj, quat_mul, quat_to_matrix, quat_to_rotvec

from conftest import fit_ellipsoid


def _earth(rec, x):
    return np.einsum("nij,nj->ni", quat_to_matrix(rec.truth), x)


def test_every_scenario_builds_seeded_and_named():
    for name, make in sim.SCENARIOS.items():
        if name == "drifting-bias-long":
            a, b = make(duration=30.0), make(duration=30.0)
        else:
            a, b = make(), make()
        assert a.name == name and a.meta["scenario"] == name and a.meta["errors"].active
        np.testing.assert_array_equal(a.gyr, b.gyr, err_msg=name)
        np.testing.assert_array_equal(a.mag, b.mag, err_msg=name)
        assert a.movement.any() and (~a.movement).any()
    assert sim.scenario("late-gyro", delay=0.01).meta["errors"].gyr_delay == 0.01
    with pytest.raises(InputError, match="unknown scenario"):
        sim.scenario("no-such")


def test_hard_iron_turning_ellipsoid_centre_is_the_offset():
    """With MEMS noise (0.3 uT) the fitted centre is the offset to 0.1 uT and the soft-iron
    shape to 1 %."""
    a = np.array([[1.08, 0.04, 0.0], [0.04, 0.95, -0.03], [0.0, -0.03, 1.02]])
    rec = sim.scenarios.hard_iron_turning(offset=(20.0, -35.0, 12.0), matrix=a)
    centre, shape = fit_ellipsoid(rec.mag)
    np.testing.assert_allclose(centre, (20.0, -35.0, 12.0), atol=0.1)
    f = np.asarray(sim.KYIV_FIELD_ENU)
    np.testing.assert_allclose(shape * (f @ f), np.linalg.inv(a @ a.T), atol=0.01)


def test_magnet_nearby_disturbs_only_near_the_magnet():
    rec = sim.scenarios.magnet_nearby(noise=sim.Noise())
    dist = np.linalg.norm(_earth(rec, rec.mag) - sim.KYIV_FIELD_ENU, axis=1)
    near = rec.meta["ref_pos"][:, 0] > 1.999
    assert np.median(dist[near]) == pytest.approx(1e-7 * 3.0 / 0.3**3 * 1e6, rel=1e-3)  # 11.1 uT beside the magnet
    assert dist[:200].max() < 0.05  # 2.3 m away


@pytest.mark.parametrize("make, expected", [
    (lambda: sim.scenarios.late_gyro(delay=0.005), 1.0),
    (lambda: sim.scenarios.lowpass_gyro(cutoff=20.0, order=2), sim.lowpass_delay(20.0, 200.0, 2)),
])
def test_late_and_lowpassed_gyro_show_their_delay_against_the_accelerometer(make, expected):
    """What a time-offset estimator sees: the gyro later than the accelerometer by the delay
    (noise and biases on, within 0.1 sample)."""
    lags = sensor_lags(make())
    assert lags.gyr - lags.acc == pytest.approx(expected, abs=0.1)
    assert lags.mag - lags.acc == pytest.approx(0.0, abs=0.1)


def test_scaled_gyro_regresses_to_I_plus_S_plus_M():
    """Least squares of the gyro on the reference's rate gives ``I + S + M`` to 1e-3."""
    rec = sim.scenarios.scaled_gyro()
    e = rec.meta["errors"]
    q = rec.truth
    w = quat_to_rotvec(quat_mul(quat_conj(q[:-1]), q[1:])) * rec.rate  # the mean rate over each interval
    x, y = w, rec.gyr[1:] - rec.meta["gyr_bias"][1:]
    t = np.linalg.lstsq(x, y, rcond=None)[0].T
    np.testing.assert_allclose(t, np.eye(3) + np.diag(e.gyr_scale) + e.gyr_misalignment, atol=1e-3)


def test_drifting_bias_long_drifts_and_rests_show_it():
    rec = sim.scenarios.drifting_bias_long(duration=300.0)
    bias = rec.meta["gyr_bias"]
    assert np.ptp(bias, axis=0).max() > 1e-3  # rad/s: it wanders (2e-4 * sqrt(300) = 3.5e-3 per axis)
    rest = ~rec.movement
    err = np.abs(rec.gyr[rest] - bias[rest])
    assert err.std() < 0.01  # at rest the gyro reads the bias plus white noise (0.005)


def test_vibrating_tapped_and_lossy():
    vib = sim.scenarios.vibrating(noise=sim.Noise())
    x = vib.acc - sim.scenarios.vibrating(noise=sim.Noise(), amplitude=(0.0, 0.0, 0.0)).acc
    np.testing.assert_allclose(x.std(axis=0), [1.0, 1.0, 2.0], rtol=0.1)  # mean-sampled: the band's sinc
    tap = sim.scenarios.tapped(noise=sim.Noise())
    quiet = sim.scenarios.tapped(noise=sim.Noise(), times=())
    hit = tap.time[np.any(tap.acc != quiet.acc, axis=1)]
    np.testing.assert_allclose(hit, [4.005, 9.505, 15.005], atol=1e-9)  # each 5 ms tap within one 5 ms sample
    lossy = sim.scenarios.lossy()
    dt = np.diff(lossy.time)
    assert lossy.rate is None and dt.max() == pytest.approx(1.005, abs=1e-9)
    assert 0.005 < np.mean(dt[dt < 0.1] > 0.0075) < 0.05  # about 2 % of the rows lost


def test_scenarios_run_from_the_command_line(tmp_path):
    from fusionkit.cli import main

    assert main(["run", "poisson", "sim:tapped", "-o", str(tmp_path / "o.csv")]) == 0
    assert len((tmp_path / "o.csv").read_text().splitlines()) == len(sim.scenario("tapped")) + 1


def test_the_docs_scenario_table_names_every_scenario_and_its_duration(monkeypatch):
    """docs/simulator.md listed late-mag as 35 s (it lasts 39.2 s) and missed carried-magnet: its table
    now has every name of SCENARIOS once and each duration it states to the second. The durations come
    from the scenarios' segments on the sample grid (as simulate() lasts), not from simulating them."""
    import re
    from pathlib import Path

    from fusionkit.sim import scenarios

    text = (Path(__file__).resolve().parents[1] / "docs" / "simulator.md").read_text()
    rows = re.findall(r"^\| `([a-z-]+)` \| `([a-z_]+)\(.*?\)`(?:, ([\d.]+) s)? \|", text, flags=re.M)
    assert sorted(name for name, _, _ in rows) == sorted(sim.SCENARIOS)

    def lasts(name, segs, errors, rate, noise, seed, **kw):  # (scenarios' _run, without simulating)
        return type("Lasts", (), {"meta": {}, "seconds": sum(max(1, round(s.duration * rate)) for s in segs) / rate})

    monkeypatch.setattr(scenarios, "_run", lasts)
    for name, function, seconds in rows:
        assert sim.SCENARIOS[name].__name__ == function, name
        if seconds:
            actual = sim.SCENARIOS[name]().seconds
            assert abs(float(seconds) - actual) <= 0.5, f"{name}: the docs say {seconds} s, it lasts {actual} s"
