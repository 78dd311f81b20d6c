r"""Simulation of a delayed second-order system.

.. math::

    m\,\ddot x + \sum_i c_i\, g_i(x, \dot x) = f(t) + b\, x^{(q)}(t - \tau)

is integrated with the classical fixed-step Runge–Kutta method.  The delayed state is read
from a history buffer by cubic Hermite interpolation between stored nodes (position with
velocity, or velocity with acceleration), which keeps the method fourth-order accurate for
any :math:`\tau \ge h`.  Before :math:`t = 0` the feedback sees either nothing
(``history = "zero"``: the loop is closed at :math:`t=0`, as in the paper's simulator) or
the initial state held constant (``history = "initial"``).

Parameters may be given for a batch of ``B`` systems at once (arrays of shape ``(B,)`` or
``(B, k)``); one pass then simulates all of them, which is what a finite-difference
Jacobian needs.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
from numba import njit
from scipy.interpolate import CubicSpline

from cvxid.errors import CvxidError
from cvxid.model.terms import (
    AbsProduct,
    Constant,
    Monomial,
    Sign,
    Term,
    velocity_symbol,
)

HISTORIES = ("zero", "initial")
MAX_SUBSTEPS = 16
"""Most integration steps per sample that a short delay may ask for."""
DIVERGED = 1e8


class SimulationDiverged(CvxidError):
    """The simulated state left every reasonable bound."""


@dataclass(frozen=True)
class System:
    """A delayed second-order system with numeric coefficients."""

    terms: tuple[Term, ...]
    coefficients: np.ndarray  # (k,) or (B, k)
    mass: float | np.ndarray = 1.0
    coordinate: str = "x"
    gain: float | np.ndarray = 0.0
    tau: float | np.ndarray = 0.0
    derivative: int = 0
    history: str = "zero"

    def __post_init__(self):
        if self.history not in HISTORIES:
            raise CvxidError(f"history must be one of {', '.join(HISTORIES)}, got '{self.history}'")
        if np.any(np.asarray(self.tau) < 0):
            raise CvxidError(f"the delay must be >= 0, got {self.tau}")

    def equation(self) -> str:
        coefs = np.atleast_2d(self.coefficients)[0]
        lhs = f"{float(np.ravel(self.mass)[0]):.6g} {self.coordinate}''"
        for t, c in zip(self.terms, coefs):
            lhs += f" {'-' if c < 0 else '+'} {abs(c):.6g} {t.name}"
        rhs = "f"
        gain = float(np.ravel(self.gain)[0])
        if gain:
            s = self.coordinate + "'" * self.derivative
            rhs += f" {'-' if gain < 0 else '+'} {abs(gain):.6g} {s}(t - {float(np.ravel(self.tau)[0]):.6g})"
        return f"{lhs} = {rhs}"


def simulate(
    system: System,
    time: np.ndarray,
    force: Callable[[np.ndarray], np.ndarray] | np.ndarray,
    x0: float | np.ndarray,
    v0: float | np.ndarray,
    substeps: int = 1,
) -> tuple[np.ndarray, np.ndarray]:
    """Positions and velocities at the sample ``time`` (uniform, from its first value).

    ``force`` is a function of time or samples on ``time`` (then interpolated by a cubic
    spline between samples).  Returns arrays of shape ``(n,)``, or ``(n, B)`` for a batch.
    """
    if np.any(np.asarray(system.mass) <= 0):
        raise SimulationDiverged(
            f"the model's mass is {system.mass} (not positive): it cannot be simulated; "
            "constrain the inertia to be positive or use richer data"
        )
    t = np.asarray(time, dtype=float)
    n = t.size
    dt = float((t[-1] - t[0]) / (n - 1))
    coefs = np.atleast_2d(np.asarray(system.coefficients, dtype=float))
    batch = max(coefs.shape[0], np.size(system.mass), np.size(system.tau), np.size(system.gain), np.size(x0), np.size(v0))
    coefs = np.broadcast_to(coefs, (batch, coefs.shape[1])).T.copy()  # (k, B)
    mass = np.broadcast_to(np.asarray(system.mass, float), (batch,))
    tau = np.broadcast_to(np.asarray(system.tau, float), (batch,))
    gain = np.broadcast_to(np.asarray(system.gain, float), (batch,))
    delayed = bool(np.any(gain != 0) and np.any(tau > 0))
    substeps = int(substeps)
    resolvable = tau[tau >= dt / MAX_SUBSTEPS]
    if delayed and resolvable.size:
        substeps = max(substeps, int(np.ceil(dt / resolvable.min() - 1e-12)))
    h = dt / substeps
    instant = tau < h  # delays shorter than a step act on the current state (error O(tau))
    steps = (n - 1) * substeps
    f = half_steps(force, t, h, steps)
    f = np.broadcast_to(f[:, None] if f.ndim == 1 else f, (2 * steps + 1, batch))

    X = np.zeros((steps + 1, batch))
    V = np.zeros((steps + 1, batch))
    A = np.zeros((steps + 1, batch))
    X[0], V[0] = x0, v0
    cols = np.arange(batch)
    pos, vel = system.coordinate, velocity_symbol(system.coordinate)
    q = system.derivative
    y_hist = X if q == 0 else V
    d_hist = V if q == 0 else A

    offs, ws = hermite_stages(tau, h)
    fill = X[0] if (system.history == "initial" and q == 0) else np.zeros(batch)
    codes = _term_codes(system)
    if codes is not None:
        xs, vs, failed = _rk4_kernel(
            np.ascontiguousarray(f), mass.copy(), coefs, *codes, gain.copy(), q, offs, ws,
            instant.copy(), fill.copy(), delayed, X[0].copy(), V[0].copy(), h, steps, substeps,
        )
        if failed >= 0:
            _diverged(t[0] + failed * h)
        return _shape(system, xs, vs)

    def lagged(k, ci):
        """x^(q)(t_k + c h - tau), c = (0, 1/2, 1)[ci], from the buffer (or the history
        before t = 0)."""
        w0, w1, w2, w3 = ws[ci]
        i = k + offs[ci]
        # the stage at the end of a step reads the left limit at t = 0 (a step ends there)
        early = (i < 0) | ((i == 0) & (w0 == 1.0) & (ci == 2))
        j = np.clip(i, 0, steps - 1)  # (delays shorter than a step never use the value)
        out = w0 * y_hist[j, cols] + w1 * d_hist[j, cols] + w2 * y_hist[j + 1, cols] + w3 * d_hist[j + 1, cols]
        return np.where(early, fill, out)

    def accel(step2, x, v, k, ci):
        rhs = f[step2].copy()
        if delayed:
            rhs += gain * np.where(instant, x if q == 0 else v, lagged(k, ci))
        states = {pos: x, vel: v}
        for term, coef in zip(system.terms, coefs):
            rhs -= coef * term.evaluate(states)
        return rhs / mass

    x, v = X[0].copy(), V[0].copy()
    for k in range(steps):
        a1 = accel(2 * k, x, v, k, 0)
        A[k] = a1
        x2, v2 = x + 0.5 * h * v, v + 0.5 * h * a1
        a2 = accel(2 * k + 1, x2, v2, k, 1)
        x3, v3 = x + 0.5 * h * v2, v + 0.5 * h * a2
        a3 = accel(2 * k + 1, x3, v3, k, 1)
        x4, v4 = x + h * v3, v + h * a3
        a4 = accel(2 * k + 2, x4, v4, k, 2)
        x = x + h / 6 * (v + 2 * v2 + 2 * v3 + v4)
        v = v + h / 6 * (a1 + 2 * a2 + 2 * a3 + a4)
        X[k + 1], V[k + 1] = x, v
        if not (np.abs(x).max() < DIVERGED and np.abs(v).max() < DIVERGED):
            _diverged(t[0] + (k + 1) * h)
    return _shape(system, X[::substeps], V[::substeps])


def half_steps(force: Callable[[np.ndarray], np.ndarray] | np.ndarray, t: np.ndarray, h: float,
               steps: int) -> np.ndarray:
    """The force at every RK4 node and midpoint :math:`t_0 + j h/2`: called when it is a
    function of time, else a cubic spline through its samples on ``t``."""
    fine = t[0] + 0.5 * h * np.arange(2 * steps + 1)
    if callable(force):
        return np.asarray(force(fine), dtype=float)
    samples = np.asarray(force, dtype=float)
    if samples.shape != t.shape:
        raise CvxidError(f"force has {samples.size} samples, time has {t.size}")
    return CubicSpline(t, samples)(fine)


def hermite_stages(tau: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """Where the delayed times :math:`t_k + c h - \\tau` of the RK4 stages
    (:math:`c = 0, 1/2, 1`) fall on the grid: the node offset ``(3, B)`` from step ``k`` and
    the cubic Hermite weights ``(3, 4, B)`` of (value, slope, next value, next slope).  Both
    are the same for every step, so they are computed once."""
    offs, ws = [], []
    for c in (0.0, 0.5, 1.0):
        u = c - np.asarray(tau, float) / h
        u = np.where(np.abs(u - np.round(u)) < 1e-9, np.round(u), u)
        off = np.floor(u).astype(int)
        theta = u - off
        t2, t3 = theta * theta, theta**3
        offs.append(off)
        ws.append(np.array([2 * t3 - 3 * t2 + 1, (t3 - 2 * t2 + theta) * h, -2 * t3 + 3 * t2, (t3 - t2) * h]))
    return np.array(offs), np.array(ws)


def _diverged(when: float):
    raise SimulationDiverged(
        f"the simulation diverged at t = {when:.4g} s (|x| or |x'| > {DIVERGED:g}): the model "
        "is unstable under this input; check its coefficients"
    )


def _shape(system: System, xs: np.ndarray, vs: np.ndarray):
    single = all(np.ndim(a) == 0 for a in (system.tau, system.gain, system.mass))
    if xs.shape[1] == 1 and np.ndim(system.coefficients) == 1 and single:
        return xs[:, 0], vs[:, 0]
    return xs, vs


def _term_codes(system: System):
    """(kinds, powers of x, powers of x') of terms the compiled kernel knows, else None."""
    pos, vel = system.coordinate, velocity_symbol(system.coordinate)
    kinds, px, pv = [], [], []
    for term in system.terms:
        if isinstance(term, Monomial) and set(term.factors) <= {pos, vel}:
            kinds.append(0)
            px.append(term.factors.get(pos, 0))
            pv.append(term.factors.get(vel, 0))
        elif isinstance(term, Constant):
            kinds.append(0)
            px.append(0)
            pv.append(0)
        elif isinstance(term, (Sign, AbsProduct)) and term.coordinate == pos and not getattr(term, "smoothing", 0):
            kinds.append(1 if isinstance(term, Sign) else 2)
            px.append(0)
            pv.append(0)
        else:
            return None  # a user's own term: the Python integrator runs it
    return np.array(kinds, np.int64), np.array(px, np.int64), np.array(pv, np.int64)


@njit(cache=True)
def _accel_kernel(b, x, v, fk, k, ci, mass, coefs, kinds, px, pv, gain, q, offs, ws, instant, fill,
                  delayed, X, V, A, steps):
    rhs = fk
    if delayed and gain[b] != 0.0:
        if instant[b]:
            d = x if q == 0 else v
        else:
            i = k + offs[ci, b]
            w0, w1, w2, w3 = ws[ci, 0, b], ws[ci, 1, b], ws[ci, 2, b], ws[ci, 3, b]
            if i < 0 or (i == 0 and w0 == 1.0 and ci == 2):
                d = fill[b]
            else:
                j = min(i, steps - 1)
                if q == 0:
                    d = w0 * X[j, b] + w1 * V[j, b] + w2 * X[j + 1, b] + w3 * V[j + 1, b]
                else:
                    d = w0 * V[j, b] + w1 * A[j, b] + w2 * V[j + 1, b] + w3 * A[j + 1, b]
        rhs += gain[b] * d
    for m in range(kinds.size):
        if kinds[m] == 0:
            val = x ** px[m] * v ** pv[m]
        elif kinds[m] == 1:
            val = 1.0 if v > 0 else (-1.0 if v < 0 else 0.0)
        else:
            val = v * abs(v)
        rhs -= coefs[m, b] * val
    return rhs / mass[b]


@njit(cache=True)
def _rk4_kernel(f, mass, coefs, kinds, px, pv, gain, q, offs, ws, instant, fill, delayed, x0, v0, h,
                steps, stride):
    """The same RK4 with history buffer as the Python loop, compiled (one system at a time)."""
    batch = x0.size
    X = np.zeros((steps + 1, batch))
    V = np.zeros((steps + 1, batch))
    A = np.zeros((steps + 1, batch))
    failed = -1
    args = (mass, coefs, kinds, px, pv, gain, q, offs, ws, instant, fill, delayed)
    for b in range(batch):
        x, v = x0[b], v0[b]
        X[0, b], V[0, b] = x, v
        for k in range(steps):
            a1 = _accel_kernel(b, x, v, f[2 * k, b], k, 0, *args, X, V, A, steps)
            A[k, b] = a1
            x2, v2 = x + 0.5 * h * v, v + 0.5 * h * a1
            a2 = _accel_kernel(b, x2, v2, f[2 * k + 1, b], k, 1, *args, X, V, A, steps)
            x3, v3 = x + 0.5 * h * v2, v + 0.5 * h * a2
            a3 = _accel_kernel(b, x3, v3, f[2 * k + 1, b], k, 1, *args, X, V, A, steps)
            x4, v4 = x + h * v3, v + h * a3
            a4 = _accel_kernel(b, x4, v4, f[2 * k + 2, b], k, 2, *args, X, V, A, steps)
            x = x + h / 6 * (v + 2 * v2 + 2 * v3 + v4)
            v = v + h / 6 * (a1 + 2 * a2 + 2 * a3 + a4)
            X[k + 1, b], V[k + 1, b] = x, v
            if not (abs(x) < 1e8 and abs(v) < 1e8):
                if failed < 0 or k + 1 < failed:
                    failed = k + 1
                break
    return X[::stride].copy(), V[::stride].copy(), failed
