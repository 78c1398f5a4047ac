"""Files and configs fusionkit cannot use give a FusionkitError naming the file (README: `except
FusionkitError` catches all), and the CLI one line on stderr, never a traceback (issue 16 item 12)."""

import json

import numpy as np
import pytest

import fusionkit as fk
from fusionkit import sim
from fusionkit.cli import main
from fusionkit.config import MAX_CONFIG_DEPTH, load_config
from fusionkit.errors import ConfigError, InputError
from fusionkit.io import write_csv
from fusionkit.pipeline import MAX_COMPILED_CORRECTORS


@pytest.fixture(scope="module")
def csv_lines(tmp_path_factory):
    """A good CSV recording's lines (header first)."""
    path = tmp_path_factory.mktemp("csv") / "good.csv"
    write_csv(sim.simulate([sim.Rest(1.0)], rate=100.0, seed=1), path)
    return path.read_text().splitlines()


def _hdf5(path, keep=1.0):
    import h5py

    with h5py.File(path, "w") as f:
        f["imu_gyr"] = np.zeros((500, 3))
        f["imu_acc"] = np.tile([0.0, 0.0, 9.81], (500, 1))
        f.attrs["sampling_rate"] = 100.0
    data = path.read_bytes()
    path.write_bytes(data[: int(len(data) * keep)])


def _text_cell(lines):
    row = lines[5].split(",")
    row[2] = "abc"
    return "\n".join(lines[:5] + [",".join(row)] + lines[6:])


def _without_t(lines, comment):
    return "\n".join([comment] + [line.split(",", 1)[1] for line in lines])


def _drop(lines, column):
    """The CSV without one column (a sensor's or the reference's set left partial)."""
    j = lines[0].split(",").index(column)
    return "\n".join(",".join(c for i, c in enumerate(line.split(",")) if i != j) for line in lines)


GARBAGE = np.random.default_rng(0).bytes(4000)

# name -> (file name, writer(path, lines), the message's tail after the file name)
BAD_RECORDINGS = {
    "truncated hdf5": ("trunc.hdf5", lambda p, ls: _hdf5(p, keep=0.5), r"cannot read this HDF5 file: OSError"),
    "garbage hdf5": ("junk.h5", lambda p, ls: p.write_bytes(GARBAGE), r"cannot read this HDF5 file: OSError"),
    "text in a csv": ("text.csv", lambda p, ls: p.write_text(_text_cell(ls)), r"line 6, column 3: 'abc' is not a number"),
    "rate=abc": ("rate.csv", lambda p, ls: p.write_text(_without_t(ls, "# rate=abc")),
                 r"line 1: '# rate=abc' is not a rate in Hz"),
    "header only": ("head.csv", lambda p, ls: p.write_text(ls[0] + "\n"), r"no data rows after the header"),
    "duplicated column": ("dup.csv", lambda p, ls: p.write_text("\n".join([ls[0] + ",gyr_x"] + [x + ",5" for x in ls[1:]])),
                          r"column\(s\) \['gyr_x'\] appear more than once"),
    "short row": ("short.csv", lambda p, ls: p.write_text("\n".join(ls[:3] + [ls[3].rsplit(",", 1)[0]] + ls[4:])),
                  r"line 4 has \d+ values, the header \d+ names"),
    "mag without mag_z": ("mag.csv", lambda p, ls: p.write_text(_drop(ls, "mag_z")),
                          r"columns \['mag_x', 'mag_y'\] without \['mag_z'\]: give all of"),
    "quaternion without qz": ("quat.csv", lambda p, ls: p.write_text(_drop(ls, "qz")),
                              r"columns \['qw', 'qx', 'qy'\] without \['qz'\]: give all of"),
    "latin-1 csv": ("latin.csv", lambda p, ls: p.write_bytes("# caf\xe9\n".encode("latin-1") + "\n".join(ls).encode()),
                    r"cannot read this CSV file: UnicodeDecodeError"),
    "garbage ulg": ("junk.ulg", lambda p, ls: p.write_bytes(b"not a flight log\n" * 200),
                    r"cannot read this ULog file"),
}


@pytest.mark.parametrize("case", list(BAD_RECORDINGS))
def test_a_bad_recording_is_an_input_error_naming_the_file(case, tmp_path, csv_lines):
    name, write, message = BAD_RECORDINGS[case]
    if name.endswith(".ulg"):
        pytest.importorskip("pyulog")
    path = tmp_path / name
    write(path, csv_lines)
    with pytest.raises(InputError, match=rf"^{name}: {message}"):
        fk.load(path)


def test_load_names_its_argument_when_it_is_no_path():
    """``fk.load(42)`` and ``fk.load(None)`` were pathlib's TypeError ("expected str, bytes or
    os.PathLike object")."""
    for bad, what in ((42, "int 42"), (None, "NoneType None"), (b"x.csv", "bytes b'x.csv'")):
        with pytest.raises(InputError, match=rf"path must be a file name \(str or pathlib.Path\) or 'sim:NAME', "
                                             rf"got {what}"):
            fk.load(bad)


def test_a_broken_trials_json_is_an_input_error(tmp_path):
    from fusionkit.benchmarking import discover

    _hdf5(tmp_path / "01_trial.hdf5")
    for text in (b"{not json", b"[1, 2]", b'{"trials": {"01_trial": 3}}', b"\xff\xfe"):
        (tmp_path / "trials.json").write_bytes(text)
        with pytest.raises(InputError, match=r"trials.json: not BROAD's trials.json"):
            discover(tmp_path)


def test_a_csv_with_a_byte_order_mark_reads_like_one_without(tmp_path, csv_lines):
    plain, bom = tmp_path / "plain.csv", tmp_path / "bom.csv"
    plain.write_text("\n".join(csv_lines))
    bom.write_text("\n".join(csv_lines), encoding="utf-8-sig")
    a, b = fk.load(plain), fk.load(bom)
    assert bom.read_bytes()[:3] == b"\xef\xbb\xbf" and len(b) == len(a) > 0
    np.testing.assert_array_equal(a.time, b.time)
    np.testing.assert_array_equal(a.gyr, b.gyr)


def _deep(n):
    return '{"estimator": "poisson-quat", "x": ' + "[" * n + "]" * n + "}"


BAD_CONFIGS = {
    "non-utf-8 toml": ("latin.toml", 'estimator = "poisson-quat"\n# caf\xe9\n'.encode("latin-1"), r"is not UTF-8 text"),
    "json list": ("list.json", b"[1, 2]", r"must be an object of settings .* got a JSON list"),
    "deep json": ("deep.json", _deep(100_000).encode(), r"nests deeper than a configuration can"),
    "nested json": ("nested.json", _deep(MAX_CONFIG_DEPTH + 5).encode(), r"nests deeper .*: x\.0\.0"),
    "deep toml": ("deep.toml", ("x = " + "[" * 100_000 + "]" * 100_000).encode(), r"nests deeper"),
    "bad json": ("bad.json", b'{"estimator": }', r"is not valid JSON"),
}


@pytest.mark.parametrize("case", list(BAD_CONFIGS))
def test_a_bad_config_file_is_a_config_error_naming_the_file(case, tmp_path):
    name, data, message = BAD_CONFIGS[case]
    path = tmp_path / name
    path.write_bytes(data)
    with pytest.raises(ConfigError, match=rf"config file '.*{name}' {message}"):
        fk.compose(path)


def test_config_strings_and_names():
    with pytest.raises(ConfigError, match=r"got a JSON list"):  # was "not valid TOML"
        load_config("[1, 2]")
    assert load_config('[estimator]\nname = "poisson-quat"\n') == {"estimator": {"name": "poisson-quat"}}
    with pytest.raises(ConfigError, match="nests deeper"):
        fk.compose({"estimator": "poisson-quat", "x": [[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[1]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]})
    deep = 1
    for _ in range(5000):
        deep = [deep]
    with pytest.raises(ConfigError, match=r"filter 'pipeline' nests deeper .*: correctors\.0\.0"):  # was RecursionError
        fk.make("pipeline", estimator="poisson-quat", correctors=deep)
    # a parameter called "name" is an unknown parameter, not a second plugin name (was a TypeError)
    with pytest.raises(ConfigError, match=r"name: unknown parameter"):
        fk.make("poisson", name="x")
    with pytest.raises(ConfigError, match=r"name: unknown parameter"):
        fk.compose({"estimator": "poisson-quat", "name": "x"})


def test_a_config_file_name_in_another_case_or_with_another_suffix(tmp_path, monkeypatch, capsys):
    """A config file's suffix is read in any case (``GD.TOML`` was parsed as TOML text: "Invalid
    statement"; ``fusionkit run GD.TOML`` said "unknown plugin 'GD.TOML'"), and a name that looks
    like a file but is missing or not .toml/.json is an error naming it and the suffixes read
    (``nosuch.yaml`` was "not valid TOML: Expected '='")."""
    import fusionkit.cli as cli

    monkeypatch.chdir(tmp_path)
    (tmp_path / "GD.TOML").write_text('[estimator]\nname = "poisson-dcm"\n[alignment]\nmode = "fixed"\n')
    (tmp_path / "gd.Json").write_text(json.dumps({"estimator": "poisson-dcm", "alignment": {"mode": "fixed"}}))
    (tmp_path / "gd.yaml").write_text("estimator: poisson-dcm\n")
    (tmp_path / "gd").write_text('estimator = "poisson-dcm"\n')
    for src in ("GD.TOML", tmp_path / "GD.TOML", "gd.Json", "./gd.Json"):
        assert fk.compose(src).config.estimator.name == "poisson-dcm", src
    assert cli._build_filter("GD.TOML", {}).config.estimator.name == "poisson-dcm"
    formats = r"fusionkit reads TOML \(\.toml\) and JSON \(\.json\) config files"
    for src, message in (("nosuch.yaml", rf"config file 'nosuch.yaml' does not exist; {formats}"),
                         ("nosuch.TOML", r"config file 'nosuch.TOML' does not exist$"),
                         ("gd.yaml", rf"config file 'gd.yaml' has the suffix '.yaml': {formats}"),
                         ("gd", rf"config file 'gd' has no suffix: {formats}"),
                         ("conf/pipeline", r"config file 'conf/pipeline' does not exist"),
                         (tmp_path, r"is a folder, not a config file")):
        with pytest.raises(ConfigError, match=message):
            fk.compose(src)
        if isinstance(src, str):
            assert main(["run", src, "sim:slow-rotation", "-o", str(tmp_path / "o.csv")]) == 2
            err = capsys.readouterr().err
            assert len(err.strip().splitlines()) == 1 and f"config file '{src}'" in err, err
    assert load_config('estimator = "poisson.dcm"') == {"estimator": "poisson.dcm"}  # one line of TOML: text
    (tmp_path / "run=3").mkdir()  # an existing file is a file, whatever its name holds
    (tmp_path / "run=3" / "gd.toml").write_text('[estimator]\nname = "poisson-dcm"\n[alignment]\nmode = "fixed"\n')
    assert fk.compose("run=3/gd.toml").config.estimator.name == "poisson-dcm"
    # a mistyped filter name with a dot is no file name: the registry's hint
    assert main(["run", "ahrs.madgwick", "sim:slow-rotation", "-o", str(tmp_path / "o.csv")]) == 2
    assert "did you mean 'ahrs-madgwick'" in capsys.readouterr().err


def test_too_many_correctors_run_the_reference_path_or_refuse_numba():
    rec = sim.simulate([sim.Rest(0.5)], rate=100.0, seed=2)
    f = fk.compose({"estimator": "poisson-quat", "alignment": {"mode": "fixed", "duration": 0.1},
                    "correctors": ["gradient-descent"] * (MAX_COMPILED_CORRECTORS + 1)})
    n = MAX_COMPILED_CORRECTORS + 1
    with pytest.warns(UserWarning, match=rf"{n} correctors are more than the compiled loop chains \({n - 1}"):
        res = f.run(rec)
    assert res.diagnostics["backend"] == "reference" and np.isfinite(res.quat).all()
    with pytest.raises(ConfigError, match=rf"backend='numba': {n} correctors"):
        f.run(rec, backend="numba")


def _cli_cases(tmp_path, csv_lines):
    """(argv, what the one line must name) for every bad input of the issue, through `fusionkit run`."""
    cases = []
    for name, write, _ in BAD_RECORDINGS.values():
        if name.endswith(".ulg") and not _have("pyulog"):
            continue
        write(tmp_path / name, csv_lines)
        cases.append((["run", "poisson", str(tmp_path / name), "-o", str(tmp_path / "o.csv")], name))
    for name, data, _ in BAD_CONFIGS.values():
        (tmp_path / name).write_bytes(data)
        cases.append((["run", str(tmp_path / name), "sim:translation", "-o", str(tmp_path / "o.csv")], name))
    (tmp_path / "named.json").write_text(json.dumps({"filter": "poisson", "name": "x", "params": {"frame": "XX"}}))
    cases.append((["run", str(tmp_path / "named.json"), "sim:translation", "-o", str(tmp_path / "o.csv")],
                  "frame: Input should be"))
    cases.append((["run", "poisson", "sim:translation", "-o", str(tmp_path / "o.csv"), "--param", "name=3"],
                  "name: unknown parameter"))
    cases.append((["run", "poisson", "sim:translation", "-o", str(tmp_path / "no-such-folder" / "o.csv")],
                  "no-such-folder"))
    return cases


def _have(module):
    try:
        __import__(module)
    except ImportError:
        return False
    return True


def main_err(argv, capsys):
    main(argv)
    return capsys.readouterr().err


def test_the_cli_prints_one_line_for_each_bad_input(tmp_path, csv_lines, capsys):
    for argv, names in _cli_cases(tmp_path, csv_lines):
        assert main(argv) == 2, argv
        err = capsys.readouterr().err.splitlines()
        err = [line for line in err if not line.startswith("Warning: unknown file version")]  # pyulog's own print
        assert len(err) == 1 and err[0].startswith("fusionkit: error: ") and names in err[0], (argv, err)
        assert "Traceback" not in err[0]
    assert "; name: unknown parameter" in main_err(["run", str(tmp_path / "named.json"), "sim:translation", "-o",
                                                     str(tmp_path / "o.csv")], capsys)
