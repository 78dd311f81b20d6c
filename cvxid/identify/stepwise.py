r"""Structure selection by simulation error: stepwise forward, then backward.

When a true term needs the velocity (:math:`\dot x^3`), every velocity estimate leaves an
in-band error that the equation-error regression turns into wrong terms, and the true
support appears nowhere on its λ path.  The simulation error compares positions only:

.. math::

    J(S) = \min_{\theta_S} \sqrt{\tfrac1n \textstyle\sum_k
        \big(x_\mathrm{measured}(t_k) - x_\mathrm{simulated}(t_k; \theta_S)\big)^2}

for a support :math:`S` of library terms.  Each candidate support starts from its own
equation-error fit (the convex least squares on the same regression, which lands close
enough for a local output-error fit) and is polished by :func:`cvxid.identify.output_error.output_error`
on a coarse simulation step.

* **Forward**: from the base terms, add the term that lowers :math:`J` most, while it falls
  by at least ``min_gain``.
* **Backward**: drop a term when :math:`J` without it (warm-started from the current fit)
  stays within ``tolerance`` of :math:`\max(J, \hat\sigma)`, with :math:`\hat\sigma` the noise
  level of the measured position (at the noise floor every remaining difference is noise).
* The selected model is polished once more at the sample step.

It costs one local output-error fit per candidate (parallel with joblib); use it for
libraries of tens of terms, not hundreds.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass
from typing import Sequence

import numpy as np
import pandas as pd
from joblib import Parallel, delayed

from cvxid.data.experiment import Experiment
from cvxid.errors import CvxidError, CvxidWarning
from cvxid.identified import IdentifiedModel
from cvxid.identify.output_error import output_error, polish, with_tau
from cvxid.identify.problem import Problem
from cvxid.identify.profile import profile_delay
from cvxid.model.equation import ModelSpec
from cvxid.model.library import Library
from cvxid.progress import progress
from cvxid.regression.builder import RegressionBuilder
from cvxid.regression.regression import Regression
from cvxid.metrics import noise_level


@dataclass(frozen=True)
class Stepwise:
    """The selected model and every step of the search."""

    model: IdentifiedModel
    history: pd.DataFrame  # step, action, term, rms
    noise: float
    seconds: float

    def __repr__(self) -> str:
        lines = [f"Stepwise selection by simulation error ({self.seconds:.1f} s, noise level {self.noise:.4g}):"]
        lines += ["  " + line for line in self.history.to_string(index=False).splitlines()]
        return "\n".join(lines)


RANKING = 8
"""Output-error iterations when candidates are only ranked, on twice the step (the chosen
one is then converged on the step itself)."""


def _start(spec: ModelSpec, regression: Regression, terms: Sequence[str], tau: float | None) -> IdentifiedModel:
    """The equation-error least-squares fit of ``spec`` restricted to ``terms``, started
    at the delay ``tau`` (the regression's own for an exact delay; for a Taylor delay the
    coefficient map's estimate is replaced by ``tau``, the current output-error delay: the
    map's is biased and a poor start falls into another minimum of the simulation error)."""
    reduced = spec.with_library(Library([t for t in spec.library if t.name in terms]))
    problem = Problem.from_regression(regression.subset(reduced.column_names), reduced.nonnegative)
    fit = problem.refit(np.ones(problem.k, bool))
    exact = spec.delay is not None and spec.delay.exact
    model = IdentifiedModel(reduced, dict(zip(problem.names, map(float, fit.coefficients))), tau=tau if exact else None)
    if spec.delay is not None and not exact and tau is not None:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", CvxidWarning)
            model = with_tau(model, tau)
    return model


def _delay(fit, exact: bool) -> float | None:
    """The delay of an output-error fit (None without a delay)."""
    if exact:
        return fit.model.tau
    return fit.parameters.get("tau")


def _without(model: IdentifiedModel, term: str) -> IdentifiedModel:
    """``model`` with ``term`` dropped and every other coefficient kept (a warm start)."""
    spec = model.spec.with_library(Library([t for t in model.spec.library if t.name != term]))
    return IdentifiedModel(spec, {n: model.coefficients.get(n, 0.0) for n in spec.column_names}, tau=model.tau)


def _score(model: IdentifiedModel, experiment: Experiment, step: float, iterations: int = 30):
    """The output-error fit from ``model`` (None and inf when every simulation diverges)."""
    try:
        with warnings.catch_warnings():  # trial fits: their intermediate delays may be anything
            warnings.simplefilter("ignore", CvxidWarning)
            fit = output_error(model, experiment, step=step, max_iterations=iterations)
    except CvxidError:
        return None, np.inf
    return fit, fit.rms_after if np.isfinite(fit.rms_after) else np.inf


def _backward(pool, fit, rms, current, base, train, step, floor, tolerance, rows):
    """Drop terms while the simulation error stays within ``tolerance`` of the larger of
    itself and the noise ``floor``; ``current`` and ``rows`` are updated in place."""
    while True:
        removable = [n for n in current if n not in base]
        trials = pool(delayed(_score)(_without(fit.model, n), train, step) for n in removable)
        if not trials:
            return fit, rms
        best = int(np.argmin([r for _, r in trials]))
        if not trials[best][1] <= max((1 + tolerance) * rms, floor):
            return fit, rms
        current.remove(removable[best])
        fit, rms = trials[best]
        rows.append({"step": len(rows), "action": "remove", "term": removable[best], "rms": rms})


def stepwise_output_error(spec: ModelSpec, family: RegressionBuilder, train: Experiment, base: Sequence[str] | None = None,
                          min_gain: float = 0.01, tolerance: float = 0.005, step: float = 1e-3,
                          n_jobs: int = 2) -> Stepwise:
    """Select the library terms of ``spec`` by simulation error on ``train`` (see the
    module docstring).  ``family`` builds the equation-error regression of the whole
    library (at the current delay, for an exact delay); ``base`` are the terms always kept
    (default: the library's linear terms, e.g. ``x`` and ``x'``)."""
    start = time.perf_counter()
    names = spec.library.names
    linear = [spec.coordinate, spec.coordinate + "'"]
    if base is None:
        base = [n for n in linear if n in names]
    unknown = set(base) - set(names)
    if unknown:
        raise CvxidError(f"stepwise base term(s) {', '.join(sorted(unknown))} are not in the library")
    base = list(base)
    sigma = noise_level(train.output(spec.coordinate))
    step = max(step, train.dt)
    exact = spec.delay is not None and spec.delay.exact
    tau = None
    if exact:  # the delay of the base support; the output-error fits move it from there
        keep = [c.name in base or c.group != "library" for c in spec.columns]
        tau = profile_delay(family, support=keep, nonnegative=spec.nonnegative).estimate
    with warnings.catch_warnings():  # the base fit's first (Taylor) delay may have the wrong sign
        warnings.simplefilter("ignore", CvxidWarning)
        fit = polish(_start(spec, family.at(tau), base, tau), train, coarse_step=step, final=False, max_iterations=25)
    current, rms = list(base), fit.rms_after
    rows = [{"step": 0, "action": "start", "term": ", ".join(base) or "(none)", "rms": rms}]
    with Parallel(n_jobs=n_jobs) as pool:
        while len(current) < len(names):
            tau = _delay(fit, exact)
            regression = family.at(tau if exact else None)
            candidates = [n for n in names if n not in current]
            trials = pool(delayed(_score)(_start(spec, regression, current + [n], tau), train, 2 * step, RANKING)
                          for n in progress(candidates, f"stepwise: adding term {len(current) + 1}"))
            best = int(np.argmin([r for _, r in trials]))
            if trials[best][0] is None:
                break
            chosen, score = _score(trials[best][0].model, train, step)  # converge the chosen fit
            if chosen is None or not score < (1 - min_gain) * rms:
                break
            current.append(candidates[best])
            fit, rms = chosen, score
            rows.append({"step": len(rows), "action": "add", "term": candidates[best], "rms": rms})
        fit, rms = _backward(pool, fit, rms, current, base, train, step, (1 + tolerance) * sigma, tolerance, rows)
    final = output_error(fit.model, train, fit.initial, step=train.dt, max_iterations=20)
    rows.append({"step": len(rows), "action": "polish at the sample step", "term": "", "rms": final.rms_after})
    info = dict(final.model.info, selection="stepwise output error")
    chosen = IdentifiedModel(final.model.spec, final.model.coefficients, 0.0, info, final.model.tau)
    return Stepwise(chosen, pd.DataFrame(rows), sigma, time.perf_counter() - start)
