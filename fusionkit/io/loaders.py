"""Read recordings: BROAD ``.hdf5`` trials and a documented CSV layout.

CSV layout (comma separated, one header line, ``#`` comment lines allowed before it):

=================  ==========================================================
column             meaning
=================  ==========================================================
``t``              time in s (optional if ``rate=`` is given to :func:`load`)
``gyr_x..gyr_z``   angular rate, rad/s (or the ``gyr_unit``)
``acc_x..acc_z``   specific force, m/s^2 (or the ``acc_unit``)
``mag_x..mag_z``   magnetic field, any unit (optional)
``qw,qx,qy,qz``    reference orientation body->ENU (optional)
=================  ==========================================================

A comment line ``# rate=285.7`` gives the rate when there is no ``t`` column, ``# body=FRD``
the sensors' body axes (``Recording.body``; without it they are not known), ``# gyr_unit=deg/s`` and
``# acc_unit=g`` the units of the columns (:class:`~fusionkit.types.Recording`'s ``gyr_unit`` and
``acc_unit``: deg/s, mrad/s, mdeg/s; g, mg), converted on loading. With a ``t`` column a
rate (``rate=`` or the comment) must match its typical interval within 1 %, and ``t`` is the clock.
A magnetometer or a reference is all its columns or none. Arguments of :func:`load` (``rate=``,
``body=``, ``gyr_unit=``, ``acc_unit=``; ``fusionkit run``'s ``--rate``, ``--gyr-unit``,
``--acc-unit``) override the comments.
"""

from __future__ import annotations

import os
import warnings
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..types import Recording
from ..validation import check_positive
from ._guard import file_errors

__all__ = ["load", "load_broad", "load_csv", "write_csv"]

_VEC = {k: [f"{k}_{a}" for a in "xyz"] for k in ("gyr", "acc", "mag")}
_QUAT = ["qw", "qx", "qy", "qz"]


def check_path(path) -> Path:
    """``path`` as a :class:`~pathlib.Path` when it is a file of a kind :func:`load` reads, else
    the :class:`InputError` that :func:`load` gives, before anything is read (a command checks
    its inputs before it prints a table's header). Anything but a str or a path is an InputError
    naming the argument (``load(42)`` was pathlib's TypeError)."""
    if not isinstance(path, (str, os.PathLike)):
        raise InputError(f"path must be a file name (str or pathlib.Path) or 'sim:NAME', got {type(path).__name__} "
                         f"{path!r:.60}")
    p = Path(path)
    if not p.exists():
        raise InputError(f"no such file: {str(p)!r}")
    if p.is_dir():  # (it was "cannot read 'broad': supported are .hdf5/.h5 ...")
        raise InputError(f"{str(p)!r} is a folder: give one recording file (fusionkit bench --data takes a folder "
                         "of trials)")
    if p.suffix.lower() not in (".hdf5", ".h5", ".csv", ".ulg"):
        raise InputError(f"cannot read {p.name!r}: supported are .hdf5/.h5 (BROAD, GNSS scenario), .ulg (PX4) and "
                         ".csv")
    return p


def load(path, **kwargs) -> Recording:
    """Read a recording: a BROAD trial or GNSS scenario (``.hdf5``/``.h5``), a PX4 log (``.ulg``),
    ``.csv`` (see module doc; ``rate``, ``body``, ``gyr_unit``, ``acc_unit`` as for
    :func:`load_csv`), or ``sim:NAME``, a built-in simulated recording (as every ``fusionkit``
    command reads it: a scenario of :data:`fusionkit.sim.SCENARIOS` or a demo recording)."""
    if isinstance(path, str) and path.startswith("sim:"):
        from ..sim import load_sim

        given = sorted(k for k, v in kwargs.items() if v is not None)
        if given:
            raise InputError(f"{path}: {', '.join(f'{k}=' for k in given)} "
                             f"{'applies' if len(given) == 1 else 'apply'} to a .csv file only; a simulated recording "
                             "carries its own clock, body axes and units")
        return load_sim(path[4:])
    p = check_path(path)
    suffix = p.suffix.lower()
    given = sorted(k for k, v in kwargs.items() if v is not None)  # (None: not given, as a caller passes it on)
    if given and suffix != ".csv":  # (a .ulg or GNSS scenario ignored them, a BROAD trial failed to "read")
        raise InputError(f"{p.name}: {', '.join(f'{k}=' for k in given)} "
                         f"{'applies' if len(given) == 1 else 'apply'} to a .csv file only; this file carries its "
                         "own clock, body axes and units")
    if suffix != ".csv":
        kwargs = {}
    if suffix in (".hdf5", ".h5"):
        from .gnss import is_gnss_scenario, load_gnss_scenario

        return load_gnss_scenario(p) if is_gnss_scenario(p) else load_broad(p, **kwargs)
    if suffix == ".csv":
        return load_csv(p, **kwargs)
    from .ulog import load_ulog  # (.ulg: check_path left no other suffix)

    return load_ulog(p)


@file_errors("HDF5")
def load_broad(path) -> Recording:
    """One BROAD trial: gyr, acc, mag, ``opt_quat`` as truth (body->ENU) and the ``movement`` mask;
    ``opt_pos`` (m, ENU, NaN where the markers were lost) as ``meta["ref_pos"]``."""
    try:
        import h5py
    except ImportError as exc:  # pragma: no cover
        raise InputError("reading .hdf5 needs h5py (pip install h5py)") from exc
    p = Path(path)
    with h5py.File(p, "r") as f:
        missing = [k for k in ("imu_gyr", "imu_acc", "sampling_rate") if k not in f and k not in f.attrs]
        if missing:
            raise InputError(f"{p.name}: not a BROAD trial, missing {missing}")
        rate = float(np.asarray(f.attrs["sampling_rate"]).reshape(-1)[0])
        return Recording(
            gyr=f["imu_gyr"][:], acc=f["imu_acc"][:], mag=f["imu_mag"][:] if "imu_mag" in f else None,
            rate=rate, truth=f["opt_quat"][:] if "opt_quat" in f else None, truth_frame="ENU",
            movement=f["movement"][:] if "movement" in f else None, name=p.stem,
            meta={"path": str(p), "dataset": "BROAD", **({"ref_pos": f["opt_pos"][:]} if "opt_pos" in f else {})},
            body=None,  # the README names no vehicle axes (a hand-held IMU): not known
        )


@file_errors("CSV")
def load_csv(path, rate: float | None = None, body: str | None = None, gyr_unit: str | None = None,
             acc_unit: str | None = None) -> Recording:
    """A CSV file in the layout of the module doc; ``rate``, ``body``, ``gyr_unit`` and ``acc_unit``
    override the comments (a rate with a ``t`` column only confirms it: an InputError where they
    disagree). A unit mistake the Recording refuses says how to give the unit for a CSV."""
    p = Path(path)
    header, comment_rate, comment_body, skip = None, None, None, 0
    units = {"gyr_unit": None, "acc_unit": None}  # from '# gyr_unit=deg/s' / '# acc_unit=g' lines
    with open(p, encoding="utf-8-sig") as fh:  # a byte-order mark is not part of the first name
        for line in fh:
            skip += 1
            s = line.strip()
            if s.startswith("#"):
                text = s.lstrip("#").strip()
                if text.startswith("rate="):
                    try:
                        comment_rate = float(text.split("=", 1)[1])
                    except ValueError:
                        raise InputError(f"{p.name}: line {skip}: {s!r} is not a rate in Hz") from None
                elif text.startswith("body="):
                    comment_body = text.split("=", 1)[1].strip()
                elif "=" in text and (key := text.partition("=")[0].strip()) in units:
                    units[key] = text.partition("=")[2].strip()
                continue
            header = [c.strip() for c in s.split(",")]
            break
    if header is None:
        raise InputError(f"{p.name}: empty CSV file")
    twice = sorted({c for c in header if header.count(c) > 1})
    if twice:
        raise InputError(f"{p.name}: column(s) {twice} appear more than once in the header")
    for k in ("gyr", "acc"):
        if not all(c in header for c in _VEC[k]):
            raise InputError(f"{p.name}: missing columns {_VEC[k]} (header is {header})")
    for names in (_VEC["mag"], _QUAT):  # optional, but a sensor or a quaternion is all its columns or none
        have = [c for c in names if c in header]
        if have and len(have) < len(names):
            raise InputError(f"{p.name}: columns {have} without {[c for c in names if c not in have]}: give all "
                             f"of {names} or none (header is {header})")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # numpy's "input contained no data": reported below
        try:
            data = np.loadtxt(p, delimiter=",", skiprows=skip, ndmin=2, encoding="utf-8-sig")
        except ValueError:
            raise InputError(f"{p.name}: {_bad_row(p, skip, len(header))}") from None
    if data.size == 0:
        raise InputError(f"{p.name}: no data rows after the header (line {skip})")
    if data.shape[1] != len(header):
        raise InputError(f"{p.name}: {data.shape[1]} columns of data but {len(header)} names in the header")
    col = {c: i for i, c in enumerate(header)}

    def pick(names):
        return data[:, [col[c] for c in names]]

    t = data[:, col["t"]] if "t" in col else None
    given = "the rate argument" if rate is not None else "its '# rate=' line"
    rate = rate if rate is not None else comment_rate
    if t is None and rate is None:
        raise InputError(f"{p.name}: no 't' column and no rate: add a '# rate=...' line (Hz) before the header, "
                         "or give the rate: load(..., rate=...) in Python, --rate on the command line")
    if t is not None and rate is not None:
        _check_rate_against_t(p.name, given, check_positive("rate", rate), t)
        rate = None  # the 't' column is the clock (its gaps included); the rate only confirmed it
    gyr_unit = gyr_unit if gyr_unit is not None else units["gyr_unit"]
    acc_unit = acc_unit if acc_unit is not None else units["acc_unit"]
    try:
        return Recording(
            gyr=pick(_VEC["gyr"]), acc=pick(_VEC["acc"]),
            mag=pick(_VEC["mag"]) if all(c in col for c in _VEC["mag"]) else None,
            t=t, rate=rate,
            truth=pick(_QUAT) if all(c in col for c in _QUAT) else None,
            name=p.stem, meta={"path": str(p)}, body=body if body is not None else comment_body,
            gyr_unit=gyr_unit, acc_unit=acc_unit or "m/s^2",  # (None: rad/s, range-checked)
        )
    except InputError as exc:  # "pass gyr_unit='deg/s'": how a CSV's reader takes it
        named = [k for k in units if f"{k}=" in str(exc) or f"{k} " in str(exc)]
        if not named:
            raise
        how = "; ".join(f"a '# {k}=UNIT' line before the header, load(..., {k}='UNIT') in Python, or "
                        f"--{k.replace('_', '-')} UNIT on the command line" for k in named)
        raise InputError(f"{p.name}: {exc} (for a CSV: {how})") from None


def _check_rate_against_t(name: str, given: str, rate: float, t: np.ndarray) -> None:
    """A rate given with a 't' column must describe it: its typical (median) interval within 1 %
    of ``1 / rate``. The rate is meant for a file without timestamps; one that contradicts them
    (a '# rate=' line from another export, ``--rate`` typed for a different file) once replaced
    them silently, every sample's interval wrong by their ratio."""
    d = np.diff(t)
    d = d[np.isfinite(d)]
    if d.size == 0:  # one sample (or no finite interval): nothing to compare; Recording checks t
        return
    typical = float(np.median(d))
    if typical <= 0.0:  # (it said "typical interval 0 s, inf Hz": the column repeats, review rev27b)
        raise InputError(f"{name}: the 't' column repeats its values ({int(np.count_nonzero(d == 0.0))} of its "
                         f"{d.size} intervals are 0, e.g. timestamps rounded coarser than the {rate:g} Hz rate "
                         f"({given}) samples): give t at a finer resolution, or leave the 't' column out and give "
                         "the rate alone")
    if not abs(typical * rate - 1.0) <= 0.01:
        raise InputError(f"{name}: the rate {rate:g} Hz ({given}) contradicts the 't' column (typical interval "
                         f"{typical:.6g} s, {1.0 / typical:.6g} Hz): give one "
                         "clock, the 't' column or a rate for a file without it")


def _bad_row(p: Path, skip: int, width: int) -> str:
    """Where a CSV's data stop being ``width`` numbers per line: the line, the column, the text."""
    with open(p, encoding="utf-8-sig") as fh:
        for number, line in enumerate(fh, 1):
            if number <= skip or not line.strip() or line.lstrip().startswith("#"):
                continue
            cells = line.strip().split(",")
            if len(cells) != width:
                return f"line {number} has {len(cells)} values, the header {width} names"
            for j, cell in enumerate(cells):
                try:
                    float(cell)
                except ValueError:
                    return f"line {number}, column {j + 1}: {cell.strip()!r} is not a number"
    return "a value that numpy cannot read as a number"


def write_csv(rec: Recording, path) -> None:
    """Write a recording in the CSV layout :func:`load_csv` reads."""
    cols, names = [rec.time[:, None]], ["t"]
    for k in ("gyr", "acc", "mag"):
        v = getattr(rec, k)
        if v is not None:
            cols.append(v)
            names += _VEC[k]
    if rec.truth is not None:
        from ..conventions import change_frame

        cols.append(change_frame(rec.truth, rec.truth_frame, "ENU"))
        names += _QUAT
    header = ("" if rec.body is None else f"# body={rec.body}\n") + ",".join(names)
    # the time to the last bit: at 10 digits an epoch time (1.7e9 s) kept whole seconds, and load_csv then
    # refused the file ("t must be strictly increasing"); the samples to 10 digits
    fmt = ["%.17g"] + ["%.10g"] * (sum(c.shape[1] for c in cols) - 1)
    np.savetxt(path, np.hstack(cols), delimiter=",", header=header, comments="", fmt=fmt)
