"""Every convention of fusionkit, written once.

Quaternions
    ``[w, x, y, z]`` (scalar first), Hamilton product, unit norm. A result quaternion ``q``
    rotates body-frame vectors into the earth frame: ``v_earth = R(q) v_body``. scipy's
    ``Rotation`` is scalar-last: use :func:`to_scipy` / :func:`from_scipy`.

Units
    gyroscope rad/s; accelerometer m/s^2 as *specific force* (reads about +g along "up" at
    rest); magnetometer any unit (only its direction is used); time s; angles rad unless a name
    ends in ``_deg``.

Timing
    ``quat[k]`` is the orientation after sample ``k``, at ``t[k]``; sample ``k``'s rate is held
    over ``(t[k-1], t[k]]``. An accelerometer or magnetometer sampled like the gyro (point
    samples, or means over the interval) describes the middle of that step: ``recommended``
    pairs them there by default (its ``acc_delay`` / ``mag_delay``; 0 is the end of the step);
    the source filters pair them with the end of the step, as their documents do. The
    simulator's ``sampling`` option makes either kind of data.

Earth frames (:data:`FRAMES`)
    ``"ENU"`` (default): x East, y North, z Up.
    ``"NED"``: x North, y East, z Down.
    ``"NWU"``: x North, y West, z Up.
    ``"NUE"``: source 000's geographic frame Me: axis 1 North, axis 2 Up, axis 3 East.

Euler angles (:func:`quat_to_euler`, :func:`euler_to_quat`), always returned as
``(heading, pitch, roll)`` in rad:
    ENU, NED, NWU: intrinsic z-y'-x'' (yaw about the frame's z axis, then pitch about the new y,
    then roll about the new x): ``R = Rz(yaw) Ry(pitch) Rx(roll)``.
    NUE: source 000's sequence Me -(psi about axis 2)-> -(theta about axis 3)-> -(gamma about
    axis 1)-> Mr, i.e. ``R = Ry(psi) Rz(theta) Rx(gamma)`` (intrinsic y-z'-x''). The document's
    matrix L (its eq. 1) maps earth to body, ``L = R^T``; see :func:`source000_matrix`.

Body axes (:func:`check_body`, :func:`body_matrix`)
    A sensor's axis convention names where its x, y, z axes point on the vehicle, one letter
    each: ``F``/``B`` forward/back, ``L``/``R`` left/right, ``U``/``D`` up/down, one letter of
    each pair, right-handed: ``"FLU"`` (ROS, ISO 8855), ``"FRD"`` (aerospace, PX4,
    gnss-ins-sim), ``"RFU"`` (source 001's x right, y forward, z up), ... (24 in all).
    ``Recording.body`` carries it (None: not known) and every filter takes the same ``body=``
    argument (:func:`resolve_body`): a filter whose method assumes body axes (``gst``,
    ``gst-gnss``: RFU) maps the sensors into them; the others never need a forward axis. Every
    filter's output stays body -> earth for the *recording's* axes.

Gravity
    ``GRAVITY`` = 9.780327 m/s^2, source 000's model (the equatorial normal gravity).
"""

from __future__ import annotations

import functools
from typing import Literal

import numpy as np

from .errors import ConfigError, InputError
from .rotations import _arr, matrix_to_quat, quat_from_axis_angle, quat_mul, quat_to_matrix

__all__ = [
    "FRAMES",
    "Frame",
    "GRAVITY",
    "DEFAULT_FRAME",
    "check_frame",
    "frame_matrix",
    "up_vector",
    "north_vector",
    "east_vector",
    "change_frame",
    "quat_to_euler",
    "euler_to_quat",
    "source000_matrix",
    "source000_quat",
    "source000_euler",
    "to_scipy",
    "from_scipy",
    "BODY_LETTERS",
    "check_body",
    "body_matrix",
    "body_axis",
    "change_body",
    "resolve_body",
]

Frame = Literal["ENU", "NED", "NWU", "NUE"]
FRAMES: tuple[str, ...] = ("ENU", "NED", "NWU", "NUE")
DEFAULT_FRAME = "ENU"
#: source 000's gravity model, m/s^2
GRAVITY = 9.780327

# Rows: the frame's axes expressed in ENU coordinates, so v_frame = M @ v_enu.
_FROM_ENU = {
    "ENU": np.eye(3),
    "NED": np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]]),
    "NWU": np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]),
    "NUE": np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]]),
}


def check_frame(frame: str, name: str = "frame") -> str:
    """Return ``frame`` if it is a known earth frame, else raise :class:`ConfigError` naming ``name``."""
    if not isinstance(frame, str) or frame not in _FROM_ENU:
        raise ConfigError(f"{name} must be one of {FRAMES}, got {frame!r}")
    return frame


def frame_matrix(src: str, dst: str) -> np.ndarray:
    """Matrix ``M`` with ``v_dst = M @ v_src`` for earth-frame vectors."""
    return _FROM_ENU[check_frame(dst)] @ _FROM_ENU[check_frame(src)].T


def up_vector(frame: str) -> np.ndarray:
    """The unit "up" vector in ``frame`` coordinates."""
    return frame_matrix("ENU", frame) @ np.array([0.0, 0.0, 1.0])


def north_vector(frame: str) -> np.ndarray:
    """The unit "north" vector in ``frame`` coordinates."""
    return frame_matrix("ENU", frame) @ np.array([0.0, 1.0, 0.0])


def east_vector(frame: str) -> np.ndarray:
    """The unit "east" vector in ``frame`` coordinates."""
    return frame_matrix("ENU", frame) @ np.array([1.0, 0.0, 0.0])


def change_frame(quat, src: str, dst: str) -> np.ndarray:
    """Re-express body->``src`` quaternions as body->``dst`` quaternions."""
    return quat_mul(_frame_quat(src, dst), np.asarray(quat, dtype=float))


@functools.lru_cache(maxsize=None)
def _frame_quat(src: str, dst: str) -> np.ndarray:
    """The quaternion of ``frame_matrix(src, dst)`` (per sample in the alignment's reference path:
    computed once per pair; read only)."""
    q = matrix_to_quat(frame_matrix(src, dst))
    q.flags.writeable = False
    return q


def _axis_quat(axis: int, angle):
    e = np.zeros(3)
    e[axis] = 1.0
    angle = np.asarray(angle, dtype=float)
    if angle.ndim == 0:  # one angle (per sample in the reference paths): quat_from_axis_angle's
        half = 0.5 * angle  # operations on the unit axis, without its normalisation and concatenation
        s = np.sin(half)
        return np.array([np.cos(half), s * e[0], s * e[1], s * e[2]])
    return quat_from_axis_angle(e, angle)


def euler_to_quat(heading, pitch, roll, frame: str = DEFAULT_FRAME) -> np.ndarray:
    """Body->``frame`` quaternion from ``(heading, pitch, roll)`` in rad (see module doc)."""
    check_frame(frame)
    if frame == "NUE":
        return source000_quat(heading, pitch, roll)
    q = quat_mul(_axis_quat(2, heading), _axis_quat(1, pitch))
    return quat_mul(q, _axis_quat(0, roll))


def _unit(quat, name: str = "quat") -> np.ndarray:
    """``quat`` (``(4,)`` or ``(..., 4)``) with every quaternion of unit length: the Euler angles
    and scipy's rotations are those of the rotation it stands for (``quat_to_matrix`` assumes unit
    length: 2 x a 1 rad yaw read as 1.815 rad). A zero quaternion is no orientation: an InputError
    by index; a NaN one stays NaN. ``quat`` itself when already of unit length to rounding."""
    q = _arr(quat, name, (4,))
    n2 = np.einsum("...i,...i->...", q, q)
    if not (np.abs(n2 - 1.0) > 2e-9).any():  # (|q|^2 - 1 = 2 (|q| - 1) near 1; NaN: False)
        return q
    if (n2 == 0.0).any():
        i = np.unravel_index(int(np.argmax(n2 == 0.0)), n2.shape) if n2.ndim else ()
        raise InputError(f"{name}{list(map(int, i)) if i else ''} is a zero quaternion: no orientation")
    return q / np.sqrt(n2)[..., None]


def quat_to_euler(quat, frame: str = DEFAULT_FRAME) -> np.ndarray:
    """``(..., 3)`` array of ``(heading, pitch, roll)`` in rad of body->``frame`` quaternions
    (normalised first: :func:`_unit`)."""
    check_frame(frame)
    quat = _unit(quat)
    if frame == "NUE":
        return source000_euler(quat)
    r = quat_to_matrix(quat)
    yaw = np.arctan2(r[..., 1, 0], r[..., 0, 0])
    pitch = np.arcsin(np.clip(-r[..., 2, 0], -1.0, 1.0))
    roll = np.arctan2(r[..., 2, 1], r[..., 2, 2])
    return np.stack([yaw, pitch, roll], axis=-1)


def source000_matrix(psi, theta, gamma) -> np.ndarray:
    """Source 000's matrix L (eq. 1), earth (N, Up, E) to body: ``V_r = L V_e``. Angles in rad."""
    sp, cp = np.sin(psi), np.cos(psi)
    st, ct = np.sin(theta), np.cos(theta)
    sg, cg = np.sin(gamma), np.cos(gamma)
    return np.array(
        [
            [cp * ct, st, -sp * ct],
            [sp * sg - cp * st * cg, ct * cg, cp * sg + sp * st * cg],
            [sp * cg + cp * st * sg, -ct * sg, cp * cg - sp * st * sg],
        ]
    )


def source000_quat(psi, theta, gamma) -> np.ndarray:
    """Body->NUE quaternion of source 000's angles, derived from matrix (1): ``R(q) = L^T``.

    As extracted, the document's own quaternion formulas (2) and (3) disagree with each other
    and with (1) in the order and sign of the vector components (for a pure pitch (3) puts
    -sin(theta/2) in the third component, (2) in the first; rotation about axis 3 by +theta has
    +sin(theta/2) in the third). Matrix (1) is self-consistent (it is R1(gamma) R3(theta)
    R2(psi) of frame rotations), so the quaternion is built as y-z'-x'' intrinsic rotations,
    which ``tests/test_conventions.py`` checks against (1).
    """
    q = quat_mul(_axis_quat(1, psi), _axis_quat(2, theta))
    return quat_mul(q, _axis_quat(0, gamma))


def source000_euler(quat) -> np.ndarray:
    """``(psi, theta, gamma)`` of body->NUE quaternions, by source 000's Appendix 1.

    With ``L = R(q)^T``: ``sin(theta) = l12``, ``tan(gamma) = -l32 / l22``,
    ``tan(psi) = -l13 / l11`` (1-based indices of L; the cos(theta) factors cancel in atan2).
    """
    lt = quat_to_matrix(quat)  # = L^T, so l_ij = lt[..., j, i]
    theta = np.arcsin(np.clip(lt[..., 1, 0], -1.0, 1.0))
    gamma = np.arctan2(-lt[..., 1, 2], lt[..., 1, 1])
    psi = np.arctan2(-lt[..., 2, 0], lt[..., 0, 0])
    return np.stack([psi, theta, gamma], axis=-1)


def to_scipy(quat):
    """scipy ``Rotation`` of ``[w, x, y, z]`` quaternions."""
    from scipy.spatial.transform import Rotation

    q = _unit(quat)  # (shape checked: an (N, 3) array was an IndexError from inside, a zero row scipy's error)
    return Rotation.from_quat(q[..., [1, 2, 3, 0]])


def from_scipy(rotation) -> np.ndarray:
    """``[w, x, y, z]`` quaternions of a scipy ``Rotation``."""
    q = rotation.as_quat()
    return np.asarray(q)[..., [3, 0, 1, 2]]



# ---- body axis conventions -------------------------------------------------------------------

#: each letter's direction in FLU coordinates (x forward, y left, z up)
BODY_LETTERS = {
    "F": (1.0, 0.0, 0.0), "B": (-1.0, 0.0, 0.0),
    "L": (0.0, 1.0, 0.0), "R": (0.0, -1.0, 0.0),
    "U": (0.0, 0.0, 1.0), "D": (0.0, 0.0, -1.0),
}


def _to_flu(body: str) -> np.ndarray:
    """``A`` with ``v_flu = A @ v_body``: its columns are the body's axes in FLU."""
    return np.array([BODY_LETTERS[c] for c in body]).T


def check_body(body, name: str = "body", error: type[Exception] = ConfigError) -> str:
    """``body`` as an upper-case axis convention (see the module doc), else raise ``error``
    naming ``name``."""
    if not isinstance(body, str) or len(body) != 3 or not set(body.upper()) <= set(BODY_LETTERS):
        raise error(f"{name} must be a body axis convention of three letters from F/B, L/R, U/D such as 'FLU', "
                    f"'FRD' or 'RFU', got {body!r}")
    b = body.upper()
    a = _to_flu(b)
    if abs(np.linalg.det(a) - 1.0) > 1e-9:
        pairs = {"F": "FB", "B": "FB", "L": "LR", "R": "LR", "U": "UD", "D": "UD"}
        why = ("it names the same direction twice" if len({pairs[c] for c in b}) < 3
               else "it is left-handed")
        raise error(f"{name}={body!r} is not a right-handed set of body axes ({why}): e.g. 'FLU', 'FRD', 'RFU'")
    return b


def body_matrix(src: str, dst: str) -> np.ndarray:
    """Matrix ``M`` with ``v_dst = M @ v_src`` for body-frame vectors (gyro, accelerometer,
    magnetometer) measured in axes ``src`` and re-expressed in axes ``dst``."""
    if isinstance(src, str) and isinstance(dst, str):  # a reference step asks per sample: computed once
        return _body_matrix(src, dst).copy()
    return _body_matrix.__wrapped__(src, dst)


@functools.lru_cache(maxsize=None)
def _body_matrix(src: str, dst: str) -> np.ndarray:
    return _to_flu(check_body(dst)).T @ _to_flu(check_body(src))


def body_axis(body: str, direction: str) -> np.ndarray:
    """The unit vector of ``direction`` (one of F, B, L, R, U, D) in ``body`` axes."""
    return body_matrix("FLU", body) @ np.array(BODY_LETTERS[direction.upper()])


def change_body(quat, src: str, dst: str) -> np.ndarray:
    """Re-express body(``src``)->earth quaternions as body(``dst``)->earth quaternions (the same
    attitude of the same sensor, its axes named differently)."""
    return quat_mul(np.asarray(quat, dtype=float), matrix_to_quat(body_matrix(dst, src)))


def resolve_body(recording: str | None, argument: str | None, where: str) -> str | None:
    """The body axes a run uses: the ``body=`` ``argument`` of ``where`` (a filter or plugin
    name) and the ``recording``'s ``Recording.body``, either when only one is given; None when
    neither is. Both given and different is a :class:`ConfigError` naming both."""
    rec = None if recording is None else check_body(recording, "Recording.body")
    arg = None if argument is None else check_body(argument, f"{where}: body")
    if rec is not None and arg is not None and rec != arg:
        raise ConfigError(f"{where}: body={arg!r} contradicts the recording's body axes {rec!r} (Recording.body); "
                          "drop the argument or fix the recording")
    return arg if arg is not None else rec
