"""Plots for benchmark results (matplotlib, PNG; ``pip install "fusionkit[plot]"``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import ConfigError

__all__ = ["plot_error_over_time", "plot_by_group", "plot_throughput", "write_plots", "filter_styles",
           "throughput_bars", "library"]

# distinct hues: matplotlib's tab10, then Dark2's darker ones (no two neighbours alike)
_COLOURS = ["#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22",
            "#17becf", "#1b9e77", "#d95f02", "#7570b3", "#e7298a", "#66a61e", "#000000"]
_DASHES = ["-", "--", ":", "-."]
#: one colour per library in throughput charts
LIBRARY_COLOURS = {"fusionkit": "#1f77b4", "fusionkit (Python reference)": "#aec7e8", "vqf": "#d62728",
                   "imufusion": "#2ca02c", "ahrs": "#ff7f0e"}


def require_matplotlib() -> None:
    """A ConfigError saying how to install matplotlib when it is missing: called by what draws,
    and by ``fusionkit bench --plots`` before the benchmark runs (it failed after the whole run)."""
    try:
        import matplotlib  # noqa: F401
    except ImportError as exc:
        raise ConfigError("plots need matplotlib: pip install 'fusionkit[plot]'") from exc


def _figure(**kwargs):
    """A new ``matplotlib.figure.Figure``, drawn and saved without pyplot: the user's backend (a
    notebook's inline or a GUI one) stays as it was (``matplotlib.use("Agg")`` switched it for
    the whole session), no window opens, and nothing is left in pyplot's figure list to close.
    ``Figure.savefig`` picks the canvas for the file's format itself, so it works headless."""
    require_matplotlib()
    from matplotlib.figure import Figure

    return Figure(**kwargs)


def filter_styles(names) -> dict[str, dict]:
    """``{name: {"color": ..., "linestyle": ...}}``: every filter its own hue, and look-alike names
    (one family before the first '-': gst / gst-gnss, vqf / vqf-basic / vqf-offline) also their
    own line style, so a legend entry is found in the plot."""
    out, family = {}, {}
    for i, n in enumerate(dict.fromkeys(names)):
        base = n.split("[")[0].split("-")[0]
        k = family[base] = family.get(base, -1) + 1
        out[n] = {"color": _COLOURS[i % len(_COLOURS)], "linestyle": _DASHES[k % len(_DASHES)]}
    return out


def library(backend: str | None) -> str:
    """The library that computed a run, from its ``backend`` ("numba", "reference",
    "peer:vqf 2.1.2", ...)."""
    b = str(backend or "")
    if b.startswith("peer:"):
        return b[5:].split()[0]
    return "fusionkit (Python reference)" if b == "reference" else "fusionkit"


def throughput_bars(ax, names, values, backends) -> None:
    """Horizontal bars of samples/s, coloured by library, on a linear axis with each value written
    (a log axis hides that a factor of two is a factor of two)."""
    libs = [library(b) for b in backends]
    colours = [LIBRARY_COLOURS.get(lib, "#7f7f7f") for lib in libs]
    y = np.arange(len(names))
    ax.barh(y, values, color=colours)
    ax.set_yticks(y)
    ax.set_yticklabels(names, fontsize=8)
    ax.invert_yaxis()
    top = max([v for v in values if np.isfinite(v)] or [1.0])
    for yi, v in zip(y, values):
        if np.isfinite(v):
            ax.text(v + 0.01 * top, yi, f"{v:,.0f}", va="center", fontsize=7)
    ax.set_xlim(0, 1.18 * top)
    ax.xaxis.set_major_formatter(lambda v, _: f"{v / 1e6:g} M" if top >= 1e6 else f"{v:,.0f}")
    ax.set_xlabel("samples/s")
    ax.grid(axis="x", alpha=0.3)
    from matplotlib.patches import Patch

    seen = list(dict.fromkeys(libs))
    ax.legend([Patch(color=LIBRARY_COLOURS.get(lib, "#7f7f7f")) for lib in seen], seen, fontsize=8,
              loc="lower right", title="library", title_fontsize=8)


def plot_error_over_time(filters, trial, path, max_points: int = 4000) -> Path:
    """Error over time on one trial for several filters: inclination (every filter) and total
    (9D filters only: a 6D filter's total is its unknown heading) in two panels."""
    from .metrics import truth_errors
    from .report import aiding, not_applicable
    from .runner import FilterSpec

    fig = _figure(figsize=(10, 7))
    rec = trial.load()
    axes = fig.subplots(2, 1, sharex=True)
    t = rec.time
    step = max(1, len(t) // max_points)
    specs = [FilterSpec.of(item) for item in filters]
    style = filter_styles([s.label for s in specs])
    for spec in specs:
        f = spec.build()
        res = f.run(rec, progress=False)
        e = truth_errors(res.quat, res.frame, rec)
        for ax, m in zip(axes, ("inclination", "total")):
            if m not in not_applicable(aiding(f, rec), gnss_heading=bool(f.requires_gnss), rec=rec):
                ax.plot(t[::step], e[m][::step], lw=1, label=spec.label, **style[spec.label])
    for ax, title in zip(axes, ("inclination error (the tilt part), every filter",
                                "total error (the whole rotation), 9D filters only")):
        if rec.movement is not None:
            m = rec.movement.astype(float)
            ax.fill_between(t[::step], 0, 1, where=m[::step] > 0, transform=ax.get_xaxis_transform(), color="0.92",
                            label="movement (evaluated)")
        ax.set_ylabel("error [deg]")
        ax.set_title(f"{trial.name}: {title}", fontsize=10)
        ax.grid(alpha=0.3)
        if ax.lines:
            ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
        else:  # e.g. only 6D or gyro-only filters: none has a total error
            ax.text(0.5, 0.5, "no filter in this run has this error", transform=ax.transAxes, ha="center")
    axes[-1].set_xlabel("time [s]")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    return Path(path)


def plot_by_group(result, path, metric: str | None = None) -> Path:
    """Bar charts of the mean error per group, one bar per filter: one panel per metric in the
    table's order (inclination for every filter, total for the 9D ones), never mixed. A linear
    axis from 0 with each value written on its bar, as the throughput chart: on a log axis with
    an automatic lower limit 1.17 deg looked ten times smaller than 1.74 deg."""
    from .report import metric_label, metric_unit

    metrics = result.metrics() if metric is None else [metric]
    groups = list(dict.fromkeys(g for r in result.records for g in (r["groups"] or ["all"])))
    style = filter_styles(result.filters)
    x = np.arange(len(groups))
    fig = _figure(figsize=(max(8, len(groups) * 0.9) + 3, 4.2 * len(metrics)))
    axes = fig.subplots(len(metrics), 1, squeeze=False)
    for ax, m in zip(axes[:, 0], metrics):
        bg, na = result.by_group(m), result.not_applicable(m)
        filters = [f for f in result.filters if f not in na]
        w = 0.8 / max(1, len(filters))
        upright = len(filters) * len(groups) > 12  # narrow bars: the values written upwards
        top = 0.0
        for i, f in enumerate(filters):
            values = [bg.get(f, {}).get(g, np.nan) for g in groups]
            bars = ax.bar(x + i * w, values, w, label=f, color=style[f]["color"])
            ax.bar_label(bars, labels=[f"{v:.2f}" if np.isfinite(v) else "" for v in values], fontsize=7,
                         padding=2, rotation=90 if upright else 0)
            top = max([top] + [v for v in values if np.isfinite(v)])
        ax.set_ylim(0, (1.3 if upright else 1.15) * top if top > 0 else 1.0)
        ax.set_xticks(x + 0.4 - w / 2)
        ax.set_xticklabels(groups, rotation=35, ha="right")
        ax.set_title(metric_label(m), fontsize=10)
        ax.set_ylabel(f"RMSE [{metric_unit(m)}]")
        ax.grid(axis="y", alpha=0.3)
        ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    return Path(path)


def plot_throughput(result, path) -> Path:
    """Median samples/s per filter, coloured by library, linear axis with the values written."""
    rows = result.summary()
    backend = {}
    for r in result.records:
        backend.setdefault(r["filter"], r["backend"])
    rows = sorted((r for r in rows if np.isfinite(r["samples_per_s"])), key=lambda r: -r["samples_per_s"])
    fig = _figure(figsize=(10, 0.4 * len(rows) + 1.5))
    ax = fig.subplots()
    throughput_bars(ax, [r["filter"] for r in rows], [r["samples_per_s"] for r in rows],
                    [backend.get(r["filter"]) for r in rows])
    ax.set_title("samples/s (median over trials, one core, compile excluded)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    return Path(path)


def write_plots(result, folder, trial=None) -> list[Path]:
    """The three plots into ``folder``: by group, throughput, and error over time on ``trial``
    (default: the first trial with a reference)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    out = [plot_by_group(result, folder / "by_group.png"), plot_throughput(result, folder / "throughput.png")]
    if trial is not None:
        specs = list(dict.fromkeys((r["name"], tuple(sorted(r["params"].items()))) for r in result.records))
        out.append(plot_error_over_time([(n, dict(p)) for n, p in specs], trial, folder / f"error_{trial.name}.png"))
    return out
