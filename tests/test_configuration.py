"""Configs a user can print, save, change and run: ``fusionkit describe NAME --toml/--json`` and
``fusionkit run CONFIG`` (docs/configuration.md)."""

import json
try:
    import tomllib
except ImportError:  # Python 3.10
    import tomli as tomllib

import numpy as np
import pytest

import fusionkit as fk
from fusionkit import sim
from fusionkit.cli import main
from fusionkit.config import to_toml


@pytest.fixture(scope="module")
def rec():
    deg = np.pi / 180
    segs = [sim.Rest(3.0), sim.Rotate((0, 0, 1), 90 * deg, 1.5), sim.Rotate((1, 0, 0), 40 * deg, 1.0)]
    return sim.simulate(segs, rate=100.0, noise=sim.Noise.mems(), seed=5)


def _describe(capsys, *args) -> str:
    assert main(["describe", *args]) == 0
    return capsys.readouterr().out


@pytest.mark.parametrize("name", ["gradient-descent", "poisson", "recommended", "channel-dcm"])
@pytest.mark.parametrize("fmt", ["--toml", "--json"])
def test_a_printed_config_runs_to_the_same_numbers(name, fmt, rec, capsys, tmp_path):
    text = _describe(capsys, name, fmt)
    cfg = tomllib.loads(text) if fmt == "--toml" else json.loads(text)
    path = tmp_path / ("my.toml" if fmt == "--toml" else "my.json")
    path.write_text(text)
    from fusionkit.cli import _build_filter

    mine = _build_filter(str(path), {})
    assert np.abs(mine.run(rec).quat - fk.make(name).run(rec).quat).max() < 1e-12
    if "filter" not in cfg:  # a preset: the printed thing is its composition
        assert cfg["estimator"]["name"] == fk.make(name).pipeline_config().estimator.name


def test_a_param_changes_one_setting_of_a_config_file(capsys, tmp_path):
    """``fusionkit run CONFIG --param a.b=v`` sets that one value in the file's table: the table was
    replaced by {b: v}, so alignment.duration dropped gradient-descent's fixed mode, auto heading
    and max_rate for the defaults (a motion alignment that no detector ends: an error here, a silent
    change where a motion detector is listed) and estimator.params.step dropped the estimator's name."""
    from fusionkit.cli import _build_filter, _parse_params

    text = _describe(capsys, "gradient-descent", "--toml")
    path = tmp_path / "gd.toml"
    path.write_text(text)
    cfg = tomllib.loads(text)

    def build(*params):
        return _build_filter(str(path), _parse_params(list(params))).config

    got = build("alignment.duration=5", "estimator.params.step=exact", "correctors.0.params.beta=0.2",
                "detectors.0.params.norm_threshold=0.2")
    want = fk.compose(cfg).config.alignment.model_dump() | {"duration": 5.0}
    assert got.alignment.model_dump() == want and want["mode"] == "fixed" and want["heading"] == "auto"
    assert (got.estimator.name, got.estimator.params["step"]) == ("poisson-quat", "exact")
    assert got.correctors[0].name == "gradient-descent" and got.correctors[0].params["beta"] == 0.2
    assert got.correctors[0].params["iterations"] == cfg["correctors"][0]["params"]["iterations"]
    assert got.detectors[0].name == "magnetic" and got.detectors[0].params["norm_threshold"] == 0.2
    with pytest.raises(fk.FusionkitError, match=r"--param correctors.3: correctors is a list of 1 \(give an index "
                                                r"from 0 to 0, e.g. correctors.0\)"):
        build("correctors.3.params.beta=0.2")
    # plugins by their names alone, in a table and in a list (the estimator lost its name: review rev27b)
    short = tmp_path / "short.json"
    short.write_text('{"estimator": "poisson-quat", "correctors": ["gradient-descent"], '
                     '"alignment": {"mode": "fixed", "duration": 2.0, "heading": "auto"}}')
    got = _build_filter(str(short), _parse_params(["estimator.params.step=exact",
                                                   "correctors.0.params.beta=0.2"])).config
    assert (got.estimator.name, got.estimator.params["step"]) == ("poisson-quat", "exact")
    assert (got.correctors[0].name, got.correctors[0].params["beta"]) == ("gradient-descent", 0.2)


def test_a_preset_with_one_plugin_changed(rec, capsys, tmp_path):
    """gradient-descent's composition with the magnetic detector swapped for the acceleration
    detector runs through `fusionkit run` and differs where the new detector fires."""
    cfg = tomllib.loads(_describe(capsys, "gradient-descent", "--toml"))
    assert [d["name"] for d in cfg["detectors"]] == ["magnetic"]
    cfg["detectors"] = [{"name": "acceleration", "params": {"threshold": 0.3}}]
    path = tmp_path / "mine.toml"
    path.write_text(to_toml(cfg))
    out = tmp_path / "out.csv"
    assert main(["run", str(path), "sim:translation", "-o", str(out)]) == 0
    capsys.readouterr()
    rows = np.loadtxt(out, delimiter=",", skiprows=1)
    ref = fk.compose(cfg).run([r for r in sim.demo_recordings() if r.name == "translation"][0])
    assert np.abs(rows[:, 1:5] - ref.quat).max() < 1e-8  # the CSV keeps 9 digits
    assert (ref.flags & fk.Flag.ACC_REJECTED).any()


def test_describe_shows_the_composition(capsys):
    out = _describe(capsys, "gradient-descent")
    assert "composition" in out and "estimator: poisson-quat" in out and "correctors: gradient-descent" in out
    assert "    alignment: fixed (3.0 s, heading auto)\n" in out
    assert "composition" not in _describe(capsys, "rest", "--kind", "detector")
    # an alignment that is off has no duration nor heading (it printed "none (10.0 s, heading zero)")
    assert "    alignment: none\n" in _describe(capsys, "recommended")


def test_a_detector_has_no_runnable_config(capsys):
    assert main(["describe", "rest", "--kind", "detector", "--toml"]) == 2
    assert "only filters" in capsys.readouterr().err


def test_compose_says_a_monolithic_filters_config_is_for_make(tmp_path):
    """``fk.compose(fk.describe("ekf").config())`` was pydantic's "estimator: Field required ...
    filter: unknown parameter": now a ConfigError saying what the config is and to use make."""
    cfg = fk.describe("ekf").config()
    path = tmp_path / "ekf.json"
    path.write_text(json.dumps(cfg))
    for src in (cfg, path):
        with pytest.raises(fk.ConfigError, match=r"a monolithic filter's config \(\{'filter': 'ekf'.*build this filter "
                           r"with fk.make\('ekf', \*\*params\)") as exc:
            fk.compose(src)
        assert "Field required" not in str(exc.value)
    assert isinstance(fk.make("ekf", **cfg["params"]), fk.Filter)  # what the message says works


def test_toml_writer_round_trips_and_says_where_null_was():
    cfg = {"a": 1, "b": None, "c": {"d": [1.0, float("inf")], "e": "x\"y"}, "f": [{"name": "n", "params": {}}]}
    text = to_toml(cfg)
    assert "# b = None" in text
    back = tomllib.loads(text)
    assert back == {"a": 1, "c": {"d": [1.0, float("inf")], "e": "x\"y"}, "f": [{"name": "n", "params": {}}]}
