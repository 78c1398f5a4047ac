"""``fusionkit demo``: every registered filter side by side on the package's simulated recordings.

No external data. Prints a table (inclination RMSE over the moving samples; heading RMSE, for a
6D filter after removing the constant heading offset it cannot know, none for a gyro-only one;
throughput and backend) and, with matplotlib, writes a plot with one panel per metric. Peers
(``fusionkit[peers]``) are registered filters too, so they appear when installed.
"""

from __future__ import annotations

import time

import numpy as np

from .benchmarking.metrics import broad_errors
from .conventions import change_frame
from .errors import FusionkitError
from .registry import default_registry
from .rotations import quat_conj, quat_from_axis_angle, quat_mul
from .sim import demo_recordings


def _heading_aligned(q_est, q_ref, k0):
    """Rotate ``q_est`` about the vertical so that it matches ``q_ref`` in heading at sample ``k0``."""
    err = quat_mul(q_est[k0], quat_conj(q_ref[k0]))  # earth-frame error; its z part is the heading offset
    ang = 2.0 * np.arctan2(err[3], err[0])
    return quat_mul(quat_from_axis_angle([0.0, 0.0, 1.0], -ang), q_est)


def evaluate(filter_names=None, recordings=None, progress: bool | None = True):
    """Run the filters on the recordings; return a list of row dicts and the per-sample errors
    ``{(filter, recording): (time, {"inclination": ..., "heading": ...})}`` (heading ``None`` for a
    gyro-only filter). Progress on stderr (a bar on a terminal, else a line per run)."""
    from .benchmarking.report import aiding
    from .benchmarking.runner import Progress

    reg = default_registry()
    for name in filter_names or ():  # names the user gave: a typo is an error, not a skipped row
        reg.get(name, "filter")
    names = filter_names or [n for n in reg.names("filter") if n != "pipeline"]
    recordings = recordings or demo_recordings()
    rows, curves = [], {}
    bar = Progress(len(names) * len(recordings), "demo") if progress is not False else None
    for name in names:
        try:
            f = reg.make(name, "filter")
            f.run(recordings[0].slice(0, 50))  # compile outside the timing
        except FusionkitError as exc:
            rows.append({"filter": name, "recording": "-", "error": str(exc).splitlines()[0]})
            for _ in recordings:
                bar is not None and bar.update(name, "skipped")
            continue
        for rec in recordings:
            t0 = time.perf_counter()
            res = f.run(rec)
            elapsed = time.perf_counter() - t0
            q_ref = change_frame(rec.truth, rec.truth_frame, res.frame)
            dim, kind = f.dimension(rec), aiding(f, rec)
            k0 = int(np.argmax(rec.movement))  # a 6D filter's heading offset, taken where the motion starts
            q = res.quat if dim == "9D" else _heading_aligned(res.quat, q_ref, k0)
            errs = broad_errors(q, q_ref)
            m = rec.movement
            heading = None if kind == "gyro-only" else errs["heading"]  # an integrator's heading is its start's
            rows.append({
                "filter": name, "recording": rec.name, "dimension": kind,
                "inclination_deg": float(np.sqrt(np.nanmean(errs["inclination"][m] ** 2))),
                "heading_deg": float("nan") if heading is None else float(np.sqrt(np.nanmean(heading[m] ** 2))),
                "samples_per_s": len(rec) / elapsed, "backend": res.diagnostics.get("backend", "?"),
            })
            curves[(name, rec.name)] = (rec.time, {"inclination": errs["inclination"], "heading": heading})
            if bar is not None:
                bar.update(f"{name} on {rec.name}")
    if bar is not None:
        bar.close()
    return rows, curves


def format_table(rows) -> str:
    head = (f"{'filter':16s} {'recording':15s} {'aiding':9s} {'incl. RMSE':>11s} {'heading RMSE':>13s} "
            f"{'samples/s':>12s}  backend")
    lines = [head, "-" * len(head)]
    for r in rows:
        if "error" in r:
            lines.append(f"{r['filter']:16s} skipped: {r['error']}")
            continue
        heading = "n/a" if np.isnan(r["heading_deg"]) else f"{r['heading_deg']:.3f} d"
        lines.append(f"{r['filter']:16s} {r['recording']:15s} {r['dimension']:9s} {r['inclination_deg']:9.3f} d "
                     f"{heading:>13s} {r['samples_per_s']:12,.0f}  {r['backend']}")
    lines += ["", "RMSE over the moving samples, deg (d). inclination: the error's tilt part. heading: the error's "
              "rotation about the vertical (not the ENU yaw angle); a 6D filter's after removing the constant "
              "offset at the motion's start it cannot know; n/a for a gyro-only filter (its heading is its start's). "
              "samples/s: one run's wall time, compile excluded."]
    return "\n".join(lines)


def plot_errors(curves, path, rows=None) -> list[str] | bool:
    """One panel per metric in the table's order: inclination and heading error over time on
    one recording (fusionkit's filters and the peers side by side, so each panel has few lines;
    1 s moving RMS), then samples/s coloured by library. Returns the panels' titles (False
    without matplotlib)."""
    try:
        from .benchmarking.plots import _figure, filter_styles, throughput_bars
    except ImportError:  # pragma: no cover
        return False
    try:
        fig = _figure(figsize=(13, 11))
    except FusionkitError:
        return False
    recs = list(dict.fromkeys(r for _, r in curves))
    rec = "translation" if "translation" in recs else recs[0]  # the hardest one: accelerations
    names = list(dict.fromkeys(f for f, r in curves if r == rec))
    backend = {r["filter"]: r["backend"] for r in rows or [] if "error" not in r}
    groups = {"fusionkit": [n for n in names if not str(backend.get(n, "")).startswith("peer")],
              "peers": [n for n in names if str(backend.get(n, "")).startswith("peer")]}
    groups = {g: ns for g, ns in groups.items() if ns}
    style = filter_styles(names)
    grid = fig.add_gridspec(3, len(groups), height_ratios=[1, 1, 1.1])
    for row, (metric, label) in enumerate((("inclination", "inclination error"), ("heading", "heading error"))):
        for col, (group, ns) in enumerate(groups.items()):
            ax = fig.add_subplot(grid[row, col])
            for n in ns:
                t, errs = curves[(n, rec)]
                if errs[metric] is None:
                    continue
                ax.plot(t, _moving_rms(errs[metric], t), lw=1.2, label=n, **style[n])
            ax.set_title(f"{label}, {group} ({rec})", fontsize=10)
            ax.set_ylabel(f"{label} [deg], 1 s RMS")
            ax.set_yscale("log")  # good filters' tenths and poor ones' degrees on one axis
            ax.set_ylim(bottom=0.01)  # below 0.01 deg is noise (a 6D filter's heading is zero by its alignment)
            ax.grid(alpha=0.3, which="both")
            if row == 1:
                ax.set_xlabel("time [s]")
            if row == 0:
                ax.legend(fontsize=8, ncol=2, loc="upper left")
    if rows:
        ax = fig.add_subplot(grid[2, :])
        sps = {}
        for r in rows:
            if "error" not in r:
                sps.setdefault(r["filter"], []).append(r["samples_per_s"])
        order = sorted(sps, key=lambda n: -np.median(sps[n]))
        throughput_bars(ax, order, [float(np.median(sps[n])) for n in order], [backend[n] for n in order])
        ax.set_title("samples/s (median over the recordings; one core, compile excluded)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    return [ax.get_title() for ax in fig.axes]


def _moving_rms(e, t, window: float = 1.0):
    """RMS over a centred window of ``window`` seconds (NaN-aware)."""
    n = max(1, int(round(window / max(float(np.median(np.diff(t))), 1e-9))))
    v = np.where(np.isfinite(e), e, 0.0) ** 2
    k = np.ones(n)
    num = np.convolve(v, k, "same")
    den = np.convolve(np.isfinite(e).astype(float), k, "same")
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.sqrt(num / den)


def run_demo(plot: str | None = "fusionkit-demo.png", filters=None) -> int:
    """Print the side-by-side table; write the error plot to ``plot`` (None or '' for none)."""
    rows, curves = evaluate(filters)
    n = len({r["filter"] for r in rows})
    which = "every registered filter" if not filters else f"{n} filter{'s' if n != 1 else ''} (--filters)"
    print(f"fusionkit demo: {which} on simulated MEMS recordings (200 Hz, noise and gyro bias)")
    print(format_table(rows))
    if plot:
        if plot_errors(curves, plot, rows):
            print(f"plot: {plot}")
        else:
            print("plot skipped: install matplotlib (pip install 'fusionkit[plot]')")
    return 0
