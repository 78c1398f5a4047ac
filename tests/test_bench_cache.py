"""The bench cache follows a third-party plugin's code (issue 16 item 1): fixing a plugin re-runs
it, in a pipeline too, and cached results are marked as such."""

import importlib
import sys
import textwrap

import numpy as np
import pytest

import fusionkit as fk
from fusionkit import registry, sim
from fusionkit.benchmarking import bench
from fusionkit.cli import main
from fusionkit.io import write_csv

PLUGIN = """
    from fusionkit.filters.poisson import PoissonFilter
    from fusionkit.estimators.poisson import PoissonQuat

    SIGN = {sign}


    class SignFilter(PoissonFilter):
        name = "sign-test"

        def run(self, rec, **kw):
            res = super().run(rec, **{{**kw, "backend": "reference"}})
            res.quat[:, 1:] *= SIGN  # SIGN = -1: the inverse rotation (the "sign bug")
            return res


    class SignQuat(PoissonQuat):
        name = "sign-quat"

        def propagate(self, state, gyr, dt):
            super().propagate(state, SIGN * gyr, dt)  # SIGN = -1: turns the wrong way

        def kernel(self):
            return None  # the readable path only
"""


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    d = tmp_path_factory.mktemp("tilted")
    rec = sim.simulate([sim.Rest(2), sim.Rotate((1, 0, 0), np.radians(30), 2), sim.Rest(1)], rate=100.0, seed=3)
    write_csv(rec, d / "tilt.csv")
    return d


@pytest.fixture
def plugin(tmp_path, monkeypatch):
    """``write(sign)``: (re)write the plugin module, import it afresh and register its classes on
    a fresh default registry, as a new process would see the edited source."""
    monkeypatch.syspath_prepend(str(tmp_path))
    name = f"fk_sign_plugin_{tmp_path.name.replace('-', '_')}"

    def write(sign):
        (tmp_path / f"{name}.py").write_text(textwrap.dedent(PLUGIN.format(sign=sign)))
        importlib.invalidate_caches()
        mod = importlib.reload(sys.modules[name]) if name in sys.modules else importlib.import_module(name)
        reg = registry.Registry()
        reg.register(mod.SignFilter)
        reg.register(mod.SignQuat)
        monkeypatch.setattr(registry, "_DEFAULT", reg)
        return mod

    yield write
    sys.modules.pop(name, None)


SIGN = ("sign-test", {"alignment": "fixed", "alignment_duration": 1.0})


def score(res):
    (r,) = res.records
    assert r["error"] is None, r["error"]
    return r["metrics"]["score"], r["cached"]


def test_fixing_a_plugin_reruns_it(data, tmp_path, plugin):
    plugin(-1)
    bad, cached = score(bench([SIGN], data, cache_dir=tmp_path / "cache"))
    assert not cached and bad > 10  # the inverse rotation: twice the tilt off
    again = bench([SIGN], data, cache_dir=tmp_path / "cache")
    assert score(again) == (bad, True)
    assert f"{bad:.2f}*" in again.table() and "*: from the cache (1 of 1 results)" in again.table()
    code = again.records[0]["versions"]["plugins"]
    assert list(code) == [next(m for m in sys.modules if m.startswith("fk_sign_plugin_"))]
    assert code[list(code)[0]].startswith("(no distribution) ")

    plugin(1)  # the fix
    fixed, cached = score(bench([SIGN], data, cache_dir=tmp_path / "cache"))
    assert not cached and fixed < 1
    assert "*" not in bench([SIGN], data, cache=False).table()


def test_a_pipeline_reruns_when_a_plugin_it_composes_changes(data, tmp_path, plugin):
    spec = [("pipeline", {"estimator": "sign-quat", "detectors": ["motion"],
                          "alignment": {"mode": "fixed", "duration": 1.0}})]
    plugin(-1)
    bad, _ = score(bench(spec, data, cache_dir=tmp_path / "cache"))
    assert score(bench(spec, data, cache_dir=tmp_path / "cache")) == (bad, True)
    plugin(1)
    fixed, cached = score(bench(spec, data, cache_dir=tmp_path / "cache"))
    assert not cached and fixed < 1 < bad


def test_the_cli_says_how_many_results_came_from_the_cache(data, tmp_path, plugin, monkeypatch, capsys):
    plugin(1)
    monkeypatch.setenv("FUSIONKIT_CACHE", str(tmp_path / "cache"))
    argv = ["bench", "--data", str(data), "--filters", "sign-test"]
    assert main(argv) == 0
    assert "from the cache" not in capsys.readouterr().err
    assert main(argv) == 0
    out = capsys.readouterr()
    assert "1 of 1 results from the cache" in out.err and "--no-cache" in out.err
    assert "*: from the cache" in out.out
    assert main(argv + ["--no-cache"]) == 0
    assert "from the cache" not in capsys.readouterr().err


def test_the_result_cache_follows_fusionkits_cache_directory(tmp_path, monkeypatch):
    """$FUSIONKIT_CACHE_DIR (README: fusionkit's cache) moves the bench results too; it was
    ignored (~/.cache/fusionkit/bench whatever it said). $FUSIONKIT_CACHE still wins."""
    from fusionkit.benchmarking.runner import _cache_dir

    monkeypatch.delenv("FUSIONKIT_CACHE", raising=False)
    monkeypatch.setenv("FUSIONKIT_CACHE_DIR", str(tmp_path / "dir"))
    assert _cache_dir(None) == tmp_path / "dir" / "bench"
    monkeypatch.delenv("FUSIONKIT_CACHE_DIR")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert _cache_dir(None) == tmp_path / "xdg" / "fusionkit" / "bench"
    monkeypatch.setenv("FUSIONKIT_CACHE", str(tmp_path / "old"))
    assert _cache_dir(None) == tmp_path / "old" / "bench"
    assert _cache_dir(tmp_path / "given") == tmp_path / "given" / "bench"


def test_a_filter_whose_source_cannot_be_found_is_never_cached(data, tmp_path, monkeypatch):
    from fusionkit.filters.poisson import PoissonFilter

    cls = type("Typed", (PoissonFilter,), {"name": "typed-in", "__module__": "not_a_module_anywhere"})
    reg = registry.Registry()
    reg.register(cls)
    monkeypatch.setattr(registry, "_DEFAULT", reg)
    for _ in range(2):
        assert not bench(["typed-in"], data, cache_dir=tmp_path).records[0]["cached"]
    assert fk.make("typed-in").name == "typed-in"


def test_a_cached_result_takes_the_label_and_params_asked_for(data, tmp_path):
    """Specs with the same full config share a cache entry (``step`` first-order is poisson's
    default); a hit kept the label and params of the run that saved it, so the second of two
    specs came back named like the first and a sweep found no value for its set (nan)."""
    specs = ["poisson", ("poisson", {"step": "first-order"})]
    fresh = bench(specs, data, cache=False)
    want = [(r["filter"], r["params"]) for r in fresh.records]
    assert want == [("poisson", {}), ("poisson[step=first-order]", {"step": "first-order"})]
    bench(specs, data, cache_dir=tmp_path)
    again = bench(specs, data, cache_dir=tmp_path)
    assert [(r["filter"], r["params"], r["cached"]) for r in again.records] == [(*w, True) for w in want]
    assert [r["metrics"] for r in again.records] == [r["metrics"] for r in fresh.records]

    from fusionkit.benchmarking.sweep import sweep  # the new-user probe: bench, then a sweep over the default
    grid = {"step": ["exact", "first-order"]}
    bench(["poisson"], data, cache_dir=tmp_path / "sweep")
    swept = sweep("poisson", grid, data, cache_dir=tmp_path / "sweep")
    assert all(r["cached"] == (r["filter"] == "poisson[step=first-order]") for r in swept.result.records)
    assert swept.mean_by_combo() == sweep("poisson", grid, data, cache=False).mean_by_combo()


def test_different_parameters_never_share_a_cache_entry(data, tmp_path):
    from fusionkit.benchmarking.runner import FilterSpec, _spec_key

    keys = {_spec_key(FilterSpec.of(("poisson", {"step": s}))) for s in ("exact", "first-order")}
    assert len(keys) == 2 and "" not in keys
    bench([("poisson", {"step": "exact"})], data, cache_dir=tmp_path)
    assert not bench([("poisson", {"step": "first-order"})], data, cache_dir=tmp_path).records[0]["cached"]


def test_csv_has_full_precision_numbers_and_a_cached_column(data, tmp_path):
    """CSV is for programs: the metrics were rounded to 2 decimals with the cache's ``*`` glued
    on ("0.60*"), which no CSV reader takes as a number."""
    import csv

    bench(["poisson", "gradient-descent"], data, cache_dir=tmp_path)
    res = bench(["poisson", "gradient-descent"], data, cache_dir=tmp_path)
    assert all(r["cached"] for r in res.records)
    rows = list(csv.DictReader(res.table("csv").splitlines()))
    assert list(rows[0]) == ["filter", "trial", "aiding", "inclination", "total", "samples_per_s", "cached", "error"]
    for row, r in zip(rows, res.records):
        assert row["cached"] == "true" and float(row["samples_per_s"]) == r["samples_per_s"]
        for m in ("inclination", "total"):
            assert row[m] == ("" if r["metrics"][m] is None else repr(r["metrics"][m]))
    assert rows[1]["filter"] == "gradient-descent" and float(rows[1]["total"]) == res.records[1]["metrics"]["total"]
    assert [r["cached"] for r in csv.DictReader(bench(["poisson"], data, cache=False).table("csv").splitlines())] \
        == ["false"]
