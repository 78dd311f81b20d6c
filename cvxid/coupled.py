r"""Coupled second-order systems: several coordinates, one shared delay.

.. math::

    m_i\,\ddot q_i + \sum_j c_{ij}\, g_{ij}(q, \dot q) = \beta_i\, u(t) + b_i\, q_d(t-\tau),
    \qquad i = 1..N,

where every equation has its own coordinate :math:`q_i` (its second derivative is the
equation's inertia), the terms may read every coordinate, :math:`u` is one shared input and
:math:`q_d` the coordinate fed back with the delay :math:`\tau`.

:func:`simulate_coupled` integrates it with RK4 and a Hermite history buffer (the delayed
coordinate's position and velocity); :func:`identify_coupled` identifies all equations in
one cvxpy problem: the per-equation regressions are stacked block-diagonally
(:meth:`~cvxid.regression.Regression.block`), coefficients shared across equations are
tied by equality constraints, and the delay is profiled on the joint objective.
:func:`flexible_joint` makes the data of the paper's section 5 rig.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable, Sequence

import numpy as np
from scipy.optimize import minimize_scalar

from .data import Experiment
from .errors import CvxidError
from .identified import IdentifiedModel
from .model import ModelSpec
from .problem import Problem
from .regression import DelayFamily, Regression
from .simulate import DIVERGED, SimulationDiverged
from .terms import FunctionTerm, Term, parse_term, velocity_symbol


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
    equations: tuple[Equation, ...]
    delayed: str
    tau: float
    history: str = "zero"


def simulate_coupled(system: CoupledSystem, time: np.ndarray, force: Callable[[np.ndarray], np.ndarray],
                     x0: dict, v0: dict) -> tuple[dict, dict]:
    """Positions and velocities of every coordinate at the sample ``time`` (RK4, one step
    per sample; the delay must be at least one step)."""
    t = np.asarray(time, float)
    h = float(t[1] - t[0])
    coords = [eq.coordinate for eq in system.equations]
    if system.delayed not in coords:
        raise CvxidError(f"the delayed coordinate {system.delayed!r} is not one of {coords}")
    if system.tau < h:
        raise CvxidError(f"the delay {system.tau:g} s is shorter than the step {h:g} s")
    n, d = len(t), coords.index(system.delayed)
    X, V = np.zeros((n, len(coords))), np.zeros((n, len(coords)))
    X[0] = [x0[c] for c in coords]
    V[0] = [v0[c] for c in coords]
    mid = force(t[:-1] + 0.5 * h)
    ends = force(t)
    lag = system.tau / h
    before = 0.0 if system.history == "zero" else X[0, d]

    def delayed(k: int, c: float) -> float:
        u = k + c - lag
        i = int(np.floor(u + 1e-9))
        if u < -1e-9 or (abs(u) < 1e-9 and c == 1.0):
            return before
        i = min(max(i, 0), k - 1) if u < k else k
        th = u - i
        if i + 1 > k:  # at the current node
            return X[k, d]
        t2, t3 = th * th, th**3
        return ((2 * t3 - 3 * t2 + 1) * X[i, d] + (t3 - 2 * t2 + th) * h * V[i, d]
                + (-2 * t3 + 3 * t2) * X[i + 1, d] + (t3 - t2) * h * V[i + 1, d])

    def accel(x, v, f, qd):
        states = {c: x[j] for j, c in enumerate(coords)}
        states.update({velocity_symbol(c): v[j] for j, c in enumerate(coords)})
        out = np.empty(len(coords))
        for j, eq in enumerate(system.equations):
            rhs = eq.input_gain * f + eq.delay_gain * qd
            for term, coef in zip(eq.terms, eq.coefficients):
                rhs -= coef * float(term.evaluate(states))
            out[j] = rhs / eq.mass
        return out

    for k in range(n - 1):
        x, v = X[k], V[k]
        a1 = accel(x, v, ends[k], delayed(k, 0.0))
        x2, v2 = x + 0.5 * h * v, v + 0.5 * h * a1
        a2 = accel(x2, v2, mid[k], delayed(k, 0.5))
        x3, v3 = x + 0.5 * h * v2, v + 0.5 * h * a2
        a3 = accel(x3, v3, mid[k], delayed(k, 0.5))
        x4, v4 = x + h * v3, v + h * a3
        a4 = accel(x4, v4, ends[k + 1], delayed(k, 1.0))
        X[k + 1] = x + h / 6 * (v + 2 * v2 + 2 * v3 + v4)
        V[k + 1] = v + h / 6 * (a1 + 2 * a2 + 2 * a3 + a4)
        if not np.all(np.abs(X[k + 1]) < DIVERGED):
            raise SimulationDiverged(f"the coupled simulation diverged at t = {t[k + 1]:.4g} s")
    return {c: X[:, j] for j, c in enumerate(coords)}, {c: V[:, j] for j, c in enumerate(coords)}


# ---------------------------------------------------------------------- identification
@dataclass(frozen=True)
class CoupledResult:
    """Identified equations, the shared delay and the joint problem's figures."""

    models: dict[str, IdentifiedModel]
    tau: float
    profile: tuple[np.ndarray, np.ndarray]
    problem: Problem

    def __repr__(self) -> str:
        lines = [f"Coupled identification: tau = {self.tau:.5g}"]
        lines += [f"  {m.equation()}" for m in self.models.values()]
        return "\n".join(lines)


def _joint(specs: dict[str, ModelSpec], families: dict[str, DelayFamily], tau: float):
    return Regression.block({label: families[label].at(tau) for label in specs})


def identify_coupled(specs: dict[str, ModelSpec], experiments: Sequence[Experiment] | Experiment,
                     ties: Sequence[tuple[str, str, float]] = (), velocity: str = "savgol",
                     grid: int = 41, window: float | None = None) -> CoupledResult:
    """Least squares of every equation in one problem, ``ties`` (``("eq:column",
    "eq:column", factor)``) holding across them, the shared exact delay profiled on the
    joint optimal value."""
    delays = {(s.delay.coordinate, s.delay.tau_min, s.delay.tau_max) for s in specs.values() if s.delay}
    if len(delays) != 1 or any(s.delay is None or not s.delay.exact for s in specs.values()):
        raise CvxidError("a coupled identification needs one shared exact delay in every equation")
    _, lo, hi = delays.pop()
    families = {label: DelayFamily(spec, experiments, velocity, window) for label, spec in specs.items()}
    nonnegative = [f"{label}:{n}" for label, spec in specs.items() for n in spec.nonnegative]

    def value(tau):
        problem = Problem.from_regression(_joint(specs, families, tau), nonnegative, ties=ties)
        return problem.refit(np.ones(problem.k, bool)).train_mse

    taus = np.linspace(lo, hi, grid)
    values = np.array([value(t) for t in taus])
    i = int(np.argmin(values))
    best = minimize_scalar(value, bounds=(taus[max(i - 1, 0)], taus[min(i + 1, grid - 1)]), method="bounded",
                           options={"xatol": 1e-6 * hi})
    tau = float(best.x) if best.fun <= values[i] else float(taus[i])
    problem = Problem.from_regression(_joint(specs, families, tau), nonnegative, ties=ties)
    fit = problem.refit(np.ones(problem.k, bool))
    models = {}
    for label, spec in specs.items():
        coefs = {n.split(":", 1)[1]: float(c) for n, c in zip(problem.names, fit.coefficients)
                 if n.startswith(label + ":")}
        models[label] = IdentifiedModel(spec, coefs, tau=tau)
    return CoupledResult(models, tau, (taus, values), problem)


# ---------------------------------------------------------------------- the paper's rig
QUANSER = {
    # Table 3 of the paper (J_eq as its Table 5 implies: 0.0102 - 0.008121)
    "J_eq": 0.00208, "J_l": 0.0038, "B_eq": 0.015, "B_l": 0.004, "k_s": 1.3,
    "k_g": 70.0, "k_t": 7.68e-3, "k_m": 7.68e-3, "R_m": 2.6, "eta_g": 0.9, "eta_m": 0.69,
}


def flexible_joint(k_p: float = 3.16, tau: float = 0.2, coulomb: float = 0.05, params: dict | None = None,
                   stiction_speed: float = 0.05):
    """The rotary flexible joint under proportional control of the delayed theta:

    .. math::

        J_{eq}\\ddot\\theta + (B_{eq}+b)\\dot\\theta - k_s\\alpha - B_l\\dot\\alpha
            + f_c\\,\\mathrm{sign}\\,\\dot\\theta = a k_p\\theta_d - a k_p\\,\\theta(t-\\tau)

        J_{eq}\\ddot\\alpha - (B_{eq}+b)\\dot\\theta + k_s(1+J_{eq}/J_l)\\alpha
            + B_l(1+J_{eq}/J_l)\\dot\\alpha - f_c\\,\\mathrm{sign}\\,\\dot\\theta
            = -a k_p\\theta_d + a k_p\\,\\theta(t-\\tau)

    with :math:`a = \\eta_g k_g \\eta_m k_t / R_m` and :math:`b = a k_g k_m` (the motor's
    back-emf).  The shared input is :math:`u = a k_p \\theta_d`.  The friction is simulated as
    :math:`f_c \\tanh(\\dot\\theta/v_s)` with ``stiction_speed`` :math:`v_s`: an ideal sign
    makes the integrator chatter where the joint sticks, which no sampled regression column
    reproduces.  Returns the system and the true physical constants."""
    p = dict(QUANSER, **(params or {}))
    a = p["eta_g"] * p["k_g"] * p["eta_m"] * p["k_t"] / p["R_m"]
    b = a * p["k_g"] * p["k_m"]
    ratio = 1 + p["J_eq"] / p["J_l"]
    th = [parse_term(n, ("theta", "alpha")) for n in ("theta'", "alpha", "alpha'")]
    al = [parse_term(n, ("alpha", "theta")) for n in ("theta'", "alpha", "alpha'")]
    friction = [FunctionTerm("sign(theta')", "Coulomb friction (smoothed below the stiction speed)",
                             lambda st: np.tanh(st["theta'"] / stiction_speed), frozenset({"theta'"}))] if coulomb else []
    theta = Equation("theta", p["J_eq"], tuple(th + friction),
                     (p["B_eq"] + b, -p["k_s"], -p["B_l"]) + ((coulomb,) if coulomb else ()), 1.0, -a * k_p)
    alpha = Equation("alpha", p["J_eq"], tuple(al + friction),
                     (-(p["B_eq"] + b), p["k_s"] * ratio, p["B_l"] * ratio) + ((-coulomb,) if coulomb else ()),
                     -1.0, a * k_p)
    truth = dict(p, a=a, b=b, k_p=k_p, tau=tau, f_c=coulomb, gain=a * k_p)
    return CoupledSystem((theta, alpha), "theta", tau, "zero"), truth


def flexible_joint_experiment(system: CoupledSystem, truth: dict, reference: str, duration: float = 60.0,
                              dt: float = 1e-3, noise: float = 0.0, seed: int = 0) -> Experiment:
    """Closed-loop data of the joint: sine (training) or square (test) reference of
    amplitude 2 rad at 0.66 Hz; outputs theta, alpha; input u = a k_p theta_d."""
    t = np.arange(int(round(duration / dt)) + 1) * dt
    if reference == "sine":
        ref = lambda s: 2.0 * np.sin(2 * np.pi * 0.66 * s)  # noqa: E731
    elif reference == "square":
        ref = lambda s: 2.0 * np.where(np.sin(2 * np.pi * 0.66 * s) >= 0, 1.0, -1.0)  # noqa: E731
    else:
        raise CvxidError(f"reference must be 'sine' or 'square', got {reference!r}")
    gain = truth["a"] * truth["k_p"]
    x, v = simulate_coupled(system, t, lambda s: gain * ref(s), {"theta": 0.0, "alpha": 0.0},
                            {"theta": 0.0, "alpha": 0.0})
    rng = np.random.default_rng(seed)
    outputs = {c: x[c] + noise * rng.standard_normal(t.size) for c in x}
    u = gain * ref(t)
    return Experiment(t, outputs, {"u": u, "minus_u": -u}, name=reference, velocities=v)


def flexible_joint_specs(gain: float, library: Sequence[str] = ("theta'", "alpha", "alpha'"),
                         tau_max: float = 0.5) -> dict[str, ModelSpec]:
    """The two equations' model specs (exact shared delay of theta, known gain)."""
    from .delay import DelayedFeedback
    from .library import Library

    def spec(coord, other, inp, g):
        delay = DelayedFeedback("theta", 0, g, method="exact", tau_max=tau_max)
        lib = Library(parse_term(n, (coord, other)) for n in library)
        return ModelSpec(lib, coordinate=coord, input=inp, delay=delay, nonnegative=(f"{coord}''",), others=(other,))

    return {"theta": spec("theta", "alpha", "u", -gain), "alpha": spec("alpha", "theta", "minus_u", gain)}


def with_terms(specs: dict[str, ModelSpec], extra: Sequence[str]) -> dict[str, ModelSpec]:
    """Every equation with the ``extra`` terms added."""
    return {label: replace(s, library=s.library + [parse_term(n, s.coordinates) for n in extra])
            for label, s in specs.items()}
