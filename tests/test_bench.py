"""The side-by-side runner, its outputs and its failure modes, on CSV recordings made here."""

import json
import re

import numpy as np
import pytest

import fusionkit as fk
from fusionkit import sim
from fusionkit.benchmarking import bench, discover
from fusionkit.benchmarking.runner import FilterSpec
from fusionkit.benchmarking.sweep import sweep
from fusionkit.cli import main
from fusionkit.errors import ConfigError, InputError, PluginError
from fusionkit.filters.poisson import PoissonFilter
from fusionkit.io import write_csv


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    d = tmp_path_factory.mktemp("csvdata")
    deg = np.pi / 180
    for i, segs in enumerate([[sim.Rest(11), sim.Rotate((0, 0, 1), 60 * deg, 2), sim.Rest(1)],
                              [sim.Rest(11), sim.Rotate((1, 0, 0), 30 * deg, 2), sim.Rest(1)]]):
        rec = sim.simulate(segs, rate=100.0, noise=sim.Noise.mems(), seed=i)
        write_csv(rec, d / f"trial{i}.csv")
    # a recording without a reference
    r = sim.simulate([sim.Rest(11), sim.Rest(1)], rate=100.0, seed=5)
    write_csv(fk.Recording(gyr=r.gyr, acc=r.acc, rate=100.0), d / "noref.csv")
    return d


def test_discover_and_select(data):
    names = [t.name for t in discover(data)]
    assert names == ["noref", "trial0", "trial1"]
    assert [t.name for t in discover(data, ["trial1"])] == ["trial1"]
    with pytest.raises(InputError, match="matches 2 recordings"):
        discover(data, ["trial"])
    with pytest.raises(InputError, match="does not exist"):
        discover(data / "nope")


def test_bench_records_and_tables(data, tmp_path):
    res = bench(["poisson", ("poisson", {"step": "exact"})], data, cache_dir=tmp_path)
    assert len(res.records) == 6
    r = next(r for r in res.records if r["trial"] == "trial0" and r["filter"] == "poisson")
    assert r["error"] is None and r["dimension"] == "6D" and r["backend"] == "numba"
    assert r["samples_per_s"] > 0 and r["versions"]["fusionkit"] == fk.__version__
    assert r["config"]["step"] == "first-order" and r["groups"] == ["csv"]
    assert 0 < r["metrics"]["inclination"] < 2 and r["metrics"]["score"] == r["metrics"]["inclination"]
    noref = next(r for r in res.records if r["trial"] == "noref")
    assert noref["metrics"] == {} and noref["samples_per_s"] > 0  # speed only
    text = res.table()
    assert "poisson[step=exact]" in text and "samples/s" in text
    md = res.table("markdown")
    assert md.startswith("**inclination RMSE") and "| trial | poisson | poisson[step=exact] |" in md
    recs = json.loads(res.table("json"))
    assert {r["trial"] for r in recs} == {"noref", "trial0", "trial1"}
    assert res.table("csv").splitlines()[0] == "filter,trial,aiding,inclination,samples_per_s,cached,error"
    assert set(res.by_group()["poisson"]) == {"csv"}
    with pytest.raises(ConfigError, match="format"):
        res.table("xml")


def test_cache_makes_a_rerun_instant(data, tmp_path):
    first = bench("poisson", data, trials=["trial0"], cache_dir=tmp_path)  # one name alone: one filter (was 'p')
    again = bench(["poisson"], data, trials=["trial0"], cache_dir=tmp_path)
    assert not first.records[0]["cached"] and again.records[0]["cached"]
    assert again.records[0]["metrics"] == first.records[0]["metrics"]
    other = bench([("poisson", {"step": "exact"})], data, trials=["trial0"], cache_dir=tmp_path)
    assert not other.records[0]["cached"]  # another config, another key


def test_a_failing_filter_is_reported_and_the_rest_continue(data, tmp_path):
    class Fragile(PoissonFilter):
        name = "fragile-test"

        def run(self, rec, **kw):
            if rec.name == "trial1":
                raise RuntimeError("boom on trial1")
            return super().run(rec, **kw)

    fk.register(Fragile)
    try:
        res = bench(["fragile-test", "poisson"], data, cache=False)
    finally:
        fk.default_registry()._extra.remove(next(e for e in fk.default_registry()._extra if e.cls is Fragile))
        fk.default_registry().refresh()
    bad = [r for r in res.records if r["error"]]
    assert len(bad) == 1 and bad[0]["trial"] == "trial1" and "boom on trial1" in bad[0]["error"]
    assert bad[0]["aiding"] == "gyro-only"  # (taken before the run: it was missing, and the table said 6D)
    assert "error: fragile-test on trial1: RuntimeError: boom on trial1" in res.table()
    assert all(not r["error"] for r in res.records if r["filter"] == "poisson")


def test_a_refused_value_is_one_error_before_any_trial_runs(data, capsys):
    """A value the filter refuses was an error record per trial, its reason cut to "invalid
    configuration for filter 'poisson':", under an empty "by group:"; now bench raises it once,
    whole, and the CLI prints it on one line as ``fusionkit run`` does."""
    with pytest.raises(ConfigError, match=r"invalid configuration for filter 'poisson':\n  step: Input should be"):
        bench(["poisson"], data, params={"step": "abc"}, cache=False)
    assert main(["bench", "--data", str(data), "--filters", "poisson", "--param", "step=abc", "--no-cache"]) == 2
    out = capsys.readouterr()
    assert out.out == "" and out.err.count("\n") == 1
    assert out.err.startswith("fusionkit: error: invalid configuration for filter 'poisson': step: Input should be "
                              "'first-order' or 'exact' (got 'abc')")


def test_when_every_run_fails_only_the_errors_are_printed(data, capsys, monkeypatch):
    from fusionkit import registry

    class Broken(PoissonFilter):
        name = "broken-test"

        def run(self, rec, **kw):
            raise RuntimeError("no run today:\n  the first reason\n  the second reason")

    reg = registry.Registry()
    reg.register(Broken)
    monkeypatch.setattr(registry, "_DEFAULT", reg)
    assert main(["bench", "--data", str(data), "--filters", "broken-test", "--trials", "trial0,trial1",
                 "--no-cache"]) == 1
    out = capsys.readouterr().out.strip().splitlines()
    assert out == [f"error: broken-test on {t}: RuntimeError: no run today: the first reason; the second reason"
                   for t in ("trial0", "trial1")]  # no empty speed or "by group:" section, the whole reason


def test_a_magnetometer_without_a_finite_sample_is_judged_6d(tmp_path):
    """With nan_policy='skip' a filter runs an all-NaN magnetometer as none (the same
    quaternions): it is judged as 6D (inclination; no total or heading), not on a 9D total of the
    arbitrary heading it cannot know."""
    r = sim.simulate([sim.Rest(11), sim.Rotate((0, 0, 1), 1.0, 2), sim.Rest(1)], rate=100.0,
                     noise=sim.Noise.mems(), seed=3)
    write_csv(fk.Recording(gyr=r.gyr, acc=r.acc, mag=np.full_like(r.mag, np.nan), rate=100.0, truth=r.truth),
              tmp_path / "nan_mag.csv")
    rec = bench([("gradient-descent", {"nan_policy": "skip"})], tmp_path, cache=False).records[0]
    assert rec["error"] is None and rec["dimension"] == "6D" and rec["aiding"] == "6D"
    assert rec["metrics"]["score"] == rec["metrics"]["inclination"] and rec["metrics"]["total"] is None


def test_unknown_filter_and_parameters(data):
    for jobs in (0, -1, 1.5, True):
        with pytest.raises(ConfigError, match=r"jobs must be a whole number of worker processes >= 1"):
            bench(["poisson"], data, jobs=jobs)
    with pytest.raises(PluginError, match="did you mean 'poisson'"):
        bench(["poison"], data)
    with pytest.raises(ConfigError, match="match no field"):
        bench(["poisson"], data, params={"beta": 0.1})


def test_params_apply_by_field_or_by_filter(data):
    res = bench(["poisson", "vqf"], data, trials=["trial0"], cache=False,
                params={"frame": "NED", "vqf.tau_acc": 2.0, "poisson.motion.window": 0.2})
    cfg = {r["name"]: r["config"] for r in res.records}
    assert cfg["poisson"]["frame"] == "NED" and cfg["vqf"]["frame"] == "NED"
    assert cfg["vqf"]["tau_acc"] == 2.0 and cfg["poisson"]["motion"]["window"] == 0.2


def test_process_pool_gives_the_same_numbers(data):
    one = bench(["poisson"], data, cache=False)
    two = bench(["poisson"], data, cache=False, jobs=2)
    key = lambda r: r["trial"]  # noqa: E731
    for a, b in zip(sorted(one.records, key=key), sorted(two.records, key=key)):
        assert a["metrics"] == b["metrics"]


def test_dask_local_cluster_on_loopback(data):
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True, host="127.0.0.1",
                                  protocol="tcp", dashboard_address=None) as cluster:
        assert cluster.scheduler_address.startswith("tcp://127.0.0.1:")
        res = bench(["poisson"], data, cache=False, scheduler=cluster.scheduler_address)
    local = bench(["poisson"], data, cache=False)
    assert sorted((r["trial"], r["metrics"].get("score")) for r in res.records) == \
        sorted((r["trial"], r["metrics"].get("score")) for r in local.records)


def test_sweep_reports_tagp_and_per_trial_minimum(data, capsys):
    s = sweep("poisson", {"motion.window": [0.05, 0.2], "step": ["first-order", "exact"]}, data,
              trials=["trial0", "trial1"], cache=False)
    assert len(s.combos) == 4
    params, best = s.tagp
    means = dict((json.dumps(c, sort_keys=True), v) for c, v in s.mean_by_combo())
    assert best == min(means.values())
    ptm = s.per_trial_minimum()
    assert set(ptm) == {"trial0", "trial1"}
    assert np.mean([v for _, v in ptm.values()]) <= best + 1e-12  # never worse than the common best
    assert "TAGP" in s.report()
    with pytest.raises(ConfigError, match="no parameter 'beta'"):
        sweep("poisson", {"beta": [1]}, data)
    # a fixed parameter beside the grid's in the same table is kept (the grid's table replaced it)
    s = sweep("poisson", {"motion.window": [0.05]}, data, trials=["trial0"], base={"motion": {"arm_after": 5.0}},
              cache=False)
    assert s.combos == [{"motion": {"arm_after": 5.0, "window": 0.05}}]
    for base in ({"motion": {"window": 0.1}}, {"motion": 3}):
        with pytest.raises(ConfigError, match="'motion.window' is both in the grid and a fixed parameter"):
            sweep("poisson", {"motion.window": [0.05]}, data, base=base)
    assert main(["sweep", "poisson", "--data", str(data), "--grid", "step=exact", "--grid", "step=first-order"]) == 2
    assert "--grid step is given twice" in capsys.readouterr().err  # (the second replaced the first)


def test_filter_spec_labels():
    assert FilterSpec.of("vqf").label == "vqf"
    assert FilterSpec.of(("vqf", {"tau_acc": 2})).label == "vqf[tau_acc=2]"
    assert FilterSpec.of(("poisson", {"motion": {"window": 0.2}})).kwargs == {"motion": {"window": 0.2}}


def test_cli_bench_and_sweep(data, tmp_path, capsys):
    out = tmp_path / "t.md"
    assert main(["bench", "--data", str(data), "--filters", "poisson", "--trials", "trial0,trial1", "--format",
                 "markdown", "-o", str(out), "--no-cache", "--plots", str(tmp_path / "plots")]) == 0
    assert out.read_text().startswith("**inclination RMSE") and "| trial | poisson |" in out.read_text()
    assert (tmp_path / "plots" / "by_group.png").stat().st_size > 5000
    assert (tmp_path / "plots" / "throughput.png").exists()
    assert list((tmp_path / "plots").glob("error_*.png"))
    assert main(["bench", "--data", str(tmp_path / "missing"), "--filters", "poisson"]) == 2
    assert "does not exist" in capsys.readouterr().err
    assert main(["sweep", "poisson", "--data", str(data), "--trials", "trial0", "--grid", "step=first-order,exact",
                 "--no-cache"]) == 0
    assert re.search(r"TAGP \(best common parameters\): \{'step': '(first-order|exact)'\}", capsys.readouterr().out)


def test_group_tables_follow_the_chosen_format(data, capsys):
    """``bench --format table`` printed its per-trial tables as text and its group tables in
    markdown (and ``group_table`` gave csv for any format but markdown)."""
    argv = ["bench", "--data", str(data), "--filters", "poisson", "--trials", "trial0", "--no-cache"]
    assert main(argv) == 0
    text = capsys.readouterr().out
    groups = text[text.index("by group:"):]
    assert "|" not in text and "**" not in text
    assert groups.splitlines()[2:4] == ["inclination RMSE (deg, the error's tilt part; every filter, 6D and 9D), "
                                        "mean per group", "group  poisson"]
    assert main(argv + ["--format", "markdown"]) == 0
    groups = capsys.readouterr().out.split("by group:")[1]
    assert "**inclination RMSE" in groups and "| group | poisson |" in groups
    res = bench(["poisson"], data, trials=["trial0"], cache=False)
    assert res.group_table().splitlines()[1] == "group  poisson"  # as table(): aligned text by default
    assert res.group_table(format="csv").splitlines()[1:] == ["group,poisson", f"csv,{res.by_group()['poisson']['csv']:.2f}"]
    with pytest.raises(ConfigError, match="format must be table, markdown or csv"):
        res.group_table(format="json")


def test_loaders_on_the_shared_data(broad_dir):
    root = broad_dir.parent
    trials = discover(root)
    kinds = {t.dataset for t in trials}
    assert kinds == {"broad", "gnss", "ulog"}
    broad = [t for t in trials if t.dataset == "broad"]
    assert all("all_trials" in t.groups for t in broad)
    heli = fk.load(root / "gnss" / "heli_cruise" / "heli_cruise.h5")
    assert heli.truth_frame == "NED" and heli.gnss.valid.all() and heli.rate is None
    car = fk.load(root / "gnss" / "car_drive" / "car_drive.h5")
    gap = ~car.gnss.valid
    assert gap.any() and car.gnss.t[gap].min() == pytest.approx(170.0) and car.gnss.t[gap].max() < 230.0
    sitl = fk.load(root / "ulog" / "sample_logging_tagged_and_default_params.ulg")
    assert sitl.meta["truth_kind"] == "ground truth (simulator)" and sitl.mag is not None
    real = fk.load(root / "ulog" / "sample.ulg")
    assert real.meta["truth_kind"] == "autopilot estimate"


def test_a_gnss_filter_on_data_without_gnss_is_not_applicable(data):
    res = bench(["gst-gnss", "poisson"], data, trials=["trial0"], cache=False)
    r = next(r for r in res.records if r["name"] == "gst-gnss")
    assert r["skipped"] and r["error"] is None and r["metrics"] == {}
    assert "n/a" in res.table() and "error:" not in res.table()


def test_cache_key_follows_the_code(data, tmp_path, monkeypatch):
    from fusionkit.benchmarking import runner

    bench(["poisson"], data, trials=["trial0"], cache_dir=tmp_path)
    assert bench(["poisson"], data, trials=["trial0"], cache_dir=tmp_path).records[0]["cached"]
    monkeypatch.setattr(runner, "_code_fingerprint", lambda: "changed-code")
    assert not bench(["poisson"], data, trials=["trial0"], cache_dir=tmp_path).records[0]["cached"]


def test_the_offline_mode_and_its_options_are_in_the_cache_key():
    """The offline mode keeps its inner filter's config: its cache key was the online filter's, and a
    re-run of the README's ``bench([("recommended", {"offline": True}), "recommended"])`` printed the
    online numbers in the offline row (both marked cached)."""
    from fusionkit.benchmarking.runner import _spec_key

    keys = {_spec_key(FilterSpec.of(s)) for s in ("recommended", ("recommended", {"offline": True}),
                                                   ("recommended", {"offline": True, "inclination": "average"}))}
    assert "" not in keys and len(keys) == 3


def test_offline_is_a_parameter_of_bench_and_sweep_and_describe_says_who_has_it(data):
    """``--param offline=true`` was refused by bench ("match no field of the filters") and a sweep's
    ``--grid offline=true,false`` ("recommended has no parameter 'offline'"), while ``fusionkit run``
    took it; ``describe`` never said which filters have the offline mode."""
    from fusionkit.benchmarking.runner import _apply_params

    (spec,) = _apply_params([FilterSpec.of("recommended")], {"offline": True, "inclination": "average"})
    assert spec.kwargs == {"offline": True, "inclination": "average"}
    assert spec.build().options()["inclination"] == "average"
    with pytest.raises(ConfigError, match="metric must be one of"):  # the grid passed its check
        sweep("recommended", {"offline": [True, False]}, data, metric="nope")
    assert "offline: make('recommended', offline=True)" in str(fk.describe("recommended"))
    assert "offline: not supported: it needs a GNSS stream" in str(fk.describe("gst-gnss"))
    assert fk.describe("mag-heading").offline is None


def test_a_sweep_report_gives_its_metrics_unit():
    """A navigation metric's sweep says m (or m/s), not deg: the report's header, TAGP, per-trial
    minimum and table all said deg, whatever the metric."""
    from fusionkit.benchmarking.sweep import SweepResult

    class Fake:  # a bench result: position error 1 / 3 m on two trials, + 0.5 m with max age 2
        trials = scored_trials = ["a", "b"]

        def _other_references(self):
            return {}

        def value(self, label, trial, metric):
            return {"a": 1.0, "b": 3.0}[trial] + (0.5 if "=2" in label else 0.0)

    s = SweepResult("ins-gnss", {"gnss_max_age": [1, 2]}, "position", Fake(), [{"gnss_max_age": 1}, {"gnss_max_age": 2}])
    body = s.report().split("\n", 1)[1]
    assert "mean over trials (m)" in body and "-> 2.000 m" in body and "best): 2.000 m" in body
    assert "| error (m) |" in body and "deg" not in body


def test_sweep_takes_the_navigation_metrics():
    """``ins-gnss`` sweeps on GNSS flights rank by ``position`` / ``velocity`` / ``position_gap_end``
    (:func:`~fusionkit.benchmarking.metrics.navigation_errors`): the metric check once refused them.
    A grid value the filter refuses is checked after the metric, before any run: its error shows the
    metric passed."""
    for metric in ("position", "velocity", "position_gap_end"):
        with pytest.raises(fk.ConfigError, match="gnss_max_age"):
            sweep("ins-gnss", {"gnss_max_age": [-1.0]}, "unused", metric=metric)
    with pytest.raises(fk.ConfigError, match="metric must be one of"):
        sweep("ins-gnss", {"gnss_max_age": [0.5]}, "unused", metric="rmse")


def test_metrics_of_a_nue_result_split_about_the_vertical():
    """A result in source 000's NUE frame (Up is its second axis) gets the metrics of the same
    orientations in ENU, NED or NWU: the heading/inclination split is about the vertical. It once
    split about NUE's z axis (East): a pure heading error counted as inclination."""
    from fusionkit.benchmarking.metrics import rms_errors, trial_metrics
    from fusionkit.conventions import change_frame
    from fusionkit.rotations import quat_from_axis_angle, quat_mul

    rng = np.random.default_rng(3)
    n = 200
    truth = rng.normal(size=(n, 4))
    truth /= np.linalg.norm(truth, axis=1, keepdims=True)
    rec = fk.Recording(gyr=np.zeros((n, 3)), acc=np.tile([0.0, 0.0, 9.81], (n, 1)), rate=100.0, truth=truth)
    # a heading error of 2 deg (about ENU's Up) and a tilt of 1 deg (about East), in the earth frame
    err = quat_mul(quat_from_axis_angle([0.0, 0.0, 1.0], np.radians(2.0)),
                   quat_from_axis_angle([1.0, 0.0, 0.0], np.radians(1.0)))
    est = quat_mul(err, truth)
    want = rms_errors(fk.Result(quat=est, flags=np.zeros(n, np.uint32), frame="ENU"), rec)
    assert want["heading"] == pytest.approx(2.0, abs=0.02) and want["inclination"] == pytest.approx(1.0, abs=0.02)
    for frame in ("NED", "NWU", "NUE"):
        res = fk.Result(quat=change_frame(est, "ENU", frame), flags=np.zeros(n, np.uint32), frame=frame)
        got = rms_errors(res, rec)
        assert got == pytest.approx(want, rel=1e-9), frame
        assert trial_metrics(res, rec, "9D")["inclination"] == pytest.approx(want["inclination"], rel=1e-9), frame


def test_a_reference_that_is_not_a_truth_is_left_out_of_the_means():
    """A PX4 log without a simulator's truth carries the autopilot's own estimate as its reference:
    bench averaged the agreement with it into the mean over trials with the real errors, unmarked."""
    import copy

    from fusionkit.benchmarking.datasets import Trial

    base = sim.demo_recordings()[0]
    px4 = copy.copy(base.slice(0, 3200))
    px4.meta = {**px4.meta, "truth_kind": "autopilot estimate"}
    recs = {"truth": base.slice(0, 4400), "px4": px4}  # (12 s of rest first)

    class Mem(Trial):
        def load(self):
            return recs[self.name]

    res = bench(["poisson"], [Mem("truth", "csv", ""), Mem("px4", "csv", "")], cache=False, progress=False)
    s = res.summary("inclination")[0]
    assert s["trials"] == 1 and s["mean"] == pytest.approx(res.value("poisson", "truth", "inclination"))
    assert res.value("poisson", "px4", "inclination") != pytest.approx(s["mean"])  # (it was in the mean: 2 trials)
    text = res.table("table", metric="inclination")
    assert "px4 (vs autopilot estimate)" in text and "not in the mean: px4" in text
    groups = res.by_group("inclination")["poisson"]
    assert set(groups) == {"all"} and groups["all"] == pytest.approx(s["mean"])


def test_a_sweep_chooses_by_the_trials_scored_against_a_truth_and_a_cached_hit_keeps_json_params(tmp_path):
    """Review rev32: the sweep's means (TAGP, per-trial minimum) still averaged a PX4 log's autopilot estimate in;
    and a cache hit took the spec's params as given (a numpy bool), which the JSON table could not write."""
    import copy

    from fusionkit.benchmarking.datasets import Trial

    base = sim.demo_recordings()[0]
    px4 = copy.copy(base.slice(0, 3200))
    px4.meta = {**px4.meta, "truth_kind": "autopilot estimate"}
    recs = {"truth": base.slice(0, 4400), "px4": px4}

    class Mem(Trial):
        def load(self):
            return recs[self.name]

        @property
        def fingerprint(self):
            return self.name

    trials = [Mem("truth", "csv", ""), Mem("px4", "csv", "")]
    res = sweep("poisson", {"step": ["exact", "first-order"]}, trials, metric="inclination", cache=False,
                progress=False)
    for combo, mean in res.mean_by_combo():
        assert mean == pytest.approx(res.result.value(res._label(combo), "truth", "inclination"))
    assert set(res.per_trial_minimum()) == {"truth"} and "not in the means: px4" in res.report()
    spec = [("poisson", {"early_motion": np.bool_(False)})]
    for _ in range(2):  # the second from the cache
        out = bench(spec, trials[:1], cache_dir=tmp_path, progress=False)
    assert out.records[0]["cached"] and json.loads(out.table("json"))[0]["params"] == {"early_motion": False}
