"""The pipeline's compiled loop, written out as Python source and cached on disk.

A pipeline of kernel-capable plugins runs as one numba loop. Its body depends on the
composition (which kernels, in which order, which take GNSS rows), so it cannot be one static
function. Closures over the kernels worked, but numba cannot cache closures: every new process
paid the whole compile (1-3 s on this machine) before its first result.

Here the loop is *generated as source text*: one module per composition that imports each
plugin's kernel by its module and name and calls them in the pipeline's fixed per-sample order
(:mod:`fusionkit.pipeline` documents it). The module is written to the cache directory
(``$FUSIONKIT_CACHE_DIR``, else ``$XDG_CACHE_HOME/fusionkit`` or ``~/.cache/fusionkit``) under
a name that hashes the source text, the numba and fusionkit versions, and the source of every
package a kernel comes from, so numba's own on-disk cache (``cache=True``) serves the next
process, and any change to a plugin's code makes a new file instead of a stale hit. Kernels that
cannot be imported by name (closures, functions defined in ``__main__``) get the same source
compiled in memory, without the disk cache.

Two functions come out of one template, so they cannot drift apart:

- ``loop(gyr, acc, mag, dt, has_mag, S, P, O, out_q, out_f, out_c, start, stop, gn)`` over a
  recording (without a magnetometer, ``has_mag`` False, ``mag`` may be one row: it is read there
  and never judged valid), and
- ``step(g0, g1, g2, a0, a1, a2, m0, m1, m2, h, has_mag, S, P, O, q, n0..n5) -> (flags, crit)``
  for one sample, used by ``Pipeline.update()`` (``q`` receives the quaternion): ``loop`` over
  a one-sample recording, so it reuses the loop's compiled code instead of compiling its own.

``S`` is every state end to end (estimator, each kernel's, the pipeline's run state), ``P``
every parameter vector end to end, ``O`` their bounds (:func:`pack`).
"""

from __future__ import annotations

import hashlib
import importlib.util
import math
import os
import re
import sys
import tempfile
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Callable

from . import _numba
from ._sources import fusionkit_hash, source_hash
from .gnss_rows import NO_GNSS
from .navigation.alignment import ALIGNED_BEFORE, ALIGNED_NOW, ALIGNING, BIAS, PHASE, SEEN
from .errors import PluginError
from .types import CHANNEL_SIZE

__all__ = ["Layout", "KernelSpec", "get_compiled", "cache_base", "cache_dir", "pack", "unpack", "repack", "STEP_WORK", "static_params"]


@dataclass(frozen=True)
class KernelSpec:
    """One plugin kernel in the loop: its function, role (``"model"``, ``"det"``, ``"state"``,
    ``"rate"``, ``"bias"``, ``"factor"``), whether it takes the GNSS row, and for detectors the flag it sets and whether
    its criteria are the ones the pipeline reports (its first detector's); for correctors, whether
    it works on the estimator's state itself (its ``state_layout``: no quaternion round trip) and
    whether it takes the correctors' channel (:class:`fusionkit.types.Channel`)."""

    func: Callable
    role: str
    gnss: bool = False
    flag: int = 0
    first: bool = False
    on_x: bool = False  # a corrector that works on the estimator's state itself (``state_layout``)
    channel: bool = False  # a corrector that publishes or reads the channel: ``ch`` after its parameters
    static: tuple = ()  # compile-time options (bools), arguments after all the others (protocols.CorrectorKernel)

    def __post_init__(self):
        for v in self.static:
            if type(v) is not bool:
                raise PluginError(f"kernel {_name(self.func)}: each static option must be a Python bool (bool(x) of a "
                                  f"numpy one), got {v!r} of type {type(v).__name__}")


@dataclass(frozen=True)
class Layout:
    """The structure of a compiled pipeline: the estimator's ``(propagate, to_quat, from_quat)``,
    whether its state is its unit quaternion, the kernels in order (their roles say where each
    runs), and the offsets of the pending correction rate, of the previous output and of the
    correctors' channel in the pipeline's run state. Sizes are not part of it: the bounds of every
    state and parameter vector in ``S`` and ``P`` come at run time in ``O`` (see :func:`pack`), so
    one compiled loop serves every sample rate."""

    est: tuple[Callable, Callable, Callable]
    unit_quat: bool
    kernels: tuple[KernelSpec, ...]
    rcorr: int
    qprev: int
    chan: int = -1  # where the channel (CHANNEL_SIZE numbers) starts in the run state

    @property
    def uses_gnss(self) -> bool:
        return any(k.gnss for k in self.kernels)


def pack(states, params):
    """``(S, P, O)``: the states (estimator, each kernel's, the run state) and the parameter
    vectors (estimator, each kernel's, alignment, loop) end to end, and their bounds
    ``O = [lo, hi] * len(states) + [lo, hi] * len(params)`` (int64)."""
    import numpy as np

    bounds = []
    for group in (states, params):
        o = 0
        for a in group:
            bounds += [o, o + a.size]
            o += a.size
    S = np.concatenate([np.asarray(a, dtype=float).ravel() for a in states])
    P = np.concatenate([np.asarray(a, dtype=float).ravel() for a in params])
    return S, P, np.array(bounds, dtype=np.int64)


def unpack(S, O, states) -> None:
    """Copy ``S`` back into ``states`` (the arrays :func:`pack` joined)."""
    for i, a in enumerate(states):
        a[...] = S[O[2 * i]:O[2 * i + 1]].reshape(a.shape)


def repack(S, O, states) -> None:
    """Copy ``states`` (the arrays :func:`pack` joined) into ``S`` again: :func:`unpack`'s inverse."""
    for i, a in enumerate(states):
        S[O[2 * i]:O[2 * i + 1]] = a.ravel()


def _ref(func: Callable) -> tuple[str, str] | None:
    """``(module, name)`` under which ``func`` can be imported, or None (a closure, ``__main__``)."""
    py = getattr(func, "py_func", func)
    mod, name = getattr(py, "__module__", None), getattr(py, "__qualname__", "")
    if not mod or mod == "__main__" or "<" in name or "." in name:
        return None
    m = sys.modules.get(mod)
    return (mod, name) if m is not None and getattr(m, name, None) is func else None


_GN = "n0, n1, n2, n3, n4, n5"
#: entries past the states in a stream's ``S`` that ``step`` takes its one-sample arrays from
STEP_WORK = 20
_SAMPLE = "g0, g1, g2, a0, a1, a2, m0, m1, m2"


def _body(lay: Layout, names: dict[int, str], ind: str) -> list[str]:
    """The per-sample lines (the order of :meth:`Pipeline._step`), indented by ``ind``; they end
    with the output quaternion in ``q`` and ``flags``, ``crit`` set."""
    rc, qp = lay.rcorr, lay.qprev
    L = ["gyr_ok, acc_ok, mag_ok, flags = validity_flags(g0, g1, g2, a0, a1, a2, m0, m1, m2, has_mag, "
         "pp[0], pp[1])"]
    models = [i for i, k in enumerate(lay.kernels) if k.role == "model"]
    if models:  # 1b. sensor models correct the sample; validity is judged on what they give
        L += [f"v[{j}] = {s}" for j, s in enumerate(_SAMPLE.split(", "))]
        L.append("mflags = 0")
        for i in models:
            L += [f"c = {names[i]}(s{i}, v, gyr_ok, acc_ok, mag_ok, al[{qp}:{qp + 4}], h, p{i}{_st(lay.kernels[i], i)})",
                  "if c > 0:", "    mflags |= c"]
        L.append(f"{_SAMPLE} = v[0], v[1], v[2], v[3], v[4], v[5], v[6], v[7], v[8]")
        L.append("gyr_ok, acc_ok, mag_ok, flags = validity_flags(g0, g1, g2, a0, a1, a2, m0, m1, m2, has_mag, "
                 "pp[0], pp[1])")
        L.append("flags |= mflags")
    L += ["if not gyr_ok:  # every plugin sees an invalid sample as non-finite (the reference's None / NaN)",
          "    g0 = g1 = g2 = math.nan", "if not mag_ok:", "    m0 = m1 = m2 = math.nan"]
    L.append("crit = 0")
    dets = [i for i, k in enumerate(lay.kernels) if k.role == "det"]
    if dets:  # 2. detectors
        L.append("if gyr_ok and acc_ok:")
        for i in dets:
            k = lay.kernels[i]
            L += [f"    c = {names[i]}(s{i}, {_SAMPLE}, h, p{i}" + (f", {_GN})" if k.gnss else ")"),
                  "    if c != 0:", f"        flags |= {k.flag}"]
            if k.first:
                L.append("    crit = c")
    # 3. alignment
    L += ["done = False",
          f"if al[{PHASE}] == 0.0:",
          f"    status = align_step(al, ap, {_SAMPLE}, gyr_ok, acc_ok, mag_ok, (flags & motion) != 0, h, q)",
          f"    if status == {ALIGNED_NOW} or status == {ALIGNED_BEFORE}:",
          "        e_from_quat(q, x)",
          f"    if status == {ALIGNING} or status == {ALIGNED_NOW}:",
          "        flags |= 1", "        done = True",
          "if not done:",
          f"    al[{SEEN}] += 1.0"]
    factors = [i for i, k in enumerate(lay.kernels) if k.role == "factor"]
    L += _bias_lines(lay, names, bool(factors))
    L += ["    if gyr_ok:",
          f"        e_propagate(x, g0 - al[{BIAS}] + al[{rc}], g1 - al[{BIAS + 1}] + al[{rc + 1}], "
          f"g2 - al[{BIAS + 2}] + al[{rc + 2}], h, ep)"]
    cors = [i for i, k in enumerate(lay.kernels) if k.role in ("state", "rate")]
    if cors:  # 5. correctors (the bias removed; MAG_DISTURBED / ACC_REJECTED withhold a sensor)
        has_rate = any(lay.kernels[i].role == "rate" for i in cors)
        L += [f"    b0, b1, b2 = g0 - al[{BIAS}], g1 - al[{BIAS + 1}], g2 - al[{BIAS + 2}]"]
        if not _withholds(lay):
            L += ["    ga_ok = acc_ok and (flags & 512) == 0", "    gm_ok = mag_ok and (flags & 256) == 0"]
        if has_rate:
            L.append("    rate[0] = rate[1] = rate[2] = 0.0")
        for i in cors:
            k = lay.kernels[i]
            direct = lay.unit_quat or k.on_x  # the state is the quaternion, or the corrector works on it
            qq = "x" if direct else "q"
            gn = _ch(k) + (f", {_GN}" if k.gnss else "") + _st(k, i) + ")"
            if not direct:
                L.append("    e_to_quat(x, q)")
            if k.role == "rate":
                L.append(f"    cf = {names[i]}({qq}, s{i}, b0, b1, b2, a0, a1, a2, m0, m1, m2, ga_ok, gm_ok, flags, "
                         f"h, p{i}, rate" + gn)
            else:
                L.append(f"    cf = {names[i]}(x, {qq}, s{i}, b0, b1, b2, a0, a1, a2, m0, m1, m2, ga_ok, gm_ok, h, "
                         f"p{i}" + gn)
                if not direct:
                    L += ["    if cf >= 0:", "        e_from_quat(q, x)"]
            L += ["    if cf > 0:", "        flags |= cf"]
        if has_rate:
            L.append(f"    al[{rc}], al[{rc + 1}], al[{rc + 2}] = rate[0], rate[1], rate[2]")
    # the output: a unit-quaternion state is the quaternion (normalised by its propagation), no second normalisation
    L.append("    q[0], q[1], q[2], q[3] = x[0], x[1], x[2], x[3]" if lay.unit_quat else "    e_to_quat(x, q)")
    for i in factors:  # 6. factor correctors compose the output, in order
        L += [f"    cf = {names[i]}(q, s{i}, bv, g0, g1, g2, h0, h1, h2, h3, a0, a1, a2, m0, m1, m2, ga_ok, gm_ok, flags, "
              f"h, p{i}{_ch(lay.kernels[i])}{_st(lay.kernels[i], i)})", "    if cf > 0:", "        flags |= cf"]
    L.append(f"al[{qp}], al[{qp + 1}], al[{qp + 2}], al[{qp + 3}] = q[0], q[1], q[2], q[3]")
    _check_calls(L, names, lay)
    return [ind + s for s in L]


#: CPython compiles a call of more positional arguments than this as ``f(*args)`` (a tuple built on
#: the stack), which numba cannot inline into the loop
MAX_CALL_ARGS = 30


def _check_calls(lines: list[str], names: dict[int, str], lay: Layout) -> None:
    """Raise where a kernel's call takes more than :data:`MAX_CALL_ARGS` arguments (a plugin's
    kernel with too many ``static`` options: pack some into its ``params`` instead)."""
    index = {n: i for i, n in names.items()}
    pat = re.compile(r"\b(" + "|".join(map(re.escape, names.values())) + r")\((.*)\)")
    for line in lines:
        m = pat.search(line)
        if m and m.group(2).count(",") + 1 > MAX_CALL_ARGS:
            k = lay.kernels[index[m.group(1)]]
            raise PluginError(f"kernel {_name(k.func)}: the loop's call takes {m.group(2).count(',') + 1} arguments "
                              f"with its {len(k.static)} static options, more than the {MAX_CALL_ARGS} numba can inline "
                              "(CPython passes more as *args): move some options into its params")


def _name(func) -> str:
    """A kernel function's name for a message."""
    py = getattr(func, "py_func", func)
    return f"{getattr(py, '__module__', '?')}.{getattr(py, '__qualname__', repr(py))}"


def _ch(k: KernelSpec) -> str:
    """The channel argument of a corrector kernel's call (none for one that does not take it)."""
    return ", ch" if k.channel else ""


def _st(k: KernelSpec, i: int) -> str:
    """The kernel's compile-time options, the arguments at the end of its call: literals in a loop
    that inlines its kernels (numba then compiles only the branches they select), and read from
    the end of the kernel's parameter vector (:func:`static_params`) in one that calls them, so
    that one loop, and one compiled kernel, serves every value of them (the test suite's)."""
    if _numba.LOOP_INLINE:
        return "".join(f", {v!r}" for v in k.static)
    m = len(k.static)
    return "".join(f", p{i}[p{i}.shape[0] - {m - j}] != 0.0" for j in range(m))


def static_params(params, static: tuple):
    """A kernel's parameter vector as the loop packs it: ``params`` with its static options
    appended (1.0 / 0.0), which a loop that calls its kernels passes from there (:func:`_st`)."""
    import numpy as np

    return np.concatenate([params, np.array(static, dtype=float)]) if static else params


def _withholds(lay: Layout) -> bool:
    """Whether the bias or factor correctors' lines already set ``ga_ok`` / ``gm_ok``."""
    return any(k.role in ("bias", "factor") for k in lay.kernels)


def _bias_lines(lay: Layout, names: dict[int, str], factors: bool) -> list[str]:
    """Before the propagation: the bias correctors update the gyro bias ``bv`` (the alignment's,
    in the run state); with factor correctors, ``w`` keeps the rate the propagation integrates."""
    if not _withholds(lay):
        return []
    rc = lay.rcorr
    L = ["    ga_ok = acc_ok and (flags & 512) == 0", "    gm_ok = mag_ok and (flags & 256) == 0"]
    for i, k in enumerate(lay.kernels):
        if k.role == "bias":
            L += [f"    cf = {names[i]}(s{i}, bv, g0, g1, g2, a0, a1, a2, m0, m1, m2, ga_ok, gm_ok, flags, h, p{i}"
                  f"{_ch(k)}{_st(k, i)})",
                  "    if cf > 0:", "        flags |= cf"]
    if factors:  # h: the way back from the end of the step to its middle, exp(-w dt / 2), once per sample
        L += ["    hh = -0.5 * h",
              f"    h0, h1, h2, h3 = rotvec_quat_entries((g0 - bv[0] + al[{rc}]) * hh, "
              f"(g1 - bv[1] + al[{rc + 1}]) * hh, (g2 - bv[2] + al[{rc + 2}]) * hh)"]
    return L


def _views(lay: Layout) -> list[str]:
    n = len(lay.kernels)

    def pa(j):  # the bounds of parameter vector j in O (after the n + 2 states' bounds)
        return 2 * (n + 2) + 2 * j

    out = ["x = S[O[0]:O[1]]", f"al = S[O[{2 * n + 2}]:O[{2 * n + 3}]]",
           f"ep = P[O[{pa(0)}]:O[{pa(0) + 1}]]", f"ap = P[O[{pa(n + 1)}]:O[{pa(n + 1) + 1}]]",
           f"pp = P[O[{pa(n + 2)}]:O[{pa(n + 2) + 1}]]"]
    for i in range(n):
        out += [f"s{i} = S[O[{2 + 2 * i}]:O[{3 + 2 * i}]]", f"p{i} = P[O[{pa(i + 1)}]:O[{pa(i + 1) + 1}]]"]
    out += ["rate = np.zeros(3)", "v = np.empty(9)", "motion = int(pp[2])"]
    if _withholds(lay):  # the gyro bias, a view of the run state
        out.append(f"bv = al[{BIAS}:{BIAS + 3}]")
    if any(k.channel for k in lay.kernels):  # the correctors' channel, a view of the run state
        out.append(f"ch = al[{lay.chan}:{lay.chan + CHANNEL_SIZE}]")
    return ["    " + s for s in out]


# -- the loop calls its per-sample kernels inline ---------------------------------------------
#
# A call from the loop to a separately compiled kernel passes every array as its parts and keeps
# the state in memory across the call; the kernels inlined (numba's IR inlining of
# :func:`fusionkit._numba.inline_copy` twins, the kernels' own helpers included) make one body
# that LLVM optimises as a whole. Only ``loop`` does (``step`` calls ``loop``): the rare paths
# (the alignment and its end) keep the calls, which costs less compile time.
# With ``fusionkit._numba.LOOP_INLINE`` off (the test suite's setting) the loop calls the kernels
# instead (``call_copy``): the same numbers, a fraction of the compile time.

_INLINE = "i_"


def _hot(lay: Layout) -> list[str]:
    """The names the loop calls inline: every sample's validity, propagation and output, and
    every plugin kernel."""
    return ["validity_flags", "e_propagate", "e_to_quat"] + [f"k{i}" for i in range(len(lay.kernels))]


def _inlined(lines: list[str], hot: list[str]) -> list[str]:
    """``lines`` with each call of a name in ``hot`` made a call of its inline twin."""
    pat = re.compile(r"\b(" + "|".join(map(re.escape, hot)) + r")\(")
    return [pat.sub(lambda m: f"{_INLINE}{m.group(1)}(", s) for s in lines]


def source(lay: Layout, cache: bool, imports: dict[int, tuple[str, str]] | None,
           est_imports: list[tuple[str, str]] | None = None) -> str:
    """The module's text. ``imports``: kernel index -> (module, name) to import it from, and
    ``est_imports`` the estimator's three functions; None: they are provided as globals
    (``k0, k1, ...``, ``e_propagate``, ...) by the in-memory build."""
    names = {i: f"k{i}" for i in range(len(lay.kernels))}
    head = ["# Generated by fusionkit._loopgen: a pipeline's compiled loop. Do not edit."]
    if imports is not None:
        head += ["import math", "import numpy as np", "from fusionkit._numba import call_copy, inline_copy, njit",
                 "from fusionkit._kernels import rotvec_quat_entries, validity_flags",
                 "from fusionkit.navigation.alignment import align_step"]
        head += [f"from {m} import {n} as e_{w}" for (m, n), w in
                 zip(est_imports, ("propagate", "to_quat", "from_quat"))]
        head += [f"from {mod} import {name} as {names[i]}" for i, (mod, name) in sorted(imports.items())]
    gn_load = ["        r = min(k, last)",
               "        n0, n1, n2, n3, n4, n5 = gn[r, 0], gn[r, 1], gn[r, 2], gn[r, 3], gn[r, 4], gn[r, 5]"]
    hot = _hot(lay)
    twin = "inline_copy" if _numba.LOOP_INLINE else "call_copy"  # (the test suite's: FUSIONKIT_LOOP_INLINE)
    head += ["", f"# the loop calls these through fusionkit._numba.{twin}; step() calls the kernels"]
    head += [f"{_INLINE}{n} = {twin}({n})" for n in hot]
    loop = ["", "", f"@njit(cache={cache}, forward_copies=True)",
            "def loop(gyr, acc, mag, dt, has_mag, S, P, O, out_q, out_f, out_c, start, stop, gn):",
            *_views(lay), "    q = np.empty(4)", "    last = gn.shape[0] - 1", "    n0 = n1 = n2 = n3 = n4 = n5 = 0.0",
            "    ms = 1 if has_mag else 0  # without a magnetometer: its row 0 each sample (never judged valid)",
            "    for k in range(start, stop):",
            "        g0, g1, g2 = gyr[k, 0], gyr[k, 1], gyr[k, 2]",
            "        a0, a1, a2 = acc[k, 0], acc[k, 1], acc[k, 2]",
            "        m0, m1, m2 = mag[k * ms, 0], mag[k * ms, 1], mag[k * ms, 2]",
            "        h = dt[k]",
            *(gn_load if lay.uses_gnss else []),
            *_inlined(_body(lay, names, "        "), hot),
            "        out_q[k, 0], out_q[k, 1], out_q[k, 2], out_q[k, 3] = q[0], q[1], q[2], q[3]",
            "        out_f[k] = flags", "        out_c[k] = crit"]
    step = _step(cache, len(lay.kernels))
    return "\n".join(head + loop + step + _step_sample(cache, len(lay.kernels)))


def _step(cache: bool, n: int) -> list[str]:
    """``step``: ``loop`` run over a one-sample recording made of its arguments.

    The same compiled code serves ``run()`` and ``update()``, so a stream's results are the
    loop's by construction, and a composition pays one compile, not a second one for a separately
    typed and lowered one-sample body. The one-sample arrays are views of ``S``'s tail past the
    states (:data:`STEP_WORK` entries, which :meth:`Pipeline.update`'s stream appends): no
    allocation per call but the two flags (an ``S`` without the tail gets fresh arrays)."""
    return ["", "", f"@njit(cache={cache})", f"def step({_SAMPLE}, h, has_mag, S, P, O, q, {_GN}):",
            *_one_sample(n, _GN), "    return fc[0], fc[1]", ""]


def _one_sample(n: int, gnss: str) -> list[str]:
    """The body ``step`` and ``step_sample`` share: the sample written into ``S``'s tail, ``loop``
    run over it, the orientation copied out (``gnss``: the row's six values, names or constants)."""
    end = 2 * n + 3  # the run state's end in O: the last state's
    return [f"    e = O[{end}]",
            f"    W = S[e:e + {STEP_WORK}] if S.shape[0] - e >= {STEP_WORK} else np.empty({STEP_WORK})",
            "    w = W[0:9].reshape((3, 1, 3))",
            "    w[0, 0, 0], w[0, 0, 1], w[0, 0, 2] = g0, g1, g2",
            "    w[1, 0, 0], w[1, 0, 1], w[1, 0, 2] = a0, a1, a2",
            "    w[2, 0, 0], w[2, 0, 1], w[2, 0, 2] = m0, m1, m2",
            "    dt = W[9:10]", "    dt[0] = h",
            "    gn = W[10:16].reshape((1, 6))",
            f"    gn[0, 0], gn[0, 1], gn[0, 2], gn[0, 3], gn[0, 4], gn[0, 5] = {gnss}",
            "    out_q = W[16:20].reshape((1, 4))", "    fc = np.zeros(2, np.uint32)",
            "    loop(w[0], w[1], w[2], dt, has_mag, S, P, O, out_q, fc[0:1], fc[1:2], np.int64(0), np.int64(1), gn)",
            "    q[0], q[1], q[2], q[3] = out_q[0, 0], out_q[0, 1], out_q[0, 2], out_q[0, 3]"]


def _step_sample(cache: bool, n: int) -> list[str]:
    """``step_sample``: ``step`` without a GNSS row, returning the flags: ``update()``'s fast path
    (each argument of a call from Python costs its type check, and most streams have no GNSS).
    It runs ``loop`` itself rather than calling ``step``: numba optimises a callee again inside
    each caller, so a stream without GNSS (most) would otherwise compile ``step`` too."""
    gn = ", ".join("math.nan" if v != v else "math.inf" if v == math.inf else repr(float(v)) for v in NO_GNSS)
    return ["", f"@njit(cache={cache})", f"def step_sample({_SAMPLE}, h, has_mag, S, P, O, q):",
            *_one_sample(n, gn), "    return fc[0]", ""]


# -- building and caching -------------------------------------------------------------------

_BUILT: dict[Any, Any] = {}


def cache_base() -> Path:
    """fusionkit's cache directory: ``$FUSIONKIT_CACHE_DIR``, else ``$XDG_CACHE_HOME/fusionkit`` or
    ``~/.cache/fusionkit`` (the compiled loops' and the bench results' home)."""
    env = os.environ.get("FUSIONKIT_CACHE_DIR")
    return Path(env) if env else Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "fusionkit"


def cache_dir() -> Path | None:
    """Where generated loops are written: ``loops/`` under :func:`cache_base`, else (without
    ``$FUSIONKIT_CACHE_DIR``) under a per-user temporary directory; None when none is writable (the
    loops are then compiled in memory)."""
    cands = [cache_base()]
    if not os.environ.get("FUSIONKIT_CACHE_DIR"):
        cands.append(Path(tempfile.gettempdir()) / f"fusionkit-{os.getuid() if hasattr(os, 'getuid') else 'user'}")
    for d in cands:
        try:
            (d / "loops").mkdir(parents=True, exist_ok=True)
            if os.access(d / "loops", os.W_OK):
                return d / "loops"
        except OSError:
            continue
    return None


def _fingerprint(module: str) -> str:
    """A hash of the source of the package a kernel comes from (fusionkit's, or a plugin's): a
    kernel calls helpers from other modules of its package, which numba compiles into the cached
    loop, so an edit anywhere in the package must make a new cache entry (:mod:`fusionkit._sources`)."""
    top = module.split(".")[0]
    return fusionkit_hash() if top == "fusionkit" else (source_hash(top) or "")


def _static_blind(lay: Layout) -> Layout:
    """``lay`` with every kernel's static options set to False: what a loop that calls its kernels is
    generated from (its source reads their values from the parameters, :func:`_st`), so that every
    value of them is one module in the process, not one each with the same source."""
    ks = tuple(replace(k, static=(False,) * len(k.static)) if k.static else k for k in lay.kernels)
    return replace(lay, kernels=ks)


def get_compiled(lay: Layout):
    """The module holding ``loop`` and ``step`` for ``lay`` (built once per process; from the
    disk cache when every kernel can be imported by name)."""
    if not _numba.LOOP_INLINE:  # (the called loop reads the static options from the parameters: one for every value)
        lay = _static_blind(lay)
    key = (lay, _numba.LOOP_INLINE)
    if key in _BUILT:
        return _BUILT[key]
    funcs = {i: k.func for i, k in enumerate(lay.kernels)}
    for f in (*lay.est, *funcs.values()):  # a plugin's own numba.njit: fusionkit's cache stamp
        _numba.adopt(f)
    refs = {i: _ref(f) for i, f in funcs.items()}
    est_refs = [_ref(f) for f in lay.est]
    where = cache_dir()
    mod = None
    if where is not None and all(r is not None for r in list(refs.values()) + est_refs):
        import numba

        from . import __version__

        text = source(lay, True, refs, est_refs)
        mods = sorted({m for m, _ in list(refs.values()) + est_refs})
        digest = hashlib.sha256("\n".join([text, numba.__version__, __version__]
                                          + [_fingerprint(m) for m in mods]).encode()).hexdigest()[:24]
        path = where / f"loop_{digest}.py"
        try:
            if not path.exists():
                tmp = path.with_suffix(f".{os.getpid()}.tmp")
                tmp.write_text(text)
                os.replace(tmp, path)
            name = f"_fusionkit_loop_{digest}"
            spec = importlib.util.spec_from_file_location(name, path)
            mod = importlib.util.module_from_spec(spec)
            sys.modules[name] = mod
            spec.loader.exec_module(mod)
        except OSError:
            mod = None
    if mod is None:  # in memory: the kernels as globals, no disk cache
        import types

        import numpy as np

        from ._kernels import rotvec_quat_entries, validity_flags
        from ._numba import call_copy, inline_copy, njit
        from .navigation.alignment import align_step

        mod = types.ModuleType("_fusionkit_loop_memory")
        ns = mod.__dict__
        ns.update({f"k{i}": f for i, f in funcs.items()}, math=math, np=np, njit=njit, inline_copy=inline_copy,
                  call_copy=call_copy,
                  validity_flags=validity_flags, align_step=align_step, rotvec_quat_entries=rotvec_quat_entries,
                  e_propagate=lay.est[0], e_to_quat=lay.est[1], e_from_quat=lay.est[2])
        exec(compile(source(lay, False, None), "<fusionkit pipeline loop>", "exec"), ns)
    _BUILT[key] = mod
    return mod
