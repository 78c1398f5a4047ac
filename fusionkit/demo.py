"""``fusionkit demo``: every registered filter side by side on the package's simulated recordings.

No external data. Prints a table (inclination RMSE over the moving samples; heading RMSE, for a
6D or gyro-only filter after removing the constant heading offset it cannot know; throughput
and backend) and, with matplotlib, writes a plot of the inclination error over time. Peers
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


def evaluate(filter_names=None, recordings=None):
    """Run the filters on the recordings; return a list of row dicts and the per-sample errors."""
    reg = default_registry()
    names = filter_names or [n for n in reg.names("filter") if n != "pipeline"]
    recordings = recordings or demo_recordings()
    rows, curves = [], {}
    for name in names:
        try:
            f = reg.make(name, "filter")
            f.run(recordings[0].slice(0, 50))  # compile outside the timing
        except FusionkitError as exc:
            rows.append({"filter": name, "recording": "-", "error": str(exc).splitlines()[0]})
            continue
        for rec in recordings:
            t0 = time.perf_counter()
            res = f.run(rec)
            elapsed = time.perf_counter() - t0
            q_ref = change_frame(rec.truth, rec.truth_frame, res.frame)
            dim = f.dimension(rec)
            k0 = int(np.argmax(rec.movement))  # a 6D filter's heading offset, taken where the motion starts
            q = res.quat if dim == "9D" else _heading_aligned(res.quat, q_ref, k0)
            errs = broad_errors(q, q_ref)
            m = rec.movement
            rows.append({
                "filter": name, "recording": rec.name, "dimension": dim,
                "inclination_deg": float(np.sqrt(np.nanmean(errs["inclination"][m] ** 2))),
                "heading_deg": float(np.sqrt(np.nanmean(errs["heading"][m] ** 2))),
                "samples_per_s": len(rec) / elapsed, "backend": res.diagnostics.get("backend", "?"),
            })
            curves[(name, rec.name)] = (rec.time, errs["inclination"])
    return rows, curves


def format_table(rows) -> str:
    head = (f"{'filter':16s} {'recording':15s} {'dim':3s} {'incl. RMSE':>11s} {'heading RMSE':>13s} "
            f"{'samples/s':>12s}  backend")
    lines = [head, "-" * len(head)]
    for r in rows:
        if "error" in r:
            lines.append(f"{r['filter']:16s} skipped: {r['error']}")
            continue
        lines.append(f"{r['filter']:16s} {r['recording']:15s} {r['dimension']:3s} {r['inclination_deg']:9.3f} d "
                     f"{r['heading_deg']:11.3f} d {r['samples_per_s']:12,.0f}  {r['backend']}")
    return "\n".join(lines)


def plot_errors(curves, path) -> bool:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return False
    recs = sorted({r for _, r in curves})
    names = sorted({f for f, _ in curves})
    # one colour per filter, the same in every panel; tab10 repeats after ten filters
    cmap = plt.get_cmap("tab10" if len(names) <= 10 else "tab20")
    colour = {f: cmap(i % cmap.N) for i, f in enumerate(names)}
    fig, axes = plt.subplots(len(recs), 1, figsize=(11, 2.6 * len(recs)), sharex=False, squeeze=False)
    for ax, rec in zip(axes[:, 0], recs):
        for (f, r), (t, e) in sorted(curves.items()):
            if r == rec:
                ax.plot(t, e, label=f, lw=1, color=colour[f])
        ax.set_title(rec)
        ax.set_ylabel("inclination error [deg]")
        ax.set_yscale("symlog", linthresh=0.1)  # small errors of good filters and large ones of poor ones
        ax.grid(alpha=0.3)
    axes[-1, 0].set_xlabel("time [s]")
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="center left", bbox_to_anchor=(0.83, 0.5), fontsize=8)  # one legend, outside
    fig.tight_layout(rect=(0, 0, 0.82, 1))
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return True


def run_demo(plot: str | None = "fusionkit-demo.png", filters=None) -> int:
    """Print the side-by-side table; write the error plot to ``plot`` (None or '' for none)."""
    rows, curves = evaluate(filters)
    print("fusionkit demo: every registered filter on simulated MEMS recordings (200 Hz, noise and gyro bias)")
    print(format_table(rows))
    if plot:
        if plot_errors(curves, plot):
            print(f"plot: {plot}")
        else:
            print("plot skipped: install matplotlib (pip install 'fusionkit[plot]')")
    return 0
