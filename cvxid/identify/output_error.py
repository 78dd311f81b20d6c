r"""Output-error polish: from the convex estimate to the least simulation error.

Starting from an identified model and its support, the mass, the coefficients of the
selected terms, the delay :math:`\tau` (and an unknown gain) and the initial state
:math:`(x_0, \dot x_0)` are adjusted to minimise

.. math::

    \sum_k \big(x_\mathrm{measured}(t_k) - x_\mathrm{simulated}(t_k;\theta)\big)^2

with scipy's ``least_squares``.  The equation-error estimate is biased by noise in the
velocity columns; the simulation error is not, because only :math:`x` is compared.  A
forward-difference Jacobian needs one simulation per parameter: they run as one batch
through the vectorised integrator, so a Jacobian costs about one simulation's Python
overhead.  The simulation uses a step of about ``step`` seconds (a whole number of samples),
which keeps RK4 accurate while the record is long.  Standard errors come from the
Jacobian at the optimum, :math:`\sigma^2 (J^T J)^{-1}`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import least_squares
from scipy.signal import savgol_filter

from cvxid.data.experiment import Experiment
from cvxid.errors import CvxidError
from cvxid.identified import IdentifiedModel
from cvxid.regression.velocity import savgol_window
from cvxid.simulate import SimulationDiverged, System, simulate


@dataclass(frozen=True)
class PolishResult:
    """The polished model, its parameter table and how the fit went."""

    model: IdentifiedModel
    parameters: dict[str, float]
    standard_errors: dict[str, float]
    rms_before: float
    rms_after: float
    x0: float
    v0: float
    iterations: int
    seconds: float

    def interval(self, name: str, z: float = 1.96) -> tuple[float, float]:
        value, se = self.parameters[name], self.standard_errors[name]
        return value - z * se, value + z * se


STARTS = 5
"""Delays tried as starting points (the simulation error has local minima in tau)."""


def polish(model: IdentifiedModel, experiment: Experiment, coarse_step: float = 1e-3, final: bool = True,
           max_iterations: int = 200) -> PolishResult:
    """Output-error polish with several starting delays: each start is fitted on a coarse
    simulation step, the best is refined at the sample step (unless ``final`` is false)."""
    start = time.perf_counter()
    delay = model.spec.delay
    taus = [model.tau] if model.tau is not None else [model.physical.get("tau")]
    if delay is not None:
        taus += list(np.linspace(delay.tau_min, delay.tau_max, STARTS + 2)[1:-1])
    taus = [t for t in taus if t is not None] or [None]
    best = None
    for tau in taus:
        trial = model if tau is None else with_tau(model, tau)
        try:
            fit = output_error(trial, experiment, step=coarse_step, max_iterations=max_iterations)
        except CvxidError:
            continue
        if best is None or fit.rms_after < best.rms_after:
            best = fit
    if best is None:
        raise CvxidError("the output-error polish failed from every starting delay (diverging simulations)")
    if not final:
        return replace(best, rms_before=output_rms(model, experiment), seconds=time.perf_counter() - start)
    last = output_error(best.model, experiment, best.x0, best.v0, step=experiment.dt, max_iterations=50)
    return PolishResult(last.model, last.parameters, last.standard_errors, output_rms(model, experiment),
                        last.rms_after, last.x0, last.v0, last.iterations, time.perf_counter() - start)


def output_rms(model: IdentifiedModel, experiment: Experiment) -> float:
    """Root-mean-square free-run simulation error of ``model`` on ``experiment`` (inf if the
    simulation diverges)."""
    y = experiment.output(model.spec.coordinate)
    x0, v0 = initial_state(experiment.time, y)
    try:
        x, _ = model.simulate(experiment, x0, v0)
    except SimulationDiverged:
        return float("inf")
    return float(np.sqrt(np.mean((x - y) ** 2)))


def initial_state(t: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """Position and velocity at the first sample, from a Savitzky–Golay fit whose window
    is chosen from the noise (a short fixed window lets the noise into the velocity)."""
    w = savgol_window(y)
    dt = float(t[1] - t[0])
    return (float(savgol_filter(y, w, 3, mode="interp")[0]),
            float(savgol_filter(y, w, 3, deriv=1, delta=dt, mode="interp")[0]))


def with_tau(model: IdentifiedModel, tau: float) -> IdentifiedModel:
    """``model`` with its physical parameters kept and the delay set to ``tau`` (a Taylor
    model's delay shares rewritten into its columns)."""
    system = model.system()
    params = {model.spec.parameter_name(t.name): c for t, c in zip(system.terms, np.atleast_1d(system.coefficients))}
    params["m"] = float(system.mass)
    params["tau"] = float(tau)
    return _updated(model, system, params)


def output_error(
    model: IdentifiedModel,
    experiment: Experiment,
    x0: float | None = None,
    v0: float | None = None,
    step: float = 1e-3,
    max_iterations: int = 30,
) -> PolishResult:
    """Polish ``model`` on ``experiment`` by output error from its own delay (see the
    module docstring; :func:`polish` adds several starting delays)."""
    start = time.perf_counter()
    spec = model.spec
    system = model.system()
    history = system.history
    coord = spec.coordinate
    stride = max(1, int(round(step / experiment.dt)))
    t = experiment.time[::stride]
    if t.size < 20:
        raise CvxidError(f"experiment '{experiment.name}' is too short for the output-error polish")
    y = experiment.output(coord)[::stride]
    u = experiment.input(spec.input)[::stride]
    guess = initial_state(t, y)
    x0 = guess[0] if x0 is None else x0
    v0 = guess[1] if v0 is None else v0
    has_delay = spec.delay is not None and system.gain != 0
    estimate_gain = has_delay and spec.delay.gain is None
    names = ["m"] if spec.inertia else []
    names += [spec.parameter_name(term.name) for term in system.terms]
    theta0 = ([system.mass] if spec.inertia else []) + list(np.atleast_1d(system.coefficients))
    if has_delay:
        names.append("tau")
        theta0.append(float(system.tau))
    if estimate_gain:
        names.append("gain")
        theta0.append(float(system.gain))
    names += ["x0", "v0"]
    theta0 = np.array(theta0 + [x0, v0], dtype=float)
    k = len(system.terms)

    def unpack(thetas: np.ndarray) -> tuple[System, np.ndarray, np.ndarray]:
        i = 0
        mass = thetas[:, 0] if spec.inertia else np.full(len(thetas), spec.mass)
        i += int(spec.inertia)
        coefs = thetas[:, i : i + k]
        i += k
        tau = np.maximum(thetas[:, i], 0.0) if has_delay else 0.0
        i += int(has_delay)
        gain = system.gain
        if estimate_gain:
            gain = thetas[:, i]
            i += 1
        batch = System(system.terms, coefs, np.maximum(mass, 1e-12), coord, gain, tau, system.derivative, history)
        return batch, thetas[:, i], thetas[:, i + 1]

    def residuals(thetas: np.ndarray) -> np.ndarray:
        batch, xs, vs = unpack(np.atleast_2d(thetas))
        try:
            x, _ = simulate(batch, t, u, xs, vs)
        except SimulationDiverged:
            return np.full((len(t), len(np.atleast_2d(thetas))), 1e6)
        x = x.reshape(len(t), -1)
        return x - y[:, None]

    cache: dict[bytes, np.ndarray] = {}

    def fun(theta):
        key = theta.tobytes()
        if key not in cache:
            cache.clear()
            cache[key] = residuals(theta[None, :])[:, 0]
        return cache[key]

    def jac(theta):
        h = 1e-6 * np.maximum(np.abs(theta), 1e-3)
        thetas = np.vstack([theta, theta + np.diag(h)])
        r = residuals(thetas)
        cache.clear()
        cache[theta.tobytes()] = r[:, 0]
        return (r[:, 1:] - r[:, :1]) / h

    before = float(np.sqrt(np.mean(fun(theta0) ** 2)))
    lower = np.full(theta0.size, -np.inf)
    upper = np.full(theta0.size, np.inf)
    if spec.inertia:
        lower[0] = 1e-9
    if has_delay:
        i = names.index("tau")
        lower[i], upper[i] = spec.delay.tau_min, spec.delay.tau_max
        theta0[i] = np.clip(theta0[i], lower[i], upper[i])
    sol = least_squares(fun, theta0, jac=jac, bounds=(lower, upper), method="trf", x_scale="jac",
                        max_nfev=max_iterations)
    theta = sol.x
    r = fun(theta)
    after = float(np.sqrt(np.mean(r**2)))
    dof = max(r.size - theta.size, 1)
    try:
        cov = np.linalg.inv(sol.jac.T @ sol.jac) * float(r @ r) / dof
        se = np.sqrt(np.clip(np.diag(cov), 0, None))
    except np.linalg.LinAlgError:
        se = np.full(theta.size, np.nan)
    params = dict(zip(names, map(float, theta)))
    errors = dict(zip(names, map(float, se)))
    refined = _updated(model, system, params)
    return PolishResult(refined, params, errors, before, after, params["x0"], params["v0"], int(sol.nfev),
                      time.perf_counter() - start)


def _updated(model: IdentifiedModel, system: System, params: dict) -> IdentifiedModel:
    """The identified model with the polished physical parameters written back into its
    regression coefficients (the delay's Taylor share re-added where it has one)."""
    spec = model.spec
    coefs = dict(model.coefficients)
    for term in system.terms:
        coefs[term.name] = params[spec.parameter_name(term.name)]
    if spec.inertia:
        coefs[spec.inertia_term.name] = params["m"]
    tau = params.get("tau", model.tau)
    if "gain" in params:
        coefs[spec.delayed_term.name] = -params["gain"]
    if spec.delay is not None and not spec.delay.exact:
        for t in spec.delay.taylor_terms():
            if t.name in coefs:
                base = coefs[t.name] if (t.name in spec.library or t.name == spec.inertia_term.name) else 0.0
                coefs[t.name] = base + spec.delay.contribution(t.order, tau)
    return IdentifiedModel(spec, coefs, model.lam, dict(model.info, refined="output_error"), tau)
