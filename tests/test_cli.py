import json
import re
import subprocess
import sys

import numpy as np
import pytest

from fusionkit.cli import main


def test_list_and_describe(capsys):
    assert main(["list"]) == 0
    out = capsys.readouterr().out
    assert "filter     poisson" in out and "detector   motion" in out
    assert main(["describe", "poisson"]) == 0
    out = capsys.readouterr().out
    assert "alignment_duration = 10.0 [s]" in out
    assert "    body = None\n" in out and "function" not in out  # (body's validator printed as its constraint)
    assert main(["describe", "nope"]) == 2
    assert "unknown plugin 'nope'" in capsys.readouterr().err


def test_run_on_a_simulated_recording(tmp_path, capsys):
    out = tmp_path / "o.csv"
    assert main(["run", "poisson", "sim:slow-rotation", "-o", str(out), "--param", "step=exact",
                 "--param", "motion.window=0.2"]) == 0
    text = capsys.readouterr().out
    assert "samples/s" in text and "RMS error vs truth" in text
    data = np.loadtxt(out, delimiter=",", skiprows=1)
    assert data.shape[1] == 9 and np.isfinite(data).all()


def test_a_warning_is_one_line(tmp_path, capsys):
    """A warning on the command line reads like an error, one line naming its kind: it was
    Python's 'path/fusionkit/cli.py:117: AlignmentWarning: ...' and then the source line of the call."""
    from fusionkit import make, sim
    from fusionkit.types import AlignmentWarning

    assert main(["run", "poisson", "sim:late-gyro", "-o", str(tmp_path / "o.csv")]) == 0
    err = [line for line in capsys.readouterr().err.splitlines() if "compiling" not in line]
    assert len(err) == 1 and re.fullmatch(r"fusionkit: warning: motion detected [\d.]+ s into the mandatory 10 s "
                                          r"alignment: .* \(AlignmentWarning\)", err[0]), err
    with pytest.warns(AlignmentWarning):  # a Python caller's warnings are its own again after main()
        make("poisson").run(sim.scenario("late-gyro"))


def test_run_without_a_finite_reference_prints_no_nan(tmp_path, capsys):
    """A reference column that is all NaN (no sample has one) gives n/a and why, not 'nan deg'."""
    from fusionkit import Recording, sim
    from fusionkit.io.loaders import write_csv

    rec = sim.demo_recordings()[0].slice(0, 300)
    path = tmp_path / "nan_ref.csv"
    write_csv(Recording(gyr=rec.gyr, acc=rec.acc, rate=200.0, truth=np.full((300, 4), np.nan)), path)
    assert main(["run", "poisson", str(path), "-o", str(tmp_path / "o.csv")]) == 0
    out = capsys.readouterr().out
    assert "inclination n/a (no finite reference sample among all samples)" in out and "nan" not in out


def test_run_with_a_config_file_and_bad_input(tmp_path, capsys):
    cfg = tmp_path / "p.json"
    cfg.write_text(json.dumps({"estimator": "poisson-dcm", "alignment": {"mode": "fixed", "duration": 2.0}}))
    assert main(["run", str(cfg), "sim:translation", "-o", str(tmp_path / "o.csv")]) == 0
    assert main(["run", "poisson", "sim:nope", "-o", str(tmp_path / "o.csv")]) == 2
    assert "unknown simulated recording" in capsys.readouterr().err
    assert main(["run", "poisson", "sim:translation", "-o", str(tmp_path / "o.csv"), "--param", "step=x"]) == 2
    assert "step" in capsys.readouterr().err


def test_module_entry_point():
    out = subprocess.run([sys.executable, "-m", "fusionkit.cli", "demo", "--help"], capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 0, out.stderr
    assert "--plot" in out.stdout and "--filters" in out.stdout


def test_demo_runs_and_plots(tmp_path, capsys, monkeypatch):
    """``fusionkit demo`` as the command runs it (every registered filter, the table, progress,
    the plot), on the demo recordings' first 15 s (12 s still, then motion): the pure-Python
    peers took most of the time on the whole recordings."""
    import fusionkit.demo

    whole = fusionkit.demo.demo_recordings
    monkeypatch.setattr(fusionkit.demo, "demo_recordings", lambda: [r.slice(0, 3000) for r in whole()])
    png = tmp_path / "demo.png"
    assert main(["demo", "--plot", str(png)]) == 0
    out, err = capsys.readouterr()
    assert "poisson" in out and "slow-rotation" in out
    assert "gyro-only" in out and "heading: the error's rotation about the vertical" in out
    assert "demo] " not in err and "poisson on slow-rotation: done" in err  # progress, a line per run
    from fusionkit.registry import default_registry

    names = [n for n in default_registry().names("filter") if n != "pipeline"]
    assert all(f"{n} " in out for n in names)  # every registered filter has a row (a result or why it was skipped)
    assert png.stat().st_size > 10_000


def test_progress_bar_on_request(capsys, imu_rec):
    import fusionkit as fk

    fk.make("poisson").run(imu_rec, progress=True)
    assert "sample" in capsys.readouterr().err  # tqdm writes its bar to stderr
    fk.make("poisson").run(imu_rec)  # short input, not a terminal: no bar
    assert capsys.readouterr().err == ""


def test_lags_table(tmp_path, capsys):
    """``fusionkit lags``: the simulator follows fusionkit's convention (half a sample for both
    sensors); a recording without a reference is reported and fails the command."""
    assert main(["lags", "sim:fast-rotation"]) == 0
    row = [line for line in capsys.readouterr().out.splitlines() if line.startswith("| sim:")][0].split("|")
    assert float(row[2]) == pytest.approx(0.5, abs=0.05) and float(row[5].rstrip(" *")) == pytest.approx(0.5, abs=0.05)
    from fusionkit import Recording, sim
    from fusionkit.io.loaders import write_csv

    rec = sim.demo_recordings()[0]
    path = tmp_path / "no_truth.csv"
    write_csv(Recording(gyr=rec.gyr, acc=rec.acc, rate=rec.rate), path)
    assert main(["lags", str(path)]) == 1
    assert "no reference" in capsys.readouterr().out


def test_lags_checks_its_inputs_before_the_table(tmp_path, capsys):
    """A path that names no recording (missing, a kind fusionkit does not read, an empty folder,
    an unknown sim: name) is one error line and no table header, also after a good input."""
    (tmp_path / "notes.txt").write_text("x")
    (tmp_path / "empty").mkdir()
    for bad, what in ((tmp_path / "nope.hdf5", "no such file"), (tmp_path / "notes.txt", "cannot read 'notes.txt'"),
                      (tmp_path / "empty", "no recordings"), ("sim:nope", "unknown simulated recording")):
        assert main(["lags", "sim:fast-rotation", str(bad)]) == 2, bad
        out, err = capsys.readouterr()
        assert out == "" and len(err.strip().splitlines()) == 1 and what in err, (bad, out, err)


def test_lags_marks_a_gravity_only_accelerometer_lag(capsys):
    """Without a reference position the accelerometer is timed against gravity's turning alone:
    heli_cruise's +7.86 samples read as a measurement. Its cells are marked ``*`` and a note under
    the table says what it is; a lag with the position in the model is not marked."""
    import argparse

    from fusionkit import sim
    from fusionkit.cli import _lag_row

    assert main(["lags", "sim:fast-rotation"]) == 0  # (a rotation scenario: no position in its meta)
    lines = capsys.readouterr().out.splitlines()
    row = [c.strip() for c in lines[2].split("|")]
    assert row[5].endswith("*") and row[6].endswith("*") and row[8] == "gravity only*"
    assert lines[-1].startswith("* acc lag from gravity alone") and "not valid under sustained linear" in lines[-1]
    rec = sim.simulate([sim.Rest(0.5), sim.Rotate((0, 1, 1), 1.0, 1.0), sim.Rotate((1, 0, 0), -1.0, 1.0)],
                       rate=100.0, seed=0, gnss_rate=None)
    rec.meta["ref_pos"] = np.zeros((len(rec), 3))  # (it stays where it is)
    text, ok, model = _lag_row("t", lambda: rec, argparse.Namespace(max_lag=8.0, cutoff=20.0))
    assert ok and model == "position" and "*" not in text


def test_lags_reads_every_file_before_the_table(tmp_path, capsys):
    """A file that is no recording (a CSV without gyro columns, e.g. a result written by ``run``)
    is one error line and no header, as the docs say: it printed the header, then the error."""
    bad = tmp_path / "out.csv"
    bad.write_text("t,qw,qx,qy,qz\n0,1,0,0,0\n0.01,1,0,0,0\n")
    assert main(["lags", "sim:fast-rotation", str(bad)]) == 2
    out, err = capsys.readouterr()
    assert out == "" and len(err.strip().splitlines()) == 1 and "missing columns" in err, (out, err)


def test_version(capsys):
    import fusionkit as fk

    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0 and capsys.readouterr().out.strip() == f"fusionkit {fk.__version__}"


def test_run_checks_the_output_path_before_computing(tmp_path, capsys, monkeypatch):
    import fusionkit.cli as cli

    def no_compute(*a, **k):  # the check must come before the recording is even loaded
        raise AssertionError("computed before checking the output path")

    monkeypatch.setattr(cli, "_load_input", no_compute)
    monkeypatch.setattr(cli, "_build_filter", no_compute)
    assert main(["run", "poisson", "sim:slow-rotation", "-o", str(tmp_path / "nope" / "x.csv")]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "does not exist" in err and "nope" in err
    assert main(["run", "poisson", "sim:slow-rotation", "-o", str(tmp_path)]) == 2  # a folder, not a file
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "it is a folder; give a file name" in err


def test_bench_sweep_and_demo_check_their_output_before_computing(tmp_path, capsys):
    """The table or plot's folder is checked first: before, bench and sweep ran every trial and
    then failed on writing ('[Errno 2] No such file or directory'), demo after its whole table.
    Here the data, filter or grid are bad too: the output's error comes first, so nothing ran."""
    out = str(tmp_path / "nope" / "x.md")
    for argv in (["bench", "--data", str(tmp_path / "none"), "--filters", "poisson", "-o", out],
                 ["sweep", "poisson", "--data", str(tmp_path / "none"), "--grid", "step=exact", "-o", out],
                 ["demo", "--filters", "poison", "--plot", out],
                 ["bench", "--data", str(tmp_path / "none"), "--filters", "poisson", "-o", str(tmp_path)]):
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert len(err.strip().splitlines()) == 1 and re.search(r"cannot write .*(does not exist|it is a folder)", err), err
    pytest.importorskip("matplotlib")
    for name, what in (("x.txt", "'.txt' is not an image format"), ("plot", "it has no image extension")):
        assert main(["demo", "--filters", "poison", "--plot", str(tmp_path / name)]) == 2  # (a traceback after the run)
        err = capsys.readouterr().err
        assert len(err.strip().splitlines()) == 1 and what in err and "png" in err, err


def test_bench_checks_its_plots_before_computing(tmp_path, capsys, monkeypatch):
    """``bench --plots DIR`` without matplotlib ran the whole benchmark, then ended in an error
    (exit 2, the folder empty); a file given as the folder likewise. Now one error line before
    anything is computed (the benchmark here would fail: it must not be reached)."""
    import fusionkit.benchmarking

    def no_compute(*a, **k):
        raise AssertionError("computed before checking --plots")

    monkeypatch.setattr(fusionkit.benchmarking, "bench", no_compute)
    (tmp_path / "f.txt").write_text("x")
    argv = ["bench", "--data", str(tmp_path / "none"), "--filters", "poisson", "--plots"]
    assert main(argv + [str(tmp_path / "f.txt")]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "f.txt is a file; give a folder" in err, err
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # import matplotlib: ImportError
    assert main(argv + [str(tmp_path / "plots")]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "plots need matplotlib: pip install 'fusionkit[plot]'" in err, err
    assert not (tmp_path / "plots").exists()


def test_run_takes_a_rate_for_a_csv_without_time(tmp_path, capsys):
    from fusionkit import Recording, sim
    from fusionkit.io.loaders import write_csv

    rec = sim.demo_recordings()[0].slice(0, 400)
    path = tmp_path / "no_t.csv"
    write_csv(Recording(gyr=rec.gyr, acc=rec.acc, rate=200.0), path)
    rows = [ln.split(",", 1) for ln in path.read_text().splitlines() if not ln.startswith("#")]
    assert rows[0][0] == "t"
    path.write_text("\n".join(r[1] for r in rows) + "\n")  # no t column, no '# rate=' line
    assert main(["run", "poisson", str(path), "-o", str(tmp_path / "o.csv")]) == 2
    assert "rate" in capsys.readouterr().err
    assert main(["run", "poisson", str(path), "--rate", "200", "-o", str(tmp_path / "o.csv")]) == 0
    t = np.loadtxt(tmp_path / "o.csv", delimiter=",", skiprows=1)[:, 0]
    assert t[1] - t[0] == pytest.approx(1 / 200)


def test_every_option_says_what_it_is(monkeypatch):
    """Every argument of every subcommand has a help text (run --backend, sweep's --data, --trials,
    --jobs, --no-cache, -o, describe's name had none)."""
    import argparse

    class Built(Exception):
        pass

    def capture(self, argv=None, namespace=None):
        raise Built(self)

    monkeypatch.setattr(argparse.ArgumentParser, "parse_args", capture)
    with pytest.raises(Built) as got:
        main(["list"])
    sub = next(a for a in got.value.args[0]._actions if isinstance(a, argparse._SubParsersAction))
    bare = [f"{name} {a.dest}" for name, p in sub.choices.items() for a in p._actions
            if not a.help and not isinstance(a, argparse._HelpAction)]
    assert bare == []


@pytest.mark.parametrize("cmd", ["list", "describe", "run", "bench", "sweep", "lags", "demo"])
def test_every_help_has_an_example(cmd, capsys):
    with pytest.raises(SystemExit):
        main([cmd, "--help"])
    text = capsys.readouterr().out
    assert "example:\n  fusionkit " + cmd in text
    if cmd in ("run", "bench", "sweep", "lags", "demo"):  # they print numbers: their units are named
        assert "deg" in text or "ms" in text


def test_run_gives_no_total_error_to_a_gyro_only_filter(tmp_path, capsys):
    """poisson integrates the gyro from a heading of 0 (body x north): its heading and total
    errors say nothing; the CSV's yaw column names its frame, so 90 (ENU: x to north) is no error."""
    out = tmp_path / "o.csv"
    assert main(["run", "poisson", "sim:slow-rotation", "-o", str(out)]) == 0
    text = capsys.readouterr().out
    assert "total n/a (gyro-only" in text and "heading n/a" in text and "inclination 0." in text
    assert "yaw_enu_deg (body x from East" in text
    head = out.read_text().splitlines()[0].split(",")
    assert "yaw_enu_deg" in head and "heading_deg" not in head
    assert main(["run", "recommended", "sim:slow-rotation", "-o", str(out)]) == 0
    assert "total 0." in capsys.readouterr().out  # a 9D filter has one


def test_bench_and_sweep_print_progress_lines_without_a_terminal(tmp_path, capsys):
    from fusionkit import Recording, sim
    from fusionkit.io.loaders import write_csv

    for i, rec in enumerate(sim.demo_recordings()[:2]):
        r = rec.slice(0, 600)
        write_csv(Recording(gyr=r.gyr, acc=r.acc, rate=200.0, truth=r.truth), tmp_path / f"trial{i}.csv")
    assert main(["bench", "--data", str(tmp_path), "--filters", "poisson", "--no-cache"]) == 0
    err = capsys.readouterr().err  # capsys: stderr is not a terminal
    assert "[1/2] poisson on trial0: done in" in err and "[2/2]" in err
    assert main(["sweep", "poisson", "--data", str(tmp_path), "--grid", "step=first-order,exact",
                 "--metric", "inclination", "--no-cache"]) == 0
    cap = capsys.readouterr()
    assert "[4/4]" in cap.err and "mean over trials (deg)" in cap.out  # progress on stderr, units in the table
    assert main(["lags", "sim:fast-rotation"]) == 0
    assert "[1/1] sim:fast-rotation: done" in capsys.readouterr().err


def test_cli_mistakes_are_named_before_any_run(tmp_path, capsys):
    """Each used to end in a traceback (an empty grid value, a one-sample recording for ``lags``) or
    in an answer that hid the mistake (an empty table for ``--filters ""``, a skipped row and exit 0
    for a misspelt demo filter, "no parameter set ran on every trial" for a bad grid value or metric).
    None of them runs a filter."""
    from fusionkit import Recording, sim
    from fusionkit.io.loaders import write_csv

    rec = sim.demo_recordings()[0].slice(0, 50)
    one = tmp_path / "one.csv"
    write_csv(Recording(gyr=rec.gyr[:1], acc=rec.acc[:1], rate=200.0, truth=rec.truth[:1]), one)
    data = ["--data", str(one), "--no-cache"]
    cases = [(["bench", *data, "--filters", ""], 2, "no filters to run"),
             (["sweep", "poisson", *data, "--grid", "step="], 2, r"step: Input should be 'first-order' or"),
             (["sweep", "poisson", *data, "--grid", "step=exact", "--metric", "rmse"], 2, "metric must be one of"),
             (["demo", "--filters", "poison", "--plot", ""], 2, "did you mean 'poisson'"),
             (["lags", str(one)], 1, "too short to time"),
             (["lags", str(one), "--max-lag", "inf"], 2, r"--max-lag must be a finite number of samples >= 0.05"),
             (["lags", str(one), "--max-lag", "0.01"], 2, r"--max-lag .* got 0.01"),
             (["lags", str(one), "--cutoff", "-1"], 2, r"--cutoff must be a frequency > 0 Hz, got -1")]
    for argv, code, match in cases:
        assert main(argv) == code, argv
        cap = capsys.readouterr()
        assert re.search(match, cap.err + cap.out), (argv, cap.err + cap.out)


def test_run_names_a_reference_that_is_not_a_truth(tmp_path, capsys, monkeypatch):
    """A PX4 log without a simulator's truth carries the autopilot's own estimate as its reference
    (``meta["truth_kind"]``): ``run`` printed the agreement with it as "RMS error vs truth"."""
    import fusionkit.cli as cli
    from fusionkit import sim

    rec = sim.demo_recordings()[0].slice(0, 400)
    rec.meta["truth_kind"] = "autopilot estimate"
    monkeypatch.setattr(cli, "_load_input", lambda *a, **k: rec)
    assert main(["run", "poisson", "sim:slow-rotation", "-o", str(tmp_path / "o.csv")]) == 0
    text = capsys.readouterr().out
    assert "RMS difference from the recording's autopilot estimate (not a truth)" in text
    assert "error vs truth" not in text
    rec.meta["truth_kind"] = "ground truth (simulator)"  # a SITL log's truth is one
    assert main(["run", "poisson", "sim:slow-rotation", "-o", str(tmp_path / "o.csv")]) == 0
    assert "RMS error vs truth" in capsys.readouterr().out


def test_demo_with_filters_says_which(capsys, monkeypatch):
    """``demo --filters`` said it ran "every registered filter"."""
    import fusionkit.demo

    whole = fusionkit.demo.demo_recordings
    monkeypatch.setattr(fusionkit.demo, "demo_recordings", lambda: [r.slice(0, 600) for r in whole()])
    assert fusionkit.demo.run_demo(plot=None, filters=["poisson"]) == 0
    out = capsys.readouterr().out
    assert "fusionkit demo: 1 filter (--filters) on simulated" in out and "every registered" not in out


def test_run_takes_the_units_of_a_csv(tmp_path, capsys):
    """A CSV in deg/s and g had no way in from the command line (``--param acc_unit=g``: "unknown
    parameter"): ``--gyr-unit`` and ``--acc-unit``, which the refusal names."""
    from fusionkit import Recording, sim
    from fusionkit.io.loaders import write_csv

    rec = sim.demo_recordings()[1].slice(2400, 4000)
    path = tmp_path / "deg_g.csv"
    write_csv(Recording(gyr=rec.gyr, acc=rec.acc, rate=200.0), path)
    data = np.loadtxt(path, delimiter=",", skiprows=1)
    data[:, 1:4] = np.degrees(data[:, 1:4])
    data[:, 4:7] /= 9.80665
    np.savetxt(path, data, delimiter=",", header=path.read_text().splitlines()[0], comments="", fmt="%.10g")
    out = str(tmp_path / "o.csv")
    assert main(["run", "poisson", str(path), "-o", out]) == 2
    assert "--acc-unit UNIT on the command line" in capsys.readouterr().err
    assert main(["run", "poisson", str(path), "-o", out, "--param", "acc_unit=g"]) == 2
    assert "pass --acc-unit g" in capsys.readouterr().err
    assert main(["run", "poisson", str(path), "-o", out, "--gyr-unit", "deg/s", "--acc-unit", "g"]) == 0
    assert main(["run", "poisson", "sim:slow-rotation", "-o", out, "--gyr-unit", "deg/s"]) == 2
    assert "--gyr-unit is for a CSV file" in capsys.readouterr().err


def test_cli_messages_name_the_cli_options_and_read_well(tmp_path, capsys):
    """A CSV without time said "pass rate=" (a Python argument) to the command line; "'poisson-quat'
    is a estimator"; "unknown plugin 'nosuch' Known: ..." lacked its full stop."""
    from fusionkit import Recording, sim
    from fusionkit.io.loaders import write_csv

    rec = sim.demo_recordings()[0].slice(0, 400)
    path = tmp_path / "no_t.csv"
    write_csv(Recording(gyr=rec.gyr, acc=rec.acc, rate=200.0), path)
    rows = [ln.split(",", 1)[1] for ln in path.read_text().splitlines()]
    path.write_text("\n".join(rows) + "\n")
    assert main(["run", "poisson", str(path), "-o", str(tmp_path / "o.csv")]) == 2
    assert "--rate on the command line" in capsys.readouterr().err
    assert main(["describe", "poisson-quat", "--toml"]) == 2
    assert "'poisson-quat' is an estimator" in capsys.readouterr().err
    assert main(["describe", "nosuch"]) == 2
    assert "unknown plugin 'nosuch'. Known: " in capsys.readouterr().err
    assert main(["describe", "poisso"]) == 2
    assert "did you mean 'poisson'" in capsys.readouterr().err


def test_describe_pipeline_toml_points_to_a_preset(capsys):
    """``describe pipeline --toml`` printed estimator = "(required)", which ``fusionkit run`` then refused as an
    unknown estimator plugin."""
    assert main(["describe", "pipeline", "--toml"]) == 2
    err = capsys.readouterr().err
    assert "'pipeline' is the composition itself" in err and "describe recommended --toml" in err


def test_a_strapdown_result_prints_a_summary():
    import numpy as np

    from fusionkit.navigation.strapdown import StrapdownResult

    r = StrapdownResult(np.zeros((5, 3)), np.ones((5, 3)), np.zeros((5, 4)), "NED", np.array([0, 1, 0, 0, 1]))
    assert repr(r).startswith("StrapdownResult(5 samples, NED, 2 GNSS resets; final velocity") and "array" not in repr(r)


def test_a_navigation_results_csv_has_its_velocity_and_position(tmp_path):
    """``fusionkit run ins-gnss ... -o out.csv`` (Result.to_csv) wrote the attitude alone; its velocity and
    position were only in the Result's diagnostics. Their columns are named for the frame's axes."""
    from fusionkit.types import Result

    n = 5
    for frame, axes in (("ENU", "enu"), ("NED", "ned")):
        r = Result(np.tile([1.0, 0.0, 0.0, 0.0], (n, 1)), np.zeros(n, np.uint32), frame,
                   {"velocity": np.arange(3 * n, dtype=float).reshape(n, 3), "position": np.ones((n, 3))})
        r.to_csv(tmp_path / "nav.csv", time=np.arange(n) * 0.1)
        head = (tmp_path / "nav.csv").read_text().splitlines()[0].split(",")
        assert head[-6:] == [f"vel_{a}_mps" for a in axes] + [f"pos_{a}_m" for a in axes]
        data = np.loadtxt(tmp_path / "nav.csv", delimiter=",", skiprows=1)
        np.testing.assert_array_equal(data[:, -6:-3], r.diagnostics["velocity"])
    plain = Result(np.tile([1.0, 0.0, 0.0, 0.0], (n, 1)), np.zeros(n, np.uint32), "ENU", {})
    plain.to_csv(tmp_path / "att.csv")
    assert (tmp_path / "att.csv").read_text().splitlines()[0].endswith(",flags")
