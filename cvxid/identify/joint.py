r"""Joint identification of coupled equations: one cvxpy problem, one shared delay.

Every equation :math:`i` of a coupled system (see :mod:`cvxid.coupled`) has its own
regression :math:`P_i c_i \approx p_i`.  They are stacked block-diagonally
(:meth:`~cvxid.regression.regression.Regression.block`) into one problem, coefficients shared across
equations are tied by linear equality constraints :math:`c_a = \rho\, c_b`, and the shared
exact delay is profiled on the joint optimal value

.. math::

    \hat\tau = \arg\min_\tau \min_{c:\ \text{ties, signs}} \sum_i \|P_i(\tau) c_i - p_i\|^2 .

:func:`polish_joint` then minimises the simulation error of all coordinates at once
(output error, as :mod:`cvxid.identify.output_error` does for one equation): the equation-error estimate
is biased when noisy columns are nearly collinear — in the flexible joint the link
deflection :math:`\alpha` follows :math:`-J_l\ddot\theta/k_s` at low frequency, so the
stiffness and the inertia are told apart only by the small high-frequency part.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Sequence

import numpy as np
import pandas as pd
from scipy.optimize import least_squares

from cvxid.data.experiment import Experiment
from cvxid.errors import CvxidError
from cvxid.identified import IdentifiedModel
from cvxid.identify.output_error import initial_state
from cvxid.identify.problem import Problem
from cvxid.identify.profile import profile_delay
from cvxid.metrics import fit_percent
from cvxid.model.equation import ModelSpec
from cvxid.model.terms import parse_term
from cvxid.regression.builder import SystemBuilder
from cvxid.regression.regression import Regression
from cvxid.simulate import (
    CoupledSystem,
    Equation,
    SimulationDiverged,
    half_steps,
    integrate_coupled,
)

Tie = tuple[str, str, float]
JOINT_SCHEMA = "cvxid.joint/1"


@dataclass(frozen=True)
class JointResult:
    """Identified equations (one :class:`~cvxid.identified.IdentifiedModel` per
    coordinate), the shared delay and the joint problem's figures."""

    models: dict[str, IdentifiedModel]
    tau: float
    profile: tuple[np.ndarray, np.ndarray]
    ties: tuple[Tie, ...] = ()
    info: dict = field(default_factory=dict)

    @property
    def specs(self) -> dict[str, ModelSpec]:
        return {label: m.spec for label, m in self.models.items()}

    @property
    def coefficients(self) -> dict[str, float]:
        """Every coefficient as ``"equation:column"``."""
        return {f"{label}:{n}": c for label, m in self.models.items() for n, c in m.coefficients.items()}

    def system(self) -> CoupledSystem:
        """The identified coupled system (each equation's input enters with gain 1)."""
        equations, delayed, history = [], None, "zero"
        for model in self.models.values():
            s = model.system()
            equations.append(Equation(model.spec.coordinate, float(s.mass), s.terms, tuple(np.atleast_1d(s.coefficients)),
                                      1.0, float(s.gain)))
            if model.spec.delay is not None:
                delayed, history = model.spec.delay.coordinate, model.spec.delay.history
        return CoupledSystem(tuple(equations), delayed or equations[0].coordinate, self.tau, history)

    def simulate(self, experiment: Experiment, initial: dict | None = None) -> dict[str, np.ndarray]:
        """Free-run simulation of every coordinate under ``experiment``'s inputs, from
        ``initial`` (coordinate → (position, velocity)) or the state estimated from the data."""
        system = self.system()
        t = experiment.time
        initial = initial or {c: initial_state(t, experiment.output(c)) for c in self._coordinates}
        x0 = np.array([[initial[c][0]] for c in self._coordinates])
        v0 = np.array([[initial[c][1]] for c in self._coordinates])
        X, _ = integrate_coupled(system, t, joint_forces(self.specs, experiment, t), *system.arrays(),
                                 np.array([self.tau]), x0, v0)
        return {c: X[:, j, 0] for j, c in enumerate(self._coordinates)}

    def compare(self, experiment: Experiment) -> pd.DataFrame:
        """Free-run fit (%) and RMS error of every coordinate on ``experiment``; a
        diverging simulation gives fit -inf."""
        rows = []
        try:
            sim = self.simulate(experiment)
        except SimulationDiverged:
            sim = None
        for c in self._coordinates:
            y = experiment.output(c)
            if sim is None:
                rows.append({"coordinate": c, "fit_percent": -np.inf, "rms": np.inf})
            else:
                rows.append({"coordinate": c, "fit_percent": fit_percent(y, sim[c]),
                             "rms": float(np.sqrt(np.mean((sim[c] - y) ** 2)))})
        return pd.DataFrame(rows).set_index("coordinate")

    def equations(self) -> list[str]:
        return [m.equation() for m in self.models.values()]

    def to_dict(self) -> dict:
        """A JSON-ready description (schema ``cvxid.joint/1``): every equation's model
        (schema ``cvxid.identified/1``), the delay and the ties."""
        return {"schema": JOINT_SCHEMA, "tau": float(self.tau),
                "ties": [{"left": a, "right": b, "factor": float(f)} for a, b, f in self.ties],
                "equations": {label: m.to_dict() for label, m in self.models.items()}}

    @classmethod
    def from_dict(cls, data: dict) -> "JointResult":
        """Rebuild a joint model written by :meth:`to_dict`, checking every field."""
        try:
            if data.get("schema") != JOINT_SCHEMA:
                raise CvxidError(f"not a cvxid joint model (schema {data.get('schema')!r}, expected {JOINT_SCHEMA!r})")
            tau = float(data["tau"])
            ties = tuple((str(t["left"]), str(t["right"]), float(t["factor"])) for t in data["ties"])
            models = {str(k): IdentifiedModel.from_dict(v) for k, v in data["equations"].items()}
        except CvxidError:
            raise
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise CvxidError(f"the joint model file is incomplete or corrupted ({type(exc).__name__}: {exc})") from None
        if not np.isfinite(tau) or any(m.tau != tau for m in models.values()):
            raise CvxidError("the joint model file's delay is not finite or differs between its equations")
        _check_ties({k: m.spec for k, m in models.items()}, ties)
        return cls(models, tau, (np.array([tau]), np.array([np.nan])), ties)

    def save(self, path) -> None:
        """Write the joint model as JSON (never pickle)."""
        Path(path).write_text(json.dumps(self.to_dict(), indent=2))

    @classmethod
    def load(cls, path) -> "JointResult":
        """Read a joint model written by :meth:`save`."""
        try:
            data = json.loads(Path(path).read_text())
        except (OSError, ValueError) as exc:
            raise CvxidError(f"cannot read the joint model {path}: {exc}") from None
        return cls.from_dict(data)

    @property
    def _coordinates(self) -> list[str]:
        return [m.spec.coordinate for m in self.models.values()]

    def __repr__(self) -> str:
        lines = [f"Joint identification of {len(self.models)} equations: tau = {self.tau:.5g}"]
        lines += [f"  {e}" for e in self.equations()]
        if self.ties:
            lines.append("  ties: " + ", ".join(f"{a} = {f:g} {b}" for a, b, f in self.ties))
        return "\n".join(lines)


def joint_forces(specs: dict[str, ModelSpec], experiment: Experiment, t: np.ndarray) -> np.ndarray:
    """Each equation's input at the RK4 nodes and midpoints of the grid ``t`` ``(2n-1, C)``."""
    h = float(t[1] - t[0])
    stride = int(round(h / experiment.dt))
    return np.column_stack([half_steps(experiment.input(s.input)[::stride][: t.size], t, h, t.size - 1)
                            for s in specs.values()])


def _check(specs: dict[str, ModelSpec]):
    delays = {(s.delay.coordinate, s.delay.tau_min, s.delay.tau_max) for s in specs.values() if s.delay}
    if len(delays) != 1 or any(s.delay is None or not s.delay.exact for s in specs.values()):
        raise CvxidError("a joint identification needs one shared exact delay (method = \"exact\") in every "
                         "equation, with the same signal and bounds")
    coords = [s.coordinate for s in specs.values()]
    if len(set(coords)) != len(coords):
        raise CvxidError(f"every equation needs its own coordinate; got {coords}")


def _check_ties(specs: dict[str, ModelSpec], ties: Sequence[Tie]):
    names = {f"{label}:{n}" for label, s in specs.items() for n in s.column_names}
    for a, b, factor in ties:
        for name in (a, b):
            if name not in names:
                raise CvxidError(f"tie {a!r} = {factor:g} {b!r}: unknown column {name!r}; the columns are "
                                 f"{', '.join(sorted(names))}")


class JointRegression:
    """The stacked regression of every equation (from ``rows``, a
    :class:`~cvxid.regression.builder.SystemBuilder` of the data or the experiments
    themselves), evaluated at any delay."""

    def __init__(self, specs: dict[str, ModelSpec], rows, velocity: str = "savgol", window: float | None = None,
                 ties: Sequence[Tie] = ()):
        self.specs = specs
        _check(specs)
        _check_ties(specs, ties)
        self.ties = tuple(ties)
        self.rows = rows if isinstance(rows, SystemBuilder) else SystemBuilder(specs, rows, velocity, window)
        self.nonnegative = [f"{label}:{n}" for label, spec in specs.items() for n in spec.nonnegative]

    def at(self, tau: float) -> Regression:
        return self.rows.at(tau, self.specs)

    def problem(self, tau: float) -> Problem:
        return Problem.from_regression(self.at(tau), self.nonnegative, ties=self.ties)

    def identify(self) -> JointResult:
        """Least squares of every equation, the delay profiled on the joint optimal value
        (:func:`~cvxid.identify.profile.profile_delay`, with its interval)."""
        profile = profile_delay(self.rows, nonnegative=self.nonnegative, model=self.specs, ties=self.ties)
        tau = profile.estimate
        problem = self.problem(tau)
        fit = problem.refit(np.ones(problem.k, bool))
        coefficients = dict(zip(problem.names, map(float, fit.coefficients)))
        info = {"method": "equation_error", "train_mse": fit.train_mse, "tau_interval": list(profile.interval)}
        return JointResult(joint_models(self.specs, coefficients, tau, info), tau, (profile.taus, profile.values),
                           self.ties, dict(info))


def identify_joint(specs: dict[str, ModelSpec], rows, ties: Sequence[Tie] = (), velocity: str = "savgol",
                   window: float | None = None) -> JointResult:
    """Least squares of every equation in one problem, ``ties`` (``("eq:column",
    "eq:column", factor)``: the first is ``factor`` times the second) holding across
    them, the shared exact delay profiled on the joint optimal value.  ``rows``: the
    experiments, or a :class:`~cvxid.regression.builder.SystemBuilder` of them to reuse."""
    return JointRegression(specs, rows, velocity, window, ties).identify()


def joint_models(specs: dict[str, ModelSpec], coefficients: dict[str, float], tau: float, info: dict):
    models = {}
    for label, spec in specs.items():
        coefs = {n: coefficients.get(f"{label}:{n}", 0.0) for n in spec.column_names}
        models[label] = IdentifiedModel(spec, coefs, info=dict(info), tau=tau)
    return models


def joint_test_mse(result: JointResult, rows, velocity: str = "savgol", window: float | None = None) -> float:
    """Mean squared equation error of ``result`` on other data (experiments or their
    :class:`~cvxid.regression.builder.SystemBuilder`), all equations stacked."""
    regression = JointRegression(result.specs, rows, velocity, window).at(result.tau)
    coefficients = result.coefficients
    return regression.mse(np.array([coefficients.get(n, 0.0) for n in regression.names]))


# ---------------------------------------------------------------------- output error
@dataclass(frozen=True)
class JointPolish:
    """The polished result, its parameters with standard errors and how the fit went."""

    result: JointResult
    parameters: dict[str, float]
    standard_errors: dict[str, float]
    rms_before: float
    rms_after: float
    evaluations: int
    seconds: float

    def table(self) -> pd.DataFrame:
        return pd.DataFrame({"value": self.parameters, "std_error": self.standard_errors})


def polish_joint(result: JointResult, experiments: Sequence[Experiment] | Experiment, step: float = 4e-3,
                 max_evaluations: int = 100) -> JointPolish:
    """Minimise the simulation error of every coordinate over the inertias, the
    coefficients on the support (ties kept), the delay (and unknown delay gains) and each
    experiment's initial state; first on a simulation step of about ``step`` seconds, then
    a few iterations at the sample step.  Standard errors from the Jacobian at the optimum,
    :math:`\\sigma^2 (J^T J)^{-1}`."""
    start = time.perf_counter()
    experiments = [experiments] if isinstance(experiments, Experiment) else list(experiments)
    coarse = max(1, int(round(step / experiments[0].dt)))
    problem = _PolishProblem(result, experiments, coarse * experiments[0].dt)
    theta = problem.start
    before = problem.rms(theta, 1)
    for stride, budget in ((coarse, max_evaluations), (1, 10)):
        sol = least_squares(lambda p: problem.residuals(p[None, :], stride)[:, 0], theta,
                            jac=lambda p: problem.jacobian(p, stride), bounds=problem.bounds, method="trf",
                            x_scale="jac", max_nfev=budget)
        theta = sol.x
    r = problem.residuals(theta[None, :], 1)[:, 0]
    after = float(np.sqrt(np.mean(r**2)))
    try:
        cov = np.linalg.inv(sol.jac.T @ sol.jac) * float(r @ r) / max(r.size - theta.size, 1)
        se = np.sqrt(np.clip(np.diag(cov), 0, None))
    except np.linalg.LinAlgError:
        se = np.full(theta.size, np.nan)
    polished = problem.result(theta, dict(result.info, method="output_error", rms_before=before, rms_after=after))
    values = {k: float(v[0]) for k, v in problem.values(theta[None, :]).items()}
    errors = dict(zip(problem.names, map(float, se)))
    errors.update({a: abs(f) * errors[b] for a, (b, f) in problem.tied.items()})
    return JointPolish(polished, values, errors, before, after, int(sol.nfev), time.perf_counter() - start)


class _PolishProblem:
    """Parameters ↔ coupled systems for :func:`polish_joint`."""

    def __init__(self, result: JointResult, experiments: list[Experiment], step: float):
        self.base = result
        self.experiments = experiments
        self.system = result.system()
        coefficients = result.coefficients
        tied = {a: (b, f) for a, b, f in result.ties if coefficients.get(a) and coefficients.get(b)}
        self.slots = []  # (equation index, column name) of every simulated number
        names, start, lower = [], [], []
        for e, (label, model) in enumerate(result.models.items()):
            spec = model.spec
            columns = ([spec.inertia_term.name] if spec.inertia else []) + [t.name for t in self.system.equations[e].terms]
            if spec.delay is not None and spec.delay.gain is None:
                columns.append(spec.delayed_term.name)
            for n in columns:
                key = f"{label}:{n}"
                self.slots.append(key)
                if key not in tied:
                    names.append(key)
                    start.append(coefficients[key])
                    lower.append(0.0 if n in spec.nonnegative else -np.inf)
        self.tied = tied
        delay = next(iter(result.models.values())).spec.delay  # shared by every equation
        lo, hi = delay.tau_min, delay.tau_max
        names.append("tau")
        start.append(float(np.clip(result.tau, lo, hi)))
        lower.append(max(lo, step))  # the integrator needs a delay of at least one step
        self.coordinates = [eq.coordinate for eq in self.system.equations]
        for i, ex in enumerate(experiments):
            for c in self.coordinates:
                x0, v0 = initial_state(ex.time, ex.output(c))
                names += [f"{c}0[{i}]", f"{c}'0[{i}]"]
                start += [x0, v0]
                lower += [-np.inf, -np.inf]
        self.names = names
        self.start = np.array(start, float)
        upper = np.full(len(names), np.inf)
        upper[names.index("tau")] = hi
        self.bounds = (np.array(lower), upper)
        self.start = np.clip(self.start, self.bounds[0], self.bounds[1])

    def values(self, thetas: np.ndarray) -> dict[str, np.ndarray]:
        values = dict(zip(self.names, thetas.T))
        for a, (b, f) in self.tied.items():
            values[a] = f * values[b]
        return values

    def residuals(self, thetas: np.ndarray, stride: int) -> np.ndarray:
        values = self.values(thetas)
        C, B = len(self.coordinates), thetas.shape[0]
        mass, gain, coefs = np.ones((C, B)), np.zeros((C, B)), []
        for e, (label, model) in enumerate(self.base.models.items()):
            spec, eq = model.spec, self.system.equations[e]
            mass[e] = values[f"{label}:{spec.inertia_term.name}"] if spec.inertia else spec.mass
            coefs += [values[f"{label}:{t.name}"] for t in eq.terms]
            if spec.delay is not None:
                gain[e] = -values[f"{label}:{spec.delayed_term.name}"] if spec.delay.gain is None else spec.delay.gain
        coefs = np.array(coefs).reshape(-1, B)
        out = []
        for i, ex in enumerate(self.experiments):
            t = ex.time[::stride]
            x0 = np.array([values[f"{c}0[{i}]"] for c in self.coordinates])
            v0 = np.array([values[f"{c}'0[{i}]"] for c in self.coordinates])
            try:
                X, _ = integrate_coupled(self.system, t, joint_forces(self.base.specs, ex, t), coefs, mass, gain,
                                         values["tau"], x0, v0)
            except SimulationDiverged:
                X = np.full((t.size, C, B), 1e6)
            Y = np.column_stack([ex.output(c)[::stride] for c in self.coordinates])
            out.append((X - Y[:, :, None]).reshape(-1, B))
        return np.vstack(out)

    def jacobian(self, theta: np.ndarray, stride: int) -> np.ndarray:
        h = 1e-6 * np.maximum(np.abs(theta), 1e-3)
        r = self.residuals(np.vstack([theta, theta + np.diag(h)]), stride)
        return (r[:, 1:] - r[:, :1]) / h

    def rms(self, theta: np.ndarray, stride: int) -> float:
        return float(np.sqrt(np.mean(self.residuals(theta[None, :], stride) ** 2)))

    def result(self, theta: np.ndarray, info: dict) -> JointResult:
        values = {k: float(v[0]) for k, v in self.values(theta[None, :]).items()}
        coefficients = dict(self.base.coefficients)
        coefficients.update({k: values[k] for k in self.slots})
        return replace(self.base, models=joint_models(self.base.specs, coefficients, values["tau"], info),
                       tau=values["tau"], info=info)


def with_terms(specs: dict[str, ModelSpec], extra: Sequence[str]) -> dict[str, ModelSpec]:
    """Every equation with the ``extra`` terms added."""
    return {label: replace(s, library=s.library + [parse_term(n, s.coordinates) for n in extra])
            for label, s in specs.items()}
