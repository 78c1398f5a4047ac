"""The ``fusionkit`` command: ``list``, ``describe NAME``, ``run NAME|CONFIG INPUT -o OUT.csv``,
``bench``, ``sweep``, ``lags INPUT...``, ``demo``."""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
import warnings
from pathlib import Path


from .config import set_dotted
from .errors import FusionkitError
from .validation import ACC_UNITS, GYR_UNITS


def _parse_params(items: list[str]) -> dict:
    """``["a=1", "motion.window=0.2", "step=exact"]`` -> nested dict with JSON-parsed values."""
    out: dict = {}
    for item in items or []:
        if "=" not in item:
            raise FusionkitError(f"--param takes name=value, got {item!r}")
        key, raw = item.split("=", 1)
        try:
            value = json.loads(raw)
        except json.JSONDecodeError:
            value = raw
        set_dotted(out, key, value)
    return out


def _build_filter(spec: str, params: dict):
    """The filter ``spec`` names: a registered filter, else a config file (.toml or .json in any
    case; a name that looks like a file, with a suffix or a folder, but is none of these is an
    error naming the file: ``GD.TOML`` was "unknown plugin 'GD.TOML'")."""
    from . import compose, make
    from .config import CONFIG_SUFFIXES, config_file, load_config
    from .registry import default_registry

    try:
        p = None if spec in default_registry().names("filter") else config_file(spec)
    except FusionkitError as exc:  # a mistyped name with a dot (ahrs.madgwick) is no file: the registry's hint
        path = Path(spec)
        if path.exists() or "/" in spec or "\\" in spec or path.suffix.lower() in CONFIG_SUFFIXES:
            raise
        try:
            return make(spec, **params)
        except FusionkitError as unknown:
            raise FusionkitError(f"{unknown} (nor is it a config file: {exc})") from None
    if p is not None:
        cfg = _merge(load_config(p), params)
        if "filter" in cfg:  # {"filter": "poisson", "params": {...}}: other keys are parameters too
            name, fparams = cfg.pop("filter"), cfg.pop("params", {})
            if not isinstance(name, str) or not isinstance(fparams, dict):
                raise FusionkitError(f"{spec}: 'filter' must be a filter name and 'params' a table of its parameters")
            return make(name, "filter", _merge(fparams, cfg))
        return compose(cfg)
    return make(spec, **params)


def _merge(base, over: dict, where: str = ""):
    """``over``'s values set into ``base`` (a config file's tables) one leaf at a time: ``--param
    alignment.duration=5`` changes the duration and keeps the file's alignment mode and heading, and
    ``correctors.0.params.beta=0.2`` the first corrector's beta (a list's element by its index).
    A dict replaced whole the table it named: the file's other settings fell back to the defaults
    (or, for ``estimator.params.step``, the estimator lost its name)."""
    for key, value in over.items():
        if isinstance(base, list):
            if not (key.isdigit() and int(key) < len(base)):
                raise FusionkitError(f"--param {where}{key}: {where[:-1]} is a list of {len(base)} "
                                     + (f"(give an index from 0 to {len(base) - 1}, e.g. {where}0)" if base else
                                        "(add the entry to the config file)"))
            key = int(key)
        current = base[key] if isinstance(key, int) else base.get(key)
        if isinstance(current, str) and isinstance(value, dict):  # a plugin by its name alone ("estimator":
            base[key] = current = {"name": current}               # "poisson-dcm", or a list's entry)
        if isinstance(value, dict) and isinstance(current, (dict, list)):
            _merge(current, value, f"{where}{key}.")
        else:
            base[key] = value
    return base


def _load_input(spec: str, rate: float | None = None, gyr_unit: str | None = None, acc_unit: str | None = None):
    """``spec``'s recording (a file or ``sim:NAME``, as :func:`fusionkit.load` reads it); ``--rate``,
    ``--gyr-unit`` and ``--acc-unit`` apply to a CSV only."""
    from . import load

    options = {"rate": rate, "gyr_unit": gyr_unit, "acc_unit": acc_unit}
    given = [f"--{k.replace('_', '-')}" for k, v in options.items() if v is not None]
    if given and (spec.startswith("sim:") or Path(spec).suffix.lower() != ".csv"):
        raise FusionkitError(f"{', '.join(given)} {'is' if len(given) == 1 else 'are'} for a CSV file (--rate: one "
                             f"without a 't' column); {spec} carries its own clock and units")
    return load(spec, **{k: v for k, v in options.items() if v is not None})


def cmd_list(args) -> int:
    from .registry import default_registry

    reg = default_registry()
    errors = reg.check_all()
    for kind, name, dist in reg.info():
        err = errors.get(f"{kind}:{name}")
        status = f"  BROKEN: {err}" if err else ""
        if err is None:
            summary = reg.get(name, kind).summary
            status = f"  {summary}" if summary else ""
        print(f"{kind:10s} {name:22s} [{dist}]{status}")
    for msg in reg.duplicates:
        print(f"DUPLICATE: {msg}")
    return 1 if errors or reg.duplicates else 0


def cmd_describe(args) -> int:
    from . import describe
    from .config import to_toml

    info = describe(args.name, args.kind)
    if args.toml or args.json:
        cfg = info.config()
        if info.kind == "filter" and info.name == "pipeline":  # (its estimator is the user's to name: the
            # config printed "(required)" there, which `fusionkit run` then refused as an unknown estimator)
            raise FusionkitError("'pipeline' is the composition itself, with no estimator of its own: print a "
                                 "preset's config to start from (fusionkit describe recommended --toml) or write "
                                 "one (docs/configuration.md)")
        if cfg is None:
            raise FusionkitError(f"{args.name!r} is {_article(info.kind)} {info.kind}: only filters print a runnable "
                                 "config "
                                 "(use it inside a pipeline config, see docs/configuration.md)")
        print(json.dumps(cfg, indent=2) if args.json else to_toml(cfg), end="\n" if args.json else "")
        return 0
    print(info)
    return 0


def _article(word: str) -> str:
    return "an" if word[:1] in "aeiou" else "a"


def _check_output(path: str) -> None:
    """Fail before any computing when ``path`` cannot be written (it is a folder, its folder is
    missing or read-only): an hour's run must not end in a traceback, nor in an error after it.
    ``run``'s CSV, ``bench``'s and ``sweep``'s table, ``demo``'s plot."""
    import os

    if Path(path).expanduser().is_dir():
        raise FusionkitError(f"cannot write {path}: it is a folder; give a file name")
    parent = Path(path).expanduser().resolve().parent
    if not parent.is_dir():
        raise FusionkitError(f"cannot write {path}: folder {parent} does not exist")
    if not os.access(parent, os.W_OK):
        raise FusionkitError(f"cannot write {path}: folder {parent} is not writable")


def _check_plot_folder(path: str) -> None:
    """Fail before the benchmark when ``--plots`` cannot be written: matplotlib missing (the whole
    run ended in an error, the folder empty), ``path`` a file, or a folder that cannot be written
    (missing folders are made, as :func:`~fusionkit.benchmarking.plots.write_plots` does)."""
    import os

    from .benchmarking.plots import require_matplotlib

    try:
        require_matplotlib()
    except FusionkitError as exc:
        raise FusionkitError(f"--plots {path}: {exc} (or leave out --plots)") from None
    folder = Path(path).expanduser().resolve()
    existing = next(p for p in (folder, *folder.parents) if p.exists())  # missing folders are made
    if not existing.is_dir():
        raise FusionkitError(f"cannot write plots into {path}: {existing} is a file; give a folder")
    if not os.access(existing, os.W_OK):
        raise FusionkitError(f"cannot write plots into {path}: folder {existing} is not writable")


#: what a recording takes, not a filter: ``--param acc_unit=g`` named no option that works
_INPUT_OPTIONS = {"rate": "--rate", "gyr_unit": "--gyr-unit", "acc_unit": "--acc-unit"}


def cmd_run(args) -> int:
    _check_output(args.output)
    params = _parse_params(args.param)
    for key, option in _INPUT_OPTIONS.items():
        if key in params:
            raise FusionkitError(f"--param {key}: {key} belongs to the recording, not the filter: pass {option} "
                                 f"{params[key]} (a CSV; or a '# {key}=...' line in it)")
    f = _build_filter(args.filter, params)
    rec = _load_input(args.input, rate=args.rate, gyr_unit=args.gyr_unit, acc_unit=args.acc_unit)
    warm = _warm_up(f, rec, args.backend)
    t0 = time.perf_counter()
    res = f.run(rec, backend=args.backend, progress=True if args.progress else None)
    elapsed = time.perf_counter() - t0
    res.to_csv(args.output, time=rec.time)
    print(f"{f.name}: {len(rec)} samples in {elapsed:.3f} s ({len(rec) / elapsed:,.0f} samples/s, "
          f"backend {res.diagnostics['backend']}; compile and warm-up {warm:.3f} s, not counted) -> {args.output}")
    nav = (", vel_*_mps and pos_*_m (velocity in m/s and position in m, in the frame's axes)"
           if getattr(res.diagnostics.get("velocity"), "shape", None) == (len(res), 3) else "")
    print(f"columns: t (s), qw..qz (body -> {res.frame}), {_yaw_definition(res.frame)}, pitch_deg, roll_deg, "
          f"flags (bits: fusionkit.Flag){nav}")
    if rec.truth is not None:
        from .benchmarking.metrics import rms_errors
        from .benchmarking.report import aiding, not_applicable

        kind = aiding(f, rec)
        na = not_applicable(kind, gnss_heading=bool(getattr(f, "requires_gnss", False)), rec=rec)
        e = rms_errors(res, rec)
        over = "the movement samples" if rec.movement is not None else "all samples"
        none = f"no finite reference sample among {over}"  # (NaN rows: samples without one; it printed "nan deg")
        ref = rec.meta.get("truth_kind", "ground truth")  # (a PX4 log's reference may be the autopilot's estimate)
        against = ("error vs truth" if ref.startswith("ground truth")
                   else f"difference from the recording's {ref} (not a truth)")
        print(f"RMS {against} over {over} ({kind} filter; heading = the error's rotation about the vertical): "
              + ", ".join(f"{k} n/a ({na[k]})" if k in na else f"{k} {v:.3f} deg" if math.isfinite(v) else
                          f"{k} n/a ({none})" for k, v in e.items()))
    return 0


def _warm_up(f, rec, backend: str, samples: int = 64) -> float:
    """Run ``f`` on the first ``samples`` of ``rec`` so that numba compiles (or loads from its
    cache) before the timed run; returns the seconds it took. The run's own errors are left to
    the real run to report."""
    t0 = time.perf_counter()
    try:
        f.run(rec.slice(0, min(samples, len(rec))), backend=backend, progress=False)
    except FusionkitError:
        pass
    return time.perf_counter() - t0


def _yaw_definition(frame: str) -> str:
    """What the CSV's yaw column means in ``frame`` (the name says the frame: ENU yaw is not a
    compass heading)."""
    return {"ENU": "yaw_enu_deg (body x from East, counter-clockwise: x to North = 90)",
            "NED": "yaw_ned_deg (body x from North, clockwise: a compass heading)",
            "NWU": "yaw_nwu_deg (body x from North, counter-clockwise)",
            "NUE": "yaw_nue_deg (source 000's heading psi)"}.get(frame, f"yaw_{frame.lower()}_deg")


def _values(raw: str) -> list:
    out = []
    for item in raw.split(","):
        try:
            out.append(json.loads(item))
        except json.JSONDecodeError:
            out.append(item)
    return out


def _flat_params(items: list[str]) -> dict:
    """``["a=1", "vqf.tau_acc=2"]`` -> ``{"a": 1, "vqf.tau_acc": 2}`` (dotted keys kept)."""
    out = {}
    for item in items or []:
        if "=" not in item:
            raise FusionkitError(f"--param takes name=value, got {item!r}")
        k, raw = item.split("=", 1)
        out[k] = _values(raw)[0] if "," not in raw else _values(raw)
    return out


def cmd_bench(args) -> int:
    from .benchmarking import bench
    from .benchmarking.datasets import discover

    if args.output:
        _check_output(args.output)
    if args.plots:
        _check_plot_folder(args.plots)
    filters = [f for f in args.filters.split(",") if f]
    trials = [t for t in args.trials.split(",") if t] if args.trials else None
    res = bench(filters, args.data, trials=trials, params=_flat_params(args.param), jobs=args.jobs,
                cache=not args.no_cache, scheduler=args.scheduler, progress=True)
    text = res.table(args.format)
    cached = sum(bool(r.get("cached")) for r in res.records)
    if cached:  # on stderr: the table (or JSON) on stdout stays as it was
        print(f"fusionkit: {cached} of {len(res.records)} results from the cache (same code, config and file); "
              f"--no-cache recomputes them", file=sys.stderr)
    groups = res.group_table(format=args.format) if args.format in ("table", "markdown") else ""
    if groups:  # (none when every run failed: it printed an empty "by group:")
        text += "\n\nby group:\n\n" + groups
    if args.output:
        Path(args.output).write_text(text + "\n")
        print(f"wrote {args.output}")
    else:
        print(text)
    if args.plots:
        from .benchmarking.plots import write_plots

        found = discover(args.data, trials)
        with_ref = [t for t in found if t.dataset in ("broad", "gnss")] or found
        for p in write_plots(res, args.plots, trial=with_ref[0] if with_ref else None):
            print(f"plot: {p}")
    return 1 if any(r["error"] for r in res.records) and all(r["error"] for r in res.records) else 0


def cmd_sweep(args) -> int:
    from .benchmarking.sweep import sweep

    if args.output:
        _check_output(args.output)
    grid = {}
    for g in args.grid:
        if "=" not in g:
            raise FusionkitError(f"--grid takes name=v1,v2,..., got {g!r}")
        k, raw = g.split("=", 1)
        if k in grid:  # (the second replaced the first)
            raise FusionkitError(f"--grid {k} is given twice: list its values once, {k}=v1,v2,...")
        grid[k] = _values(raw)
    trials = [t for t in args.trials.split(",") if t] if args.trials else None
    res = sweep(args.filter, grid, args.data, metric=args.metric, trials=trials, jobs=args.jobs,
                cache=not args.no_cache, base=_parse_params(args.param), progress=True)
    text = res.report()
    if args.output:
        Path(args.output).write_text(text + "\n")
        print(f"wrote {args.output}")
    else:
        print(text)
    return 0


def _recordings(specs: list[str]):
    """(name, loader) for each input: a recording file, ``sim:NAME``, or a folder of trials."""
    from .benchmarking.datasets import discover

    for spec in specs:
        if not spec.startswith("sim:") and Path(spec).is_dir():
            for trial in discover(spec):
                yield trial.name, trial.load
        else:
            yield spec, lambda spec=spec: _load_input(spec)


def _check_inputs(specs: list[str]) -> None:
    """Fail before any output when an input names no recording: a missing file, one of a kind
    fusionkit does not read, an unknown ``sim:`` name (a folder: :func:`_recordings` finds its
    trials). ``lags`` printed its table's header first, then the error."""
    from . import sim
    from .io.loaders import check_path

    for spec in specs:
        if spec.startswith("sim:"):
            if spec[4:] not in sim.SCENARIOS:
                _load_input(spec)  # a demo recording (a few ms to simulate), else the error naming the choices
        elif not Path(spec).is_dir():
            check_path(spec)


def cmd_lags(args) -> int:
    import inspect

    from .benchmarking.runner import Progress
    from .benchmarking.timing import sensor_lags

    step = inspect.signature(sensor_lags).parameters["step"].default  # its search grid, samples
    if not step <= args.max_lag < math.inf:  # (NaN too) before the table: every row would say it
        raise FusionkitError(f"--max-lag must be a finite number of samples >= {step} (the search step), "
                             f"got {args.max_lag:g}")
    if not args.cutoff > 0:
        raise FusionkitError(f"--cutoff must be a frequency > 0 Hz, got {args.cutoff:g}")
    _check_inputs(args.inputs)
    todo = list(_lag_inputs(args.inputs))  # (every file read and a folder's trials found before the header)
    print("| recording | gyr lag (samples) | gyr lag (ms) | gyr residual (rad/s) | acc lag (samples) | acc lag (ms) "
          "| acc residual (m/s^2) | acc model | mag lag (samples) | mag lag (ms) | mag residual |\n"
          "|---|---:|---:|---:|---:|---:|---:|---|---:|---:|---:|", flush=True)
    progress = Progress(len(todo), "lags")  # on stderr: a bar on a terminal, else a line per recording
    failed = 0
    gravity_only = False
    while todo:
        name, load = todo.pop(0)  # (a file read before the header is let go after its row)
        row, ok, model = _lag_row(name, load, args)
        del load
        progress.update(name, "done" if ok else "failed")
        print(row, flush=True)
        failed += not ok
        gravity_only |= model == "gravity"
    progress.close()
    if gravity_only:
        print(_GRAVITY_ONLY_NOTE, flush=True)
    return 1 if failed else 0


#: the accelerometer's model where the recording has no reference position (``acc model`` column), and
#: the note under the table: its lag is gravity's turning alone, which a vehicle's sustained linear
#: acceleration swamps (heli_cruise: +7.86 samples, read as a measurement), so it is marked, not left
#: out (which recording's motion allows it cannot be told from the lag; on a rotation trial it is valid)
_GRAVITY_ONLY = "gravity only*"
_GRAVITY_ONLY_NOTE = ("* acc lag from gravity alone (the recording has no reference position): a model estimate, "
                      "not a measurement, and not valid under sustained linear acceleration (a vehicle's, e.g. the "
                      "GNSS scenarios); see docs/benchmarking.md")


def _lag_inputs(specs: list[str]):
    """(name, loader) for each of ``lags``' inputs, every file read here, before the table's header: a
    file that is no recording (a CSV without gyro columns) is one error line with no header, as a
    missing one is (it printed the header, then the error). A folder's trials and ``sim:`` recordings
    are read at their row (a trial that cannot be read is reported there)."""
    for spec in specs:
        if spec.startswith("sim:") or Path(spec).is_dir():
            yield from _recordings([spec])
        else:
            rec = _load_input(spec)
            yield spec, lambda rec=rec: rec


def _lag_row(name: str, load, args) -> tuple[str, bool, str | None]:
    """One recording's row of the lags table, whether it could be timed, and the accelerometer's
    model (None: not timed). An accelerometer lag from gravity alone is marked ``*``
    (:data:`_GRAVITY_ONLY_NOTE`)."""
    from .benchmarking.timing import sensor_lags

    try:
        rec = load()
    except FusionkitError as exc:  # (a folder's trial: reported in its row; the other recordings go on)
        return f"| {name} | error: {exc} | | | | | | | | | |", False, None
    if rec.truth is None:
        return f"| {name} | no reference | | | | | | | | | |", False, None
    try:
        r = sensor_lags(rec, max_lag=args.max_lag, cutoff=args.cutoff)
    except FusionkitError as exc:  # reported in its row; the other recordings go on
        return f"| {name} | error: {exc} | | | | | | | | | |", False, None
    cells = ["-" if math.isnan(v) else f"{v:{fmt}}" for v, fmt in (  # NaN (no minimum in the range): "-"
        (r.gyr, "+.2f"), (1e3 * r.gyr_seconds, "+.2f"), (r.gyr_rms, ".3f"), (r.acc, "+.2f"),
        (1e3 * r.acc_seconds, "+.2f"), (r.acc_rms, ".3f"), (r.mag, "+.2f"), (1e3 * r.mag_seconds, "+.2f"),
        (r.mag_rms, ".3f"))]
    if r.acc_model == "gravity":
        cells[3:5] = [c if c == "-" else c + "*" for c in cells[3:5]]
    cells.insert(6, _GRAVITY_ONLY if r.acc_model == "gravity" else r.acc_model)
    return f"| {name} | " + " | ".join(cells) + " |", True, r.acc_model


def cmd_demo(args) -> int:
    from .demo import run_demo

    if args.plot:
        _check_output(args.plot)
        _check_image_format(args.plot)
    return run_demo(plot=args.plot, filters=args.filters.split(",") if args.filters else None)


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """A warning on the command line is one line, as an error is: ``fusionkit: warning: TEXT
    (Category)``, not Python's ``path/cli.py:117: Category: TEXT`` followed by the source line
    that called the filter."""
    text = " ".join(str(message).split())
    print(f"fusionkit: warning: {text} ({category.__name__})", file=sys.stderr if file is None else file)


def _check_image_format(path: str) -> None:
    """``path``'s extension is a format matplotlib writes (checked before the demo runs: 'x.txt'
    ended the demo's whole run in matplotlib's ValueError traceback). Without matplotlib the demo
    says the plot is skipped."""
    try:
        from matplotlib.backend_bases import FigureCanvasBase
    except ImportError:
        return
    kinds = FigureCanvasBase.get_supported_filetypes()
    suffix = Path(path).suffix.lower().lstrip(".")
    if suffix not in kinds:
        what = f"'.{suffix}' is not an image format matplotlib writes" if suffix else "it has no image extension"
        raise FusionkitError(f"cannot write the plot {path}: {what}; use one of {', '.join(sorted(kinds))} "
                             "(e.g. demo.png)")


def _sub(sub, name: str, help: str, example: str, units: str = ""):
    """A subcommand whose help ends with an example and the units of what it prints."""
    epilog = f"example:\n  {example}" + (f"\n\n{units}" if units else "")
    return sub.add_parser(name, help=help, description=help, epilog=epilog,
                          formatter_class=argparse.RawDescriptionHelpFormatter)


_ERRORS = ("errors are RMS over the reference's movement samples, in deg: inclination = the error's tilt part "
           "(every filter), total = the whole rotation (9D filters only), heading = the error's rotation about the "
           "vertical; a 6D or gyro-only filter gets n/a for heading and total (it cannot know north)")


def main(argv: list[str] | None = None) -> int:
    from . import __version__

    parser = argparse.ArgumentParser(
        prog="fusionkit", description="inertial attitude estimation, filters by name",
        epilog="example:\n  fusionkit demo\n  fusionkit run recommended sim:slow-rotation -o out.csv\n\n"
               "units: rad/s, m/s^2, s, deg in tables; quaternions w, x, y, z body -> earth (ENU default)",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=f"fusionkit {__version__}")
    sub = parser.add_subparsers(dest="cmd", required=True)
    _sub(sub, "list", "list registered plugins", "fusionkit list").set_defaults(func=cmd_list)
    d = _sub(sub, "describe", "parameters and source of a plugin", "fusionkit describe motion",
             "each parameter is printed with its default and unit in [brackets]")
    d.add_argument("name", help="a plugin's name (fusionkit list names them all)")
    d.add_argument("--kind", default=None, help="filter, estimator, corrector, detector or model")
    fmt = d.add_mutually_exclusive_group()
    fmt.add_argument("--toml", action="store_true", help="print a config to save, edit and pass to `fusionkit run` "
                     "(a preset's composition; a monolithic filter's parameters)")
    fmt.add_argument("--json", action="store_true", help="the same as JSON (which, unlike TOML, has null)")
    d.set_defaults(func=cmd_describe)
    r = _sub(sub, "run", "run a filter (by name or a TOML/JSON pipeline config) on a recording",
             "fusionkit run poisson trial.hdf5 -o out.csv --param step=exact\n"
             "  fusionkit run recommended imu.csv --rate 200 -o out.csv\n"
             "  fusionkit run recommended imu_deg_g.csv --gyr-unit deg/s --acc-unit g -o out.csv",
             "prints samples/s (samples per second of the run) and, with a reference, "
             + _ERRORS + ".\nThe CSV: t (s), qw..qz, yaw_<frame>_deg (ENU: body x from East counter-clockwise, "
             "so x to North is 90), pitch_deg, roll_deg, flags")
    r.add_argument("filter", help="filter name or a .toml/.json config")
    r.add_argument("input", help="a .hdf5 (BROAD) or .csv recording, or sim:NAME for a built-in one")
    r.add_argument("-o", "--output", required=True, help="output CSV (its folder must exist)")
    r.add_argument("--rate", type=float, default=None, help="sampling rate in Hz, for a CSV without a 't' column")
    r.add_argument("--gyr-unit", default=None, choices=list(GYR_UNITS),
                   help="the CSV's gyro unit, converted to rad/s (default: its '# gyr_unit=' line, else rad/s)")
    r.add_argument("--acc-unit", default=None, choices=list(ACC_UNITS),
                   help="the CSV's accelerometer unit, converted to m/s^2 (default: its '# acc_unit=' line, "
                   "else m/s^2)")
    r.add_argument("--param", action="append", default=[], metavar="NAME=VALUE", help="a filter parameter")
    r.add_argument("--backend", default="auto", choices=["auto", "numba", "reference"],
                   help="numba: the compiled loop, reference: the readable Python path (the same numbers to 1e-9), "
                        "auto: compiled where the filter can be (default)")
    r.add_argument("--progress", action="store_true", help="always show a progress bar")
    r.set_defaults(func=cmd_run)
    b = _sub(sub, "bench", "filters side by side on recordings, with the BROAD metrics",
             "fusionkit bench --data ../shared/data/broad --filters vqf,recommended --jobs 2 --plots plots/",
             _ERRORS + "; samples/s: median over trials, one core, compile excluded. Progress goes to stderr "
             "(a bar on a terminal, one line per run otherwise).")
    b.add_argument("--data", required=True, help="a folder (BROAD, GNSS scenarios, ULog, CSV) or a file")
    b.add_argument("--filters", required=True, help="comma-separated filter names")
    b.add_argument("--trials", default="", help="comma-separated trial names or prefixes (default: all)")
    b.add_argument("--param", action="append", default=[], metavar="NAME=VALUE",
                   help="a parameter for every filter that has it, or FILTER.NAME=VALUE for one")
    b.add_argument("--jobs", type=int, default=1, help="worker processes")
    b.add_argument("--scheduler", default=None, help="a Dask distributed scheduler address (instead of --jobs)")
    b.add_argument("--format", default="table", choices=["table", "json", "csv", "markdown"],
                   help="the tables' format (default: table)")
    b.add_argument("-o", "--output", default=None, help="write the table to this file")
    b.add_argument("--plots", default=None, help="folder for PNG plots")
    b.add_argument("--no-cache", action="store_true", help="ignore and do not write the result cache")
    b.set_defaults(func=cmd_bench)
    s = _sub(sub, "sweep", "a parameter grid for one filter: TAGP and per-trial minimum",
             "fusionkit sweep ahrs-madgwick --data ../shared/data/broad --grid gain=0.03,0.06,0.12 --jobs 2",
             "errors in deg (the --metric's RMSE over the movement samples; m and m/s for position and velocity); "
             "progress on stderr as for bench")
    s.add_argument("filter", help="the filter to sweep")
    s.add_argument("--data", required=True, help="a folder (BROAD, GNSS scenarios, ULog, CSV) or a file")
    s.add_argument("--grid", action="append", required=True, metavar="NAME=V1,V2,...",
                   help="a parameter and its values (repeat for a grid of several; nested with dots)")
    s.add_argument("--param", action="append", default=[], metavar="NAME=VALUE", help="a fixed parameter")
    s.add_argument("--trials", default="", help="comma-separated trial names or prefixes (default: all)")
    s.add_argument("--metric", default="score", help="score (9D: total, 6D: inclination), total, inclination, ...")
    s.add_argument("--jobs", type=int, default=1, help="worker processes")
    s.add_argument("--no-cache", action="store_true", help="ignore and do not write the result cache")
    s.add_argument("-o", "--output", default=None, help="write the report to this file")
    s.set_defaults(func=cmd_sweep)
    lg = _sub(sub, "lags", "how many samples the gyro, accelerometer and magnetometer run behind the "
              "reference orientation (fusionkit's convention: 0.5)", "fusionkit lags ../shared/data/broad sim:slow-rotation",
              "lags in samples and ms (+: the sensor is late); residuals: gyro rad/s, accelerometer m/s^2, "
              "magnetometer in the recording's unit")
    lg.add_argument("inputs", nargs="+", help="recording files, folders of trials, or sim:NAME")
    lg.add_argument("--max-lag", type=float, default=8.0, help="search range, samples")
    lg.add_argument("--cutoff", type=float, default=20.0, help="low-pass on both sides, Hz")
    lg.set_defaults(func=cmd_lags)
    m = _sub(sub, "demo", "every built-in filter side by side on simulated recordings", "fusionkit demo --plot demo.png",
             "inclination and heading RMSE in deg over the moving samples (heading: the error's rotation about the "
             "vertical, n/a for a gyro-only filter; for a 6D filter after removing the constant offset it cannot "
             "know); samples/s: wall time of one run, compile excluded")
    m.add_argument("--plot", default="fusionkit-demo.png", help="PNG to write ('' for none)")
    m.add_argument("--filters", default="", help="comma-separated filter names (default: all)")
    m.set_defaults(func=cmd_demo)
    args = parser.parse_args(argv)
    try:
        with warnings.catch_warnings():  # (restores showwarning: main() called from Python keeps its own)
            warnings.showwarning = _show_warning
            return args.func(args)
    except FusionkitError as exc:  # one line: a config's several problems joined with "; "
        first, *rest = [line.strip() for line in str(exc).splitlines() if line.strip()] or [type(exc).__name__]
        print(f"fusionkit: error: {first} {'; '.join(rest)}".rstrip(), file=sys.stderr)
        return 2
    except OSError as exc:  # a path given on the command line: missing folder, no permission, disk full
        print(f"fusionkit: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("fusionkit: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
