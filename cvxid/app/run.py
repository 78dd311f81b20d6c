"""The main job: a problem spec in, an identified model and its figures out.

``run(spec)`` loads (or simulates) the experiments, builds the regressions, sweeps the
:math:`\\lambda` path on the training data, selects the solution with the least test error
and returns a :class:`RunResult` that prints, tabulates and serialises itself.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path as FilePath

import numpy as np
import pandas as pd

from cvxid.app.report import records
from cvxid.data.experiment import Experiment
from cvxid.diagnose.diagnosis import Diagnosis, Refinement, diagnose, refine
from cvxid.errors import CvxidError, CvxidWarning
from cvxid.identified import IdentifiedModel
from cvxid.identify.bootstrap import Bootstrap, BootstrapSettings, bootstrap
from cvxid.identify.loss import huber_refit
from cvxid.identify.orders import OrderSearch, search_orders
from cvxid.identify.output_error import PolishResult, polish
from cvxid.identify.path import Path
from cvxid.identify.problem import Problem
from cvxid.identify.profile import profile_delay
from cvxid.identify.stepwise import Stepwise, stepwise_output_error
from cvxid.regression.algebraic import AlgebraicOrders
from cvxid.regression.builder import RegressionBuilder, build_regression
from cvxid.regression.regression import Regression
from cvxid.regression.velocity import ESTIMATORS
from cvxid.spec.load import load_problem
from cvxid.spec.problem import ProblemSpec

RESULT_SCHEMA = 1


@dataclass
class RunResult:
    """Everything one run produced."""

    spec: ProblemSpec
    model: IdentifiedModel
    path: Path | None
    problem: Problem
    train: Experiment
    test: Experiment | None
    test_mse: float
    test_nmse: float
    seconds: float
    warnings: list[str] = field(default_factory=list)
    bootstrap: Bootstrap | None = None
    order_search: OrderSearch | None = None
    tau: dict | None = None
    polish: PolishResult | None = None
    diagnosis: Diagnosis | None = None
    refinement: Refinement | None = None
    velocity_scores: dict | None = None
    stepwise: Stepwise | None = None

    def table(self) -> pd.DataFrame:
        truth = self.spec.truth.physical if self.spec.truth else None
        return self.model.table(truth)

    def to_dict(self) -> dict:
        phys = self.model.physical
        return {
            "schema": RESULT_SCHEMA,
            "name": self.spec.name,
            "equation": self.model.equation(),
            "equation_latex": self.model.equation_latex(),
            "regression_equation": self.model.regression_equation(),
            "coefficients": {k: float(v) for k, v in self.model.coefficients.items()},
            "physical": {k: float(v) for k, v in phys.items()},
            "truth": self.spec.truth.physical if self.spec.truth else None,
            "support": self.model.support,
            "test_mse": self.test_mse,
            "test_nmse": self.test_nmse,
            "lambda": self.model.lam,
            "estimator": self.spec.fit.estimator,
            "selection": self.spec.fit.selection,
            "velocity": self.spec.fit.velocity,
            "velocity_scores": self.velocity_scores,
            "algebraic_orders": vars(AlgebraicOrders.for_model(self.spec.model)),
            "solver": self.problem.solver,
            "seconds": self.seconds,
            "warnings": self.warnings,
            "tau": self.tau,
            "diagnosis": None if self.diagnosis is None else {
                "ranking": self.diagnosis.records(),
                "groups": self.diagnosis.groups,
            },
            "refinement": None if self.refinement is None else [s.as_dict() for s in self.refinement.steps],
            "polish": None if self.polish is None else {
                "method": "output_error",
                "rms_before": self.polish.rms_before,
                "rms_after": self.polish.rms_after,
                "standard_errors": self.polish.standard_errors,
                "seconds": self.polish.seconds,
            },
            "bootstrap": None if self.bootstrap is None else {
                "samples": len(self.bootstrap.coefficients),
                "terms": records(self.bootstrap.summary()),
                "physical": records(self.bootstrap.physical_summary()),
            },
            "stepwise": None if self.stepwise is None else {
                "history": self.stepwise.history.to_dict(orient="records"),
                "noise": self.stepwise.noise,
                "seconds": self.stepwise.seconds,
            },
            "order_search": None if self.order_search is None else {
                "best_order": self.order_search.best_order,
                "table": records(self.order_search.table),
            },
        }

    def summary(self) -> str:
        frame = self.table()
        if self.bootstrap is not None:
            spread = self.bootstrap.physical_summary()
            frame["boot std"] = spread["std"].reindex(frame.index)
        lines = [
            f"cvxid: {self.spec.name}",
            f"  identified: {self.model.equation()}",
            f"  support ({len(self.model.support)}): {', '.join(self.model.support)}",
            f"  lambda = {self.model.lam:.3g} ({self.spec.fit.estimator}, solver {self.problem.solver}, "
            f"velocity {self.spec.fit.velocity})",
            (f"  test MSE = {self.test_mse:.4g}  (relative {self.test_nmse:.3g})" if self.test is not None
             else "  test MSE: no test experiment ([data.test]) to score on"),
            *([f"  tau = {self.tau['estimate']:.5g} ({self.tau['method']}"
               + (f", 95 % interval {self.tau['interval'][0]:.5g} … {self.tau['interval'][1]:.5g})"
                  if self.tau["interval"] else ")")] if self.tau else []),
            *([f"  output-error polish: simulation RMS {self.polish.rms_before:.4g} -> "
               f"{self.polish.rms_after:.4g} in {self.polish.seconds:.1f} s"] if self.polish else []),
            "",
            frame.to_string(float_format=lambda v: f"{v:.4f}"),
            "",
            f"  {self.seconds:.1f} s",
        ]
        if self.order_search is not None:
            lines[-1:-1] = [repr(self.order_search), ""]
        if self.stepwise is not None:
            lines[-1:-1] = [repr(self.stepwise), ""]
        if self.diagnosis is not None:
            lines[-1:-1] = [repr(self.diagnosis), ""]
        if self.refinement is not None:
            lines[-1:-1] = [repr(self.refinement), ""]
        lines += [f"  warning: {w}" for w in self.warnings]
        return "\n".join(lines)

    def __repr__(self) -> str:
        return self.summary()


def run(spec: ProblemSpec | str | FilePath):
    """Identify the model of a problem spec (a :class:`ProblemSpec` or a path to one).

    Steps: load or simulate the experiments; for an exact delay, profile the delay on the
    whole library; (optionally) search the library order; sweep lambda and select on the
    test experiment; (optionally) bootstrap; for an exact delay, profile the delay again on
    the selected support; (optionally) polish by output error.  A coupled spec
    (``[[model.equation]]``) runs :func:`cvxid.app.joint_run.run_joint` and returns its
    :class:`~cvxid.app.joint_run.JointRunResult`.
    """
    if not isinstance(spec, ProblemSpec):
        spec = load_problem(spec) if isinstance(spec, (str, FilePath)) else spec
    if not isinstance(spec, ProblemSpec):  # a coupled spec ([[model.equation]])
        from cvxid.app.joint_run import run_joint

        return run_joint(spec)
    start = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", CvxidWarning)
        if spec.fit.velocity == "auto":
            result = _best_velocity(spec)
        else:
            result = _identify(spec)
    result.warnings = list(dict.fromkeys(str(w.message) for w in caught if issubclass(w.category, CvxidWarning)))
    result.seconds = time.perf_counter() - start
    return result


def _best_velocity(spec: ProblemSpec) -> RunResult:
    """``velocity = "auto"``: identify with each estimator, keep the least test error."""
    if "test" not in spec.data:
        raise CvxidError('velocity = "auto" chooses by the test error: add [data.test]')
    scores, best = {}, None
    for name in ESTIMATORS:
        result = _identify(replace(spec, fit=replace(spec.fit, velocity=name)))
        scores[name] = result.test_mse
        if best is None or result.test_mse < best.test_mse:
            best = result
    best.velocity_scores = scores
    return best


def _identify(spec: ProblemSpec) -> RunResult:
    fit = spec.fit
    if fit.estimator == "stepwise_oe" and (fit.orders or fit.bootstrap or spec.diagnose is not None
                                           or fit.loss != "squared"):
        raise CvxidError('estimator = "stepwise_oe" selects the terms itself: remove [fit] orders, bootstrap and '
                         'loss, and [diagnose]')
    train = spec.experiment("train")
    test = spec.experiment("test") if "test" in spec.data else None
    velocity = fit.velocity if fit.velocity in ESTIMATORS else "measured"
    model_spec = spec.model
    if fit.orders:
        model_spec = replace(spec.model, library=spec.library(max(fit.orders)))
    exact = model_spec.delay is not None and model_spec.delay.exact
    family = RegressionBuilder(model_spec, train, velocity, fit.window)
    test_family = RegressionBuilder(model_spec, test, velocity, fit.window) if test else None
    if fit.estimator == "stepwise_oe":
        return _stepwise(spec, family, test_family, train, test)
    whole = profile_delay(family, nonnegative=model_spec.nonnegative) if exact else None
    tau = whole.estimate if exact else None
    regression = family.at(tau)
    validation = test_family.at(tau) if test else None
    search = None
    if fit.orders:
        search = order_search(spec, fit.orders, train=regression, test=validation, boot=fit.bootstrap)
        model_spec = model_spec.with_library(spec.library(search.best_order))
        regression = regression.subset(model_spec.column_names)
        validation = validation.subset(model_spec.column_names)
    problem = Problem.from_regression(regression, model_spec.nonnegative, fit.solver)
    path = Path.compute(
        problem, fit.lambdas, validation.residual if validation else None, estimator=fit.estimator, debias=fit.debias
    )
    best = path.best(fit.selection) if validation else path.fits[-1]
    keep = best.support | (problem.penalties == 0)
    coefs = dict(zip(problem.names, np.where(keep, best.coefficients, 0.0)))
    ensemble = None
    if fit.bootstrap:
        ensemble = search.ensembles[search.best_order] if search else bootstrap(
            regression, fit.lambdas, validation.residual if validation else None, fit.bootstrap,
            model_spec.nonnegative, fit.solver, fit.estimator, fit.debias, fit.selection,
        )
        coefs = dict(ensemble.mean)  # the paper's estimate (its eq. 18)
        keep = np.array([coefs[n] != 0 for n in problem.names])
    tau_info = None
    if exact:
        same = keep.all() and not fit.orders  # the first profile was of this very problem
        profile = whole if same else profile_delay(family, support=keep, nonnegative=model_spec.nonnegative,
                                                   model=model_spec)
        tau = profile.estimate
        refit = Problem.from_regression(family.at(tau, model_spec), model_spec.nonnegative, fit.solver).refit(keep)
        coefs = dict(zip(problem.names, np.where(keep, refit.coefficients, 0.0)))
        validation = test_family.at(tau, model_spec) if test else None
        tau_info = profile.as_dict()
    if fit.loss == "huber":
        robust, _ = huber_refit(family.at(tau, model_spec), keep, model_spec.nonnegative, fit.solver)
        coefs = dict(zip(problem.names, np.where(keep, robust.coefficients, 0.0)))
    model = IdentifiedModel(model_spec, {n: float(c) for n, c in coefs.items()}, best.lam, tau=tau)
    if ensemble is not None:
        ensemble.physical = pd.DataFrame(
            [model_spec.physical(dict(r), tau) for _, r in ensemble.coefficients.iterrows()]
        )
    if model_spec.delay is not None and not exact:
        interval = None
        if ensemble is not None:
            taus = ensemble.physical["tau"]
            interval = [float(taus.quantile(0.025)), float(taus.quantile(0.975))]
        tau_info = {"estimate": model.physical["tau"], "interval": interval, "method": "taylor"}
    diagnosis = refinement = None
    if spec.diagnose is not None and test is not None:
        settings = spec.diagnose
        refinement = refine(model, train, test, settings.candidates, settings.min_improvement,
                            settings.max_steps if settings.refine else 0, velocity, fit.window,
                            builders=(family, test_family))
        model = refinement.model
        diagnosis = refinement.diagnoses[0] if refinement.diagnoses else diagnose(
            model, train, test, settings.candidates, velocity, fit.window, builders=(family, test_family))
        if refinement.steps and model_spec.delay is not None and model_spec.delay.exact:
            tau_info = dict(tau_info, estimate=model.tau, interval=None, method="profile (after refinement)")
        model_spec = model.spec
        problem = Problem.from_regression(family.at(model.tau, model_spec), model_spec.nonnegative, fit.solver)
        validation = test_family.at(model.tau, model_spec)
    polished = None
    if fit.refine == "output_error":
        polished = polish(model, train)
        model = polished.model
        if model_spec.delay is not None:
            tau_info = {
                "estimate": polished.parameters["tau"],
                "interval": list(polished.interval("tau")),
                "method": "output_error",
            }
    vector = np.array([model.coefficients[n] for n in problem.names])
    return RunResult(
        spec, model, path, problem, train, test,
        validation.mse(vector) if validation else float("nan"),
        validation.nmse(vector) if validation else float("nan"),
        0.0, [], ensemble, search, tau_info, polished, diagnosis, refinement,
    )


def _stepwise(spec: ProblemSpec, family: RegressionBuilder, test_family: RegressionBuilder | None, train: Experiment,
              test: Experiment | None) -> RunResult:
    """``estimator = "stepwise_oe"``: terms chosen by simulation error
    (:mod:`cvxid.identify.stepwise`), the final model polished at the sample step."""
    fit = spec.fit
    search = stepwise_output_error(spec.model, family, train)
    model = search.model
    columns = list(model.spec.column_names)
    problem = Problem.from_regression(family.at(model.tau).subset(columns), model.spec.nonnegative, fit.solver)
    vector = np.array([model.coefficients[n] for n in columns])
    scored = test_family.at(model.tau).subset(columns) if test_family is not None else None
    estimate = model.tau if model.tau is not None else model.physical.get("tau")
    tau_info = None if spec.model.delay is None else {"estimate": estimate, "interval": None, "method": "output_error"}
    return RunResult(
        spec, model, None, problem, train, test,
        scored.mse(vector) if scored else float("nan"), scored.nmse(vector) if scored else float("nan"),
        0.0, [], tau=tau_info, stepwise=search,
    )


def order_search(spec: ProblemSpec, orders=range(1, 7), samples: int | None = None, fraction: float = 0.5,
                 seed: int = 0, n_jobs: int = 1, train: Regression | None = None, test: Regression | None = None,
                 show_progress: bool = True, boot: BootstrapSettings | None = None) -> OrderSearch:
    """The paper's Algorithm 1 on ``spec``'s polynomial library: every order in ``orders``
    scored on the test experiment, with its fit settings; ``samples`` bootstraps per order
    (none: a single path each), or ``boot`` settings.  ``train``/``test`` regressions at
    the highest order may be passed to skip building them."""
    if "test" not in spec.data and test is None:
        raise CvxidError("the order search scores orders on the test experiment: add [data.test]")
    fit = spec.fit
    orders = sorted({int(o) for o in orders})
    top = replace(spec.model, library=spec.library(orders[-1]))
    velocity = fit.velocity if fit.velocity in ESTIMATORS else "measured"
    train = train if train is not None else build_regression(top, spec.experiment("train"), velocity)
    test = test if test is not None else build_regression(top, spec.experiment("test"), velocity)
    if boot is None and samples:
        boot = BootstrapSettings(samples, fraction, seed, n_jobs)
    return search_orders(top, spec.library, train, test, orders, fit.lambdas, fit.estimator, fit.debias,
                         fit.selection, fit.solver, boot, show_progress)


def refine_spec(spec: ProblemSpec | str | FilePath, **settings):
    """Run ``spec`` with its diagnosis loop on (``[diagnose] refine = true``); the loop's
    :class:`~cvxid.diagnose.diagnosis.Refinement` (steps, diagnoses, final model, ``plot()``)."""
    from cvxid.spec.problem import DiagnoseSettings

    if not isinstance(spec, ProblemSpec):
        spec = load_problem(spec)
    current = spec.diagnose or DiagnoseSettings()
    spec = replace(spec, diagnose=replace(current, refine=True, **settings))
    return run(spec).refinement
