import json
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
    assert "alignment_duration = 10.0 [s]" in capsys.readouterr().out
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


def test_run_with_a_config_file_and_bad_input(tmp_path, capsys):
    cfg = tmp_path / "p.json"
    cfg.write_text(json.dumps({"estimator": "poisson-dcm", "alignment": {"mode": "fixed", "duration": 2.0}}))
    assert main(["run", str(cfg), "sim:translation", "-o", str(tmp_path / "o.csv")]) == 0
    assert main(["run", "poisson", "sim:nope", "-o", str(tmp_path / "o.csv")]) == 2
    assert "unknown simulated recording" in capsys.readouterr().err
    assert main(["run", "poisson", "sim:translation", "-o", str(tmp_path / "o.csv"), "--param", "step=x"]) == 2
    assert "step" in capsys.readouterr().err


def test_demo_runs_and_plots(tmp_path):
    png = tmp_path / "demo.png"
    out = subprocess.run([sys.executable, "-m", "fusionkit.cli", "demo", "--plot", str(png)], capture_output=True,
                         text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    assert "poisson" in out.stdout and "slow-rotation" in out.stdout
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
    row = capsys.readouterr().out.splitlines()[-1].split("|")
    assert float(row[2]) == pytest.approx(0.5, abs=0.05) and float(row[5]) == pytest.approx(0.5, abs=0.05)
    from fusionkit import Recording, sim
    from fusionkit.io.loaders import write_csv

    rec = sim.demo_recordings()[0]
    path = tmp_path / "no_truth.csv"
    write_csv(Recording(gyr=rec.gyr, acc=rec.acc, rate=rec.rate), path)
    assert main(["lags", str(path)]) == 1
    assert "no reference" in capsys.readouterr().out
