"""benchmarks/generalisation.py reports what the filters do: its table and its numbers against a
direct run of the filters on the same recording (so the benchmark cannot silently misreport),
and the simulator's ``perturbed`` it draws its recordings from."""

from __future__ import annotations

import math
import sys

import numpy as np
import pytest

import fusionkit as fk
from fusionkit.benchmarking.metrics import broad_errors
from fusionkit.sim import scenario
from fusionkit.sim.scenarios import perturbed

sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parents[1] / "benchmarks"))
gen = pytest.importorskip("generalisation")
vqf = pytest.importorskip("vqf")


def _incl_rms(q, rec):
    e = broad_errors(q, rec.truth)["inclination"][rec.movement]
    return float(np.sqrt(np.mean(e**2)))


@pytest.fixture(scope="module")
def rows():
    conds = []
    for fam, seed in (("tapped", 3), ("vibrating", 4)):
        c = gen.draw(fam, seed, quick=True)
        c.update(rate=100.0, initial_rest=1.0)
        c["errors"].pop("mag_rate", None)
        conds.append(c)
    return [{"cond": c, "rmse": gen.evaluate(c, ("recommended", "vqf"))} for c in conds]


def test_numbers_match_a_direct_run(rows):
    c = rows[0]["cond"]
    rec = gen.build(c)
    assert rec.rate == 100.0 and rec.meta["perturbed"]["initial_rest"] == 1.0
    mine = fk.make("recommended", use_mag=False).run(rec)
    assert rows[0]["rmse"]["6D"]["recommended"] == pytest.approx(_incl_rms(mine.quat, rec), rel=1e-12)
    ts = 1.0 / rec.rate
    c64 = np.ascontiguousarray
    peer = vqf.VQF(ts).updateBatch(c64(rec.gyr), c64(rec.acc))["quat6D"]
    assert rows[0]["rmse"]["6D"]["vqf"] == pytest.approx(_incl_rms(peer, rec), rel=1e-9)
    for r in rows:
        for dims, _ in gen.DIMS:
            assert set(r["rmse"][dims]) == {"recommended", "vqf"}
            assert all(math.isfinite(v) and 0 < v < 90 for v in r["rmse"][dims].values())


def test_table_structure(rows):
    text = gen.tables(rows, ["recommended", "vqf"])
    assert "### 6D" in text and "### 9D" in text
    for fam in ("tapped", "vibrating", "all"):
        line = next(ln for ln in text.split("\n") if ln.startswith(f"| {fam} |"))
        cells = [x.strip() for x in line.strip("|").split("|")]
        assert cells[1] == ("2" if fam == "all" else "1")
        assert float(cells[2]) > 0 and float(cells[3]) > 0 and cells[4].endswith("%")
    line = next(ln for ln in text.split("\n") if ln.startswith("| tapped |"))  # the 6D table's row comes first
    assert float(line.split("|")[3]) == pytest.approx(rows[0]["rmse"]["6D"]["recommended"], abs=6e-4)
    for axis in gen.buckets(rows[0]["cond"]):
        assert f"| {axis} |" in text


def test_losses_are_the_ratios_above_the_margin(rows):
    fake = [{"cond": rows[0]["cond"], "rmse": {"6D": {"recommended": 2.0, "vqf": 1.0},
                                               "9D": {"recommended": 1.05, "vqf": 1.0}}},
            {"cond": rows[1]["cond"], "rmse": {"6D": {"recommended": 1.0, "vqf": 2.0},
                                               "9D": {"recommended": 3.0, "vqf": 2.0}}}]
    out = gen.losses(fake, ["recommended", "vqf"])
    assert [(round(q, 3), d) for q, d, _ in out] == [(2.0, "6D"), (1.5, "9D")]


def test_draws_are_deterministic_and_keep_the_family_error():
    a, b = gen.draw("late-gyro", 7), gen.draw("late-gyro", 7)
    assert gen.describe(a) == gen.describe(b) and "gyr_delay" not in a["errors"]
    assert gen.draw("late-gyro", 8)["noise"] != a["noise"]


def test_perturbed_adds_errors_and_the_initial_rest_but_keeps_the_scenarios_own():
    base = scenario("tapped", rate=50.0)
    rec = perturbed("tapped", initial_rest=5.0, errors={"gyr_scale": (0.01, 0.0, 0.0), "taps": ()}, rate=50.0)
    assert len(rec) == len(base) + 3 * 50  # its 2 s first rest made 5 s
    assert not rec.movement[:250].any() and rec.movement[251:400].any()
    e = rec.meta["errors"]
    assert e.gyr_scale == (0.01, 0.0, 0.0) and len(e.taps) == 3  # the scenario's taps stay
    again = scenario("tapped", rate=50.0)  # perturbed leaves nothing behind
    np.testing.assert_array_equal(again.gyr, base.gyr)
    with pytest.raises(fk.errors.InputError, match="unknown SensorErrors"):
        perturbed("tapped", errors={"gyro_bias": 1.0})


def test_param_sets_fusionkits_own_filters_that_have_it(monkeypatch):
    """``--param KEY=VALUE`` (``gen.PARAMS``) goes to fusionkit's filters that have the parameter, in 6D
    and 9D and offline, not to the peers; without it the filters are the defaults."""
    assert gen.make_filter("recommended", "9D").config.mag_distortion_significance == 0.0
    monkeypatch.setattr(gen, "PARAMS", {"mag_distortion_significance": 0.99})
    for dims in ("6D", "9D"):
        assert gen.make_filter("recommended", dims).config.mag_distortion_significance == 0.99
    assert gen.make_filter("recommended+offline", "9D").inner.config.mag_distortion_significance == 0.99
    gen.make_filter("vqf", "9D")  # (a peer: not given it)


@pytest.mark.parametrize("key", ["use_mag", "offline", "mag_calibration"])
def test_param_refuses_what_the_script_sets_itself(monkeypatch, capsys, key):
    """``--param`` of a keyword the script already gives its filters (``use_mag`` for 6D / 9D, ``offline``,
    the diagnosis's ``mag_calibration=False``) is refused before any run, naming it, instead of a
    ``TypeError`` (a keyword given twice) in the middle of the comparison (review rev27a)."""
    monkeypatch.setattr(sys, "argv", ["generalisation.py", "--quick", "--param", f"{key}=true"])
    monkeypatch.setattr(gen, "PARAMS", {})
    with pytest.raises(SystemExit):
        gen.main()
    assert f"--param {key}" in capsys.readouterr().err


def test_cut_starts_the_recording_in_motion():
    """``--cut S``: the condition's recording from ``S`` s after its initial rest ends, by time (a lossy recording has
    fewer rows per second than its rate), its truth and movement cut alike; the tables bucket it apart."""
    c = gen.draw("lossy", 2, quick=True, cut=2.0)
    full, cut = gen.build({k: v for k, v in c.items() if k != "cut"}), gen.build(c)
    start = c["initial_rest"] + 2.0
    assert len(full) - len(cut) == int(np.sum(full.time < start))
    np.testing.assert_array_equal(cut.gyr, full.gyr[len(full) - len(cut):])
    np.testing.assert_array_equal(cut.truth, full.truth[len(full) - len(cut):])
    assert cut.movement[:100].all() and not full.movement[:100].any()  # in motion from the first second, not at rest
    assert gen.buckets(c)["initial rest"] == "none (cut in motion)" and "from 2 s into the motion" in gen.describe(c)
