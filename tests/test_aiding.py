"""Every run says what corrected it (``Result.diagnostics["aiding"]``): a filter that can use a
magnetometer ran 6D, its heading the gyro's from an arbitrary start, on a recording without one,
and nothing in the result said so (only ``vqf`` recorded a mode)."""

import numpy as np
import pytest

import fusionkit as fk
from fusionkit import sim


@pytest.fixture(scope="module")
def recs():
    r = sim.demo_recordings()[0].slice(0, 300)  # (the readable paths: a test of what a run records, no compile)
    when = {"rate": r.rate} if r.t is None else {"t": r.t}
    nomag = fk.Recording(gyr=r.gyr, acc=r.acc, **when)
    dead = fk.Recording(gyr=r.gyr, acc=r.acc, mag=np.full_like(r.mag, np.nan), **when)
    return r, nomag, dead


@pytest.mark.parametrize("name, with_mag", [("recommended", "9D"), ("channel-dcm", "9D"), ("gst", "6D"),
                                            ("poisson", "gyro-only"), ("vqf", "9D")])
def test_every_run_records_its_aiding(recs, name, with_mag):
    r, nomag, _ = recs
    f = fk.make(name)
    res = f.run(r, backend="reference")
    assert res.diagnostics["aiding"] == with_mag
    assert f"{with_mag}," in repr(res)
    assert f.run(nomag, backend="reference").diagnostics["aiding"] == ("gyro-only" if with_mag == "gyro-only" else "6D")


def test_a_magnetometer_without_one_finite_sample_is_6d(recs):
    _, _, dead = recs
    res = fk.make("channel-dcm", nan_policy="skip").run(dead, backend="reference")
    assert res.diagnostics["aiding"] == "6D"


def test_offline_and_use_mag_false(recs):
    r, nomag, _ = recs
    for rec, aiding in ((r, "9D"), (nomag, "6D")):
        assert fk.make("recommended", offline=True).run(rec, backend="reference").diagnostics["aiding"] == aiding
    assert fk.make("recommended", use_mag=False).run(r, backend="reference").diagnostics["aiding"] == "6D"
