"""What the reports print: summaries instead of arrays, 6D inclination and 9D total kept apart,
no number a filter cannot have, plots a reader can decode, and the README's snippets."""

import re

import numpy as np
import pytest

import fusionkit as fk
from fusionkit import sim
from fusionkit.benchmarking import bench
from fusionkit.io import write_csv

REPO = __import__("pathlib").Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    d = tmp_path_factory.mktemp("reportdata")
    deg = np.pi / 180
    for i, axis in enumerate([(0, 0, 1), (1, 0, 0)]):
        rec = sim.simulate([sim.Rest(11), sim.Rotate(axis, 60 * deg, 2), sim.Rest(1)], rate=100.0,
                           noise=sim.Noise.mems(), seed=i)
        write_csv(rec, d / f"trial{i}.csv")
    return d


def test_a_recording_prints_a_summary_not_its_arrays():
    rec = sim.demo_recordings()[0]
    text = repr(rec)
    assert "array(" not in text and len(text) < 300
    assert f"{len(rec)} samples" in text and "mag" in text and "gnss" in text and "epochs" in text
    assert "truth (body -> ENU)" in text and rec.name in text
    plain = fk.Recording(gyr=np.zeros((4, 3)), acc=np.tile([0.0, 0.0, 9.81], (4, 1)), rate=100.0)
    assert repr(plain) == "Recording(4 samples; rate 100 Hz (0.0 s); gyr, acc)"
    res = fk.make("poisson").run(rec)
    assert "array(" not in repr(res) and f"{len(rec)} samples" in repr(res) and "backend numba" in repr(res)


def test_tables_keep_6d_inclination_and_9d_total_apart(data, tmp_path):
    res = bench(["poisson", "recommended", ("recommended", {"use_mag": False})], data, cache_dir=tmp_path)
    gyro = next(r for r in res.records if r["filter"] == "poisson")
    assert gyro["aiding"] == "gyro-only" and gyro["metrics"]["total"] is None  # not a 90 deg "total"
    assert "gyro-only" in gyro["not_applicable"]["total"] and gyro["metrics"]["inclination"] > 0
    six = next(r for r in res.records if r["filter"] == "recommended[use_mag=False]")
    assert six["aiding"] == "6D" and six["metrics"]["total"] is None
    assert res.metrics() == ["inclination", "total"]
    text = res.table()
    incl, total, speed = text.split("\n\n")[:3]
    assert incl.startswith("inclination RMSE") and "poisson" in incl and "recommended[use_mag=False]" in incl
    assert total.startswith("total RMSE") and "9D filters only" in total
    header = total.splitlines()[1].split()
    assert header == ["trial", "recommended"]  # the 6D and gyro-only filters have no column here ...
    assert "poisson: n/a (gyro-only" in total and "recommended[use_mag=False]: n/a (6D" in total  # ... but a reason
    assert "mean over trials" in incl and "(2)" in incl  # the mean says over how many trials
    assert speed.startswith("speed") and "gyro-only" in speed
    md = res.table("markdown")
    assert md.count("| mean over trials |") == 2
    csv = res.table("csv").splitlines()
    assert csv[0] == "filter,trial,aiding,inclination,total,samples_per_s,cached,error"
    assert csv[1].startswith("poisson,trial0,gyro-only,") and ",," in csv[1]  # no total for it
    groups = res.group_table()
    assert groups.count("mean per group") == 2


def test_demo_table_and_plot_are_one_panel_per_metric(tmp_path):
    from fusionkit.demo import evaluate, format_table, plot_errors

    recs = [r.slice(0, 4000) for r in sim.demo_recordings()[:1]]
    rows, curves = evaluate(["poisson", "recommended", "vqf"], recordings=recs, progress=False)
    table = format_table(rows)
    assert re.search(r"poisson .* gyro-only .* n/a", table)  # no heading for an integrator
    assert "heading: the error's rotation about the vertical" in table
    panels = plot_errors(curves, tmp_path / "d.png", rows)
    assert (tmp_path / "d.png").stat().st_size > 10_000
    assert [p.split(",")[0] for p in panels] == ["inclination error", "inclination error", "heading error",
                                                 "heading error", "samples/s (median over the recordings; one core"]
    assert "fusionkit" in panels[0] and "peers" in panels[1]  # fewer lines per panel


def test_look_alike_filters_get_different_colours_and_lines():
    from fusionkit.benchmarking.plots import filter_styles

    names = ["ahrs-madgwick", "gst", "gst-gnss", "poisson", "vqf", "vqf-basic", "vqf-offline"]
    st = filter_styles(names)
    assert len({s["color"] for s in st.values()}) == len(names)
    for a, b in [("gst", "gst-gnss"), ("vqf-basic", "vqf-offline"), ("vqf", "vqf-basic")]:
        assert st[a]["linestyle"] != st[b]["linestyle"]


def test_throughput_chart_is_linear_coloured_by_library_with_values():
    from fusionkit.benchmarking.plots import _figure, library, throughput_bars

    ax = _figure().subplots()
    throughput_bars(ax, ["recommended", "vqf", "ekf"], [5e6, 2.5e6, 2e3], ["numba", "peer:vqf 2.1.2", "reference"])
    assert ax.get_xscale() == "linear"
    assert {t.get_text() for t in ax.texts} == {"5,000,000", "2,500,000", "2,000"}
    colours = [tuple(p.get_facecolor()) for p in ax.patches]
    assert len(set(colours)) == 3  # three libraries
    assert [t.get_text() for t in ax.get_legend().get_texts()] == ["fusionkit", "vqf", "fusionkit (Python reference)"]
    assert library("peer:ahrs 0.4.0") == "ahrs" and library("numba") == "fusionkit"


def test_plots_leave_the_users_matplotlib_backend_alone(tmp_path):
    """Drawing a plot does not switch matplotlib's backend: ``matplotlib.use("Agg")`` in every plot
    switched a notebook's (or a GUI's) backend for the rest of the session. The figure is drawn
    without pyplot, so nothing is left open in pyplot either."""
    matplotlib = pytest.importorskip("matplotlib")
    from fusionkit.benchmarking.plots import plot_throughput

    class Result:  # what plot_throughput reads of a BenchResult
        records = [{"filter": "poisson", "backend": "numba"}, {"filter": "vqf", "backend": "peer:vqf 2.1.2"}]

        def summary(self):
            return [{"filter": "poisson", "samples_per_s": 2e6}, {"filter": "vqf", "samples_per_s": 1e6}]

    before = matplotlib.get_backend()
    pyplot = __import__("sys").modules.get("matplotlib.pyplot")
    open_before = pyplot.get_fignums() if pyplot else []
    matplotlib.use("svg")  # the user's choice (a non-interactive one: the tests run headless)
    try:
        path = plot_throughput(Result(), tmp_path / "t.png")
        assert matplotlib.get_backend() == "svg"
        assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"  # the file's format, whatever the backend
        pyplot = __import__("sys").modules.get("matplotlib.pyplot")
        assert (pyplot.get_fignums() if pyplot else []) == open_before
    finally:
        matplotlib.use(before)


def test_group_bars_are_linear_from_zero_with_values(tmp_path, monkeypatch):
    """by_group.png drew its bars on a log axis with an automatic lower limit: 1.17 deg looked ten
    times smaller than 1.74 deg and the ticks read '6x10^0'. Now a linear axis from 0, each value
    written on its bar (as the throughput chart), a missing value left without a label."""
    pytest.importorskip("matplotlib")
    from fusionkit.benchmarking import plots

    class Result:  # what plot_by_group reads of a BenchResult
        filters = ["poisson", "vqf"]
        records = [{"groups": ["slow"]}, {"groups": ["fast"]}]

        def metrics(self):
            return ["inclination"]

        def by_group(self, metric):
            return {"poisson": {"slow": 1.17, "fast": 6.5}, "vqf": {"slow": 1.74}}

        def not_applicable(self, metric):
            return {}

    figures = []
    monkeypatch.setattr(plots, "_figure", lambda _new=plots._figure, **kw: figures.append(_new(**kw)) or figures[-1])
    plots.plot_by_group(Result(), tmp_path / "g.png")
    ax = figures[0].axes[0]
    assert ax.get_yscale() == "linear" and ax.get_ylim()[0] == 0 and ax.get_ylim()[1] > 6.5
    assert sorted(t.get_text() for t in ax.texts if t.get_text()) == ["1.17", "1.74", "6.50"]
    assert (tmp_path / "g.png").stat().st_size > 5000


def test_a_6d_reason_says_what_is_true_of_the_recording(capsys, tmp_path):
    """"6D: no magnetometer, heading unobservable" was printed for a 6D filter on a recording that has
    one: the reason now tells a filter that does not read it from a recording without one."""
    import dataclasses

    from fusionkit.benchmarking.report import not_applicable
    from fusionkit.cli import main

    rec = sim.demo_recordings()[0].slice(0, 10)
    six = fk.make("recommended", use_mag=False)
    cases = ((rec, "6D: the filter does not read the magnetometer, heading unobservable"),
             (dataclasses.replace(rec, mag=None), "6D: no magnetometer in the recording, heading unobservable"))
    for r, why in cases:
        assert not_applicable(six.aiding(r), rec=r) == {"total": why, "heading": why}
    assert not_applicable("6D")["total"] == "6D: no magnetometer used, heading unobservable"  # recording unknown
    assert not_applicable("9D", rec=rec) == {} and "gyro-only" in not_applicable("gyro-only", rec=rec)["total"]
    assert main(["run", "gst", "sim:slow-rotation", "-o", str(tmp_path / "o.csv"), "--backend", "reference"]) == 0
    assert "total n/a (6D: the filter does not read the magnetometer" in capsys.readouterr().out


def test_readme_streaming_snippet_works_with_timestamps():
    """The README's streaming loop, run as written on a recording with ``t`` (no ``rate``)."""
    text = (REPO / "README.md").read_text()
    block = text[text.index("# streaming"):]
    snippet = "\n".join(block.splitlines()[:4])
    assert "update(" in snippet
    src = sim.demo_recordings()[1].slice(0, 2000)
    assert src.rate is None and src.t is not None  # timestamps only
    ns = {"fk": fk, "rec": src}
    exec(snippet, ns)
    ref = fk.make("poisson").run(src, backend="reference")
    assert np.allclose(ns["q"], ref.quat[-1], atol=1e-9)
