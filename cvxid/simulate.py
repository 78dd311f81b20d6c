r"""Simulation of delayed second-order systems: one integrator for N >= 1 coordinates.

.. math::

    m_i\,\ddot q_i + \sum_j c_{ij}\, g_{ij}(q, \dot q) = \beta_i\, u_i(t) + b_i\, q_d^{(r)}(t-\tau),
    \qquad i = 1..N,

where every equation has its own coordinate :math:`q_i` (its second derivative is the
equation's inertia), the terms may read every coordinate, and :math:`q_d^{(r)}` (position,
:math:`r = 0`, or velocity, :math:`r = 1`) of one coordinate is fed back with the delay
:math:`\tau`.  A single equation (:class:`System`) is the case :math:`N = 1`; a coupled
one is a :class:`CoupledSystem`.  Both run through :func:`integrate`.

The method is the classical fixed-step Runge–Kutta method.  An equation's own Coulomb
friction :math:`F_c\,\operatorname{sign}(\dot q_i)` (:math:`F_c > 0`) is the force that
would bring the motion to rest within one step, up to its bound,

.. math::

    F = \operatorname{clip}\big(R_i + m_i \dot q_i / h,\; -F_c,\; F_c\big),

with :math:`R_i` the equation's other forces: the motion sticks while they stay below
:math:`F_c`, and slides with :math:`\pm F_c` once the speed is more than a step's friction
from rest.  The same friction (its direction :math:`F/F_c \in [-1, 1]`) acts on the other
equations that read it.  The force is continuous in the state and the parameters, so the
simulation is too: a sign switched inside a step (or Karnopp's band, which balanced the
forces within :math:`|\dot q_i| \le h F_c/m_i` and jumped at its edge) makes the
simulation jump as a parameter moves, and an output-error fit then stops wherever its
finite differences happen to straddle a jump (measured: the delay's median error on
held-out Coulomb systems 3.1 % → 1.6 %, the 95 % intervals covering 75 % → 95 %;
docs/benchmarks.md).  A negative coefficient pushes (:math:`F_c\operatorname{sign}`,
nothing to stick).  With friction the scheme is first order in :math:`h` (the motion comes
to rest over one step: on `hidden_friction`'s system the error is 3.9e-3 at the sample
step and halves with each halving, against 1.0e-3 with the band), and a coordinate held by
its own friction creeps at :math:`O(h)` while another equation's friction pushes on it (the
clip sees that push only after it).  The delayed state is read from
a history buffer by cubic Hermite interpolation between stored nodes (position with
velocity, or velocity with acceleration), which keeps the method fourth-order accurate for
any :math:`\tau \ge h`; a delay shorter than the sample step is resolved by sub-steps, and
one shorter than a step acts on the current state.  Before the first sample the feedback
reads

* ``history = "measured"``: a given past signal (``past``: a function of time returning the
  delayed signal and its slope, e.g. the smoothed measurement before the simulation's
  start), interpolated like the simulated history, so the simulation is smooth in
  :math:`\tau`;
* ``history = "zero"``: nothing (the loop is closed at :math:`t=0`, as in the paper's
  simulator);
* ``history = "initial"``: the initial position held constant.

Parameters may be given for a batch of ``B`` systems at once; one pass then simulates all
of them, which is what a finite-difference Jacobian needs.  Terms the compiled kernel knows
(monomials of the coordinates and their velocities, constants, ``sign(q')`` — smoothed or
not — and ``q'|q'|``) run compiled; a user's own term runs the same scheme in Python.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
from numba import njit, prange
from scipy.interpolate import CubicSpline

from cvxid.errors import CvxidError
from cvxid.model.delay import HISTORIES
from cvxid.metrics import band_edge
from cvxid.model.expression import (ABS, ADD, CONST, COS, DIV, EXP, MUL, NEG, POSITION, POW, SIGN, SIN, SUB,
                                    TANH, VELOCITY)
from cvxid.model.terms import (
    AbsProduct,
    Constant,
    Expression,
    Monomial,
    Sign,
    Term,
    velocity_symbol,
)


STEP_PHASE = 0.25
"""Largest phase advance :math:`\\omega h` of one RK4 step at the output's band edge: a
record sampled at only a few times its bandwidth (the Silverbox: :math:`\\omega\\,dt =
0.84`) is integrated in sub-steps, so that a model is simulated as the continuous system it
is and not as the discretisation RK4 makes of it at the sample step (there the Silverbox's
output-error model reaches 0.286 mV on its test; simulated at a quarter step it is 2 mV off,
and fitted at a quarter step it reaches 0.258 mV)."""

MAX_SUBSTEPS = 16
"""Most integration steps per sample that a short delay may ask for."""
DIVERGED = 1e8

Force = Callable[[np.ndarray], np.ndarray] | np.ndarray
Past = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]
"""The delayed signal before the start: times -> (values, slopes)."""


class SimulationDiverged(CvxidError):
    """The simulated state left every reasonable bound."""


@dataclass(frozen=True)
class System:
    """A delayed second-order system of one coordinate with numeric coefficients."""

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


@dataclass(frozen=True)
class Equation:
    """One equation of a coupled system with numeric coefficients."""

    coordinate: str
    mass: float
    terms: tuple[Term, ...]
    coefficients: tuple[float, ...]
    input_gain: float = 1.0
    delay_gain: float = 0.0


@dataclass(frozen=True)
class CoupledSystem:
    """Several equations sharing one delayed coordinate (its position, or with
    ``derivative = 1`` its velocity, is fed back)."""

    equations: tuple[Equation, ...]
    delayed: str
    tau: float
    history: str = "zero"
    derivative: int = 0

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Coefficients ``(T, 1)``, inertias and delay gains ``(C, 1)``: a batch of one for
        :func:`integrate`."""
        return (np.concatenate([eq.coefficients for eq in self.equations])[:, None],
                np.array([[eq.mass] for eq in self.equations]), np.array([[eq.delay_gain] for eq in self.equations]))


def substeps_for(output: np.ndarray, dt: float) -> int:
    """Sub-steps per sample for an accurate simulation of a record: :math:`\\lceil \\omega_{95}
    dt / \\text{STEP\\_PHASE} \\rceil`, :math:`\\omega_{95}` the output's 95 % band edge
    (:func:`~cvxid.metrics.band_edge`); 1 for records sampled well above their band."""
    finite = np.asarray(output, float)
    finite = finite[np.isfinite(finite)]
    if finite.size < 8:
        return 1
    return int(min(MAX_SUBSTEPS, max(1, np.ceil(band_edge(finite, dt) * dt / STEP_PHASE - 1e-9))))


# ---------------------------------------------------------------------- entry points
def simulate(system: System, time: np.ndarray, force: Force, x0: float | np.ndarray, v0: float | np.ndarray,
             substeps: int = 1, past: Past | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Positions and velocities at the sample ``time`` (uniform, from its first value).

    ``force`` is a function of time (its value ``(S,)`` or, for a batch, ``(S, B)``) or
    samples on ``time`` (then interpolated by a cubic spline between samples); ``past``
    the delayed signal before ``time[0]`` (``history = "measured"``).  Returns arrays of
    shape ``(n,)``, or ``(n, B)`` for a batch.
    """
    coefs = np.atleast_2d(np.asarray(system.coefficients, dtype=float))
    batch = max(coefs.shape[0], np.size(system.mass), np.size(system.tau), np.size(system.gain), np.size(x0),
                np.size(v0))
    row = lambda a: np.broadcast_to(np.asarray(a, float), (batch,))[None, :]  # noqa: E731  (1, B)
    t = np.asarray(time, dtype=float)

    def forces(fine: np.ndarray, h: float) -> np.ndarray:
        f = half_steps(force, t, h, fine.size // 2)
        return f[:, None, None] if f.ndim == 1 else f[:, None, :]

    X, V = integrate(
        t, forces, [system.coordinate], [tuple(system.terms)], np.broadcast_to(coefs, (batch, coefs.shape[1])).T,
        row(system.mass), row(system.gain), row(system.tau)[0], row(x0), row(v0), 0, system.derivative,
        system.history, substeps, past,
    )
    xs, vs = X[:, 0, :], V[:, 0, :]
    single = all(np.ndim(a) == 0 for a in (system.tau, system.gain, system.mass))
    if xs.shape[1] == 1 and np.ndim(system.coefficients) == 1 and single:
        return xs[:, 0], vs[:, 0]
    return xs, vs


def simulate_coupled(system: CoupledSystem, time: np.ndarray, force: Force | list[Force], x0: dict,
                     v0: dict, past: Past | None = None, substeps: int = 1) -> tuple[dict, dict]:
    """Positions and velocities of every coordinate at the sample ``time``.  ``force`` is
    the shared input (a function of time or samples on ``time``) or a list of one input
    per equation, scaled by each equation's ``input_gain``; ``past`` and ``substeps`` as in
    :func:`simulate`.  Starts ``x0``, ``v0`` of shape ``(B,)`` (every coordinate's) are a
    batch of ``B`` runs of the same system, in parallel: the values then ``(n, B)``."""
    t = np.asarray(time, float)
    coords = [eq.coordinate for eq in system.equations]
    gains = np.array([eq.input_gain for eq in system.equations])
    inputs = force if isinstance(force, list) else [force] * len(coords)

    def forces(fine: np.ndarray, h: float) -> np.ndarray:
        each = np.column_stack([half_steps(f, t, h, fine.size // 2) for f in inputs])
        return (each * gains[None, :])[:, :, None]

    batch = np.ndim(x0[coords[0]]) > 0
    starts = [np.array([np.atleast_1d(np.asarray(s[c], float)) for c in coords]) for s in (x0, v0)]
    width = starts[0].shape[1]
    coefs, mass, delay_gain = (np.repeat(a, width, axis=1) for a in system.arrays())
    X, V = integrate(t, forces, coords, [eq.terms for eq in system.equations], coefs, mass, delay_gain,
                     np.full(width, system.tau), *starts, _delayed_index(system), system.derivative, system.history,
                     substeps, past)
    pick = (lambda a, j: a[:, j, :]) if batch else (lambda a, j: a[:, j, 0])  # noqa: E731
    return {c: pick(X, j) for j, c in enumerate(coords)}, {c: pick(V, j) for j, c in enumerate(coords)}


def _delayed_index(system: CoupledSystem) -> int:
    coords = [eq.coordinate for eq in system.equations]
    if system.delayed not in coords:
        raise CvxidError(f"the delayed coordinate {system.delayed!r} is not one of {coords}")
    return coords.index(system.delayed)


# ---------------------------------------------------------------------- the integrator
def integrate(t: np.ndarray, forces: Callable[[np.ndarray, float], np.ndarray], coordinates: list[str],
              terms: list[tuple[Term, ...]], coefs: np.ndarray, mass: np.ndarray, gain: np.ndarray, tau: np.ndarray,
              x0: np.ndarray, v0: np.ndarray, delayed: int, derivative: int = 0, history: str = "zero",
              substeps: int = 1, past: Past | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The one integrator.  ``C`` coordinates, ``B`` variants: ``terms[i]`` are equation
    ``i``'s terms, ``coefs`` ``(T, B)`` all equations' coefficients in order, ``mass`` and
    ``gain`` (of the delayed feedback) ``(C, B)``, ``tau`` ``(B,)``, initial states
    ``(C, B)``; ``forces(fine, h)`` gives each equation's input at the RK4 nodes and
    midpoints ``fine`` of step ``h``, broadcastable to ``(S, C, B)``; ``delayed`` is the
    index of the fed-back coordinate, ``derivative`` 0 (position) or 1 (velocity);
    ``past`` the fed-back signal before ``t[0]`` for ``history = "measured"``.
    Returns positions and velocities ``(n, C, B)`` at the samples ``t``."""
    if history not in HISTORIES:
        raise CvxidError(f"history must be one of {', '.join(HISTORIES)}, got '{history}'")
    mass, gain = np.asarray(mass, float), np.asarray(gain, float)
    if np.any(mass <= 0):
        raise SimulationDiverged(
            f"the model's inertia is {np.min(mass):g} (not positive): it cannot be simulated; "
            "constrain the inertia to be positive or use richer data"
        )
    n = t.size
    dt = float((t[-1] - t[0]) / (n - 1))
    C, B = mass.shape
    tau = np.broadcast_to(np.asarray(tau, float), (B,))
    substeps = delay_substeps(tau, dt, int(substeps)) if np.any(gain != 0) else int(substeps)
    h = dt / substeps
    steps = (n - 1) * substeps
    fine = t[0] + 0.5 * h * np.arange(2 * steps + 1)
    F = np.ascontiguousarray(np.broadcast_to(forces(fine, h), (fine.size, C, B)))
    instant = tau < h  # delays shorter than a step act on the current state (error O(tau))
    offs, ws = hermite_stages(tau, h)
    x0 = np.ascontiguousarray(np.broadcast_to(np.asarray(x0, float), (C, B)))
    v0 = np.ascontiguousarray(np.broadcast_to(np.asarray(v0, float), (C, B)))
    fill = x0[delayed].copy() if (history == "initial" and derivative == 0) else np.zeros(B)
    past_values, past_slopes = _past_nodes(history, past, t[0], tau, h, np.any(gain != 0))
    codes = _term_codes(coordinates, terms)
    # every array C-contiguous and writable: one compiled signature (numba types a read-only
    # view apart, and would compile the kernel again for it)
    own = lambda a: np.require(a, float, ["C", "W"])  # noqa: E731  (copies only when needed)
    args = (own(F), own(mass), own(coefs), own(gain), delayed, derivative, offs, ws, instant, own(fill),
            own(past_values), own(past_slopes), own(x0), own(v0), h, steps)
    if codes is not None:
        X, V, failed = _kernel(codes, *args)
    else:
        X, V, failed = _python_kernel(coordinates, terms, *args)
    if failed >= 0:
        raise SimulationDiverged(
            f"the simulation diverged at t = {t[0] + failed * h:.4g} s (|x| or |x'| > {DIVERGED:g}): the model "
            "is unstable under this input; check its coefficients"
        )
    return X[::substeps], V[::substeps]


def delay_substeps(tau: np.ndarray, dt: float, substeps: int = 1) -> int:
    """Sub-steps per sample of a batch whose fed-back delays are ``tau``: at least one step
    per shortest resolvable delay (shorter than ``dt / MAX_SUBSTEPS`` acts at once)."""
    tau = np.atleast_1d(np.asarray(tau, float))
    resolvable = tau[tau >= dt / MAX_SUBSTEPS]
    return max(substeps, int(np.ceil(dt / resolvable.min() - 1e-12))) if resolvable.size else substeps


def _past_nodes(history: str, past: Past | None, start: float, tau: np.ndarray, h: float,
                fed_back: bool) -> tuple[np.ndarray, np.ndarray]:
    """The past signal and its slope at the nodes ``start - j h`` that the longest delay
    reads (oldest first), or empty arrays when the history is assumed."""
    if history != "measured" or not fed_back:
        return np.zeros(0), np.zeros(0)
    if past is None:
        raise CvxidError(
            'history = "measured" reads the fed-back signal before the start: pass past= (see '
            'cvxid.regression.history), or simulate with history "zero" or "initial"'
        )
    nodes = start - h * np.arange(int(np.ceil(np.max(tau) / h)) + 2, 0, -1)
    values, slopes = past(nodes)
    return np.ascontiguousarray(values, float), np.ascontiguousarray(slopes, float)


def half_steps(force: Force, t: np.ndarray, h: float, steps: int) -> np.ndarray:
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


# ---------------------------------------------------------------------- term codes
KIND_MONOMIAL, KIND_SIGN, KIND_ABS, KIND_TANH, KIND_EXPRESSION = 0, 1, 2, 3, 4


def _term_codes(coordinates: list[str], terms: list[tuple[Term, ...]]):
    """Every term of every equation for the compiled kernel: (equation, kind, powers of
    positions ``(T, C)``, powers of velocities, coordinate read, smoothing, first and end
    index of its program in ``ops``/``args``) and the expressions' programs (``ops``,
    ``args``, :mod:`cvxid.model.expression`); None when a term is a user's own Python
    function (the Python kernel runs it)."""
    symbols = {c: j for j, c in enumerate(coordinates)}
    C = len(coordinates)
    rows, ops, args = [], [], []
    for e, eq_terms in enumerate(terms):
        for term in eq_terms:
            px, pv = np.zeros(C, np.int64), np.zeros(C, np.int64)
            if isinstance(term, Monomial) and all(s.rstrip("'") in symbols for s in term.factors) and all(
                    len(s) - len(s.rstrip("'")) <= 1 for s in term.factors):
                for s, p in term.factors.items():
                    (pv if s.endswith("'") else px)[symbols[s.rstrip("'")]] = p
                rows.append((e, KIND_MONOMIAL, px, pv, 0, 0.0, 0, 0))
            elif isinstance(term, Constant):
                rows.append((e, KIND_MONOMIAL, px, pv, 0, 0.0, 0, 0))
            elif isinstance(term, Sign) and term.coordinate in symbols:
                rows.append((e, KIND_TANH if term.smoothing else KIND_SIGN, px, pv, symbols[term.coordinate],
                             term.smoothing, 0, 0))
            elif isinstance(term, AbsProduct) and term.coordinate in symbols:
                rows.append((e, KIND_ABS, px, pv, symbols[term.coordinate], 0.0, 0, 0))
            elif isinstance(term, Expression) and set(term.coordinates) <= set(symbols):
                program = term.parsed.program
                reads = (program.ops == POSITION) | (program.ops == VELOCITY)  # its coordinates, renumbered
                renumbered = np.where(reads, [symbols[term.coordinates[int(a)]] if r else a
                                              for a, r in zip(program.args, reads)], program.args)
                rows.append((e, KIND_EXPRESSION, px, pv, 0, 0.0, len(ops), len(ops) + program.ops.size))
                ops += program.ops.tolist()
                args += renumbered.tolist()
            else:
                return None
    if not rows:
        return (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, C), np.int64), np.zeros((0, C), np.int64),
                np.zeros(0, np.int64), np.zeros(0), np.zeros(0, np.int64), np.zeros(0, np.int64),
                np.zeros(0, np.int64), np.zeros(0))
    eqs, kinds, px, pv, tc, scale, starts, stops = zip(*rows)
    return (np.array(eqs, np.int64), np.array(kinds, np.int64), np.array(px), np.array(pv), np.array(tc, np.int64),
            np.array(scale, float), np.array(starts, np.int64), np.array(stops, np.int64),
            np.array(ops, np.int64), np.array(args, float))


# ---------------------------------------------------------------------- kernels
@njit(cache=True, error_model="numpy", inline="always")
def _delayed_value(b, x, v, k, ci, d, q, offs, ws, instant, fill, Hy, Hd, X, V, A, steps):
    """:math:`q_d^{(r)}(t_k + c h - \\tau)` from the history buffer (or before t = 0)."""
    if instant[b]:
        return x[d] if q == 0 else v[d]
    i = k + offs[ci, b]
    w0 = ws[ci, 0, b]
    P = Hy.size
    if P > 0 and i < 0:  # the measured past: Hermite between its nodes (node 0 is the start)
        y1, d1 = Hy[P + i + 1] if i + 1 < 0 else 0.0, Hd[P + i + 1] if i + 1 < 0 else 0.0
        if i + 1 == 0:
            y1, d1 = (X[0, d, b], V[0, d, b]) if q == 0 else (V[0, d, b], A[0, d, b])
        return w0 * Hy[P + i] + ws[ci, 1, b] * Hd[P + i] + ws[ci, 2, b] * y1 + ws[ci, 3, b] * d1
    # the stage at the end of a step reads the left limit at t = 0 (a step ends there)
    if i < 0 or (i == 0 and w0 == 1.0 and ci == 2 and P == 0):
        return fill[b]
    j = min(i, steps - 1)
    if q == 0:
        return w0 * X[j, d, b] + ws[ci, 1, b] * V[j, d, b] + ws[ci, 2, b] * X[j + 1, d, b] + ws[ci, 3, b] * V[j + 1, d, b]
    return w0 * V[j, d, b] + ws[ci, 1, b] * A[j, d, b] + ws[ci, 2, b] * V[j + 1, d, b] + ws[ci, 3, b] * A[j + 1, d, b]


@njit(cache=True, error_model="numpy")
def _program(ops, args, first, stop, x, v, stack):
    """An expression's postfix program (:mod:`cvxid.model.expression`) at the state (x, v)."""
    top = 0
    for i in range(first, stop):
        op = ops[i]
        if op <= VELOCITY:
            stack[top] = args[i] if op == CONST else (x[int(args[i])] if op == POSITION else v[int(args[i])])
            top += 1
        elif op <= POW:
            top -= 1
            a, b = stack[top - 1], stack[top]
            if op == ADD:
                stack[top - 1] = a + b
            elif op == SUB:
                stack[top - 1] = a - b
            elif op == MUL:
                stack[top - 1] = a * b
            elif op == DIV:
                stack[top - 1] = a / b
            else:
                stack[top - 1] = a ** b
        else:
            a = stack[top - 1]
            if op == NEG:
                a = -a
            elif op == SIN:
                a = np.sin(a)
            elif op == COS:
                a = np.cos(a)
            elif op == TANH:
                a = np.tanh(a)
            elif op == EXP:
                a = np.exp(a)
            elif op == ABS:
                a = abs(a)
            elif op == SIGN:
                a = 1.0 if a > 0 else (-1.0 if a < 0 else 0.0)
            else:
                a = np.sqrt(a)
            stack[top - 1] = a
    return stack[0]


@njit(cache=True, error_model="numpy", inline="always")
def _accel(b, s, x, v, k, ci, terms, stack, sign, F, mass, coefs, gain, d, q, offs, ws, instant, fill, Hy, Hd, X, V,
           A, steps, h, out):
    eqs, kinds, px, pv, tc, scale, starts, stops, ops, args = terms
    C = x.size
    qd = _delayed_value(b, x, v, k, ci, d, q, offs, ws, instant, fill, Hy, Hd, X, V, A, steps)
    for e in range(C):
        out[e] = F[s, e, b] + gain[e, b] * qd
    for m in range(eqs.size):
        kind = kinds[m]
        if kind == 1:
            continue  # Coulomb friction acts last: an equation's own may stick
        if kind == 0:
            val = 1.0
            for c in range(C):
                for _ in range(px[m, c]):
                    val *= x[c]
                for _ in range(pv[m, c]):
                    val *= v[c]
        elif kind == 2:
            val = v[tc[m]] * abs(v[tc[m]])
        elif kind == 4:
            val = _program(ops, args, starts[m], stops[m], x, v, stack)
        else:
            val = np.tanh(v[tc[m]] / scale[m])
        out[eqs[m]] -= coefs[m, b] * val
    for c in range(C):  # each coordinate's friction direction, in [-1, 1] while it sticks
        sign[c] = 1.0 if v[c] > 0 else (-1.0 if v[c] < 0 else 0.0)
    for m in range(eqs.size):
        e = eqs[m]
        if kinds[m] == 1 and tc[m] == e and coefs[m, b] > 0:
            bound = coefs[m, b]  # the force that would bring the motion to rest within a step, up to the bound
            sign[e] = min(max(out[e] + mass[e, b] * v[e] / h, -bound), bound) / bound
            out[e] -= bound * sign[e]
        elif kinds[m] == 1 and tc[m] == e:
            out[e] -= coefs[m, b] * sign[e]  # a negative "friction" pushes: no rest to come to
    for m in range(eqs.size):
        if kinds[m] == 1 and tc[m] != eqs[m]:  # the same friction, acting on another equation
            out[eqs[m]] -= coefs[m, b] * sign[tc[m]]
    for e in range(C):
        out[e] /= mass[e, b]


@njit(cache=True)
def _diverged(x, v) -> bool:
    """A state beyond :data:`DIVERGED` or not finite (NaN compares false: scalar tests, as a
    parallel reduction would drop it)."""
    for c in range(x.size):
        if not (abs(x[c]) < DIVERGED and abs(v[c]) < DIVERGED):
            return True
    return False


@njit(cache=True, error_model="numpy", parallel=True)
def _kernel(terms, F, mass, coefs, gain, d, q, offs, ws, instant, fill, Hy, Hd, x0, v0, h, steps):
    """RK4 with a Hermite history of the delayed coordinate, the variants of the batch in
    parallel threads (compiled; a Jacobian's columns are one batch).  ``terms``: the codes
    of :func:`_term_codes`."""
    C, B = x0.shape
    X = np.zeros((steps + 1, C, B))
    V = np.zeros((steps + 1, C, B))
    A = np.zeros((steps + 1, C, B))
    failures = np.full(B, -1)
    for b in prange(B):
        a = np.zeros((4, C))  # the four stages' accelerations
        x, v, xs, vs, sign = x0[:, b].copy(), v0[:, b].copy(), np.zeros(C), np.zeros(C), np.zeros(C)
        stack = np.zeros(max(terms[8].size, 1))  # the expressions' stack machine
        X[0, :, b], V[0, :, b] = x, v
        for k in range(steps):  # no allocation inside the loop: the work arrays are reused
            for j in range(4):  # stage j at t_k + c h, c = 0, 1/2, 1/2, 1 (one call site: inlined once)
                ci = (j + 1) // 2
                c = 0.5 * ci
                for i in range(C):
                    xs[i] = x[i] + c * h * vs[i] if j > 0 else x[i]
                    vs[i] = v[i] + c * h * a[j - 1, i] if j > 0 else v[i]
                _accel(b, 2 * k + ci, xs, vs, k, ci, terms, stack, sign, F, mass, coefs, gain, d, q, offs, ws,
                       instant, fill, Hy, Hd, X, V, A, steps, h, a[j])
                if j == 0:  # the later stages may read this step's slope of a fed-back velocity
                    A[k, :, b] = a[0]
            for i in range(C):
                x[i] += h / 6 * (6 * v[i] + h * (a[0, i] + a[1, i] + a[2, i]))
                v[i] += h / 6 * (a[0, i] + 2 * a[1, i] + 2 * a[2, i] + a[3, i])
                X[k + 1, i, b], V[k + 1, i, b] = x[i], v[i]
            if _diverged(x, v):
                failures[b] = k + 1
                break
    failed = -1
    for b in range(B):
        if failures[b] >= 0 and (failed < 0 or failures[b] < failed):
            failed = failures[b]
    return X, V, failed


def _python_kernel(coordinates, terms, F, mass, coefs, gain, d, q, offs, ws, instant, fill, Hy, Hd, x0, v0, h, steps):
    """The same scheme in Python, vectorised over the batch, for terms the compiled kernel
    does not know (a user's own :class:`~cvxid.model.terms.Term`)."""
    C, B = x0.shape
    X = np.zeros((steps + 1, C, B))
    V = np.zeros((steps + 1, C, B))
    A = np.zeros((steps + 1, C, B))
    cols = np.arange(B)
    rows = np.cumsum([0] + [len(t) for t in terms])
    y_hist, d_hist = (X, V) if q == 0 else (V, A)

    P = Hy.size

    def node(j):  # node j of the fed-back signal: the measured past before the start (j < 0)
        inside = np.clip(j, 0, steps)
        if P == 0:
            return y_hist[inside, d, cols], d_hist[inside, d, cols]
        before = np.clip(P + j, 0, P - 1)
        return (np.where(j < 0, Hy[before], y_hist[inside, d, cols]),
                np.where(j < 0, Hd[before], d_hist[inside, d, cols]))

    def delayed(x, v, k, ci):
        w0, w1, w2, w3 = ws[ci]
        i = k + offs[ci]
        early = (i < 0) | ((i == 0) & (w0 == 1.0) & (ci == 2)) if P == 0 else np.zeros(B, bool)
        j = np.clip(i, -P, steps - 1)
        (y0, d0), (y1, d1) = node(j), node(j + 1)
        out = w0 * y0 + w1 * d0 + w2 * y1 + w3 * d1
        return np.where(instant, x[d] if q == 0 else v[d], np.where(early, fill, out))

    def accel(s, x, v, k, ci):
        qd = delayed(x, v, k, ci)
        states = {c: x[j] for j, c in enumerate(coordinates)}
        states.update({velocity_symbol(c): v[j] for j, c in enumerate(coordinates)})
        out = F[s] + gain * qd[None, :]
        coulomb = []  # Coulomb friction acts last: an equation's own may stick
        for e, eq_terms in enumerate(terms):
            for m, term in enumerate(eq_terms):
                if isinstance(term, Sign) and not term.smoothing and term.coordinate in coordinates:
                    coulomb.append((e, coordinates.index(term.coordinate), coefs[rows[e] + m]))
                else:
                    out[e] -= coefs[rows[e] + m] * term.evaluate(states)
        sign = np.sign(v)
        for e, j, c in coulomb:
            if j == e:
                bound = np.maximum(c, 0.0)
                resting = np.clip(out[e] + mass[e] * v[e] / h, -bound, bound) / np.where(c > 0, c, 1.0)
                sign[e] = np.where(c > 0, resting, sign[e])
                out[e] -= c * sign[e]
        for e, j, c in coulomb:
            if j != e:
                out[e] -= c * sign[j]
        return out / mass

    x, v = x0.copy(), v0.copy()
    X[0], V[0] = x, v
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
            return X, V, k + 1
    return X, V, -1
