"""Poisson integrators against closed-form rotations."""

import numpy as np
import pytest

import fusionkit as fk
from fusionkit.rotations import quat_angle, quat_from_axis_angle, quat_mul

AXIS = np.array([1.0, -2.0, 0.5]) / np.linalg.norm([1.0, -2.0, 0.5])
Q0 = quat_from_axis_angle([0.3, 0.2, 0.9], 0.8)


def integrate(est, rate, dt, n, backend):
    w = rate * AXIS
    x = est.initial_state(Q0)
    if backend == "numba":
        k = est.kernel()
        for _ in range(n):
            k.propagate(x, w[0], w[1], w[2], dt, k.params)
        out = np.empty(4)
        k.to_quat(x, out)
        return out
    for _ in range(n):
        est.propagate(x, w, dt)
    return est.quat(x)


def truth(rate, dt, n):
    return quat_mul(Q0, quat_from_axis_angle(AXIS, rate * dt * n))


@pytest.mark.parametrize("backend", ["reference", "numba"])
@pytest.mark.parametrize("name,params", [("poisson-quat", {"step": "exact"}), ("poisson-dcm", {})])
def test_exact_steps_are_exact_for_constant_rate(name, params, backend):
    est = fk.make(name, kind="estimator", **params)
    rate, dt, n = 3.0, 0.01, 2000  # 60 rad in total
    err = quat_angle(integrate(est, rate, dt, n, backend), truth(rate, dt, n))
    assert err < 1e-9


@pytest.mark.parametrize("backend", ["reference", "numba"])
def test_first_order_step_error_has_the_expected_order(backend):
    """Normalised [1, w dt/2] rotates by 2 atan(|w dt|/2) = |w dt| - |w dt|^3/12 + ...: the angle
    error after n steps is n |w dt|^3 / 12, so halving dt (twice the steps) quarters it."""
    est = fk.make("poisson-quat", kind="estimator")
    rate, total = 2.0, 5.0
    errs = []
    for dt in (0.02, 0.01, 0.005):
        n = int(round(total / dt))
        e = quat_angle(integrate(est, rate, dt, n, backend), truth(rate, dt, n))
        predicted = n * (rate * dt) ** 3 / 12
        assert e == pytest.approx(predicted, rel=0.02)
        errs.append(e)
    assert errs[0] / errs[1] == pytest.approx(4.0, rel=0.05)


def test_without_normalisation_the_first_order_norm_grows():
    est = fk.make("poisson-quat", kind="estimator", normalize=False)
    x = est.initial_state(Q0)
    for _ in range(100):
        est.propagate(x, np.array([1.0, 0, 0]), 0.01)
    assert np.linalg.norm(x) > 1.0 + 1e-4  # |[1, w dt/2]| > 1 at every step
    assert abs(np.linalg.norm(est.quat(x)) - 1) < 1e-12


def test_dcm_stays_orthonormal():
    est = fk.make("poisson-dcm", kind="estimator")
    x = est.initial_state(Q0)
    rng = np.random.default_rng(0)
    for _ in range(10000):
        est.propagate(x, rng.normal(size=3) * 5, 0.01)
    c = x.reshape(3, 3)
    assert np.abs(c.T @ c - np.eye(3)).max() < 1e-12
