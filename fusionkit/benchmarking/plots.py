"""Plots for benchmark results (matplotlib, PNG; ``pip install "fusionkit[plot]"``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import ConfigError

__all__ = ["plot_error_over_time", "plot_by_group", "plot_throughput", "write_plots"]


def _plt():
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError as exc:
        raise ConfigError("plots need matplotlib: pip install 'fusionkit[plot]'") from exc
    return plt


def plot_error_over_time(filters, trial, path, max_points: int = 4000) -> Path:
    """Error over time on one trial for several filters (each judged by its own dimension)."""
    from .metrics import broad_errors
    from .runner import FilterSpec
    from ..conventions import change_frame

    plt = _plt()
    rec = trial.load()
    fig, ax = plt.subplots(figsize=(10, 4))
    t = rec.time
    step = max(1, len(t) // max_points)
    for item in filters:
        spec = FilterSpec.of(item)
        f = spec.build()
        res = f.run(rec, progress=False)
        dim = f.dimension(rec)
        e = broad_errors(res.quat, change_frame(rec.truth, rec.truth_frame, res.frame))
        ax.plot(t[::step], e["total" if dim == "9D" else "inclination"][::step], lw=1,
                label=f"{spec.label} ({'total' if dim == '9D' else 'inclination'})")
    if rec.movement is not None:
        m = rec.movement.astype(float)
        ax.fill_between(t[::step], 0, 1, where=m[::step] > 0, transform=ax.get_xaxis_transform(), color="0.9",
                        label="movement (evaluated)")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("error [deg]")
    ax.set_title(trial.name)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="upper left")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)


def plot_by_group(result, path, metric: str = "score") -> Path:
    """Bar chart: mean error per group, one bar per filter."""
    plt = _plt()
    bg = result.by_group(metric)
    filters = result.filters
    groups = list(dict.fromkeys(g for r in result.records for g in (r["groups"] or ["all"])))
    x = np.arange(len(groups))
    w = 0.8 / max(1, len(filters))
    fig, ax = plt.subplots(figsize=(max(8, len(groups) * 0.9) + 2.5, 4.5))
    # one colour per filter: tab10 repeats after ten, tab20 (pairs of shades) after twenty
    cmap = plt.get_cmap("tab10" if len(filters) <= 10 else "tab20")
    for i, f in enumerate(filters):
        ax.bar(x + i * w, [bg.get(f, {}).get(g, np.nan) for g in groups], w, label=f, color=cmap(i % cmap.N))
    ax.set_xticks(x + 0.4 - w / 2)
    ax.set_xticklabels(groups, rotation=35, ha="right")
    ax.set_ylabel("RMSE [deg] (9D: total, 6D: inclination)")
    ax.set_yscale("log")  # errors span two decades; a linear axis hides the differences among good filters
    ax.grid(axis="y", which="both", alpha=0.3)
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)


def plot_throughput(result, path) -> Path:
    """Median samples/s per filter (log scale)."""
    plt = _plt()
    rows = result.summary()
    fig, ax = plt.subplots(figsize=(8, 0.5 * len(rows) + 1.5))
    ax.barh([r["filter"] for r in rows], [r["samples_per_s"] for r in rows], color="tab:green")
    ax.set_xscale("log")
    ax.set_xlabel("samples/s (median over trials, one core)")
    ax.invert_yaxis()
    ax.grid(axis="x", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
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
