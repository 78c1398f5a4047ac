"""The plugin protocols: :class:`Estimator`, :class:`Corrector`, :class:`Detector`, :class:`Filter`.

A plugin class declares ``name`` (unique within its kind), ``kind``, its ``Config`` (a
:class:`~fusionkit.config.PluginConfig`), ``source`` (the document it implements) and a one-line
``summary``, and implements its protocol's methods. Plugins are registered through entry points
(group ``fusionkit.<kind>s``, see :mod:`fusionkit.registry`).

State is a flat ``float64`` array owned by the caller (the pipeline): plugins are stateless
beyond their config, so a state can be copied, split and restored, and the same array feeds the
numba kernels. ``kernel()`` returns the plugin's compiled counterparts, or None when it has none
(the pipeline then runs the readable reference path).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Callable, ClassVar, Literal, NamedTuple

import numpy as np

from .config import PluginConfig, build_config
from .conventions import resolve_body
from .types import Channel, Flag

__all__ = [
    "Plugin",
    "Estimator",
    "Corrector",
    "FactorCorrector",
    "BiasCorrector",
    "Detector",
    "Filter",
    "SensorModel",
    "Sample",
    "Correction",
    "EstimatorKernel",
    "DetectorKernel",
    "CorrectorKernel",
    "SensorModelKernel",
    "DetectionResult",
    "KINDS",
    "KIND_BASES",
    "plugin_class_problem",
]

KINDS = ("filter", "estimator", "corrector", "detector", "model")


class Plugin:
    """Common base: a validated, frozen ``config`` built from a model, a mapping or keywords."""

    name: ClassVar[str] = ""
    kind: ClassVar[str] = ""
    Config: ClassVar[type[PluginConfig]] = PluginConfig
    source: ClassVar[str] = ""
    summary: ClassVar[str] = ""

    def __init__(self, config: PluginConfig | Mapping[str, Any] | None = None, **params: Any) -> None:
        self.config = build_config(type(self).Config, config, params, where=f"{self.kind} {self.name!r}")

    def __repr__(self) -> str:
        changed = {k: v for k, v in self.config.model_dump().items() if v != type(self).Config.model_fields[k].default}
        args = ", ".join(f"{k}={v!r}" for k, v in changed.items())
        return f"{type(self).__name__}({args})"


class Sample(NamedTuple):
    """One input sample as the reference paths see it (``mag`` is None when absent or invalid;
    correctors get ``gyr`` with the alignment's bias removed;
    ``gnss`` is the latest GNSS epoch as a row ``vn, ve, valid, age, new, t_epoch``, see
    :func:`fusionkit.detectors.gnss_gap.gnss_sample_rows`, or None without a GNSS stream).

    A plugin must not change the arrays it is given: they are the recording's rows (or the
    arrays passed to ``update()``), handed over as read-only views, so writing into one raises a
    :class:`~fusionkit.errors.PluginError` naming the plugin (it changed the user's recording
    silently); a sensor model returns its corrected sample as new arrays (``sample._replace``)."""

    gyr: np.ndarray
    acc: np.ndarray | None
    mag: np.ndarray | None
    dt: float
    gnss: np.ndarray | None = None


class EstimatorKernel(NamedTuple):
    """numba counterparts of an estimator: ``propagate(x, w0, w1, w2, dt, params)``,
    ``to_quat(x, out4)``, ``from_quat(q4, x)``, and the parameter vector. ``unit_quat``: the
    state *is* the unit quaternion after every propagation (a compiled pipeline then hands it to a
    state-mode corrector directly, without the round trip through ``to_quat`` / ``from_quat``, and
    takes it as the output as it is)."""

    propagate: Callable
    to_quat: Callable
    from_quat: Callable
    params: np.ndarray
    unit_quat: bool = False


class DetectorKernel(NamedTuple):
    """numba counterpart of a detector: ``step(s, g0, g1, g2, a0, a1, a2, m0, m1, m2, dt, params)
    -> int`` (the criteria bitmask), and the parameter vector. ``gnss=True``: the step takes the
    sample's GNSS row as six more arguments, ``..., params, vn, ve, valid, age, new, t_epoch``
    (:data:`Sample.gnss`'s fields; ``nan, nan, 0, inf, 0, nan`` without a GNSS stream)."""

    step: Callable
    params: np.ndarray
    gnss: bool = False


class CorrectorKernel(NamedTuple):
    """numba counterpart of a corrector.

    ``mode == "state"``: ``correct(x, q, s, g0, g1, g2, a0, a1, a2, m0, m1, m2, acc_ok, mag_ok, dt,
    params) -> int``. ``x`` is the estimator's state, ``q`` its quaternion (``to_quat(x)``), ``s``
    the corrector's state; it writes the corrected quaternion into ``q`` and returns the flag bits,
    or -1 when it left the estimator alone (the pipeline then does not write ``q`` back with
    ``from_quat``).

    ``mode == "rate"``: ``correct(q, s, g0, g1, g2, a0, a1, a2, m0, m1, m2, acc_ok, mag_ok, flags,
    dt, params, rate) -> int``: ``q`` is the estimate's quaternion (read only), ``flags`` the
    sample's flags so far; it *adds* its correction rate into ``rate`` (summed with the other rate
    correctors, fed into the next propagation) and returns its flag bits.

    ``mode == "factor"``: ``correct(q, s, b, g0, g1, g2, h0, h1, h2, h3, a0, a1, a2, m0, m1, m2,
    acc_ok, mag_ok, flags, dt, params) -> int``: ``q`` is the output composed so far (the
    estimator's quaternion with the factors of the factor correctors before it), which it
    overwrites with its own factor composed in; ``b`` is the pipeline's gyro bias (read and write);
    ``g`` the gyroscope as measured (NaN when invalid); ``h = exp(-w dt / 2)`` the way back from the
    end of the step to its middle (``w`` the rate the estimator integrated; NaN without a valid
    gyro sample), computed once per sample for every factor corrector; it returns its flag bits.

    ``mode == "bias"``: ``correct(s, b, g0, g1, g2, a0, a1, a2, m0, m1, m2, acc_ok, mag_ok, flags, dt,
    params) -> int``, run before the propagation: it updates the pipeline's gyro bias ``b`` (``g``
    as measured) and returns its flag bits.

    A corrector with a ``state_layout`` (see :class:`Corrector`) corrects the estimator's state
    ``x`` itself, in place: the pipeline then passes ``x`` as ``q`` too and does no
    ``to_quat`` / ``from_quat`` round trip around it (the return value is only flag bits).

    In both, ``g`` is the gyroscope with the alignment's bias removed (as in the reference's
    ``sample.gyr``); ``acc_ok`` / ``mag_ok`` are False where the reference's sample has None.
    ``gnss=True``: ``correct`` takes the sample's GNSS row as six more arguments at the end,
    ``vn, ve, valid, age, new, t_epoch`` (as :class:`DetectorKernel`).

    A corrector that publishes or reads a :class:`~fusionkit.types.Channel` quantity
    (:attr:`Corrector.uses_channel`) takes the channel ``ch`` (``CHANNEL_SIZE`` numbers, indexed by
    the names; read and write) right after ``params``, before any GNSS row.

    ``static``: the kernel's compile-time options (Python bools), arguments after all the others.
    The loop users run (every kernel inlined) passes them as literals, so where they select a
    branch (``if soft_iron:``) it is compiled without the branches they rule out (numba types and
    lowers none of that code). A loop that calls its kernels (the test suite's) reads them from the
    end of the kernel's parameter vector, so one compiled loop and kernel serve every value. A call
    takes at most 30 arguments in all (``fusionkit._loopgen.MAX_CALL_ARGS``)."""

    correct: Callable
    params: np.ndarray
    mode: str = "state"
    gnss: bool = False
    static: tuple = ()


class SensorModelKernel(NamedTuple):
    """numba counterpart of a sensor model: ``apply(s, v, gyr_ok, acc_ok, mag_ok, q, dt, params) ->
    int``. ``v`` holds the sample ``g0, g1, g2, a0, a1, a2, m0, m1, m2`` (the magnetometer zeros
    without one) and is corrected in place; ``q`` is the pipeline's previous output quaternion
    (read only); it returns flag bits (0 for none). ``static``: compile-time options passed after
    ``params`` (as :class:`CorrectorKernel`'s)."""

    apply: Callable
    params: np.ndarray
    static: tuple = ()


class Correction(NamedTuple):
    """What a corrector returns for one sample: a correction rate (rad/s, body frame, added to the
    gyroscope on the next propagation) for ``mode == "rate"`` correctors, None for
    ``mode == "state"`` ones (they changed the estimator state in place), and flag bits."""

    rate: np.ndarray | None
    flags: int = 0


class Estimator(Plugin, ABC):
    """Propagates orientation from gyroscope rates; owns the orientation state."""

    kind: ClassVar[str] = "estimator"
    #: the name of the state array's layout (e.g. "dcm"), for correctors that work on the state
    #: itself (:attr:`Corrector.state_layout`); "" for a private layout
    state_layout: ClassVar[str] = ""

    @abstractmethod
    def initial_state(self, quat: np.ndarray) -> np.ndarray:
        """A fresh state array holding the body->earth orientation ``quat``."""

    @abstractmethod
    def propagate(self, state: np.ndarray, gyr: np.ndarray, dt: float) -> None:
        """Advance ``state`` in place by the body rate ``gyr`` (rad/s, bias removed) over ``dt`` s."""

    @abstractmethod
    def quat(self, state: np.ndarray) -> np.ndarray:
        """The orientation of ``state`` as a unit quaternion ``[w, x, y, z]`` body->earth."""

    def set_quat(self, state: np.ndarray, quat: np.ndarray) -> None:
        """Overwrite the orientation in ``state`` (used by state-updating correctors)."""
        state[:] = self.initial_state(quat)

    def kernel(self) -> EstimatorKernel | None:
        return None


class Corrector(Plugin, ABC):
    """Pulls the estimate towards what an aiding sensor says.

    ``mode = "rate"``: returns a correction rate fed into the next propagation (Mahony/GST
    style). ``mode = "state"``: updates the estimator state directly (gradient step, DCM column
    replacement) and returns ``Correction(None, flags)``. ``mode = "factor"``: keeps its own
    correction as a factor of the output, which the estimator never sees (``recommended``'s
    ``q = Rz(delta) (x) q_tilt (x) q_gyr``): :meth:`compose` instead of :meth:`correct`.
    ``mode = "bias"``: updates the pipeline's gyro bias before the propagation:
    :meth:`update_bias` instead of :meth:`correct`.
    """

    kind: ClassVar[str] = "corrector"
    mode: ClassVar[Literal["rate", "state", "factor", "bias"]] = "rate"
    uses_mag: ClassVar[bool] = False  #: True for magnetometer correctors (makes a pipeline 9D)
    uses_gnss: ClassVar[bool] = False  #: True for correctors that read the GNSS stream (a pipeline then needs one)
    #: a flag some detector of the pipeline must set (the pipeline refuses the composition otherwise)
    requires_flag: ClassVar[Flag] = Flag.NONE
    #: a state-mode corrector that reads and writes the estimator's state itself (not through its
    #: quaternion) names the layout it needs (:attr:`Estimator.state_layout`); the pipeline refuses
    #: any other estimator. "": it works through the quaternion, with any estimator
    state_layout: ClassVar[str] = ""
    #: the :class:`~fusionkit.types.Channel` quantities it writes for the correctors after it, and
    #: those it reads (published by one before it, or by none: then 0, "nothing known"). Either
    #: makes the pipeline hand it the channel: ``channel=`` (a view, read and write) to
    #: :meth:`correct` / :meth:`FactorCorrector.compose` / :meth:`BiasCorrector.update_bias`, and
    #: ``ch`` to its kernel (:class:`CorrectorKernel`). Class attributes: a kernel's signature does
    #: not change with the configuration (:meth:`channel_reads` and :meth:`channel_publishes` say
    #: what a configuration reads and writes)
    publishes: ClassVar[tuple[Channel, ...]] = ()
    reads: ClassVar[tuple[Channel, ...]] = ()
    #: which of its :meth:`channel_publishes` a corrector after it reads, set by the pipeline that
    #: hosts it; None outside a pipeline (all of them, as far as it can know). A publisher may skip
    #: writing what nobody reads (the channel then keeps 0, "nothing known")
    channel_read: tuple[Channel, ...] | None = None

    @property
    def uses_channel(self) -> bool:
        """Whether the pipeline hands this corrector the channel (it publishes or reads)."""
        return bool(self.publishes or self.reads)

    def channel_reads(self) -> tuple[Channel, ...]:
        """What it reads with its configuration (``reads`` unless an option is off): the pipeline
        refuses a composition where one of these is published only after it."""
        return self.reads

    def channel_publishes(self) -> tuple[Channel, ...]:
        """What it writes with its configuration (``publishes`` unless an option is off): the
        pipeline's order check counts these, so a configuration that writes nothing is neither
        a second publisher nor one a reader must follow."""
        return self.publishes

    def initial_state(self, dt: float, frame: str) -> np.ndarray:
        """The corrector's own state (empty by default); ``dt`` is the nominal sample interval,
        ``frame`` the pipeline's earth frame (for its reference vectors)."""
        return np.zeros(0)

    @abstractmethod
    def correct(self, estimator: Estimator, est_state: np.ndarray, state: np.ndarray, sample: Sample,
                flags: int) -> Correction:
        """Correct after the propagation of ``sample``; ``flags`` are the sample's flags so far."""

    def kernel(self, estimator: Estimator) -> CorrectorKernel | None:
        """The compiled counterpart for this estimator (its ``mode`` that of the corrector), or None."""
        return None

    #: the pipeline calls :meth:`restart` before a sample that follows a timestamp gap (GAP) or a
    #: saturated gyro (the first unsaturated sample): what the corrector averaged has become stale
    restarts: ClassVar[bool] = False

    def restart(self, state: np.ndarray) -> None:
        """Forget what became stale across a gap or a saturated gyro (``restarts = True``)."""

    def for_body(self, body: str | None) -> "Corrector":
        """This corrector for sensors in ``body`` axes (the run's, None: not known): itself, or
        for one that needs a body axis (``gst-gnss``'s forward axis) a copy set to them. The
        pipeline calls it at each run."""
        return self


class FactorCorrector(Corrector):
    """A corrector that keeps its correction as its own factor of the output (``mode = "factor"``):
    the estimator propagates the gyroscope alone, and each factor corrector composes its factor into
    the output, in order (they come after the state and rate correctors). They see the gyroscope as
    measured and the pipeline's gyro bias, which they may update (a correction that is the gyro's
    drift teaches the bias)."""

    mode: ClassVar[str] = "factor"

    @abstractmethod
    def compose(self, state: np.ndarray, quat: np.ndarray, sample: Sample, bias: np.ndarray, rate: np.ndarray,
                flags: int) -> tuple[np.ndarray, int]:
        """``(quat', flags)``: ``quat`` (the output composed so far, body -> the pipeline's frame)
        with this corrector's factor composed in, after updating the factor from ``sample``
        (``sample.gyr`` as measured, NaN when invalid); ``bias`` is the pipeline's gyro bias (may be
        updated in place), ``rate`` what the estimator integrated over this step."""

    def correct(self, estimator, est_state, state, sample, flags) -> Correction:
        raise TypeError(f"corrector {self.name!r} is a factor corrector: the pipeline calls compose()")


class BiasCorrector(Corrector):
    """A corrector that updates the pipeline's gyro bias before the propagation (``mode = "bias"``):
    the sample's own propagation already subtracts what it learned."""

    mode: ClassVar[str] = "bias"

    @abstractmethod
    def update_bias(self, state: np.ndarray, bias: np.ndarray, sample: Sample, flags: int) -> int:
        """Update ``bias`` (in place) from ``sample`` (``gyr`` as measured, NaN when invalid);
        returns flag bits."""

    def correct(self, estimator, est_state, state, sample, flags) -> Correction:
        raise TypeError(f"corrector {self.name!r} is a bias corrector: the pipeline calls update_bias()")


class SensorModel(Plugin, ABC):
    """Corrects the raw samples before anything else reads them: a calibration (biases, scale
    factors, hard and soft iron), a time offset between sensors. It runs first on every sample
    (after the validity check; validity is judged again on what it returns), may keep its own
    state (an online estimate) and may read the previous output orientation. It never changes the
    orientation state."""

    kind: ClassVar[str] = "model"

    def initial_state(self, dt: float) -> np.ndarray:
        """The model's own state (empty by default); ``dt`` is the nominal sample interval."""
        return np.zeros(0)

    @abstractmethod
    def apply(self, state: np.ndarray, sample: Sample, quat: np.ndarray) -> tuple[Sample, int]:
        """The corrected ``sample`` (its ``acc`` / ``mag`` None where absent or invalid) and flag
        bits; ``quat`` is the previous output orientation (body -> the pipeline's frame)."""

    def kernel(self) -> SensorModelKernel | None:
        return None

    def report(self, state: np.ndarray) -> dict[str, Any]:
        """The model's estimate at the end of a run, named, in physical units: what it learned (an
        offset, a lever arm, a time offset), how well it is known and whether it is applied, read
        from ``state`` (its state array after the run's last sample). A pipeline puts it in
        ``Result.diagnostics["models"][name]``, so a user reads the estimate by name instead of
        indexing the raw state. Empty by default (a model with nothing to report); the built-ins'
        fields and units are in docs/algorithms/models.md. It only reads ``state``, and the
        compiled path's state equals the reference's, so both backends report the same."""
        return {}


@dataclass
class DetectionResult:
    """A detector run over a recording: per-sample ``criteria`` bitmask (0 = quiet), ``fired``
    (``criteria != 0``), ``onset_index`` (the first firing sample, None if never), the names of
    the criteria bits, and the backend that ran."""

    criteria: np.ndarray
    onset_index: int | None
    criteria_names: tuple[str, ...]
    backend: str = "reference"
    extras: dict[str, Any] = field(default_factory=dict)

    @property
    def fired(self) -> np.ndarray:
        return self.criteria != 0

    def which(self, i: int) -> list[str]:
        """Names of the criteria that fired on sample ``i``."""
        c = int(self.criteria[i])
        return [n for b, n in enumerate(self.criteria_names) if c & (1 << b)]


class Detector(Plugin, ABC):
    """Turns the sensor stream into events; never changes the orientation state.

    ``step`` returns a criteria bitmask (bit ``b`` = ``criteria_names[b]``); a nonzero value
    sets ``flag`` on the sample, and the pipeline reacts (e.g. MOTION ends the alignment).
    """

    kind: ClassVar[str] = "detector"
    flag: ClassVar[Flag] = Flag.NONE
    criteria_names: ClassVar[tuple[str, ...]] = ()
    #: fires only on magnetometer samples (and leaves its state alone without them): a compiled
    #: pipeline leaves it out on a recording without a magnetometer
    needs_mag: ClassVar[bool] = False

    @abstractmethod
    def initial_state(self, dt: float) -> np.ndarray:
        """A fresh state; ``dt`` is the nominal sample interval (sizes the windows)."""

    @abstractmethod
    def step(self, state: np.ndarray, sample: Sample) -> int:
        """Process one sample (gyr and acc valid), return its criteria bitmask."""

    def kernel(self) -> DetectorKernel | None:
        return None

    def run(self, rec, *, nan_policy: str = "raise", backend: str = "auto") -> DetectionResult:
        """Run over a :class:`~fusionkit.types.Recording`; samples with a non-finite gyr or acc
        raise (``nan_policy="raise"``) or are skipped with criteria 0 (``"skip"``)."""
        from .detectors._run import run_detector

        return run_detector(self, rec, nan_policy=nan_policy, backend=backend)


class Filter(Plugin, ABC):
    """A complete algorithm users pick by name.

    ``run(rec)`` processes a recording; ``update(gyr, acc, mag, dt)`` processes one sample of a
    stream and gives the same numbers; ``state`` / ``set_state`` copy and restore the full state.
    """

    kind: ClassVar[str] = "filter"
    requires_gnss: ClassVar[bool] = False  #: cannot run without a GNSS stream (benchmarks mark it n/a)

    def body_axes(self, rec) -> str | None:
        """The body axes of a run on ``rec``: the config's ``body`` or the recording's
        (:func:`~fusionkit.conventions.resolve_body`; a contradiction raises ConfigError naming
        both), None when neither says. Every ``run`` calls it, so every filter takes ``body=``."""
        return resolve_body(getattr(rec, "body", None), getattr(self.config, "body", None), f"filter {self.name!r}")

    def dimension(self, rec) -> str:
        """``"9D"`` when this filter uses the magnetometer of ``rec``, else ``"6D"`` (decides
        which error a benchmark judges it on: total for 9D, inclination for 6D)."""
        return "6D"

    def aiding(self, rec) -> str:
        """What corrects a run of this filter on ``rec``, so what its heading means: ``"9D"`` (the
        magnetometer: a heading from north), ``"6D"`` (the accelerometer only, or GNSS: without GNSS
        the heading is the gyro's, from an arbitrary start) or ``"gyro-only"`` (a composition
        without correctors: nothing corrects the integration). A filter that can use a
        magnetometer runs 6D on a recording without one, or whose magnetometer has not one finite
        sample (``nan_policy="skip"`` then runs without it). Every run records it in
        ``Result.diagnostics["aiding"]``."""
        from .validation import has_finite

        if getattr(self, "correctors", None) == []:
            return "gyro-only"
        mag = getattr(rec, "mag", None)
        return "6D" if mag is not None and not has_finite(mag) else self.dimension(rec)

    @abstractmethod
    def run(self, rec, *, backend: str = "auto", progress: bool | None = None):
        """Process a whole recording; returns a :class:`~fusionkit.types.Result`."""

    @abstractmethod
    def reset(self) -> None:
        """Forget the streaming state."""

    @abstractmethod
    def update(self, gyr, acc, mag=None, dt: float | None = None) -> np.ndarray:
        """Process one sample, return the orientation quaternion after it."""

    #: how many first samples of a stream :meth:`check_stream_units` keeps
    UNIT_CHECK_SAMPLES: ClassVar[int] = 50

    def check_stream_units(self, gyr: np.ndarray, acc: np.ndarray) -> None:
        """``update()``'s unit check: the magnitude tests ``Recording`` makes (acc in g, gyro in
        deg/s), on the stream's first samples so far (from the first one on), raising the same
        :class:`~fusionkit.errors.InputError` naming the fix."""
        from .validation import check_units

        buf = self.__dict__.setdefault("_unit_samples", [])
        if len(buf) >= self.UNIT_CHECK_SAMPLES:
            return
        buf.append(np.concatenate([gyr, acc]))
        arr = np.array(buf)
        check_units(arr[:, :3], arr[:, 3:], check_range=False)  # (a share of a few samples is no unit's proof)


#: the protocol class a plugin of each kind subclasses
KIND_BASES: dict[str, type[Plugin]] = {"filter": Filter, "estimator": Estimator, "corrector": Corrector,
                                       "detector": Detector, "model": SensorModel}


def plugin_class_problem(cls: Any) -> str | None:
    """Why ``cls`` is not a usable plugin class (None when it is): a :class:`Plugin` subclass with a
    name, a kind of :data:`KINDS`, subclassing that kind's protocol (:data:`KIND_BASES`) and
    implementing its abstract methods. A ``Plugin`` subclass that only said ``kind = "filter"`` was
    registered and made, and had no ``run()`` (an AttributeError on use)."""
    if not (isinstance(cls, type) and issubclass(cls, Plugin)):
        return f"{cls!r} is not a plugin class (a subclass of fusionkit.protocols.Plugin)"
    if cls.kind not in KINDS:
        return f"{cls.__name__}.kind must be one of {KINDS}, got {cls.kind!r}"
    if not cls.name:
        return f"{cls.__name__} has no name"
    base = KIND_BASES[cls.kind]
    if not issubclass(cls, base):
        return (f"{cls.__name__} says kind={cls.kind!r} but does not subclass fusionkit.protocols.{base.__name__}, "
                f"the {cls.kind} protocol")
    missing = sorted(getattr(cls, "__abstractmethods__", ()))
    if missing:
        return f"{cls.__name__} does not implement {', '.join(m + '()' for m in missing)} ({cls.kind} protocol)"
    return None
