"""The pipeline: a filter composed from an estimator, correctors and detectors.

Per sample, in this fixed order:

1. **validity** (:func:`fusionkit.types.sample_validity`): an invalid gyr sample is flagged
   GYR_INVALID (state held; every plugin sees it as NaN), an invalid acc / mag sample
   ACC_INVALID / MAG_INVALID (their use skipped); axes at or above ``gyr_range`` /
   ``acc_range`` are flagged SATURATED (a saturated gyro is still integrated, a saturated acc is
   not used). Across a timestamp gap (GAP) the state is held (:func:`fusionkit.types.hold_gaps`).
   **sensor models** (``models``, in order; :class:`~fusionkit.protocols.SensorModel`) then
   correct the sample (calibration, time offsets), reading the previous output orientation;
   validity is judged again on what they return. Every plugin gets the recording's rows as
   read-only views: one that writes into its input is a PluginError naming it (it changed the
   user's recording).
2. **detectors** (each on samples with valid gyr and acc): a nonzero criteria mask sets the
   detector's flag.
3. **alignment** while it runs (source 000): the sample is added to the means and the output is
   the current alignment attitude (flag ALIGNING). Mode ``motion`` ends it on the first MOTION
   sample after the mandatory ``duration`` (that sample is navigated, not averaged); mode
   ``fixed`` after ``duration``; mode ``none`` skips it. On the end, the estimator starts from
   the alignment attitude and the mean gyro output becomes the bias.
4. **bias correctors** (``mode = "bias"``), in order: they update the gyro bias (the
   alignment's, shared) before this sample's propagation subtracts it.
5. **propagation**: ``estimator.propagate(gyr - bias + correction_rate, dt)``.
6. **correctors**, in order; rate correctors' outputs are summed into the next correction rate.
   A sample flagged MAG_DISTURBED (by the ``magnetic`` detector) reaches them without its
   magnetometer reading, one flagged ACC_REJECTED (by the ``acceleration`` detector) without its
   accelerometer reading: that correction is skipped. A corrector that names a
   ``state_layout`` works on the estimator's state itself (e.g. a DCM's columns); the others
   through its quaternion. **Factor correctors** (``mode = "factor"``) come last: the estimator
   never sees their corrections; each keeps its own factor and composes it into the output, in
   order, from the estimator's quaternion on (``recommended``: ``q = Rz(delta) (x) q_tilt (x)
   q_gyr``). They see the gyroscope as measured, the rate the estimator integrated and the gyro
   bias, which they may update (it takes effect in the next propagation).

**The channel** (:class:`~fusionkit.types.Channel`): besides the gyro bias and the flags,
correctors share named quantities. One that declares ``publishes`` writes them into the run
state's channel block, and one after it that declares ``reads`` reads them in the same sample
(``inertial-tilt`` publishes its inclination error, ``mag-heading`` with ``inclination_noise``
counts it in its measurement variance); the composition is refused where a corrector reads
(:meth:`Corrector.channel_reads`) what only one that runs later publishes
(:meth:`Corrector.channel_publishes`; the bias correctors run first), or two publish a name that
one reads. The
block starts at 0 ("nothing known") and is part of the run state, so a split run and
``update()`` carry it; both paths hand the same block to the same correctors.

Before a sample that follows a timestamp gap (GAP) or a saturated gyro (the first unsaturated
sample), correctors that declare ``restarts`` forget what became stale (:meth:`Corrector.restart`).

Two paths run this: the readable reference (:meth:`Pipeline._step`) and, when every plugin has
a numba kernel (an estimator, any models, detectors and correctors of either mode), one compiled
loop generated for the composition and cached on disk (:mod:`fusionkit._loopgen`), whose
one-sample twin also serves :meth:`Pipeline.update`. ``Result.diagnostics["backend"]`` says which
ran; the tests hold the two to 1e-9 on every sample.

``quat[k]`` is the orientation after sample ``k`` has been processed; sample ``k``'s rate is
held over ``dt[k] = t[k] - t[k-1]``.
"""

from __future__ import annotations

import copy
import math
import sys
import warnings
from typing import Any, ClassVar

import numpy as np

from . import _loopgen
from ._numba import HAVE_NUMBA, resolve_backend
from .config import PipelineConfig
from .detectors._run import checked_bits, read_only, run_detector, wrote_input
from .detectors.gnss_gap import NO_GNSS, gnss_sample_rows
from .errors import ConfigError, InputError, PluginError
from .navigation.alignment import (
    ALIGN_SIZE,
    ALIGNED_BEFORE,
    ALIGNED_NOW,
    ALIGNING,
    BIAS,
    DISTURBED,
    END,
    SEEN,
    Aligner,
    report_disturbed,
)
from .protocols import Correction, Filter, Sample
from .registry import Registry, default_registry
from .types import (CHANNEL_SIZE, Channel, Flag, Recording, Result, gap_flags, gap_threshold, hold_gaps, mark_gaps,
                    sample_validity, stream_gap)
from .filters._step_filter import _after_saturation
from .validation import (as_vector, check_finite_all, check_finite_flagged, check_dt, check_sample_finite,
                         finite_rows, finite_sample)

__all__ = ["Pipeline", "run_detector"]

# the pipeline's run state "align": the alignment's fields, the pending correction rate, the
# previous output quaternion (what sensor models read), and the correctors' channel (types.Channel)
_RCORR = ALIGN_SIZE
_QPREV = ALIGN_SIZE + 3
_CHAN = ALIGN_SIZE + 7
_STATE_SIZE = _CHAN + CHANNEL_SIZE
_CHUNK = 200_000
_INVALID = int(Flag.GYR_INVALID | Flag.ACC_INVALID | Flag.MAG_INVALID)
#: the most correctors the compiled loop takes: its first compile grows by about half a second per
#: corrector (measured in docs/robustness.md); beyond this a composition is more likely a mistake,
#: and the reference path needs no compile and gives the same numbers
MAX_COMPILED_CORRECTORS = 64


def _bad_correction(cor, out) -> None:
    """A corrector's ``correct`` returned something else than a :class:`Correction` with a rate of
    shape (3,) (or None): a PluginError naming it (numpy's broadcast error, or ``|=`` on an
    array's ``.flags``, named neither the plugin nor what it should return)."""
    what = (f"a Correction whose rate has shape {np.shape(out.rate)}" if type(out) is Correction
            else f"{type(out).__name__}")
    raise PluginError(f"corrector {cor.name!r}: correct() returned {what}; it must return "
                      "Correction(rate, flags), rate an array of shape (3,) in rad/s or None")


def _is_vec3(v) -> bool:
    """Whether ``v`` is a sample's vector as the pipeline reads it: a numeric array of shape (3,)."""
    return isinstance(v, np.ndarray) and v.shape == (3,) and v.dtype.kind in "fiu"


def _model_output_ok(out) -> bool:
    """Whether a sensor model's ``apply`` returned ``(Sample, flags)``: a Sample whose ``gyr`` is a
    vector of 3 and ``acc`` / ``mag`` one or None, and flags an int from 0 to 2**32 - 1."""
    if not isinstance(out, (tuple, list)) or isinstance(out, Sample) or len(out) != 2:
        return False
    sample, f = out
    return (isinstance(sample, Sample) and _flags_ok(f) and _is_vec3(sample.gyr)
            and (sample.acc is None or _is_vec3(sample.acc)) and (sample.mag is None or _is_vec3(sample.mag)))


def _flags_ok(f) -> bool:
    """Flag bits as a model returns them: an int (numpy's too, a bool's 0 / 1) from 0 to 2**32 - 1."""
    return isinstance(f, (int, np.integer, np.bool_)) and 0 <= int(f) <= 0xFFFFFFFF


def _bad_model_output(mod, out) -> None:
    """A sensor model's ``apply`` returned something else than ``(Sample, flags)`` (see
    :func:`_model_output_ok`): a PluginError naming it and what is wrong, as for a corrector
    (:func:`_bad_correction`). Python's or numpy's error named neither: "too many values to
    unpack" for a Sample alone, an IndexError for a gyr of shape (2,), an AttributeError for a
    list, a TypeError for flags None."""
    if isinstance(out, Sample):
        what = "a Sample alone, not (sample, flags)"
    elif not isinstance(out, (tuple, list)) or len(out) != 2:
        what = f"{type(out).__name__} {out!r:.60}"
    elif not isinstance(out[0], Sample):
        what = f"({type(out[0]).__name__}, ...): the first item is not a fusionkit.protocols.Sample"
    else:
        sample, f = out
        bad = [f"sample.{k} of type {type(v).__name__}" + (f", shape {v.shape}, dtype {v.dtype}"
                                                          if isinstance(v, np.ndarray) else "")
               for k, v in (("gyr", sample.gyr), ("acc", sample.acc), ("mag", sample.mag))
               if not _is_vec3(v) and (k == "gyr" or v is not None)]
        if not _flags_ok(f):
            bad.append(f"flags {f!r:.40} ({type(f).__name__})")
        what = "(sample, flags) with " + ", ".join(bad)
    raise PluginError(f"sensor model {mod.name!r}: apply() returned {what}; it must return (sample, flags): a "
                      "Sample whose gyr is an array of shape (3,) and acc / mag arrays of shape (3,) or None, and "
                      "flags an int of flag bits from 0 to 2**32 - 1 (0 for none)")


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
        self._configured = self.correctors  # as built; each run sets them to its body axes (for_body)
        self.detectors = [reg.make(d.name, "detector", d.params) for d in spec.detectors]
        self.models = [reg.make(m.name, "model", m.params) for m in spec.models]
        #: "auto": update() runs the compiled step when every plugin has a kernel; "reference":
        #: the readable one (the same numbers to 1e-9)
        self.update_backend = "auto"
        if spec.alignment.mode == "motion" and not any(d.flag & Flag.MOTION for d in self.detectors):
            raise ConfigError(
                "alignment mode 'motion' ends on a MOTION flag, but no detector sets it: add the "
                "'motion' detector or use mode 'fixed'"
            )
        modes = [c.mode for c in self.correctors if c.mode != "bias"]
        if "factor" in modes and any(m != "factor" for m in modes[modes.index("factor"):]):
            raise ConfigError("factor correctors compose their factors onto the estimate: they come after every "
                              "state and rate corrector (reorder the correctors)")
        self._restarts = any(c.restarts for c in self.correctors)
        _check_channel(self.correctors)
        read = {name for c in self.correctors for name in c.channel_reads()}
        for c in self.correctors:  # what of its channel quantities another corrector reads (it may skip the rest;
            # _check_channel has made sure every reader comes after its publisher)
            c.channel_read = tuple(name for name in c.channel_publishes() if name in read)
        for c in self.correctors:
            if c.state_layout and c.state_layout != self.estimator.state_layout:
                raise ConfigError(f"corrector {c.name!r} works on a {c.state_layout!r} estimator state, but estimator "
                                  f"{self.estimator.name!r} has layout {self.estimator.state_layout or 'private'!r}")
            if c.requires_flag and not any(d.flag & c.requires_flag for d in self.detectors):
                raise ConfigError(f"corrector {c.name!r} acts on {c.requires_flag.name} samples, but no detector "
                                  f"sets that flag: add one (e.g. 'rest' for REST)")
        self._stream: dict[str, Any] | None = None
        self._packed: tuple | None = None  # the compiled stream: (step, S, P, O, q, states, step_sample)
        self._fast_dt = 0.0  # update()'s fast path takes intervals up to this (0: not yet, see update)
        self.last_flags = 0

    def pipeline_config(self) -> PipelineConfig:
        """The composition this filter runs (presets override this)."""
        return self.config

    @property
    def requires_gnss(self) -> bool:  # (a preset may say so as a class attribute; a composition, by its correctors)
        """Whether a corrector of this composition reads the GNSS stream (``uses_gnss``): it then
        cannot run without one (a composed ``gst-gnss`` ran flagging every sample a GNSS gap, and was
        scored as a 6D filter, its track-angle heading "n/a")."""
        return any(getattr(c, "uses_gnss", False) for c in self.correctors)

    def _uses_mag(self) -> bool:
        """Whether the composition reads a magnetometer where the recording has one (its alignment's
        heading, or a magnetometer corrector): what :meth:`dimension` and the input checks ask."""
        return self.spec.alignment.heading == "magnetometer" or any(
            c.uses_mag and getattr(c.config, "use_mag", True) for c in self.correctors)

    def dimension(self, rec) -> str:
        return "9D" if self._uses_mag() and rec.mag is not None else "6D"

    # -- state -----------------------------------------------------------------------------
    def aligner(self) -> Aligner:
        """The alignment state machine (made once)."""
        if "_aligner" not in self.__dict__:
            self.__dict__["_aligner"] = Aligner(self.spec.alignment, self.spec.frame)
        return self.__dict__["_aligner"]

    def new_state(self, dt: float) -> dict[str, Any]:
        """A fresh run state for nominal sample interval ``dt``."""
        al = self.aligner().new_state(_STATE_SIZE)
        q0 = np.array(self.spec.alignment.initial_quat)
        al[_QPREV:_QPREV + 4] = q0
        return {
            "dt": float(dt),
            "x": self.estimator.initial_state(q0),
            "mod": [m.initial_state(dt) for m in self.models],
            "det": [d.initial_state(dt) for d in self.detectors],
            "cor": [c.initial_state(dt, self.spec.frame) for c in self.correctors],
            "align": al,
        }

    @property
    def state(self) -> dict[str, Any] | None:
        """A deep copy of the streaming state (None before the first ``update``)."""
        self._sync_stream()
        return copy.deepcopy(self._stream)

    def set_state(self, state: dict[str, Any]) -> None:
        """Restore a state from :attr:`state` or ``Result.diagnostics["state"]``."""
        self._stream = self._check_state(copy.deepcopy(state))
        self._packed = None

    def _check_state(self, st: dict[str, Any]) -> dict[str, Any]:
        keys = {"dt", "x", "mod", "det", "cor", "align"}
        if not isinstance(st, dict) or set(st) != keys:
            raise InputError(f"state must be a dict with keys {sorted(keys)}")
        ref = self.new_state(st["dt"])
        for k in ("x", "align"):
            if np.shape(st[k]) != ref[k].shape:
                raise InputError(f"state[{k!r}] has shape {np.shape(st[k])}, expected {ref[k].shape}")
        for k in ("mod", "det", "cor"):
            if len(st[k]) != len(ref[k]) or any(np.shape(a) != b.shape for a, b in zip(st[k], ref[k])):
                raise InputError(f"state[{k!r}] does not belong to this pipeline (its plugins' states differ: "
                                 "saved by another configuration, or by an older fusionkit?)")
        return st

    def reset(self) -> None:
        self._stream = None
        self._packed = None
        self._fast_dt = 0.0

    # -- the readable reference path -------------------------------------------------------
    def _step(self, st, gyr, acc, mag, dt, has_mag, gnss=None) -> tuple[np.ndarray, int, int]:
        """Process one sample; returns (quat body->frame, flags, first detector's criteria)."""
        cfg, al = self.spec, st["align"]
        gyr_ok, acc_ok, mag_ok, flags = sample_validity(gyr, acc, mag if has_mag else None, cfg.gyr_range,
                                                        cfg.acc_range)
        if self.models:  # 1b. sensor models; validity judged again on what they give
            # gyr a copy of its own, as before: a model correcting it in place changes nobody's array (acc and
            # mag are the recording's rows, read-only)
            sample = Sample(np.array(gyr, dtype=float), acc if acc_ok else None, mag if mag_ok else None, dt, gnss)
            mflags = 0
            try:  # (the arrays are read-only views: a plugin that writes into them is named, see wrote_input)
                for i, mod in enumerate(self.models):
                    out = mod.apply(st["mod"][i], sample, al[_QPREV:_QPREV + 4].copy())
                    if not _model_output_ok(out):
                        _bad_model_output(mod, out)  # (a plugin's mistake, named: Python's or numpy's error was not)
                    sample, f = out[0], int(out[1])
                    mflags |= f
            except ValueError as exc:
                wrote_input("sensor model", mod, exc)
                raise
            gyr = sample.gyr
            acc = sample.acc if sample.acc is not None else np.zeros(3)
            mag = sample.mag if sample.mag is not None else np.zeros(3)
            gyr_ok, acc_ok, mag_ok, flags = sample_validity(gyr, acc, mag if has_mag else None, cfg.gyr_range,
                                                            cfg.acc_range)
            flags |= mflags
        if not gyr_ok:  # every plugin sees an invalid gyro sample as non-finite (not as a huge rate)
            gyr = np.full(3, np.nan)
        sample = Sample(gyr, acc if acc_ok else None, mag if mag_ok else None, dt, gnss)

        # 2. detectors
        crit0 = 0
        try:
            for i, det in enumerate(self.detectors):
                if gyr_ok and acc_ok:
                    bits = checked_bits(det, det.step(st["det"][i], sample))  # (a plugin's mistake, named)
                    if i == 0:
                        crit0 = bits
                    if bits:
                        flags |= det.flag
        except ValueError as exc:
            wrote_input("detector", det, exc)
            raise
        # 3. alignment
        status, q = self.aligner().step(al, gyr, acc, mag, gyr_ok, acc_ok, mag_ok, bool(flags & Flag.MOTION), dt)
        if status in (ALIGNED_NOW, ALIGNED_BEFORE):
            st["x"] = self.estimator.initial_state(q)
        if status in (ALIGNING, ALIGNED_NOW):
            al[_QPREV:_QPREV + 4] = q
            return q, flags | Flag.ALIGNING, crit0
        al[SEEN] += 1.0
        if flags & Flag.MAG_DISTURBED:  # withheld from every corrector
            sample = sample._replace(mag=None)
        if flags & Flag.ACC_REJECTED:
            sample = sample._replace(acc=None)
        bias = al[BIAS:BIAS + 3]  # a view: bias and factor correctors update it in place
        chan = {"channel": al[_CHAN:_CHAN + CHANNEL_SIZE]}  # a view: the correctors' channel
        # 4. bias correctors (the gyroscope as measured)
        try:
            for i, cor in enumerate(self.correctors):
                if cor.mode == "bias":
                    flags |= cor.update_bias(st["cor"][i], bias, sample, flags, **(chan if cor.uses_channel else {}))
        except ValueError as exc:
            wrote_input("corrector", cor, exc)
            raise
        # 5. propagation
        w = gyr - bias + al[_RCORR:_RCORR + 3]
        if gyr_ok:
            self.estimator.propagate(st["x"], w, dt)
        # 6. correctors (they see the rate the estimator integrated: the alignment's bias removed)
        q = None
        if self.correctors:
            rate = np.zeros(3)
            measured, sample = sample, sample._replace(gyr=gyr - bias)  # (a temporary of its own: writable)
            try:
                for i, cor in enumerate(self.correctors):
                    if cor.mode == "factor":
                        q, f = cor.compose(st["cor"][i], self.estimator.quat(st["x"]) if q is None else q, measured,
                                           bias, w, flags, **(chan if cor.uses_channel else {}))
                        flags |= f
                    elif cor.mode != "bias":
                        out = cor.correct(self.estimator, st["x"], st["cor"][i], sample, flags,
                                          **(chan if cor.uses_channel else {}))
                        if type(out) is not Correction or (out.rate is not None and np.shape(out.rate) != (3,)):
                            _bad_correction(cor, out)  # (a plugin's mistake, named: numpy's broadcast error was not)
                        flags |= out.flags
                        if out.rate is not None:
                            rate += out.rate
            except ValueError as exc:
                wrote_input("corrector", cor, exc)
                raise
            al[_RCORR:_RCORR + 3] = rate
        if q is None:
            q = self.estimator.quat(st["x"])
        al[_QPREV:_QPREV + 4] = q
        return q, flags, crit0

    # -- the compiled path -----------------------------------------------------------------
    def _kernels(self):
        """The plugins' kernels ``(estimator, models, detectors, correctors)``, or None when one has
        none (the reference path runs)."""
        ek = self.estimator.kernel()
        mks = [m.kernel() for m in self.models]
        dks = [d.kernel() for d in self.detectors]
        cks = [c.kernel(self.estimator) for c in self.correctors]
        if ek is None or any(k is None for k in mks + dks + cks):
            return None
        for c, k in zip(self.correctors, cks):
            if k.mode != c.mode:
                raise ConfigError(f"corrector {c.name!r}: its kernel's mode {k.mode!r} is not its mode {c.mode!r}")
        return ek, mks, dks, cks

    def _loop_params(self) -> np.ndarray:
        pp = np.zeros(3)
        pp[0] = self.spec.gyr_range if self.spec.gyr_range is not None else math.inf
        pp[1] = self.spec.acc_range if self.spec.acc_range is not None else math.inf
        pp[2] = float(Flag.MOTION)
        return pp

    def _compiled(self, st, kernels, dets):
        """The compiled module for this composition with detectors ``dets`` (indices), and
        ``(S, P, O, states)``: the run state ``st`` and every parameter vector packed for it."""
        ek, mks, dks, cks = kernels
        specs = [_loopgen.KernelSpec(k.apply, "model", static=tuple(k.static)) for k in mks]
        specs += [_loopgen.KernelSpec(dks[i].step, "det", dks[i].gnss, int(self.detectors[i].flag), i == 0)
                  for i in dets]
        specs += [_loopgen.KernelSpec(k.correct, k.mode, k.gnss, on_x=bool(c.state_layout), channel=c.uses_channel,
                                    static=tuple(k.static))
                  for c, k in zip(self.correctors, cks)]
        lay = _loopgen.Layout((ek.propagate, ek.to_quat, ek.from_quat), bool(ek.unit_quat), tuple(specs),
                              _RCORR, _QPREV, _CHAN)
        states = [st["x"], *st["mod"], *[st["det"][i] for i in dets], *st["cor"], st["align"]]
        params = [ek.params, *[_loopgen.static_params(k.params, tuple(k.static)) for k in mks],
                  *[dks[i].params for i in dets], *[_loopgen.static_params(k.params, tuple(k.static)) for k in cks],
                  self.aligner().params(), self._loop_params()]
        S, P, O = _loopgen.pack(states, params)
        return _loopgen.get_compiled(lay), S, P, O, states

    def _run_compiled(self, st, kernels, gyr, acc, mag, dt, has_mag, out_q, out_f, out_c, restart, cuts, gn,
                      bar, probe=None) -> None:
        """The compiled loop over the whole recording: the state and parameters packed once, one
        call per progress chunk and per stretch between restarts (``cuts``, where ``restart`` is
        set: the state is unpacked for :meth:`_restart` and packed again), unpacked at the end.
        ``probe``: ``(ends, read)``, after the sample before each end the state is unpacked and
        ``read(st)`` called (the loop's packed state is left as it is)."""
        # a magnetometer-only detector cannot fire without one, and its reference step leaves its state alone
        dets = [i for i, d in enumerate(self.detectors) if has_mag or not d.needs_mag]
        mod, S, P, O, states = self._compiled(st, kernels, dets)
        gn = gn if gn is not None else NO_GNSS[None, :]
        n = out_q.shape[0]
        ends, read = probe if probe is not None else ((), None)
        cuts = sorted(set(cuts) | set(ends))
        ends = set(ends)
        for start in range(0, n, _CHUNK):
            stop = min(n, start + _CHUNK)
            bounds = [start, *[c for c in cuts if start < c < stop], stop]
            for s, e in zip(bounds[:-1], bounds[1:]):
                if restart[s]:
                    _loopgen.unpack(S, O, states)
                    self._restart(st)
                    _loopgen.repack(S, O, states)
                mod.loop(gyr, acc, mag, dt, has_mag, S, P, O, out_q, out_f, out_c, s, e, gn)
                if e in ends:
                    _loopgen.unpack(S, O, states)
                    read(st)
            if bar is not None:
                bar.update(stop - start)
        _loopgen.unpack(S, O, states)

    def _sync_stream(self) -> None:
        """Copy the compiled stream's packed state back into the state dict."""
        if self._packed and self._stream is not None:
            _loopgen.unpack(self._packed[1], self._packed[3], self._packed[5])

    # -- public ----------------------------------------------------------------------------
    def run(self, rec: Recording, *, backend: str = "auto", progress: bool | None = None,
            state: dict[str, Any] | None = None, bias_at=None) -> Result:
        """Process ``rec``; start from ``state`` (``Result.diagnostics["state"]`` of an earlier
        run) to continue a split recording. ``bias_at``: increasing sample indices after which the
        gyro bias the filter uses is read, returned as ``diagnostics["bias_at"]`` ``(len, 3)`` (what
        runs split after those samples would report as ``diagnostics["bias"]``, in one run) and the
        inclination's model there as ``diagnostics["inclination_model_at"]`` ``(len, 10)`` (a corrector's
        ``inclination_model(state)``, e.g. ``inertial-tilt``'s; None where no corrector has one)."""
        if not isinstance(rec, Recording):
            raise InputError(f"rec must be a fusionkit.Recording, got {type(rec).__name__}")
        if self.requires_gnss and rec.gnss is None:
            reads = [c.name for c in self.correctors if getattr(c, "uses_gnss", False)]
            raise InputError(f"{self.name} needs a GNSS stream (Recording(gnss=...)): its {', '.join(reads)} "
                             "corrector reads it")
        n = len(rec)
        probe_ends = _probe_ends(bias_at, n)
        biases: list[np.ndarray] = []
        models: list[np.ndarray | None] = []  # the inclination's model at the same samples (:meth:`_inclination_model`)
        self._set_body(self.body_axes(rec))
        # the sensors it reads: a magnetometer it does not use (a 6D or gyro-only filter) is not judged, nor
        # a non-finite sample of it refused (nan_policy="raise" named mag[k] of a sensor it never read)
        inputs = {"gyr": rec.gyr, "acc": rec.acc, "mag": rec.mag if self._uses_mag() else None}
        if self.models:  # a sensor model may change a sample before it is judged: the input first
            check_finite_all(inputs, self.spec.nan_policy)
        has_mag = rec.mag is not None
        if self.spec.alignment.heading == "magnetometer" and not has_mag:
            raise InputError("alignment heading='magnetometer' needs mag in the recording")
        kernels = self._kernels()
        if kernels is not None and len(self.correctors) > MAX_COMPILED_CORRECTORS and backend != "reference":
            why = (f"{len(self.correctors)} correctors are more than the compiled loop chains "
                   f"({MAX_COMPILED_CORRECTORS}: its compile time grows with the count)")
            if backend == "numba":
                raise ConfigError(f"backend='numba': {why}; use backend='reference' or 'auto'")
            warnings.warn(f"{self.name}: {why}; running the reference path (same numbers, slower)", stacklevel=2)
            kernels = None
        used = resolve_backend(backend, kernels is not None)
        st = self._check_state(copy.deepcopy(state)) if state is not None else self.new_state(rec.nominal_dt)
        # without a magnetometer the compiled loop reads one row of zeros (never judged valid), the
        # reference a read-only view of it per sample
        mag_row = rec.mag if has_mag else np.zeros((1, 3))
        mag = rec.mag if has_mag else np.broadcast_to(mag_row, (n, 3))
        intervals, first_known = rec.run_intervals(continued=state is not None)
        gyr, dt, gaps = hold_gaps(rec.gyr, intervals, rec.nominal_dt, self.spec.max_gap, first_known)
        # the GNSS rows: the reference's samples carry them; compiled, only kernels that take them
        want = used != "numba" or any(k.gnss for k in kernels[2] + kernels[3])
        gn = gnss_sample_rows(rec) if rec.gnss is not None and want else None
        out_q = np.empty((n, 4))
        out_f = np.zeros(n, dtype=np.uint32)
        out_c = np.zeros(n, dtype=np.uint32)
        bar = _progress(n, progress, f"{self.name}")
        restart = (gaps | _after_saturation(rec.gyr, self.spec.gyr_range)) if self._restarts else np.zeros(n, bool)
        cuts = np.flatnonzero(restart).tolist()
        if used == "numba":
            probe = (probe_ends, lambda s: (biases.append(s["align"][BIAS:BIAS + 3].copy()),
                                            models.append(self._inclination_model(s)))) if probe_ends else None
            self._run_compiled(st, kernels, gyr, rec.acc, mag_row, dt, has_mag, out_q, out_f, out_c, restart, cuts, gn,
                               bar, probe)
        else:  # the plugins get read-only rows of the recording (one that edits its input is named, not obeyed)
            gyr, acc, mag = read_only(gyr), read_only(rec.acc), read_only(mag)
            for start in range(0, n, _CHUNK):
                stop = min(n, start + _CHUNK)
                for k in range(start, stop):
                    if restart[k]:
                        self._restart(st)
                    q, f, c = self._step(st, gyr[k], acc[k], mag[k], dt[k], has_mag, None if gn is None else gn[k])
                    out_q[k], out_f[k], out_c[k] = q, f, c
                    if probe_ends and len(biases) < len(probe_ends) and k + 1 == probe_ends[len(biases)]:
                        biases.append(st["align"][BIAS:BIAS + 3].copy())
                        models.append(self._inclination_model(st))
                if bar is not None:
                    bar.update(stop - start)
        if bar is not None:
            bar.close()
        if not self.models:  # a non-finite sample is flagged invalid: nan_policy="raise" needs no scan before
            check_finite_flagged(inputs, self.spec.nan_policy, out_f, _INVALID)
        diag = self._diagnostics(st, out_f, out_c, used)
        if bias_at is not None:
            diag["bias_at"] = np.array(biases).reshape(len(probe_ends), 3)
            diag["inclination_model_at"] = None if not models or models[0] is None else np.array(models)
        report_disturbed(st["align"], self.spec.alignment.duration)
        mark_gaps(out_f, gaps, rec.gyr, diag, gap_threshold(rec.nominal_dt, self.spec.max_gap))
        diag["aiding"] = self.aiding(rec)
        self._check_finite_output(out_q)
        return Result(out_q, out_f, self.spec.frame, diag)

    def _check_finite_output(self, q: np.ndarray) -> None:
        """A non-finite orientation is no answer: the built-in plugins never make one (a non-finite
        sample is flagged and the state held), so one comes from a plugin that returned a
        non-finite correction or state; it was passed on silently to every later sample. One sum
        decides (a quaternion's entries are bounded by 1: the sum is finite exactly when they all are),
        with no mask the size of the output; :func:`~fusionkit.validation.finite_rows` finds the first."""
        if math.isfinite(float(q.sum())):
            return
        first = int(np.argmin(finite_rows(q)))
        names = [self.spec.estimator.name] + [c.name for c in self.spec.correctors]
        raise PluginError(f"{self.name}: the orientation is not finite from sample {first} on: a plugin of this "
                          f"composition ({', '.join(names)}) returned a non-finite correction or state there "
                          "(fusionkit.testing.check_plugin(NAME) on each finds which)")

    def _inclination_model(self, st) -> np.ndarray | None:
        """What the first corrector with an ``inclination_model(state)`` (``inertial-tilt``'s: the
        gyro's rate error E, the E w the bias carries, the time constant) holds in ``st``, else None."""
        for cor, s in zip(self.correctors, st["cor"]):
            r = getattr(cor, "inclination_model", None)
            if r is not None:
                return r(s)
        return None

    def _restart(self, st) -> None:
        """Before a sample after a gap or a saturated gyro: the correctors that declare
        ``restarts`` forget what became stale."""
        for i, c in enumerate(self.correctors):
            if c.restarts:
                c.restart(st["cor"][i])

    def _set_body(self, body: str | None) -> None:
        """The correctors for sensors in ``body`` axes (a corrector with a forward axis gets
        them; the others are unchanged)."""
        cache = self.__dict__.setdefault("_by_body", {})
        if body not in cache:
            cache[body] = [c.for_body(body) for c in self._configured]
        self.correctors = cache[body]

    def _diagnostics(self, st, flags, crit, backend) -> dict[str, Any]:
        al = st["align"]
        d: dict[str, Any] = {"backend": backend, "filter": self.name, "config": self.config.model_dump()}
        d["bias"] = al[BIAS:BIAS + 3].copy()
        d["alignment_end_index"] = None if al[END] < 0 else int(al[END])
        d["alignment_disturbed"] = bool(al[DISTURBED])
        if self.detectors:
            fired = crit != 0
            first = int(fired.argmax())  # the first True, found without listing them all
            d["criteria"] = crit
            d["criteria_names"] = self.detectors[0].criteria_names
            d["onset_index"] = first if fired[first] else None
        if self.models:  # (a pipeline without models has no "models" key, as one without detectors no "criteria")
            d["models"] = self.model_reports(st)
        d["state"] = copy.deepcopy(st)
        return d

    def model_reports(self, state: dict[str, Any] | None = None) -> dict[str, dict[str, Any]]:
        """Each sensor model's :meth:`~fusionkit.protocols.SensorModel.report` of ``state`` (a run
        state: ``Result.diagnostics["state"]``, or by default the stream's after ``update()``), by the
        model's name, in the pipeline's order (a name that repeats gets ``#2``, ``#3``, ...); what
        ``run()`` puts in ``diagnostics["models"]``. The estimates by name and in physical units,
        where the state holds raw arrays in each model's private layout. Empty without models."""
        if state is None:
            state = self.state
            if state is None:
                raise InputError("model_reports() without a state reads the stream's: call update() first, or pass "
                                 "Result.diagnostics['state']")
        mods = state.get("mod") if isinstance(state, dict) else None
        if mods is None or len(mods) != len(self.models):  # (a zip of another pipeline's state reported fewer)
            raise InputError(f"state must be a run state of this pipeline (Result.diagnostics['state']), with one "
                             f"state per sensor model ({len(self.models)})")
        out: dict[str, dict[str, Any]] = {}
        for mod, s in zip(self.models, mods):
            rep = mod.report(s)
            if not isinstance(rep, dict):  # (a plugin's mistake, named)
                raise PluginError(f"sensor model {mod.name!r}: report() returned {type(rep).__name__}; it must "
                                  "return a dict (name -> value; {} for nothing to report)")
            key, k = mod.name, 1
            while key in out:
                k += 1
                key = f"{mod.name}#{k}"
            out[key] = rep
        return out

    def update(self, gyr, acc, mag=None, dt: float | None = None, gnss=None) -> np.ndarray:
        """Process one sample of a stream (``dt`` in s is required; ``gnss`` the latest epoch's
        row, see :class:`~fusionkit.protocols.Sample`); the same numbers as :meth:`run`. It runs
        the composition's compiled one-sample step when every plugin has a kernel (see
        ``update_backend``), else the reference. ``last_flags`` holds the sample's flags."""
        pk = self._packed if self._stream is not None and self.update_backend == "auto" else None
        if pk and gnss is None and type(dt) is float and 0.0 < dt <= self._fast_dt:
            # the fast path of the compiled stream (the units checked, no gap): plain float64
            # vectors, all finite
            sample = finite_sample(gyr, acc, mag)
            if sample is not None:
                g, a, m = sample
                _, S, P, O, q, _, step_sample = pk
                self.last_flags = step_sample(g[0], g[1], g[2], a[0], a[1], a[2], m[0], m[1], m[2], dt,
                                              mag is not None, S, P, O, q)
                return q.copy()
        return self._update_checked(gyr, acc, mag, dt, gnss)

    def _update_checked(self, gyr, acc, mag, dt, gnss) -> np.ndarray:
        """:meth:`update` with every check, on either path."""
        if dt is None:
            raise InputError("update() needs dt, the sample interval in s")
        dt = check_dt(dt, bounded=self._stream is None)
        g = as_vector("gyr", gyr)
        a = as_vector("acc", acc)
        has_mag = mag is not None
        m = as_vector("mag", mag) if has_mag else np.zeros(3)
        # a magnetometer it does not read (dimension 6D with one) is not refused for a non-finite sample
        check_sample_finite(self.spec.nan_policy, gyr=g, acc=a, mag=m if has_mag and self._uses_mag() else None)
        self.check_stream_units(g, a)
        if self._stream is None:
            self._stream = self.new_state(dt)
        g, dt, gap = stream_gap(g, dt, self._stream["dt"], self.spec.max_gap)
        self._set_body(self.config.body)  # no recording: the config's body axes
        if self._restarts:
            saturated = self.spec.gyr_range is not None and bool(np.max(np.abs(g)) >= self.spec.gyr_range)
            if gap or (self.__dict__.get("_saturated", False) and not saturated):
                self._sync_stream()
                self._restart(self._stream)
                self._packed = None  # packed again from the restarted state
            self._saturated = saturated
        pk = self._stream_kernel()
        if pk is not None:
            step, S, P, O, q, _, step_sample = pk
            g, a, m = g.tolist(), a.tolist(), m.tolist()
            if gnss is None:  # the fast path's function: one compile serves both
                f = step_sample(g[0], g[1], g[2], a[0], a[1], a[2], m[0], m[1], m[2], dt, has_mag, S, P, O, q)
            else:
                n = as_vector("gnss", gnss, width=6, allow_bool=True).tolist()
                f, _ = step(g[0], g[1], g[2], a[0], a[1], a[2], m[0], m[1], m[2], dt, has_mag, S, P, O, q, *n)
            self.last_flags = gap_flags(f, gap)
            if len(self.__dict__.get("_unit_samples", ())) >= self.UNIT_CHECK_SAMPLES and not (
                    self._restarts and self.spec.gyr_range is not None):  # the units are checked, no range to watch:
                self._fast_dt = gap_threshold(self._stream["dt"], self.spec.max_gap)  # the fast path may run
            return q.copy()
        gn = None if gnss is None else as_vector("gnss", gnss, width=6, allow_bool=True)
        # read-only: as_vector may return the caller's own arrays, which a plugin must not change
        q, f, _ = self._step(self._stream, read_only(g), read_only(a), read_only(m), dt, has_mag, gn)
        self.last_flags = gap_flags(f, gap)
        if not (math.isfinite(q[0]) and math.isfinite(q[1]) and math.isfinite(q[2]) and math.isfinite(q[3])):
            self._check_finite_output(q[None])  # (the stream's sample, as run() names it: sample 0 of this call)
        return q

    def _stream_kernel(self):
        """The compiled stream ``(step, S, P, O, q, states)`` (built on first use), or None for the
        reference path (``update_backend="reference"``, or a plugin without a kernel)."""
        if self.update_backend == "reference" or not HAVE_NUMBA:
            if self._packed:
                self._sync_stream()
            self._packed = None
            return None
        if self._packed is None:
            kernels = self._kernels()
            if kernels is None:
                self._packed = False
            else:  # every detector: whether a sample has a magnetometer is known per call only
                mod, S, P, O, states = self._compiled(self._stream, kernels, list(range(len(self.detectors))))
                S = np.concatenate([S, np.zeros(_loopgen.STEP_WORK)])  # the step's one-sample arrays, reused
                self._packed = (mod.step, S, P, O, np.empty(4), states, mod.step_sample)
        return self._packed or None


def _check_channel(correctors) -> None:
    """A ConfigError where a corrector reads a :class:`Channel` quantity that only a later one
    publishes (it would read the previous sample's value), or two publish one that some corrector
    reads (which one it reads would depend on the order). What a corrector publishes and reads
    with its configuration counts (:meth:`Corrector.channel_publishes`, :meth:`Corrector.channel_reads`),
    in the order they run in a sample: the bias correctors before the propagation, wherever they are
    listed, then the others as listed."""
    correctors = sorted(correctors, key=lambda c: c.mode != "bias")  # (stable: the list's order within)
    read = {name: c.name for c in reversed(correctors) for name in c.channel_reads()}  # the first reader
    by = {}
    for i, c in enumerate(correctors):
        for name in c.channel_publishes():
            if name in by and name in read:
                raise ConfigError(f"correctors {correctors[by[name]].name!r} and {c.name!r} both publish "
                                  f"{Channel(name).name}, which {read[name]!r} reads: keep one")
            by.setdefault(name, i)
    for i, c in enumerate(correctors):
        for name in c.channel_reads():
            if by.get(name, -1) >= i:
                later = " (a bias corrector runs before the others)" if c.mode == "bias" else ""
                raise ConfigError(f"corrector {c.name!r} reads {Channel(name).name}, which "
                                  f"{correctors[by[name]].name!r} publishes after it{later}: put the publisher first")


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


def _probe_ends(bias_at, n: int) -> list[int]:
    """``bias_at`` (sample indices, increasing, in ``[0, n)``) as the loop's stretch ends (index + 1)."""
    if bias_at is None:
        return []
    k = np.asarray(bias_at)
    if k.ndim != 1 or (k.size and (not np.issubdtype(k.dtype, np.integer) or k[0] < 0 or k[-1] >= n
                                   or np.any(np.diff(k) <= 0))):
        raise InputError(f"bias_at must be increasing sample indices in [0, {n}), got {bias_at!r:.80}")
    return [int(i) + 1 for i in k]
