"""Source 003 (patent): iterative gradient-descent orientation correction.

Per sample, after the gyro propagation (the ``poisson-quat`` first-order step is the patent's
steps b-d), repeat: (e) the gradient of the objective
``f(q) = R(q)^T d - a`` (``d`` the earth frame's "up", ``a`` the normalised specific force; in 9D
plus ``R(q)^T b - m`` with ``b`` the field's reference direction from the current estimate) via
its Jacobian, at the last corrected estimate (the propagated one at the first iteration);
(f) normalise it; (g, h) subtract ``beta`` times it; (i) normalise the quaternion;
(k, l) stop when converged or after ``iterations``.

**The stop test, made well defined.** The patent stops "when the correction is below epsilon";
with a normalised gradient and a fixed beta every correction has size beta, so that test can
never end the loop. Here the loop stops when the *residual* ``|f(q)|`` after a correction is
below ``epsilon`` (for the accelerometer term, ``|f|`` is about the tilt error in rad), or when
``iterations`` corrections were made (``iterations=None``: until converged, capped at
``max_iterations``). The first correction is always made, so a converged filter still corrects
once per sample, like Madgwick's.

**beta.** ``beta_scale="rate"``: the step is ``beta * dt`` (beta in rad/s, Madgwick's meaning);
``"absolute"``: ``beta`` rad per iteration (the patent's). ``beta_mode="variable"``: the
patent's adaptation, raised above one residual threshold and lowered below another. Raised, the
step is ``residual / 2`` (at most ``beta_max``): in quaternion units a rotation of about the
tilt error, so it cannot overshoot; a beta multiplied by a constant factor (tried first)
oscillates around the minimum by up to the largest step. Lowered, it is ``beta`` again.

**Extensions** (each off with its option). The stop test and the variable beta use the
accelerometer residual only (a magnetic disturbance must not trigger large steps; the
magnetometer term still enters the gradient). With ``beta_mode="variable"`` the loop goes beyond
the first correction only when the residual has stayed above ``beta_raise_above`` for
``raise_after`` s and the accelerometer is quasi-static, ``| |a|/g - 1 | < static_gate``: a real
orientation error (a restart, a saturated gyro) persists, linear acceleration and magnetic
disturbances come and go, and iterating on them multiplies the gain by the iteration count
(measured on BROAD: 43-58 deg instead of 5.8). ``beta_mode="fixed"`` iterates as the patent
does, every sample.

**The earth frame.** Source 003's frame is z up (Madgwick's: z up, x towards magnetic north, the field's
reference ``[b_x, 0, b_z]``). The objective is differentiated in Madgwick's expanded form, with
``|q| = 1`` put in before differentiating (``1 - 2 (y^2 + z^2)`` on the diagonal, his Jacobian): on the
unit sphere it is the patent's ``q* (x) d (x) q``, but its gradient has a part along ``q``,
``-2 q (d . f)``, that depends on the coordinates ``d`` is written in, and the normalised step with it.
The correction takes the gradient the source's frame gives, turned into the output frame (the
frame's own gradient plus ``2 q ((d - d_src) . f)``, ``d_src`` the reference in the source's
coordinates), so ``frame`` changes the output's axes and nothing else (before, an NED run left the
ENU one by up to 0.05 deg). In ENU 6D and in NWU (the source's) the term is zero: the same numbers.

**Madgwick's filter** is ``iterations=1``, ``beta_scale="rate"``, ``gradient_at="previous"``
(the gradient at the previous estimate, not the propagated one) and no normalisation between
propagation and correction (the ``gradient-descent`` filter's ``madgwick=True`` sets all of
these): ``q_t = normalise(q_{t-1} + (1/2 q_{t-1} (x) w - beta grad/|grad|) dt)``; tested against
the ahrs package's implementation to 1e-12.
"""

from __future__ import annotations

import math
from typing import ClassVar, Literal

import numpy as np

from .._numba import njit
from ..config import PluginConfig, param
from ..conventions import north_vector, up_vector
from ..errors import ConfigError
from ..protocols import Correction, Corrector, CorrectorKernel
from ..rotations import quat_conj, quat_mul, quat_normalize, quat_to_matrix

__all__ = ["GradientCorrector", "objective", "jacobian_t_times"]


def objective(q, d, s) -> np.ndarray:
    """``f(q) = R(q)^T d - s``: the reference direction ``d`` (earth) seen in the body, minus the
    measured direction ``s`` (unit)."""
    return quat_to_matrix(q).T @ d - s


def jacobian_t_times(q, d, f, d_src=None) -> np.ndarray:
    """``J^T f`` with ``J = d(R(q)^T d)/dq`` (3 x 4), the gradient of ``|f|^2 / 2``. With ``d_src``
    (``d`` in the source's frame, z up and x north): the gradient that frame gives, turned into the
    frame of ``q`` and ``d`` (the expanded form's part along ``q`` depends on the frame)."""
    w, x, y, z = q
    dx, dy, dz = d
    j = 2.0 * np.array([
        [z * dy - y * dz, y * dy + z * dz, -2 * y * dx + x * dy - w * dz, -2 * z * dx + w * dy + x * dz],
        [-z * dx + x * dz, y * dx - 2 * x * dy + w * dz, x * dx + z * dz, -w * dx - 2 * z * dy + y * dz],
        [y * dx - x * dy, z * dx - w * dy - 2 * x * dz, w * dx + z * dy - 2 * y * dz, x * dx + y * dy],
    ])
    g = j.T @ f
    return g if d_src is None else g + 2.0 * ((np.asarray(d) - np.asarray(d_src)) @ f) * np.asarray(q)


#: "up" in the source's frame (z up, x north: Madgwick's), whatever the output frame
_UP_SRC = np.array([0.0, 0.0, 1.0])


class GradientConfig(PluginConfig):
    beta: float = param(0.1, unit="rad/s (rate) or rad", description="step size of a correction", gt=0)
    beta_scale: Literal["rate", "absolute"] = param(
        "rate", unit="-", description="'rate': step beta*dt (Madgwick's beta); 'absolute': beta rad per iteration"
    )
    iterations: int | None = param(
        1, unit="-", description="most corrections per sample (N); None: until converged, capped by max_iterations. "
        "N > 1 recovers large errors fast but chases accelerations on hand-held motion (see BENCHMARKS.md)", ge=1
    )
    max_iterations: int = param(100, unit="-", description="safety cap for iterations=None", ge=1)
    epsilon: float = param(0.1, unit="-", description="stop when the residual |f| falls below this (about 6 deg)", gt=0)
    beta_mode: Literal["fixed", "variable"] = param("variable", unit="-", description="the patent's adaptive beta")
    beta_raise_above: float = param(
        0.35, unit="-", description="variable beta: above this residual (about 20 deg of tilt) the step is residual/2", gt=0)
    beta_lower_below: float = param(0.1, unit="-", description="variable beta: back to beta below this residual", gt=0)
    beta_max: float = param(0.8, unit="rad", description="variable beta: largest step per iteration", gt=0)
    gradient_at: Literal["propagated", "previous"] = param(
        "propagated", unit="-", description="first gradient at the propagated estimate (patent) or the previous one (Madgwick)"
    )
    use_mag: bool = param(True, unit="-", description="add the magnetometer objective when mag is given (9D)")
    raise_after: float = param(
        0.1, unit="s", description="variable beta: raise only after the residual stayed above the threshold this long "
        "(a real orientation error persists, an acceleration passes)", ge=0)
    static_gate: float | None = param(
        0.1, unit="-", description="iterate beyond one correction only while | |a|/g - 1 | is below this "
        "(quasi-static accelerometer); None: always (the patent)", gt=0)
    gravity: float = param(9.81, unit="m/s^2", description="g for the static gate", gt=0)


# state: up (3), north (3), previous corrected quaternion (4), its validity, last iteration count,
# seconds the residual has stayed above beta_raise_above
_UP, _N, _QPREV, _HAVE, _ITERS, _PERSIST = 0, 3, 6, 10, 11, 12
_SIZE = 13


class GradientCorrector(Corrector):
    """Source 003's iterative gradient-descent correction (state mode, quaternion estimators)."""

    name: ClassVar[str] = "gradient-descent"
    Config = GradientConfig
    mode: ClassVar[str] = "state"
    uses_mag: ClassVar[bool] = True
    source: ClassVar[str] = "003 (patent: iterative gradient descent)"
    summary: ClassVar[str] = "iterated normalised-gradient steps on the accelerometer (and magnetometer) objective"

    def initial_state(self, dt: float, frame: str) -> np.ndarray:
        s = np.zeros(_SIZE)
        s[_UP:_UP + 3] = up_vector(frame)
        s[_N:_N + 3] = north_vector(frame)
        return s

    def gradient(self, q, acc_dir, mag_dir, state) -> tuple[np.ndarray, float]:
        """``(J^T f, |f_acc|)`` at ``q``: the gradient of the accelerometer (and magnetometer)
        objective, and the accelerometer residual (the patent's objective), which drives the
        stop test and the variable beta."""
        up = state[_UP:_UP + 3]
        f = objective(q, up, acc_dir)
        grad = jacobian_t_times(q, up, f, _UP_SRC)
        res = math.sqrt(f @ f)
        if mag_dir is not None:
            h = quat_to_matrix(q) @ mag_dir  # the field in the earth frame
            vert = h @ up
            hor = np.linalg.norm(h - vert * up)
            b = hor * state[_N:_N + 3] + vert * up
            fm = objective(q, b, mag_dir)
            grad = grad + jacobian_t_times(q, b, fm, np.array([hor, 0.0, vert]))  # source: [b_x, 0, b_z]
        return grad, res

    def correct(self, estimator, est_state, state, sample, flags) -> Correction:
        c = self.config
        if sample.acc is None:
            state[_QPREV:_QPREV + 4], state[_HAVE] = estimator.quat(est_state), 1.0
            return Correction(None)
        acc_dir = sample.acc / np.linalg.norm(sample.acc)
        mag_dir = None
        if c.use_mag and sample.mag is not None:
            mag_dir = sample.mag / np.linalg.norm(sample.mag)
        step = c.beta * sample.dt if c.beta_scale == "rate" else c.beta
        base = step
        if c.gradient_at == "previous":
            # Madgwick: one correction with the gradient at the previous estimate, added to the
            # unnormalised propagation, then a single normalisation
            if est_state.shape != (4,):
                raise ConfigError("gradient_at='previous' needs the poisson-quat estimator (first-order step)")
            if state[_HAVE]:
                q_prev = state[_QPREV:_QPREV + 4]
            elif not np.isfinite(sample.gyr).all():  # the first sample held (no propagation to undo)
                q_prev = est_state[:4]
            else:  # the first sample: undo the first-order step q_w = q (x) p, p = [1, w dt/2]
                p = np.concatenate([[1.0], 0.5 * sample.gyr * sample.dt])
                q_prev = quat_mul(est_state[:4], quat_conj(p)) / (p @ p)
            grad, _ = self.gradient(q_prev, acc_dir, mag_dir, state)
            n = np.linalg.norm(grad)
            q_new = est_state[:4] - (step * grad / n if n > 0 else 0.0)
            q_new = quat_normalize(q_new)
            estimator.set_quat(est_state, q_new)
            state[_QPREV:_QPREV + 4], state[_HAVE], state[_ITERS] = q_new, 1.0, 1
            return Correction(None)
        q = quat_normalize(estimator.quat(est_state))
        grad, res = self.gradient(q, acc_dir, mag_dir, state)  # at the propagated estimate
        state[_PERSIST] = state[_PERSIST] + sample.dt if res > c.beta_raise_above else 0.0
        may_raise = state[_PERSIST] >= c.raise_after
        static = c.static_gate is None or abs(np.linalg.norm(sample.acc) / c.gravity - 1.0) <= c.static_gate
        cap = c.iterations if c.iterations is not None else c.max_iterations
        if c.beta_mode == "variable" and not (may_raise and static):
            # only a persistent large residual on a quasi-static accelerometer is an orientation
            # error worth iterating on; otherwise one step, or it chases accelerations
            cap = 1
        i = 0
        while i < cap:
            n = np.linalg.norm(grad)
            if n == 0.0:
                break
            if c.beta_mode == "variable" and cap > 1:
                # raised above the threshold: a step of residual/2 (in quaternion units, a rotation
                # of about the tilt error itself) cannot overshoot, where a multiplied beta does;
                # lowered back to beta below the other threshold
                if res > c.beta_raise_above and may_raise:
                    step = min(max(0.5 * res, base), c.beta_max)
                elif res < c.beta_lower_below:
                    step = base
            q = quat_normalize(q - step * grad / n)
            i += 1
            if i == cap:  # the loop ends anyway: no stop test, no next gradient
                break
            grad, res = self.gradient(q, acc_dir, mag_dir, state)  # the next step's gradient and the stop test
            if res < c.epsilon:
                break
        estimator.set_quat(est_state, q)
        state[_QPREV:_QPREV + 4], state[_HAVE], state[_ITERS] = q, 1.0, i
        return Correction(None)

    def kernel(self, estimator) -> CorrectorKernel | None:
        c = self.config
        if c.gradient_at == "previous" and estimator.name != "poisson-quat":
            return None  # the reference raises the ConfigError
        p = np.array([
            c.beta, float(c.beta_scale == "rate"), float(c.iterations or 0), float(c.max_iterations), c.epsilon,
            float(c.beta_mode == "variable"), c.beta_raise_above, c.beta_lower_below, c.beta_max,
            float(c.gradient_at == "previous"), float(c.use_mag), c.raise_after,
            c.static_gate if c.static_gate is not None else math.inf, c.gravity,
        ])
        return CorrectorKernel(_gradient_correct, p)


# ---- the kernel (GradientCorrector.correct with scalars) --------------------------------------

@njit
def _jt_f(q0, q1, q2, q3, d0, d1, d2, s0, s1, s2, c0, c1, c2):
    """``(J^T f, |f|^2)`` as five scalars, ``f = R(q)^T d - s`` (:func:`objective`,
    :func:`jacobian_t_times`; ``c``: ``d`` in the source's frame)."""
    w, x, y, z = q0, q1, q2, q3
    f0 = (1 - 2 * (y * y + z * z)) * d0 + 2 * (x * y + w * z) * d1 + 2 * (x * z - w * y) * d2 - s0
    f1 = 2 * (x * y - w * z) * d0 + (1 - 2 * (x * x + z * z)) * d1 + 2 * (y * z + w * x) * d2 - s1
    f2 = 2 * (x * z + w * y) * d0 + 2 * (y * z - w * x) * d1 + (1 - 2 * (x * x + y * y)) * d2 - s2
    j00, j01, j02, j03 = z * d1 - y * d2, y * d1 + z * d2, -2 * y * d0 + x * d1 - w * d2, -2 * z * d0 + w * d1 + x * d2
    j10, j11, j12, j13 = -z * d0 + x * d2, y * d0 - 2 * x * d1 + w * d2, x * d0 + z * d2, -w * d0 - 2 * z * d1 + y * d2
    j20, j21, j22, j23 = y * d0 - x * d1, z * d0 - w * d1 - 2 * x * d2, w * d0 + z * d1 - 2 * y * d2, x * d0 + y * d1
    k = 2.0 * ((d0 - c0) * f0 + (d1 - c1) * f1 + (d2 - c2) * f2)  # the source frame's gradient (0: it is this one)
    return (2.0 * (j00 * f0 + j10 * f1 + j20 * f2) + k * w, 2.0 * (j01 * f0 + j11 * f1 + j21 * f2) + k * x,
            2.0 * (j02 * f0 + j12 * f1 + j22 * f2) + k * y, 2.0 * (j03 * f0 + j13 * f1 + j23 * f2) + k * z,
            f0 * f0 + f1 * f1 + f2 * f2)


@njit
def _gradient_at(q0, q1, q2, q3, s, ax, ay, az, has_m, mx, my, mz):
    """:meth:`GradientCorrector.gradient`: ``(grad0..3, accelerometer residual squared)``."""
    u0, u1, u2 = s[_UP], s[_UP + 1], s[_UP + 2]
    e0, e1, e2, e3, res2 = _jt_f(q0, q1, q2, q3, u0, u1, u2, ax, ay, az, 0.0, 0.0, 1.0)
    if has_m:
        w, x, y, z = q0, q1, q2, q3
        h0 = (1 - 2 * (y * y + z * z)) * mx + 2 * (x * y - w * z) * my + 2 * (x * z + w * y) * mz
        h1 = 2 * (x * y + w * z) * mx + (1 - 2 * (x * x + z * z)) * my + 2 * (y * z - w * x) * mz
        h2 = 2 * (x * z - w * y) * mx + 2 * (y * z + w * x) * my + (1 - 2 * (x * x + y * y)) * mz
        vert = h0 * u0 + h1 * u1 + h2 * u2
        v0, v1, v2 = h0 - vert * u0, h1 - vert * u1, h2 - vert * u2
        hor = math.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
        k0, k1, k2, k3, _ = _jt_f(q0, q1, q2, q3, hor * s[_N] + vert * u0, hor * s[_N + 1] + vert * u1,
                                  hor * s[_N + 2] + vert * u2, mx, my, mz, hor, 0.0, vert)
        e0, e1, e2, e3 = e0 + k0, e1 + k1, e2 + k2, e3 + k3
    return e0, e1, e2, e3, res2


@njit
def _descend(w, x, y, z, e0, e1, e2, e3, n2, step):
    """``normalise(q - step e / |e|)`` for ``n2 = |e|^2 > 0``, computed as ``normalise(n q - step e)``
    (``n = |e|``): the square of ``|n q - step e|`` is ``n^2 (|q|^2 + step^2) - 2 n step (q . e)``,
    whose parts wait for ``n`` alone, so after the gradient the next sample waits for one square
    root, a multiplication and a subtraction before the normalising one, not for a division by
    ``n`` and a sum of squares of the corrected quaternion (the same value to rounding; a step that
    nearly cancels ``q``, where the difference loses its digits, takes the sum of squares)."""
    n = math.sqrt(n2)
    v0, v1, v2, v3 = n * w - step * e0, n * x - step * e1, n * y - step * e2, n * z - step * e3
    vv = n2 * (w * w + x * x + y * y + z * z + step * step) - (2.0 * step) * (w * e0 + x * e1 + y * e2 + z * e3) * n
    if vv < 1e-6 * n2:  # a step of about |q| along q itself (a beta near 1): the difference cancels
        vv = v0 * v0 + v1 * v1 + v2 * v2 + v3 * v3
    r = 1.0 / math.sqrt(vv)
    return v0 * r, v1 * r, v2 * r, v3 * r


@njit
def _gradient_correct(x, q, s, g0, g1, g2, a0, a1, a2, m0, m1, m2, acc_ok, mag_ok, dt, p):
    beta, rate_scaled, iterations, max_iterations, epsilon = p[0], p[1] != 0.0, int(p[2]), int(p[3]), p[4]
    variable, raise_above, lower_below, beta_max = p[5] != 0.0, p[6], p[7], p[8]
    previous, use_mag, raise_after, static_gate, gravity = p[9] != 0.0, p[10] != 0.0, p[11], p[12], p[13]
    if not acc_ok:
        s[_QPREV], s[_QPREV + 1], s[_QPREV + 2], s[_QPREV + 3], s[_HAVE] = q[0], q[1], q[2], q[3], 1.0
        return -1
    # reciprocals: one division each instead of a chain of them (same values to ~1e-16)
    na = math.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
    r = 1.0 / na
    ax, ay, az = a0 * r, a1 * r, a2 * r
    has_m = use_mag and mag_ok
    mx = my = mz = 0.0
    if has_m:
        r = 1.0 / math.sqrt(m0 * m0 + m1 * m1 + m2 * m2)
        mx, my, mz = m0 * r, m1 * r, m2 * r
    step = beta * dt if rate_scaled else beta
    base = step
    if previous:  # Madgwick: gradient at the previous estimate, added to the raw propagation
        if s[_HAVE] != 0.0:
            p0, p1, p2, p3 = s[_QPREV], s[_QPREV + 1], s[_QPREV + 2], s[_QPREV + 3]
        elif not (math.isfinite(g0) and math.isfinite(g1) and math.isfinite(g2)):
            p0, p1, p2, p3 = x[0], x[1], x[2], x[3]
        else:  # undo the first-order step: q_prev = x (x) conj(p) / |p|^2, p = [1, w dt/2]
            h0, h1, h2 = 0.5 * g0 * dt, 0.5 * g1 * dt, 0.5 * g2 * dt
            pp = 1.0 + h0 * h0 + h1 * h1 + h2 * h2
            w, xx, y, z = x[0], x[1], x[2], x[3]
            p0 = (w + xx * h0 + y * h1 + z * h2) / pp
            p1 = (-w * h0 + xx - y * h2 + z * h1) / pp
            p2 = (-w * h1 + xx * h2 + y - z * h0) / pp
            p3 = (-w * h2 - xx * h1 + y * h0 + z) / pp
        e0, e1, e2, e3, _ = _gradient_at(p0, p1, p2, p3, s, ax, ay, az, has_m, mx, my, mz)
        w, xx, y, z = x[0], x[1], x[2], x[3]
        n2 = e0 * e0 + e1 * e1 + e2 * e2 + e3 * e3
        if n2 > 0.0:
            w, xx, y, z = _descend(w, xx, y, z, e0, e1, e2, e3, n2, step)
        else:  # no gradient: the propagation normalised
            r = 1.0 / math.sqrt(w * w + xx * xx + y * y + z * z)
            w, xx, y, z = w * r, xx * r, y * r, z * r
        q[0], q[1], q[2], q[3] = w, xx, y, z
        s[_QPREV], s[_QPREV + 1], s[_QPREV + 2], s[_QPREV + 3] = w, xx, y, z
        s[_HAVE], s[_ITERS] = 1.0, 1.0
        return 0
    # the quaternion in registers from its one load to its one store (no reload on the chain)
    w, xx, y, z = q[0], q[1], q[2], q[3]
    i, cap, may_raise = 0, 0, False
    while True:  # one call site of _gradient_at for the first gradient and each next one (one inlined copy)
        e0, e1, e2, e3, res2 = _gradient_at(w, xx, y, z, s, ax, ay, az, has_m, mx, my, mz)
        if i == 0:
            # the persistence test on the squared residual, and the static gate only when it
            # matters: one correction per sample (the default) takes no square root or division here
            s[_PERSIST] = s[_PERSIST] + dt if res2 > raise_above * raise_above else 0.0
            may_raise = s[_PERSIST] >= raise_after
            cap = iterations if iterations > 0 else max_iterations
            if variable and not (may_raise and abs(na / gravity - 1.0) <= static_gate):
                cap = 1
            if cap <= 0:
                break
        res = math.sqrt(res2) if cap > 1 else 0.0  # the iterations' stop test and variable step read it
        if i > 0 and res < epsilon:
            break
        n2 = e0 * e0 + e1 * e1 + e2 * e2 + e3 * e3
        if n2 == 0.0:
            break
        if variable and cap > 1:
            if res > raise_above and may_raise:
                step = min(max(0.5 * res, base), beta_max)
            elif res < lower_below:
                step = base
        w, xx, y, z = _descend(w, xx, y, z, e0, e1, e2, e3, n2, step)
        i += 1
        if i == cap:  # the loop ends anyway: no stop test, no next gradient
            break
    q[0], q[1], q[2], q[3] = w, xx, y, z
    s[_QPREV], s[_QPREV + 1], s[_QPREV + 2], s[_QPREV + 3] = w, xx, y, z
    s[_HAVE], s[_ITERS] = 1.0, float(i)
    return 0
