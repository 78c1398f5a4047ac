"""GNSS per IMU sample: the latest epoch at each sample, as the rows GNSS-aided plugins take.

A low-level helper (only types, conventions and errors below it) shared by the GNSS-gap detector,
the pipeline, the detector runner and GNSS-aided filters, so none of them has to import another.
"""

from __future__ import annotations

import numpy as np

from .errors import InputError
from .types import Recording

__all__ = ["NO_GNSS", "gnss_per_sample", "gnss_sample_rows"]


def gnss_per_sample(rec: Recording) -> dict[str, np.ndarray]:
    """The latest GNSS epoch at each IMU sample: ``vel`` (N, 3, in the stream's frame, NaN
    before the first epoch), ``valid`` (N,), ``age`` (N, s), ``new`` (N,: an epoch arrived
    with this sample), ``index`` (N,, -1 before the first epoch), ``t`` (N,, the epoch's time)."""
    g = rec.gnss
    if g is None:
        raise InputError(f"recording {rec.name!r} has no GNSS stream")
    t = rec.time
    idx = np.searchsorted(g.t, t, side="right") - 1
    has = idx >= 0
    safe = np.clip(idx, 0, None)
    vel = np.where(has[:, None], g.vel[safe], np.nan)
    valid = has & g.valid[safe]
    age = np.where(has, t - g.t[safe], np.inf)
    new = has & np.concatenate([[True], idx[1:] != idx[:-1]])
    t_epoch = np.where(has, g.t[safe], np.nan)
    return {"vel": vel, "valid": valid, "age": age, "new": new, "index": idx, "t": t_epoch}


#: the GNSS row of a sample without GNSS (vn, ve, valid, age, new, t_epoch)
NO_GNSS = np.array([np.nan, np.nan, 0.0, np.inf, 0.0, np.nan])


def gnss_sample_rows(rec: Recording) -> np.ndarray:
    """(N, 6) rows ``vn, ve, valid, age, new, t_epoch`` (velocity north/east in m/s) of the
    latest GNSS epoch at each IMU sample: what GNSS-aided filters take per sample (also through
    ``update(..., gnss=row)``). Without a GNSS stream every row is a gap."""
    from .conventions import frame_matrix

    if rec.gnss is None:
        return np.tile(NO_GNSS, (len(rec), 1))
    g, t = rec.gnss, rec.time
    # each epoch's row once (north and east from the stream's frame), then one gather per sample; the
    # last row stands for the samples before the first epoch (the same numbers as gnss_per_sample's)
    rows = np.empty((g.t.size + 1, 6))
    rows[:-1, 0:2] = g.vel @ frame_matrix(g.frame, "NED")[:2].T
    rows[:-1, 2], rows[:-1, 3], rows[:-1, 4], rows[:-1, 5] = g.valid, 0.0, 0.0, g.t
    rows[-1] = NO_GNSS
    idx = np.searchsorted(g.t, t, side="right") - 1
    out = rows[idx]
    has = idx >= 0
    np.subtract(t, out[:, 5], out=out[:, 3], where=has)  # the epoch's age (inf before the first)
    out[0, 4] = float(has[0])
    out[1:, 4] = has[1:] & (idx[1:] != idx[:-1])
    return out
