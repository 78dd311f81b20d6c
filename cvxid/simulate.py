r"""Simulation of delayed second-order systems: one integrator for N >= 1 coordinates.

.. math::

    m_i\,\ddot q_i + \sum_j c_{ij}\, g_{ij}(q, \dot q) = \beta_i\, u_i(t) + b_i\, q_d^{(r)}(t-\tau)
    + b'_i\, q_d^{(r+1)}(t-\tau), \qquad i = 1..N,

where every equation has its own coordinate :math:`q_i` (its second derivative is the
equation's inertia), the terms may read every coordinate, and :math:`q_d^{(r)}` (position,
:math:`r = 0`, or velocity, :math:`r = 1`) of one coordinate is fed back with the delay
:math:`\tau`, and with :math:`r = 0` its rate too (the paper's
:math:`b_0 x(t-\tau) + b_1 \dot x(t-\tau)`; :math:`b'_i = 0` without it).  A single
equation (:class:`System`) is the case :math:`N = 1`; a coupled one is a
:class:`CoupledSystem`.  Both run through :func:`integrate`.

The method is the classical fixed-step Runge–Kutta method.  An equation's own Coulomb
friction :math:`F_c\,\operatorname{sign}(\dot q_i)` (:math:`F_c > 0`) is integrated as
the two regimes it switches between; so is a sign of its velocity times a factor holding
no sign (a Stribeck term :math:`F_s\,\operatorname{sign}(\dot q_i)\,e^{-(\dot q_i/v_s)^2}`:
its bound :math:`F_s e^{-(\dot q_i/v_s)^2}`, :meth:`~cvxid.model.expression.Program.signed`),
and one coordinate's frictions act as one, their bounds added.  While the coordinate slides, a step keeps the
direction it started with, :math:`-F_c \operatorname{sign}(\dot q_i(t_k))`, and when the
velocity has crossed zero by the step's end, the step is split at the instant it reached
zero (found to round-off by regula falsi on the length of the RK4 step, so that the
instant, and with it the simulation, moves smoothly with the parameters).  From rest the
friction is the force that would keep the motion at rest within the step, up to its bound,

.. math::

    F = \operatorname{clip}\big(R_i + m_i \dot q_i / h,\; -F_c,\; F_c\big),

with :math:`R_i` the equation's other forces and :math:`h` the (rest of the) step: the
motion stays exactly at rest while they stay below :math:`F_c` and breaks away,
continuously, once they pass it.  The same friction acts on the other equations that read
it (its direction, in :math:`[-1, 1]` at rest); such a push on an equation is added before
that equation's own clip when its direction is known (the pushing coordinate slides, or has
no friction of its own), so a coordinate held by its own friction does not creep under it
(two coordinates at rest pushing each other still can, by :math:`O(h)`).  A stop that a
parameter moves across a step's end moves the simulation continuously (a split at the end
of one step and one at the start of the next meet); a velocity that dips through zero and
recovers within one step is not seen (a jump of the simulation :math:`O(h^2)` in size, rare),
and where a fed-back signal jumps (an assumed history) a velocity that jumps across zero is
split there without being stopped.  The scheme before it applied the clip at every stage and
brought the motion to rest over one step: first order in :math:`h` (on `hidden_friction`'s
system a largest error of 7.9e-4 at the sample step, halving with each halving of the step);
the split step is about second order (the break-away is not located, and the history's
Hermite interpolation does not see the velocity's kinks): 5e-8 at the sample step, 1.2e-8
at half of it (docs/benchmarks.md).  A negative coefficient pushes
(:math:`F_c\operatorname{sign}`, nothing to stick).

The delayed state is read from a history buffer by cubic Hermite interpolation between
stored nodes (position with velocity, or velocity with acceleration), which keeps the method
fourth-order accurate for any :math:`\tau \ge h`; a delay shorter than the sample step is resolved by sub-steps, and
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

import sys
import types
from dataclasses import dataclass
from typing import Callable

import numpy as np
from numba import njit, prange
from numba.core import event as numba_event
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
MAX_EVENTS = 8
"""Most stops of sliding coordinates located within one step; the rest of a step after the
last takes every friction's clip (first order, bounded: no friction pushes past rest)."""
STOP_ITERATIONS = 60
"""Most regula falsi iterations to find where a sliding coordinate stops."""
STOP_TOLERANCE = 1e-14
"""A stop is found when the velocity there is this share of its change over the step (or
the bracket this share of the step)."""
DIVERGED = 1e8
"""A simulation has diverged when a state exceeds this many times its own scale
(:func:`divergence_limit`)."""

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
    rate_gain: float | np.ndarray = 0.0  # the fed-back signal's rate's: + rate_gain x'(t - tau)

    def __post_init__(self):
        _check_rate(self.derivative, self.rate_gain)
        if self.history not in HISTORIES:
            raise CvxidError(f"history must be one of {', '.join(HISTORIES)}, got '{self.history}'")
        if np.any(np.asarray(self.tau) < 0):
            raise CvxidError(f"the delay must be >= 0, got {self.tau}")

    def equation(self) -> str:
        coefs = np.atleast_2d(self.coefficients)[0]
        lhs = f"{float(np.ravel(self.mass)[0]):.6g} {self.coordinate}''"
        for t, c in zip(self.terms, coefs):
            lhs += f" {'-' if c < 0 else '+'} {abs(c):.6g}" + ("" if t.name == "1" else f" {t.name}")  # (an offset)
        rhs = "f"
        for order, gain in enumerate((self.gain, self.rate_gain), self.derivative):
            gain = float(np.ravel(gain)[0])
            if gain:
                s = self.coordinate + "'" * order
                rhs += f" {'-' if gain < 0 else '+'} {abs(gain):.6g} {s}(t - {float(np.ravel(self.tau)[0]):.6g})"
        return f"{lhs} = {rhs}"


def _check_rate(derivative: int, rate_gain) -> None:
    if np.any(np.asarray(rate_gain) != 0) and derivative != 0:
        raise CvxidError("a fed-back velocity's rate (an acceleration) cannot be fed back: a rate gain needs the "
                         "position fed back (derivative 0)")


@dataclass(frozen=True)
class Equation:
    """One equation of a coupled system with numeric coefficients."""

    coordinate: str
    mass: float
    terms: tuple[Term, ...]
    coefficients: tuple[float, ...]
    input_gain: float = 1.0
    delay_gain: float = 0.0
    delay_rate_gain: float = 0.0  # of the fed-back signal's rate


@dataclass(frozen=True)
class CoupledSystem:
    """Several equations sharing one delayed coordinate (its position, or with
    ``derivative = 1`` its velocity, is fed back)."""

    equations: tuple[Equation, ...]
    delayed: str
    tau: float
    history: str = "zero"
    derivative: int = 0

    def __post_init__(self):
        _check_rate(self.derivative, [eq.delay_rate_gain for eq in self.equations])

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Coefficients ``(T, 1)``, inertias ``(C, 1)`` and delay gains ``(Q, C, 1)`` (the
        signal's, then its rate's when one is fed back): a batch of one for
        :func:`integrate`."""
        gains = [[[eq.delay_gain] for eq in self.equations]]
        if any(eq.delay_rate_gain for eq in self.equations):
            gains.append([[eq.delay_rate_gain] for eq in self.equations])
        return (np.concatenate([eq.coefficients for eq in self.equations])[:, None],
                np.array([[eq.mass] for eq in self.equations]), np.array(gains, float))


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
    batch = max(coefs.shape[0], np.size(system.mass), np.size(system.tau), np.size(system.gain),
                np.size(system.rate_gain), np.size(x0), np.size(v0))
    row = lambda a: np.broadcast_to(np.asarray(a, float), (batch,))[None, :]  # noqa: E731  (1, B)
    t = np.asarray(time, dtype=float)

    def forces(fine: np.ndarray, h: float) -> np.ndarray:
        f = half_steps(force, t, h, fine.size // 2)
        return f[:, None, None] if f.ndim == 1 else f[:, None, :]

    X, V = integrate(
        t, forces, [system.coordinate], [tuple(system.terms)], np.broadcast_to(coefs, (batch, coefs.shape[1])).T,
        row(system.mass), _gains(system.gain, system.rate_gain, row), row(system.tau)[0], row(x0), row(v0), 0,
        system.derivative, system.history, substeps, past,
    )
    xs, vs = X[:, 0, :], V[:, 0, :]
    single = all(np.ndim(a) == 0 for a in (system.tau, system.gain, system.rate_gain, system.mass))
    if xs.shape[1] == 1 and np.ndim(system.coefficients) == 1 and single:
        return xs[:, 0], vs[:, 0]
    return xs, vs


def _gains(gain, rate_gain, row) -> np.ndarray:
    """The feedback gains ``(Q, 1, B)`` of one equation: the signal's, and its rate's when
    one is fed back."""
    fed = [gain] + ([rate_gain] if np.any(np.asarray(rate_gain) != 0) else [])
    return np.stack([row(g) for g in fed])


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
    coefs, mass, delay_gain = (np.repeat(a, width, axis=-1) for a in system.arrays())
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
    ``i``'s terms, ``coefs`` ``(T, B)`` all equations' coefficients in order, ``mass``
    ``(C, B)``, ``gain`` of the delayed feedback ``(C, B)`` or ``(Q, C, B)`` (the signal's,
    then its rate's), ``tau`` ``(B,)``, initial states ``(C, B)``; ``forces(fine, h)`` gives
    each equation's input at the RK4 nodes and midpoints ``fine`` of step ``h``,
    broadcastable to ``(S, C, B)``; ``delayed`` is the index of the fed-back coordinate,
    ``derivative`` 0 (position) or 1 (velocity); ``past`` the fed-back signal (and its
    rate) before ``t[0]`` for ``history = "measured"``.
    Returns positions and velocities ``(n, C, B)`` at the samples ``t``."""
    if history not in HISTORIES:
        raise CvxidError(f"history must be one of {', '.join(HISTORIES)}, got '{history}'")
    mass, gain = np.asarray(mass, float), np.asarray(gain, float)
    gain = gain[None] if gain.ndim == 2 else gain
    if gain.shape[0] > 1:
        _check_rate(derivative, gain[1])
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
    fill = np.zeros((gain.shape[0], B))
    if history == "initial" and derivative == 0:
        fill[0] = x0[delayed]
    past_values, past_slopes = _past_nodes(history, past, t[0], tau, h, np.any(gain != 0), gain.shape[0])
    codes = _term_codes(coordinates, terms)
    # every array C-contiguous and writable: one compiled signature (numba types a read-only
    # view apart, and would compile the kernel again for it)
    own = lambda a: np.require(a, float, ["C", "W"])  # noqa: E731  (copies only when needed)
    limit = divergence_limit(F, x0, v0)
    args = (own(F), own(mass), own(coefs), own(gain), delayed, derivative, offs, ws, own(tau / h), instant, own(fill),
            own(past_values), own(past_slopes), own(x0), own(v0), h, steps, limit)
    if codes is not None:
        X, V, failed = _kernel(codes, *args)
    else:
        X, V, failed = _python_kernel(coordinates, terms, *args)
    if failed >= 0:
        raise SimulationDiverged(
            f"the simulation diverged at t = {t[0] + failed * h:.4g} s (|x| or |x'| > {limit:.3g}): the model "
            "is unstable under this input; check its coefficients"
        )
    return X[::substeps], V[::substeps]


def divergence_limit(F: np.ndarray, x0: np.ndarray, v0: np.ndarray) -> float:
    """The size of a state that has diverged: :data:`DIVERGED` times the simulation's own
    scale, the largest of its start and its inputs (at least 1).  An absolute 1e8 called a
    stable record in nanometres or encoder counts diverged (x about 1e8: every free run, the
    polish and the comparison failed, "the model is unstable")."""
    scale = max(1.0, *(float(np.max(np.abs(a), initial=0.0)) for a in (F, x0, v0)))
    return DIVERGED * scale


def delay_substeps(tau: np.ndarray, dt: float, substeps: int = 1) -> int:
    """Sub-steps per sample of a batch whose fed-back delays are ``tau``: at least one step
    per shortest resolvable delay (shorter than ``dt / MAX_SUBSTEPS`` acts at once)."""
    tau = np.atleast_1d(np.asarray(tau, float))
    resolvable = tau[tau >= dt / MAX_SUBSTEPS]
    return max(substeps, int(np.ceil(dt / resolvable.min() - 1e-12))) if resolvable.size else substeps


def _past_nodes(history: str, past: Past | None, start: float, tau: np.ndarray, h: float,
                fed_back: bool, signals: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """The past signals (the fed-back one, then its rate) and their slopes ``(signals, P)``
    at the nodes ``start - j h`` that the longest delay reads (oldest first), or empty
    arrays when the history is assumed."""
    if history != "measured" or not fed_back:
        return np.zeros((signals, 0)), np.zeros((signals, 0))
    if past is None:
        raise CvxidError(
            'history = "measured" reads the fed-back signal before the start: pass past= (see '
            'cvxid.regression.history), or simulate with history "zero" or "initial"'
        )
    nodes = start - h * np.arange(int(np.ceil(np.max(tau) / h)) + 2, 0, -1)
    values, slopes = (np.atleast_2d(np.asarray(a, float)) for a in past(nodes))
    if values.shape[0] < signals:
        raise CvxidError(f"past= gives {values.shape[0]} fed-back signal(s), the feedback reads {signals}: "
                         "the signal and its rate (cvxid.regression.history.measured_past with orders (0, 1))")
    return np.ascontiguousarray(values[:signals]), np.ascontiguousarray(slopes[:signals])


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
    are the same for every step, so they are computed once (:func:`_hermite`)."""
    tau = np.atleast_1d(np.asarray(tau, float))
    offs, ws = np.zeros((3, tau.size), np.int64), np.zeros((3, 4, tau.size))
    for ci in range(3):
        for b in range(tau.size):
            offs[ci, b], ws[ci, 0, b], ws[ci, 1, b], ws[ci, 2, b], ws[ci, 3, b] = _hermite(0.5 * ci - tau[b] / h, h)
    return offs, ws


def hermite_weights(fractions: np.ndarray, h: float) -> np.ndarray:
    """The cubic Hermite weights ``(len, 4)`` of (value, slope, next value, next slope) at
    the ``fractions`` (in [0, 1)) of a step of length ``h`` (:func:`_hermite`, the
    integrator's own)."""
    return np.array([_hermite(float(u), h)[1:] for u in fractions]).reshape(-1, 4)


@njit(cache=True, error_model="numpy")
def _hermite(u, h):
    """The node offset and cubic Hermite weights (value, slope, next value, next slope) of
    the point ``u`` steps of length ``h`` after a node (a point within 1e-9 of a node is
    on it)."""
    if abs(u - np.round(u)) < 1e-9:
        u = np.round(u)
    off = np.floor(u)
    theta = u - off
    t2, t3 = theta * theta, theta**3
    return int(off), 2 * t3 - 3 * t2 + 1, (t3 - 2 * t2 + theta) * h, -2 * t3 + 3 * t2, (t3 - t2) * h


class _FirstCompile(numba_event.Listener):
    """Says once, on a terminal, that cvxid's simulation kernel is being compiled: the first
    run on a machine spends 20-30 s there with nothing else to show (numba's event API
    reports compiles, not loads from its on-disk cache, so later runs say nothing)."""

    said = False

    def on_start(self, event) -> None:
        from cvxid.progress import is_quiet

        dispatcher = event.data.get("dispatcher")
        if self.said or getattr(getattr(dispatcher, "py_func", None), "__module__", None) != __name__:
            return
        self.said = True
        if not is_quiet() and sys.stderr.isatty():
            print("cvxid: compiling the simulation kernel for this machine (once: about 25 s; later runs load it "
                  "from numba's cache)", file=sys.stderr, flush=True)

    def on_end(self, event) -> None:
        pass


numba_event.register("numba:compile", _FirstCompile())


# ---------------------------------------------------------------------- term codes
def _friction(term: Term, coordinates: list[str]):
    """``(coordinate index, factor)`` when ``term`` is a dry friction the integrator stops:
    ``sign(q')`` (factor None) or ``sign(q') * factor`` (the factor's
    :class:`~cvxid.model.expression.Program`, reading ``term.coordinates``); else None."""
    if isinstance(term, Sign) and not term.smoothing and term.coordinate in coordinates:
        return coordinates.index(term.coordinate), None
    if isinstance(term, Expression) and set(term.coordinates) <= set(coordinates):
        signed = term.parsed.program.signed()
        if signed is not None:
            return coordinates.index(term.coordinates[signed[0]]), signed[1]
    return None



KIND_MONOMIAL, KIND_SIGN, KIND_ABS, KIND_TANH, KIND_EXPRESSION, KIND_SIGNED = 0, 1, 2, 3, 4, 5


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
                friction = _friction(term, coordinates)  # sign(q') * factor: the factor's program
                program = term.parsed.program if friction is None else friction[1]
                reads = (program.ops == POSITION) | (program.ops == VELOCITY)  # its coordinates, renumbered
                renumbered = np.where(reads, [symbols[term.coordinates[int(a)]] if r else a
                                              for a, r in zip(program.args, reads)], program.args)
                rows.append((e, KIND_EXPRESSION if friction is None else KIND_SIGNED, px, pv,
                             0 if friction is None else friction[0], 0.0, len(ops), len(ops) + program.ops.size))
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
def _delayed_value(b, x, v, i, w0, w1, w2, w3, end, d, q, s, instant, fill, Hy, Hd, X, V, A, steps):
    """:math:`q_d^{(q)}` at the delayed time that falls ``i`` nodes on with the Hermite
    weights ``w`` (or before t = 0); ``end``: the stage ends a step; row ``s`` of ``fill``,
    ``Hy``, ``Hd``: this signal's assumed value, measured past and its slope."""
    if instant[b]:
        return x[d] if q == 0 else v[d]
    P = Hy.shape[1]
    if P > 0 and i < 0:  # the measured past: Hermite between its nodes (node 0 is the start)
        y1, d1 = Hy[s, P + i + 1] if i + 1 < 0 else 0.0, Hd[s, P + i + 1] if i + 1 < 0 else 0.0
        if i + 1 == 0:
            y1, d1 = (X[0, d, b], V[0, d, b]) if q == 0 else (V[0, d, b], A[0, d, b])
        return w0 * Hy[s, P + i] + w1 * Hd[s, P + i] + w2 * y1 + w3 * d1
    # the stage at the end of a step reads the left limit at t = 0 (a step ends there)
    if i < 0 or (i == 0 and w0 == 1.0 and end and P == 0):
        return fill[s, b]
    j = min(i, steps - 1)
    if q == 0:
        return w0 * X[j, d, b] + w1 * V[j, d, b] + w2 * X[j + 1, d, b] + w3 * V[j + 1, d, b]
    return w0 * V[j, d, b] + w1 * A[j, d, b] + w2 * V[j + 1, d, b] + w3 * A[j + 1, d, b]


@njit(cache=True, error_model="numpy", inline="always")
def _input_at(F, p, e, b):
    """Equation ``e``'s input ``p`` half-steps from the start: the node's value on a node,
    else the cubic through the four nearest nodes."""
    i = int(np.floor(p))
    if p == i:
        return F[i, e, b]
    if F.shape[0] < 4:  # a single step: straight between its nodes
        return F[i, e, b] + (p - i) * (F[i + 1, e, b] - F[i, e, b])
    j = min(max(i - 1, 0), F.shape[0] - 4)
    s = p - j
    return (-(s - 1) * (s - 2) * (s - 3) / 6 * F[j, e, b] + s * (s - 2) * (s - 3) / 2 * F[j + 1, e, b]
            - s * (s - 1) * (s - 3) / 2 * F[j + 2, e, b] + s * (s - 1) * (s - 2) / 6 * F[j + 3, e, b])


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
def _accel(b, x, v, f, terms, stack, sign, bound, modes, own, mass, coefs, hs, out):
    """Every equation's acceleration at the state (x, v) with the forces ``f`` (the inputs
    and the delayed feedback).  Each coordinate's own frictions (``sign(q')`` and ``sign(q') *
    factor``, positive) add up to one bound: sliding in the direction ``modes`` it acts
    against the motion; at rest (mode 0) it is the clip over the step ``hs``."""
    eqs, kinds, px, pv, tc, scale, starts, stops, ops, args = terms
    C = x.size
    for e in range(C):
        out[e] = f[e]
        bound[e] = 0.0
    for m in range(eqs.size):
        kind = kinds[m]
        if kind == 1 or kind == 5:
            continue  # frictions act last: an equation's own may stick
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
    for c in range(C):  # each friction's direction: sliding, the step's; at rest, in [-1, 1] from its clip
        sign[c] = modes[c] if modes[c] != 0.0 else (1.0 if v[c] > 0 else (-1.0 if v[c] < 0 else 0.0))
    for m in range(eqs.size):  # a friction's size; one on another equation whose direction is known acts now
        if kinds[m] == 1 or kinds[m] == 5:
            e, c = eqs[m], tc[m]
            size = coefs[m, b] * (_program(ops, args, starts[m], stops[m], x, v, stack) if kinds[m] == 5 else 1.0)
            if c == e and own[e] and size > 0:
                bound[e] += size  # the coordinate's own: one bound, below
            elif c == e or not (own[c] and modes[c] == 0.0):
                out[e] -= size * sign[c]  # (a negative one pushes: no rest to come to)
    for e in range(C):
        if bound[e] > 0.0 and modes[e] != 0.0:
            out[e] -= bound[e] * modes[e]  # sliding: against the motion the step started with
        elif bound[e] > 0.0:  # at rest: the force that keeps it there within the step, up to the bound
            force = min(max(out[e] + mass[e, b] * v[e] / hs, -bound[e]), bound[e])
            sign[e] = force / bound[e]
            out[e] -= force  # (the force itself: at rest, exactly none left)
    for m in range(eqs.size):  # ... and one at rest after its clip
        if (kinds[m] == 1 or kinds[m] == 5) and tc[m] != eqs[m] and own[tc[m]] and modes[tc[m]] == 0.0:
            size = coefs[m, b] * (_program(ops, args, starts[m], stops[m], x, v, stack) if kinds[m] == 5 else 1.0)
            out[eqs[m]] -= size * sign[tc[m]]
    for e in range(C):
        out[e] /= mass[e, b]


@njit(cache=True, error_model="numpy", inline="always")
def _step(b, k, frac, r, x, v, xn, vn, a, work, modes, own, terms, stack, F, mass, coefs, gain, delay, X, V, A,
          steps, h):
    """One RK4 step from the fraction ``frac`` of step ``k`` over ``r`` of a step: (x, v)
    to (xn, vn), the stages' accelerations in ``a``.  A whole step reads the delayed signal
    and the inputs at the stages' precomputed nodes; a part of one (a friction's event
    splits it) interpolates them."""
    xs, vs, f, sign, bound = work[0], work[1], work[2], work[3], work[4]
    d, q, offs, ws, tau_h, instant, fill, Hy, Hd = delay
    C = x.size
    hs = r * h
    whole = frac == 0.0 and r == 1.0
    for j in range(4):  # stage j at c = 0, 1/2, 1/2, 1 of the step (one call site: inlined once)
        ci = (j + 1) // 2
        c = 0.5 * ci
        for e in range(C):
            xs[e] = x[e] + c * hs * vs[e] if j > 0 else x[e]
            vs[e] = v[e] + c * hs * a[j - 1, e] if j > 0 else v[e]
        if whole:
            i, w0, w1, w2, w3 = k + offs[ci, b], ws[ci, 0, b], ws[ci, 1, b], ws[ci, 2, b], ws[ci, 3, b]
            for e in range(C):
                f[e] = F[2 * k + ci, e, b]
        else:
            i, w0, w1, w2, w3 = _hermite(frac + c * r - tau_h[b], h)
            i += k
            for e in range(C):
                f[e] = _input_at(F, 2 * (k + frac + c * r), e, b)
        qd = _delayed_value(b, xs, vs, i, w0, w1, w2, w3, ci == 2, d, q, 0, instant, fill, Hy, Hd, X, V, A, steps)
        if gain.shape[0] > 1:  # (the fed-back position's rate, the paper's b1 x'(t - tau))
            rate = _delayed_value(b, xs, vs, i, w0, w1, w2, w3, ci == 2, d, q + 1, 1, instant, fill, Hy, Hd, X, V, A,
                                  steps)
            for e in range(C):
                f[e] += gain[0, e, b] * qd + gain[1, e, b] * rate
        else:
            for e in range(C):
                f[e] += gain[0, e, b] * qd
        _accel(b, xs, vs, f, terms, stack, sign, bound, modes, own, mass, coefs, hs, a[j])
        if j == 0 and frac == 0.0:  # the later stages may read this step's slope of a fed-back velocity
            A[k, :, b] = a[0]
    for e in range(C):
        xn[e] = x[e] + hs / 6 * (6 * v[e] + hs * (a[0, e] + a[1, e] + a[2, e]))
        vn[e] = v[e] + hs / 6 * (a[0, e] + 2 * a[1, e] + 2 * a[2, e] + a[3, e])


def _renamed(function, name: str):
    """``function``'s code under another name (a compiled copy caches under its own)."""
    copy = types.FunctionType(function.__code__, function.__globals__, name, function.__defaults__)
    copy.__qualname__ = name
    return copy


_step_apart = njit(cache=True, error_model="numpy")(_renamed(_step.py_func, "_step_apart"))
""":func:`_step` compiled as a function of its own, for :func:`_part`: inlined there as well
it took 13 of a cold start's 36 s to compile (the kernel's whole steps keep it inlined)."""


@njit(cache=True, error_model="numpy")
def _part(b, k, frac, r, x, v, xn, vn, a, work, modes, own, terms, stack, F, mass, coefs, gain, delay, X, V, A,
          steps, h):
    """:func:`_step` called, not inlined: the parts of a step that a friction's stop splits
    (rare: the whole steps are inlined in the kernel)."""
    if r * h == 0.0:  # (a stop at the part's very start: nothing to integrate)
        xn[:], vn[:] = x, v
    else:
        _step_apart(b, k, frac, r, x, v, xn, vn, a, work, modes, own, terms, stack, F, mass, coefs, gain, delay, X, V,
                    A, steps, h)


@njit(cache=True)
def _diverged(x, v, limit) -> bool:
    """A state beyond ``limit`` (:func:`divergence_limit`) or not finite (NaN compares false:
    scalar tests, as a parallel reduction would drop it)."""
    for c in range(x.size):
        if not (abs(x[c]) < limit and abs(v[c]) < limit):
            return True
    return False


@njit(cache=True, error_model="numpy", parallel=True)
def _kernel(terms, F, mass, coefs, gain, d, q, offs, ws, tau_h, instant, fill, Hy, Hd, x0, v0, h, steps, limit):
    """RK4 with a Hermite history of the delayed coordinate, the variants of the batch in
    parallel threads (compiled; a Jacobian's columns are one batch).  ``terms``: the codes
    of :func:`_term_codes`.  A coordinate sliding against its own Coulomb friction stops at
    the instant its velocity reaches zero: the step is split there (the instant found to
    round-off), and the rest of it is integrated from rest."""
    eqs, kinds, tc = terms[0], terms[1], terms[4]
    delay = (d, q, offs, ws, tau_h, instant, fill, Hy, Hd)
    C, B = x0.shape
    X = np.zeros((steps + 1, C, B))
    V = np.zeros((steps + 1, C, B))
    A = np.zeros((steps + 1, C, B))
    failures = np.full(B, -1)
    for p in prange(B):
        b = np.int64(p)  # (prange's index is typed uint64 in one pass and int64 in another: the functions it
        #                   calls were compiled twice, 6 s of a cold start)
        a = np.zeros((4, C))  # the four stages' accelerations
        work = np.zeros((5, C))  # the stages' state, inputs, friction directions and bounds
        x, v, xn, vn, modes, ends = x0[:, b].copy(), v0[:, b].copy(), np.zeros(C), np.zeros(C), np.zeros(C), np.zeros(C)
        own = np.zeros(C, np.bool_)  # coordinates with their own (positive) Coulomb friction
        for m in range(eqs.size):
            if (kinds[m] == 1 or kinds[m] == 5) and tc[m] == eqs[m] and coefs[m, b] > 0:
                own[eqs[m]] = True
        stack = np.zeros(max(terms[8].size, 1))  # the expressions' stack machine
        X[0, :, b], V[0, :, b] = x, v
        for k in range(steps):  # no allocation inside the loop: the work arrays are reused
            frac = 0.0
            for event in range(MAX_EVENTS + 1):
                for e in range(C):  # sliding (its direction) or at rest (0); past the budget, every one the clip
                    modes[e] = (1.0 if v[e] > 0 else (-1.0 if v[e] < 0 else 0.0)) if own[e] and event < MAX_EVENTS \
                        else 0.0
                r = 1.0 - frac
                _step(b, k, frac, r, x, v, xn, vn, a, work, modes, own, terms, stack, F, mass, coefs, gain, delay, X, V,
                      A, steps, h)
                who, first, zero = -1, 2.0, False
                for e in range(C):  # each coordinate's velocity along its sliding direction at the step's end
                    ends[e] = modes[e] * vn[e]
                for e in range(C):  # the earliest stop of a sliding coordinate within the step
                    if modes[e] != 0.0 and ends[e] <= 0.0:
                        theta, found = _stop(e, modes[e] * v[e], ends[e], b, k, frac, r, x, v, xn, vn, a, work, modes,
                                             own, terms, stack, F, mass, coefs, gain, delay, X, V, A, steps, h)
                        if theta < first:
                            who, first, zero = e, theta, found
                if who < 0:
                    x[:], v[:] = xn, vn
                    break
                _part(b, k, frac, first * r, x, v, xn, vn, a, work, modes, own, terms, stack, F, mass, coefs, gain,
                      delay, X, V, A, steps, h)
                x[:], v[:] = xn, vn
                if zero:  # (else the velocity jumped across zero with a fed-back signal: the next part turns)
                    v[who] = 0.0
                frac += first * r
                if first == 1.0 or frac >= 1.0 - 1e-12:
                    break
            X[k + 1, :, b], V[k + 1, :, b] = x, v
            if _diverged(x, v, limit):
                failures[b] = k + 1
                break
    failed = -1
    for b in range(B):
        if failures[b] >= 0 and (failed < 0 or failures[b] < failed):
            failed = failures[b]
    return X, V, failed


@njit(cache=True, error_model="numpy")
def _stop(e, g0, g1, b, k, frac, r, x, v, xn, vn, a, work, modes, own, terms, stack, F, mass, coefs, gain, delay, X, V,
          A, steps, h):
    r"""The share :math:`\theta` of the step ``r`` at which coordinate ``e``'s velocity,
    sliding at the step's start (``g0`` > 0 in its direction) and past rest at its end
    (``g1`` <= 0), reaches zero, by :func:`_falsi` on the RK4 step of length
    :math:`\theta r`; and whether it is a zero (not a jump of the velocity across zero, where
    a fed-back signal jumps)."""
    bracket = _falsi_start(g0, g1)
    for _ in range(STOP_ITERATIONS):
        _part(b, k, frac, bracket[5] * r, x, v, xn, vn, a, work, modes, own, terms, stack, F, mass, coefs, gain,
              delay, X, V, A, steps, h)
        if _falsi(bracket, modes[e] * vn[e]):
            return bracket[5], True
    return bracket[5], False


@njit(cache=True)
def _falsi_start(g0, g1):
    """The bracket [lo, g(lo), hi, g(hi), side, theta, scale] of :func:`_falsi` for a zero
    in [0, 1] with g(0) = ``g0`` > 0 >= g(1) = ``g1``, its first point the chord's."""
    return np.array([0.0, g0, 1.0, g1, 0.0, g0 / (g0 - g1), g0 - g1])


@njit(cache=True)
def _falsi(bracket, g):
    """One step of the Illinois variant of regula falsi: ``g`` is the function at the
    bracket's point; True when that point is the zero to round-off
    (:data:`STOP_TOLERANCE` of the bracket's first span, or of its width), else the bracket
    narrowed and its next point set.  The compiled and the Python integrators both search
    with it, so they split a step at the same instant."""
    lo, glo, hi, ghi, side, theta, scale = bracket
    if abs(g) <= STOP_TOLERANCE * scale or hi - lo <= STOP_TOLERANCE:
        return True
    if g < 0:
        hi, ghi = theta, g
        if side == -1.0:
            glo *= 0.5
        side = -1.0
    else:
        lo, glo = theta, g
        if side == 1.0:
            ghi *= 0.5
        side = 1.0
    bracket[0], bracket[1], bracket[2], bracket[3], bracket[4] = lo, glo, hi, ghi, side
    bracket[5] = (lo * ghi - hi * glo) / (ghi - glo)
    return False


def _python_kernel(coordinates, terms, F, mass, coefs, gain, d, q, offs, ws, tau_h, instant, fill, Hy, Hd, x0, v0, h,
                   steps, limit):
    """The same scheme in Python, vectorised over the batch, for terms the compiled kernel
    does not know (a user's own :class:`~cvxid.model.terms.Term`); a step that a sliding
    coordinate's stop splits runs member by member, the stop found as the compiled kernel
    finds it (:func:`_falsi`)."""
    C, B = x0.shape
    X = np.zeros((steps + 1, C, B))
    V = np.zeros((steps + 1, C, B))
    A = np.zeros((steps + 1, C, B))
    rows = np.cumsum([0] + [len(t) for t in terms])
    frictions = {}  # row -> (equation, coordinate, its factor or None): sign(q') and sign(q') * factor
    for e, eq_terms in enumerate(terms):
        for m, term in enumerate(eq_terms):
            friction = _friction(term, coordinates)
            if friction is not None:
                j, factor = friction
                frictions[rows[e] + m] = (e, j, None if factor is None else (factor, term.coordinates))
    own = np.zeros((C, B), bool)  # coordinates with their own (positive) friction
    for row, (e, j, _) in frictions.items():
        own[e] |= (j == e) & (coefs[row] > 0)
    P = Hy.shape[1]

    def node(s, j, cols):  # node j of fed-back signal s: the measured past before the start (j < 0)
        y_hist, d_hist = (X, V) if q + s == 0 else (V, A)
        inside = np.clip(j, 0, steps)
        if P == 0:
            return y_hist[inside, d, cols], d_hist[inside, d, cols]
        before = np.clip(P + j, 0, P - 1)
        return (np.where(j < 0, Hy[s, before], y_hist[inside, d, cols]),
                np.where(j < 0, Hd[s, before], d_hist[inside, d, cols]))

    def delayed(x, v, i, w, end, cols):  # every equation's feedback force (C, cols)
        early = (i < 0) | ((i == 0) & (w[0] == 1.0) & end) if P == 0 else np.zeros(cols.size, bool)
        j = np.clip(i, -P, steps - 1)
        force = np.zeros((C, cols.size))
        for s in range(gain.shape[0]):  # the fed-back signal, then its rate
            (y0, d0), (y1, d1) = node(s, j, cols), node(s, j + 1, cols)
            out = w[0] * y0 + w[1] * d0 + w[2] * y1 + w[3] * d1
            qd = np.where(instant[cols], x[d] if q + s == 0 else v[d], np.where(early, fill[s, cols], out))
            force += gain[s][:, cols] * qd[None, :]
        return force

    def accel(x, v, feedback, f, modes, hs, cols):
        states = {c: x[j] for j, c in enumerate(coordinates)}
        states.update({velocity_symbol(c): v[j] for j, c in enumerate(coordinates)})
        out = f + feedback
        for e, eq_terms in enumerate(terms):  # frictions act last: an equation's own may stick
            for m, term in enumerate(eq_terms):
                if rows[e] + m not in frictions:
                    out[e] -= coefs[rows[e] + m, cols] * term.evaluate(states)
        sign = np.where(modes != 0, modes, np.sign(v))
        resting = own[:, cols] & (modes == 0)
        bound = np.zeros_like(out)
        sizes = {row: coefs[row, cols] * (1.0 if factor is None else factor[0].evaluate(
                 [states[c] for c in factor[1]], [states[velocity_symbol(c)] for c in factor[1]]))
                 for row, (_, _, factor) in frictions.items()}
        for row, (e, j, _) in frictions.items():  # its size; one on another equation whose direction is known now
            mine = (j == e) & own[e, cols] & (sizes[row] > 0)
            bound[e] += np.where(mine, sizes[row], 0.0)
            out[e] -= np.where(mine | ((j != e) & resting[j]), 0.0, sizes[row] * sign[j])
        held = bound > 0
        force = np.clip(out + mass[:, cols] * v / hs, -bound, bound)
        sign = np.where(held & (modes == 0), force / np.where(held, bound, 1.0), sign)
        out -= np.where(held, np.where(modes != 0, bound * modes, force), 0.0)
        for row, (e, j, _) in frictions.items():  # ... and one at rest after its clip
            if j != e:
                out[e] -= np.where(resting[j], sizes[row] * sign[j], 0.0)
        return out / mass[:, cols]

    def step(x, v, k, frac, r, modes, cols):
        if r * h == 0.0:  # (a stop at the part's very start: nothing to integrate)
            return x, v
        hs = r * h
        a, xs, vs = [], x, v
        for j, c in enumerate((0.0, 0.5, 0.5, 1.0)):
            ci = (j + 1) // 2
            if j:
                xs, vs = x + c * hs * vs, v + c * hs * a[-1]
            if frac == 0.0 and r == 1.0:
                i, w, f = k + offs[ci, cols], ws[ci][:, cols], F[2 * k + ci][:, cols]
            else:
                nodes = np.array([_hermite(frac + c * r - tau_h[b], h) for b in cols]).T
                i, w = k + nodes[0].astype(int), nodes[1:]
                f = np.array([[_input_at(F, 2 * (k + frac + c * r), e, b) for b in cols] for e in range(C)])
            a.append(accel(xs, vs, delayed(xs, vs, i, w, ci == 2, cols), f, modes, hs, cols))
            if j == 0 and frac == 0.0:
                A[k][:, cols] = a[0]
        return x + hs / 6 * (6 * v + hs * (a[0] + a[1] + a[2])), v + hs / 6 * (a[0] + 2 * a[1] + 2 * a[2] + a[3])

    def modes_at(v, cols, clip=False):  # sliding (its direction) or at rest (0); past the budget, the clip
        return np.where(own[:, cols] & (not clip), np.sign(v), 0.0)

    def stop(x, v, k, frac, r, modes, cols, e, g1):  # as the compiled kernel's _stop
        bracket = _falsi_start(modes[e, 0] * v[e, 0], g1)
        for _ in range(STOP_ITERATIONS):
            if _falsi(bracket, modes[e, 0] * step(x, v, k, frac, bracket[5] * r, modes, cols)[1][e, 0]):
                return bracket[5], True
        return bracket[5], False

    def split(x, v, k, b):  # one member's step, split where its sliding coordinates stop
        cols, frac = np.array([b]), 0.0
        for event in range(MAX_EVENTS + 1):
            modes, r = modes_at(v, cols, event == MAX_EVENTS), 1.0 - frac
            xn, vn = step(x, v, k, frac, r, modes, cols)
            ends = modes[:, 0] * vn[:, 0]
            stops = [(*stop(x, v, k, frac, r, modes, cols, e, ends[e]), e) for e in range(C)
                     if modes[e, 0] != 0 and ends[e] <= 0]
            if not stops:
                return xn, vn
            first, zero, who = min(stops, key=lambda found: found[0])
            x, v = step(x, v, k, frac, first * r, modes, cols)
            if zero:
                v[who] = 0.0
            frac += first * r
            if first == 1.0 or frac >= 1.0 - 1e-12:
                return x, v
        return x, v

    x, v = x0.copy(), v0.copy()
    everyone = np.arange(B)
    X[0], V[0] = x, v
    for k in range(steps):
        modes = modes_at(v, everyone)
        xn, vn = step(x, v, k, 0.0, 1.0, modes, everyone)
        for b in np.flatnonzero(np.any((modes != 0) & (vn * modes <= 0), axis=0)):
            xn[:, [b]], vn[:, [b]] = split(x[:, [b]], v[:, [b]], k, b)
        x, v = xn, vn
        X[k + 1], V[k + 1] = x, v
        if not (np.abs(x).max() < limit and np.abs(v).max() < limit):
            return X, V, k + 1
    return X, V, -1
