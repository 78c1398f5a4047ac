"""The pipeline: a filter composed from an estimator, correctors and detectors.

Per sample, in this fixed order:

1. **validity** (:func:`fusionkit.types.sample_validity`): an invalid gyr sample is flagged
   GYR_INVALID (state held; every plugin sees it as NaN), an invalid acc / mag sample
   ACC_INVALID / MAG_INVALID (their use skipped); axes at or above ``gyr_range`` /
   ``acc_range`` are flagged SATURATED (a saturated gyro is still integrated, a saturated acc is
   not used). Across a timestamp gap (GAP) the state is held (:func:`fusionkit.types.hold_gaps`).
2. **detectors** (each on samples with valid gyr and acc): a nonzero criteria mask sets the
   detector's flag.
3. **alignment** while it runs (source 000): the sample is added to the means and the output is
   the current alignment attitude (flag ALIGNING). Mode ``motion`` ends it on the first MOTION
   sample after the mandatory ``duration`` (that sample is navigated, not averaged); mode
   ``fixed`` after ``duration``; mode ``none`` skips it. On the end, the estimator starts from
   the alignment attitude and the mean gyro output becomes the bias.
4. **propagation**: ``estimator.propagate(gyr - bias + correction_rate, dt)``.
5. **correctors**, in order; rate correctors' outputs are summed into the next correction rate.
   A sample flagged MAG_DISTURBED (by the ``magnetic`` detector) reaches them without its
   magnetometer reading, one flagged ACC_REJECTED (by the ``acceleration`` detector) without its
   accelerometer reading: that correction is skipped.

Two paths run this: the readable reference (:meth:`Pipeline._step`) and, when every plugin has
a numba kernel (an estimator, any detectors, any correctors of either mode), one compiled loop
built by closing over the plugins' kernels (:func:`_build_loop`). ``Result.diagnostics["backend"]``
says which ran; the tests hold the two to 1e-9 on every sample.

``quat[k]`` is the orientation after sample ``k`` has been processed; sample ``k``'s rate is
held over ``dt[k] = t[k] - t[k-1]``.
"""

from __future__ import annotations

import copy
import math
import sys
from typing import Any, ClassVar

import numpy as np

from ._kernels import validity_flags
from ._numba import HAVE_NUMBA, njit, resolve_backend
from .config import PipelineConfig
from .detectors.gnss_gap import NO_GNSS, gnss_sample_rows
from .errors import ConfigError, InputError
from .navigation.alignment import (
    ALIGN_SIZE,
    ALIGNED_BEFORE,
    ALIGNED_NOW,
    ALIGNING,
    BIAS,
    DISTURBED,
    END,
    PHASE,
    SEEN,
    Aligner,
    align_step,
    report_disturbed,
)
from .protocols import DetectionResult, Detector, Filter, Sample
from .registry import Registry, default_registry
from .types import (Flag, Recording, Result, gap_flags, gap_threshold, hold_gaps, mark_gaps, sample_validity,
                    stream_gap)
from .validation import as_vector, check_finite_all, check_positive, check_sample_finite

__all__ = ["Pipeline", "run_detector"]

# the pipeline's run state "align": the alignment's fields, then the pending correction rate
_RCORR = ALIGN_SIZE
_STATE_SIZE = ALIGN_SIZE + 3
_CHUNK = 200_000


class Pipeline(Filter):
    """A filter composed from registered plugins by a :class:`~fusionkit.config.PipelineConfig`.

    >>> f = Pipeline({"estimator": "poisson-quat", "detectors": ["motion"]})  # doctest: +SKIP
    """

    name: ClassVar[str] = "pipeline"
    Config = PipelineConfig
    source: ClassVar[str] = "fusionkit (composition of plugins)"
    summary: ClassVar[str] = "estimator + correctors + detectors + alignment, composed from a config"

    def __init__(self, config=None, *, registry: Registry | None = None, **params: Any) -> None:
        super().__init__(config, **params)
        spec = self.pipeline_config()
        reg = registry or default_registry()
        self.spec = spec
        self.estimator = reg.make(spec.estimator.name, "estimator", spec.estimator.params)
        self.correctors = [reg.make(c.name, "corrector", c.params) for c in spec.correctors]
        self.detectors = [reg.make(d.name, "detector", d.params) for d in spec.detectors]
        if spec.alignment.mode == "motion" and not any(d.flag & Flag.MOTION for d in self.detectors):
            raise ConfigError(
                "alignment mode 'motion' ends on a MOTION flag, but no detector sets it: add the "
                "'motion' detector or use mode 'fixed'"
            )
        for c in self.correctors:
            if c.requires_flag and not any(d.flag & c.requires_flag for d in self.detectors):
                raise ConfigError(f"corrector {c.name!r} acts on {c.requires_flag.name} samples, but no detector "
                                  f"sets that flag: add one (e.g. 'rest' for REST)")
        self._stream: dict[str, Any] | None = None
        self.last_flags = 0

    def pipeline_config(self) -> PipelineConfig:
        """The composition this filter runs (presets override this)."""
        return self.config

    def dimension(self, rec) -> str:
        uses = self.spec.alignment.heading == "magnetometer" or any(
            c.uses_mag and getattr(c.config, "use_mag", True) for c in self.correctors)
        return "9D" if uses and rec.mag is not None else "6D"

    # -- state -----------------------------------------------------------------------------
    def aligner(self, dt: float) -> Aligner:
        """The alignment state machine for nominal interval ``dt`` (made once per dt)."""
        cache = self.__dict__.setdefault("_aligners", {})
        if dt not in cache:
            cache[dt] = Aligner(self.spec.alignment, self.spec.frame, dt)
        return cache[dt]

    def new_state(self, dt: float) -> dict[str, Any]:
        """A fresh run state for nominal sample interval ``dt``."""
        al = self.aligner(dt).new_state(_STATE_SIZE)
        q0 = np.array(self.spec.alignment.initial_quat)
        return {
            "dt": float(dt),
            "x": self.estimator.initial_state(q0),
            "det": [d.initial_state(dt) for d in self.detectors],
            "cor": [c.initial_state(dt, self.spec.frame) for c in self.correctors],
            "align": al,
        }

    @property
    def state(self) -> dict[str, Any] | None:
        """A deep copy of the streaming state (None before the first ``update``)."""
        return copy.deepcopy(self._stream)

    def set_state(self, state: dict[str, Any]) -> None:
        """Restore a state from :attr:`state` or ``Result.diagnostics["state"]``."""
        self._stream = self._check_state(copy.deepcopy(state))

    def _check_state(self, st: dict[str, Any]) -> dict[str, Any]:
        keys = {"dt", "x", "det", "cor", "align"}
        if not isinstance(st, dict) or set(st) != keys:
            raise InputError(f"state must be a dict with keys {sorted(keys)}")
        ref = self.new_state(st["dt"])
        for k in ("x", "align"):
            if np.shape(st[k]) != ref[k].shape:
                raise InputError(f"state[{k!r}] has shape {np.shape(st[k])}, expected {ref[k].shape}")
        if len(st["det"]) != len(ref["det"]) or len(st["cor"]) != len(ref["cor"]):
            raise InputError("state does not belong to this pipeline (detector/corrector count differs)")
        return st

    def reset(self) -> None:
        self._stream = None

    # -- the readable reference path -------------------------------------------------------
    def _step(self, st, gyr, acc, mag, dt, has_mag, gnss=None) -> tuple[np.ndarray, int, int]:
        """Process one sample; returns (quat body->frame, flags, first detector's criteria)."""
        cfg, al = self.spec, st["align"]
        gyr_ok, acc_ok, mag_ok, flags = sample_validity(gyr, acc, mag if has_mag else None, cfg.gyr_range,
                                                        cfg.acc_range)
        if not gyr_ok:  # every plugin sees an invalid gyro sample as non-finite (not as a huge rate)
            gyr = np.full(3, np.nan)
        sample = Sample(gyr, acc if acc_ok else None, mag if mag_ok else None, dt, gnss)

        # 2. detectors
        crit0 = 0
        for i, det in enumerate(self.detectors):
            if gyr_ok and acc_ok:
                bits = det.step(st["det"][i], sample)
                if i == 0:
                    crit0 = bits
                if bits:
                    flags |= det.flag
        # 3. alignment
        status, q = self.aligner(st["dt"]).step(al, gyr, acc, mag, gyr_ok, acc_ok, mag_ok, bool(flags & Flag.MOTION))
        if status in (ALIGNED_NOW, ALIGNED_BEFORE):
            st["x"] = self.estimator.initial_state(q)
        if status in (ALIGNING, ALIGNED_NOW):
            return q, flags | Flag.ALIGNING, crit0
        # 4. propagation
        al[SEEN] += 1.0
        if gyr_ok:
            self.estimator.propagate(st["x"], gyr - al[BIAS:BIAS + 3] + al[_RCORR:_RCORR + 3], dt)
        # 5. correctors (they see the rate the estimator integrated: the alignment's bias removed)
        if self.correctors:
            rate = np.zeros(3)
            sample = sample._replace(gyr=gyr - al[BIAS:BIAS + 3])
            if flags & Flag.MAG_DISTURBED:
                sample = sample._replace(mag=None)
            if flags & Flag.ACC_REJECTED:
                sample = sample._replace(acc=None)
            for i, cor in enumerate(self.correctors):
                out = cor.correct(self.estimator, st["x"], st["cor"][i], sample, flags)
                flags |= out.flags
                if out.rate is not None:
                    rate += out.rate
            al[_RCORR:_RCORR + 3] = rate
        return self.estimator.quat(st["x"]), flags, crit0

    # -- the compiled path -----------------------------------------------------------------
    def _kernels(self):
        ek = self.estimator.kernel()
        dks = [d.kernel() for d in self.detectors]
        cks = [c.kernel(self.estimator) for c in self.correctors]
        if ek is None or any(k is None for k in dks + cks):
            return None
        for c, k in zip(self.correctors, cks):
            if k.mode != c.mode:
                raise ConfigError(f"corrector {c.name!r}: its kernel's mode {k.mode!r} is not its mode {c.mode!r}")
        return ek, dks, cks

    def _loop_params(self) -> np.ndarray:
        pp = np.zeros(3)
        pp[0] = self.spec.gyr_range if self.spec.gyr_range is not None else math.inf
        pp[1] = self.spec.acc_range if self.spec.acc_range is not None else math.inf
        pp[2] = float(Flag.MOTION)
        return pp

    def _run_compiled(self, st, gyr, acc, mag, dt, has_mag, out_q, out_f, out_c, start, stop, gn=None) -> None:
        ek, dks, cks = self._kernels()
        # a magnetometer-only detector cannot fire without one, and its reference step leaves its state alone
        used = [i for i, d in enumerate(self.detectors) if has_mag or not d.needs_mag]
        step = _get_detectors([(dks[i].step, int(self.detectors[i].flag), st["det"][i].size, dks[i].params.size,
                                i == 0, dks[i].gnss) for i in used])
        det_state = _concat([st["det"][i] for i in used])
        det_params = _concat([dks[i].params for i in used])
        single, chain, kind = _no_state_corrector, _no_corrector, 0  # no corrector
        if len(cks) == 1 and cks[0].mode == "state" and not cks[0].gnss:  # the common case, without the chain's glue
            single, kind = cks[0].correct, 1
        elif cks:
            chain = _get_correctors(ek, [(k.correct, k.mode, s.size, k.params.size, k.gnss)
                                         for k, s in zip(cks, st["cor"])])
            kind = 2
        cor_state = _concat(st["cor"])
        cor_params = _concat([k.params for k in cks])
        uses_gnss = any(k.gnss for k in cks) or any(dks[i].gnss for i in used)
        loop = _get_loop(ek, step, single, chain, kind, any(k.mode == "rate" for k in cks), uses_gnss)
        x = st["x"]
        loop(gyr, acc, mag, dt, has_mag, x, ek.params, det_state, det_params, cor_state, cor_params,
             st["align"], self.aligner(st["dt"]).params(), self._loop_params(), out_q, out_f, out_c, start, stop,
             gn if gn is not None else NO_GNSS[None, :])
        _split(det_state, [st["det"][i] for i in used])  # the states back from the concatenations
        _split(cor_state, st["cor"])

    # -- public ----------------------------------------------------------------------------
    def run(self, rec: Recording, *, backend: str = "auto", progress: bool | None = None,
            state: dict[str, Any] | None = None) -> Result:
        """Process ``rec``; start from ``state`` (``Result.diagnostics["state"]`` of an earlier
        run) to continue a split recording."""
        if not isinstance(rec, Recording):
            raise InputError(f"rec must be a fusionkit.Recording, got {type(rec).__name__}")
        n = len(rec)
        check_finite_all({"gyr": rec.gyr, "acc": rec.acc, "mag": rec.mag}, self.spec.nan_policy)
        has_mag = rec.mag is not None
        if self.spec.alignment.heading == "magnetometer" and not has_mag:
            raise InputError("alignment heading='magnetometer' needs mag in the recording")
        kernels = self._kernels()
        used = resolve_backend(backend, kernels is not None)
        st = self._check_state(copy.deepcopy(state)) if state is not None else self.new_state(rec.nominal_dt)
        mag = rec.mag if has_mag else np.zeros((n, 3))
        gyr, dt, gaps = hold_gaps(rec.gyr, rec.dt, rec.nominal_dt, self.spec.max_gap)
        # the GNSS rows: the reference's samples carry them; compiled, only kernels that take them
        want = used != "numba" or any(k.gnss for k in kernels[1] + kernels[2])
        gn = gnss_sample_rows(rec) if rec.gnss is not None and want else None
        out_q = np.empty((n, 4))
        out_f = np.zeros(n, dtype=np.uint32)
        out_c = np.zeros(n, dtype=np.uint32)
        bar = _progress(n, progress, f"{self.name}")
        for start in range(0, n, _CHUNK):
            stop = min(n, start + _CHUNK)
            if used == "numba":
                self._run_compiled(st, gyr, rec.acc, mag, dt, has_mag, out_q, out_f, out_c, start, stop, gn)
            else:
                for k in range(start, stop):
                    q, f, c = self._step(st, gyr[k], rec.acc[k], mag[k], dt[k], has_mag,
                                         None if gn is None else gn[k])
                    out_q[k], out_f[k], out_c[k] = q, f, c
            if bar is not None:
                bar.update(stop - start)
        if bar is not None:
            bar.close()
        diag = self._diagnostics(st, out_f, out_c, used)
        report_disturbed(st["align"], st["dt"], self.spec.alignment.duration)
        mark_gaps(out_f, gaps, rec.gyr, diag, gap_threshold(rec.nominal_dt, self.spec.max_gap))
        return Result(out_q, out_f, self.spec.frame, diag)

    def _diagnostics(self, st, flags, crit, backend) -> dict[str, Any]:
        al = st["align"]
        d: dict[str, Any] = {"backend": backend, "filter": self.name, "config": self.config.model_dump()}
        d["bias"] = al[BIAS:BIAS + 3].copy()
        d["alignment_end_index"] = None if al[END] < 0 else int(al[END])
        d["alignment_disturbed"] = bool(al[DISTURBED])
        if self.detectors:
            fired = np.flatnonzero(crit)
            d["criteria"] = crit
            d["criteria_names"] = self.detectors[0].criteria_names
            d["onset_index"] = int(fired[0]) if fired.size else None
        d["state"] = copy.deepcopy(st)
        return d

    def update(self, gyr, acc, mag=None, dt: float | None = None, gnss=None) -> np.ndarray:
        """Process one sample of a stream (``dt`` in s is required; ``gnss`` the latest epoch's
        row, see :class:`~fusionkit.protocols.Sample`); same numbers as :meth:`run` with the
        reference backend. ``last_flags`` holds the sample's flags."""
        if dt is None:
            raise InputError("update() needs dt, the sample interval in s")
        dt = check_positive("dt", dt)
        g = as_vector("gyr", gyr)
        a = as_vector("acc", acc)
        has_mag = mag is not None
        m = as_vector("mag", mag) if has_mag else np.zeros(3)
        check_sample_finite(self.spec.nan_policy, gyr=g, acc=a, mag=m)
        self.check_stream_units(g, a)
        if self._stream is None:
            self._stream = self.new_state(dt)
        g, dt, gap = stream_gap(g, dt, self._stream["dt"], self.spec.max_gap)
        gn = None if gnss is None else np.asarray(gnss, dtype=float)
        q, f, _ = self._step(self._stream, g, a, m, dt, has_mag, gn)
        self.last_flags = gap_flags(f, gap)
        return q


def _progress(n: int, progress: bool | None, desc: str):
    """A tqdm bar for long runs: always with ``progress=True``, on a terminal above 1M samples
    with ``None``."""
    if progress is False or (progress is None and (n < 1_000_000 or not sys.stderr.isatty())):
        return None
    try:
        from tqdm import tqdm
    except ImportError:  # pragma: no cover
        return None
    return tqdm(total=n, desc=desc, unit="sample", unit_scale=True, leave=False)


# ---- the compiled loop ------------------------------------------------------------------------

_LOOPS: dict[tuple, Any] = {}


@njit(inline="always")
def _no_detector(s, g0, g1, g2, a0, a1, a2, m0, m1, m2, dt, p, n0, n1, n2, n3, n4, n5):
    return 0, 0


def _concat(arrays) -> np.ndarray:
    """Plugins' states or parameters end to end (one spare element: never empty for numba)."""
    return np.concatenate([np.asarray(a, dtype=float).ravel() for a in arrays] + [np.zeros(1)])


def _split(joined: np.ndarray, arrays) -> None:
    """Copy ``joined`` (from :func:`_concat`) back into ``arrays``."""
    o = 0
    for a in arrays:
        a[...] = joined[o:o + a.size].reshape(a.shape)
        o += a.size


@njit
def _no_state_corrector(x, q, s, g0, g1, g2, a0, a1, a2, m0, m1, m2, acc_ok, mag_ok, dt, p):
    return -1


@njit(inline="always")
def _no_corrector(x, q, s, g0, g1, g2, a0, a1, a2, m0, m1, m2, acc_ok, mag_ok, flags, dt, p, rate, n0, n1, n2, n3,
                  n4, n5):
    return flags


_DETECTOR_CHAINS: dict[tuple, Any] = {}


def _get_detectors(specs):
    """One compiled step for several detector kernels, ``step(s, g0, g1, g2, a0, a1, a2, m0, m1, m2,
    dt, p, n0..n5) -> (criteria of detector 0, flags)``, over their states and parameters
    concatenated in order (``n0..n5``: the sample's GNSS row, passed to the kernels that take it).
    ``specs``: ``(kernel step, flag, state size, params size, is detector 0, takes GNSS)`` each."""
    key = tuple(specs)
    if key not in _DETECTOR_CHAINS:
        step = _no_detector
        so = po = 0
        for kstep, flag, sn, pn, first, gnss in specs:
            step = _chain_detector(step, kstep, flag, so, sn, po, pn, first, gnss)
            so, po = so + sn, po + pn
        _DETECTOR_CHAINS[key] = step
    return _DETECTOR_CHAINS[key]


def _chain_detector(before, kstep, flag, so, sn, po, pn, first, gnss):
    """``before`` followed by one detector kernel on ``s[so:so + sn]``, ``p[po:po + pn]``."""

    @njit(cache=False, inline="always")
    def step(s, g0, g1, g2, a0, a1, a2, m0, m1, m2, dt, p, n0, n1, n2, n3, n4, n5):
        c0, flags = before(s, g0, g1, g2, a0, a1, a2, m0, m1, m2, dt, p, n0, n1, n2, n3, n4, n5)
        if gnss:
            c = kstep(s[so:so + sn], g0, g1, g2, a0, a1, a2, m0, m1, m2, dt, p[po:po + pn], n0, n1, n2, n3, n4, n5)
        else:
            c = kstep(s[so:so + sn], g0, g1, g2, a0, a1, a2, m0, m1, m2, dt, p[po:po + pn])
        if c != 0:
            flags |= flag
        return (c if first else c0), flags

    return step


_CORRECTOR_CHAINS: dict[tuple, Any] = {}


def _get_correctors(ek, specs):
    """One compiled step for the correctors in order, ``step(x, q, s, g0, g1, g2, a0, a1, a2, m0, m1,
    m2, acc_ok, mag_ok, flags, dt, p, rate, n0..n5) -> flags``, over their states and parameters
    concatenated (``n0..n5``: the sample's GNSS row). ``specs``: ``(kernel correct, mode, state
    size, params size, takes GNSS)`` each. A state corrector corrects the estimator (through
    ``q`` unless its state is its unit quaternion); a rate corrector reads the current quaternion
    and adds into ``rate``."""
    direct = ek.unit_quat
    key = (ek.to_quat, ek.from_quat, direct, tuple(specs))
    if key not in _CORRECTOR_CHAINS:
        step = _no_corrector
        so = po = 0
        for correct, mode, sn, pn, gnss in specs:
            step = _chain_corrector(step, correct, mode == "rate", ek.to_quat, ek.from_quat, direct, so, sn, po, pn,
                                    gnss)
            so, po = so + sn, po + pn
        _CORRECTOR_CHAINS[key] = step
    return _CORRECTOR_CHAINS[key]


def _chain_corrector(before, correct, is_rate, to_quat, from_quat, direct, so, sn, po, pn, gnss):
    """``before`` followed by one corrector kernel on ``s[so:so + sn]``, ``p[po:po + pn]``."""

    @njit(cache=False, inline="always")
    def step(x, q, s, g0, g1, g2, a0, a1, a2, m0, m1, m2, acc_ok, mag_ok, flags, dt, p, rate, n0, n1, n2, n3, n4, n5):
        flags = before(x, q, s, g0, g1, g2, a0, a1, a2, m0, m1, m2, acc_ok, mag_ok, flags, dt, p, rate, n0, n1, n2, n3,
                       n4, n5)
        cs, cp = s[so:so + sn], p[po:po + pn]
        if is_rate:
            if not direct:
                to_quat(x, q)
            qq = x if direct else q
            if gnss:
                cf = correct(qq, cs, g0, g1, g2, a0, a1, a2, m0, m1, m2, acc_ok, mag_ok, flags, dt, cp, rate,
                             n0, n1, n2, n3, n4, n5)
            else:
                cf = correct(qq, cs, g0, g1, g2, a0, a1, a2, m0, m1, m2, acc_ok, mag_ok, flags, dt, cp, rate)
        else:
            if not direct:
                to_quat(x, q)
            qq = x if direct else q
            if gnss:
                cf = correct(x, qq, cs, g0, g1, g2, a0, a1, a2, m0, m1, m2, acc_ok, mag_ok, dt, cp, n0, n1, n2, n3, n4,
                             n5)
            else:
                cf = correct(x, qq, cs, g0, g1, g2, a0, a1, a2, m0, m1, m2, acc_ok, mag_ok, dt, cp)
            if not direct and cf >= 0:
                from_quat(q, x)
        if cf > 0:
            flags |= cf
        return flags

    return step


def _get_loop(ek, det_step, cor_single, cor_chain, cor_kind, has_rate, uses_gnss):
    direct = ek.unit_quat
    key = (ek.propagate, ek.to_quat, ek.from_quat, det_step, cor_single, cor_chain, cor_kind, has_rate, direct,
           uses_gnss)
    if key not in _LOOPS:
        _LOOPS[key] = _build_loop(ek.propagate, ek.to_quat, ek.from_quat, det_step, cor_single, cor_chain, cor_kind,
                                  has_rate, direct, uses_gnss)
    return _LOOPS[key]


def _build_loop(est_propagate, est_to_quat, est_from_quat, det_step, cor_single, cor_chain, cor_kind, has_rate,
                direct, uses_gnss):
    """One compiled loop over a recording for an estimator, the detectors (one chained step, see
    :func:`_get_detectors`) and the correctors: the same steps as :meth:`Pipeline._step`.
    ``cor_kind``: 0 no corrector; 1 one state-mode kernel ``cor_single``, called directly (on the
    estimator's state itself when ``direct``: it is its unit quaternion); 2 the chained step
    ``cor_chain`` (:func:`_get_correctors`). ``has_rate``: some corrector returns a rate, the sum
    is fed into the next propagation. ``uses_gnss``: some kernel takes the GNSS row ``gn[k]`` (``gn``
    has one row per sample, or the single row of "no GNSS")."""
    if not HAVE_NUMBA:  # pragma: no cover
        raise ConfigError("numba is not installed")

    @njit(cache=False)
    def loop(gyr, acc, mag, dt, has_mag, x, ep, ds, dp, cs, cp, al, ap, pp, out_q, out_f, out_c, start, stop, gn):
        q = np.empty(4)
        rate = np.zeros(3)
        motion = int(pp[2])
        last = gn.shape[0] - 1
        n0 = n1 = n2 = n3 = n4 = n5 = 0.0
        for k in range(start, stop):
            g0, g1, g2 = gyr[k, 0], gyr[k, 1], gyr[k, 2]
            a0, a1, a2 = acc[k, 0], acc[k, 1], acc[k, 2]
            m0, m1, m2 = mag[k, 0], mag[k, 1], mag[k, 2]
            if uses_gnss:
                r = min(k, last)
                n0, n1, n2, n3, n4, n5 = gn[r, 0], gn[r, 1], gn[r, 2], gn[r, 3], gn[r, 4], gn[r, 5]
            gyr_ok, acc_ok, mag_ok, flags = validity_flags(g0, g1, g2, a0, a1, a2, m0, m1, m2, has_mag, pp[0],
                                                            pp[1])
            if not gyr_ok:  # as the reference: an invalid sample is non-finite for every plugin
                g0 = g1 = g2 = math.nan
            if not mag_ok:
                m0 = m1 = m2 = math.nan
            crit = 0
            if gyr_ok and acc_ok:
                crit, dflags = det_step(ds, g0, g1, g2, a0, a1, a2, m0, m1, m2, dt[k], dp, n0, n1, n2, n3, n4, n5)
                flags |= dflags
            out_c[k] = crit
            if al[PHASE] == 0.0:  # checked here so that navigation does not pay for the call
                status = align_step(al, ap, g0, g1, g2, a0, a1, a2, m0, m1, m2, gyr_ok, acc_ok, mag_ok,
                                    (flags & motion) != 0, q)
                if status == ALIGNED_NOW or status == ALIGNED_BEFORE:  # start the estimator from the alignment
                    est_from_quat(q, x)
                if status == ALIGNING or status == ALIGNED_NOW:
                    out_q[k, 0], out_q[k, 1], out_q[k, 2], out_q[k, 3] = q[0], q[1], q[2], q[3]
                    out_f[k] = flags | 1
                    continue
            al[SEEN] += 1.0
            if gyr_ok:
                est_propagate(x, g0 - al[BIAS] + al[_RCORR], g1 - al[BIAS + 1] + al[_RCORR + 1],
                              g2 - al[BIAS + 2] + al[_RCORR + 2], dt[k], ep)
            if cor_kind == 1:  # mag withheld on MAG_DISTURBED, acc on ACC_REJECTED, as in the reference
                gm_ok = mag_ok and (flags & 256) == 0
                ga_ok = acc_ok and (flags & 512) == 0
                if direct:
                    cf = cor_single(x, x, cs, g0 - al[BIAS], g1 - al[BIAS + 1], g2 - al[BIAS + 2], a0, a1, a2,
                                    m0, m1, m2, ga_ok, gm_ok, dt[k], cp)
                else:
                    est_to_quat(x, q)
                    cf = cor_single(x, q, cs, g0 - al[BIAS], g1 - al[BIAS + 1], g2 - al[BIAS + 2], a0, a1, a2,
                                    m0, m1, m2, ga_ok, gm_ok, dt[k], cp)
                    if cf >= 0:
                        est_from_quat(q, x)
                if cf > 0:
                    flags |= cf
            elif cor_kind == 2:
                if has_rate:
                    rate[0] = rate[1] = rate[2] = 0.0
                flags = cor_chain(x, q, cs, g0 - al[BIAS], g1 - al[BIAS + 1], g2 - al[BIAS + 2], a0, a1, a2,
                                  m0, m1, m2, acc_ok and (flags & 512) == 0, mag_ok and (flags & 256) == 0, flags,
                                  dt[k], cp, rate, n0, n1, n2, n3, n4, n5)
                if has_rate:  # (without rate correctors it stays 0, as in the reference)
                    al[_RCORR], al[_RCORR + 1], al[_RCORR + 2] = rate[0], rate[1], rate[2]
            est_to_quat(x, q)
            out_q[k, 0], out_q[k, 1], out_q[k, 2], out_q[k, 3] = q[0], q[1], q[2], q[3]
            out_f[k] = flags

    return loop


# ---- detectors on their own -------------------------------------------------------------------

_DET_LOOPS: dict[Any, Any] = {}


def _get_det_loop(step, gnss=False):
    key = (step, gnss)
    if key not in _DET_LOOPS:

        @njit(cache=False)
        def loop(gyr, acc, mag, dt, ok, s, p, out, gn):
            last = gn.shape[0] - 1
            for k in range(gyr.shape[0]):
                if ok[k]:
                    if gnss:
                        r = min(k, last)
                        out[k] = step(s, gyr[k, 0], gyr[k, 1], gyr[k, 2], acc[k, 0], acc[k, 1], acc[k, 2],
                                      mag[k, 0], mag[k, 1], mag[k, 2], dt[k], p, gn[r, 0], gn[r, 1], gn[r, 2],
                                      gn[r, 3], gn[r, 4], gn[r, 5])
                    else:
                        out[k] = step(s, gyr[k, 0], gyr[k, 1], gyr[k, 2], acc[k, 0], acc[k, 1], acc[k, 2],
                                      mag[k, 0], mag[k, 1], mag[k, 2], dt[k], p)

        _DET_LOOPS[key] = loop
    return _DET_LOOPS[key]


def run_detector(det: Detector, rec: Recording, *, nan_policy: str = "raise", backend: str = "auto",
                 every_sample: bool = False) -> DetectionResult:
    """Run one detector over a recording (see :meth:`Detector.run`): on the samples with a valid
    gyroscope and accelerometer (as in a pipeline), or on ``every_sample``. Detectors that read
    GNSS get the sample's GNSS row (:func:`~fusionkit.detectors.gnss_gap.gnss_sample_rows`)."""
    if not isinstance(rec, Recording):
        raise InputError(f"rec must be a fusionkit.Recording, got {type(rec).__name__}")
    check_finite_all({"gyr": rec.gyr, "acc": rec.acc}, nan_policy)
    if every_sample:
        ok = np.ones(len(rec), dtype=bool)
    else:
        ok = np.isfinite(rec.gyr).all(axis=1) & np.isfinite(rec.acc).all(axis=1)
        ok &= np.any(rec.acc != 0.0, axis=1)
    kernel = det.kernel()
    used = resolve_backend(backend, kernel is not None)
    s = det.initial_state(rec.nominal_dt)
    n = len(rec)
    out = np.zeros(n, dtype=np.uint32)
    mag = rec.mag if rec.mag is not None else np.zeros((n, 3))
    dt = rec.dt
    gn = gnss_sample_rows(rec) if rec.gnss is not None else None
    if used == "numba":
        _get_det_loop(kernel.step, kernel.gnss)(rec.gyr, rec.acc, mag, dt, ok, s, kernel.params, out,
                                                gn if gn is not None else NO_GNSS[None, :])
    else:
        for k in range(n):
            if ok[k]:
                m = mag[k] if rec.mag is not None else None
                out[k] = det.step(s, Sample(rec.gyr[k], rec.acc[k], m, dt[k], None if gn is None else gn[k]))
    fired = np.flatnonzero(out)
    return DetectionResult(out, int(fired[0]) if fired.size else None, det.criteria_names, used)
