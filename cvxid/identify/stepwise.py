r"""Structure selection by simulation error: stepwise forward, then backward.

When a true term needs the velocity (:math:`\dot x^3`), every velocity estimate leaves an
in-band error that the equation-error regression turns into wrong terms, and the true
support appears nowhere on its λ path.  The simulation error compares positions only:

.. math::

    J(S) = \min_{\theta_S} \sqrt{\tfrac1n \textstyle\sum_k
        \big(x_\mathrm{measured}(t_k) - x_\mathrm{simulated}(t_k; \theta_S)\big)^2}

for a support :math:`S` of library terms.  The search starts from a local output-error
fit of the base terms at the equation-error delay.  Each candidate support starts from its own
equation-error fit (the convex least squares on the same regression, which lands close
enough for a local output-error fit) and is polished by :func:`cvxid.identify.output_error.output_error`
on a coarse simulation step.

* **Forward**: from the base terms, add the term that lowers :math:`J` most, while it falls
  by at least ``min_gain``.
* **Backward**: drop a term when :math:`J` without it (warm-started from the current fit)
  stays within ``tolerance`` of :math:`\max(J, \hat\sigma)`, with :math:`\hat\sigma` the noise
  level of the measured position (at the noise floor every remaining difference is noise).
* The selected model is polished by :func:`~cvxid.identify.output_error.polish`: the
  delay profiled over its whole range on the selected terms (the search's fits are local
  in the delay, and a search started where the base terms put the delay can stay far from
  it), then every parameter at the sample step, with the delay's interval.  (A profile of
  the base terms' delay before the search, as there was, found the true support less
  often and took a quarter longer on the held-out tuning systems: 42 against 44 of 50,
  362 against 269 s.)

Once the current fit is within :data:`SCREEN_BELOW` times the noise level, each forward
step first ranks every candidate by the score test at the current fit (one batch of
simulations, :mod:`cvxid.identify.score`) and fits the :data:`SCREEN` best; each
backward step tries the :data:`REMOVALS` terms with the smallest Wald statistics; the other
candidates are fitted only when none of those will do, so the search stops where a trial
of every candidate would.  The fits run one after another by default (``n_jobs``): with a
screened handful per step, worker processes cost more to start than they save (measured on
``duffing_delay.toml``).  Use it for libraries of tens of terms, not hundreds.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, replace
from typing import Sequence

import numpy as np
import pandas as pd
from joblib import Parallel, delayed

from cvxid.data.experiment import Experiment
from cvxid.errors import CvxidError, CvxidWarning
from cvxid.identified import IdentifiedModel
from cvxid.identify.output_error import PolishResult, linearisation, output_error, polish, with_tau
from cvxid.identify.score import score_gains
from cvxid.identify.problem import Problem
from cvxid.identify.profile import profile_delay
from cvxid.model.equation import ModelSpec
from cvxid.model.library import Library
from cvxid.parallel import one_blas_thread
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
    final: PolishResult  # the last fit: the delay profiled on the selected terms, its interval

    def __repr__(self) -> str:
        lines = [f"Stepwise selection by simulation error ({self.seconds:.1f} s, noise level {self.noise:.4g}):"]
        lines += ["  " + line for line in self.history.to_string(index=False).splitlines()]
        return "\n".join(lines)


SCREEN = 4
"""Candidates fitted at each forward step: the best by the score test at the current fit
(:func:`_screen`).  On 50 tuning systems (``cvxid bench --heldout --mode selection
--estimator stepwise_oe --seeds 0:10 --known-gain``) the term a search of every candidate
added was among the first 4 in 126 of its 141 steps, and a screen at every step (and
:data:`REMOVALS`) gave the same model on 49 of the 50 systems, in two thirds of the time."""
SCREEN_BELOW = 2.0
"""The screen is used only when the current simulation error is at most this many times
the noise level: far from the data the first-order ranking misleads (on the paper's system,
``SEEDS=8 python examples/structure_from_noisy_x.py``, screening from the start found the
true support on 4 of 8 records instead of 7, each first step taking another term)."""
REMOVALS = 2
"""Terms tried at each backward step: the least significant by their Wald statistic
(:func:`_least_significant`; on 30 tuning systems with the gain estimated, the removal a
trial of every term chose was the first of this order 27 times and the second 3 times)."""
SEED = 1e-30
"""A candidate's coefficient in the score test's simulations (zero, but simulated)."""
RANKING = 8
"""Output-error iterations when candidates are only ranked, on twice the step (the chosen
one is then converged on the step itself)."""


def _polished(fit, train: Experiment, step: float, rows: list[dict]) -> PolishResult:
    """The search's last fit polished (its delay profiled over the range, then every
    parameter at the sample step), the step recorded in ``rows``."""
    with warnings.catch_warnings():  # a start outside the bounds is the search's own, not the user's
        warnings.simplefilter("ignore", CvxidWarning)
        final = polish(fit.model, train, coarse_step=step, initial=fit.initial)
    action = "polish (delay profiled) at the sample step" if final.profile is not None else "polish at the sample step"
    rows.append({"step": len(rows), "action": action, "term": "", "rms": final.rms_after})
    return final


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


def _screen(spec: ModelSpec, fit, candidates: list[str], train: Experiment, step: float) -> list[str]:
    """``candidates`` ranked by the score test at the current fit (:mod:`cvxid.identify.score`):
    each one's first-order fall of the simulation error, from one batch of simulations."""
    model = fit.model
    wider = replace(spec.with_library(Library([t for t in spec.library if t.name in model.spec.library.names
                                               or t.name in candidates])),
                    input_delay=model.spec.input_delay)  # the fitted input delay, if any
    coefficients = {n: model.coefficients.get(n, SEED) for n in wider.column_names}
    with warnings.catch_warnings():  # as the trial fits: an early (Taylor) delay may have the wrong sign
        warnings.simplefilter("ignore", CvxidWarning)
        names, r, J = linearisation(IdentifiedModel(wider, coefficients, tau=model.tau), train, fit.initial, step)
    own = [names.index(wider.parameter_name(n)) for n in candidates]
    gains, steps = score_gains(r, np.delete(J, own, axis=1), J[:, own])
    gains = np.where((steps < 0) & np.isin(candidates, list(spec.nonnegative)), 0.0, gains)
    return [candidates[i] for i in np.argsort(-gains, kind="stable")]


def _least_significant(terms: list[str], fit) -> list[str]:
    r"""``terms`` ordered by the Wald statistic :math:`|\theta_j| / \mathrm{se}_j` of their
    coefficients in ``fit``, smallest first: the first-order rise of the simulation error
    when each is dropped and the others refitted, least first.  A term the fit left out
    (its coefficient exactly 0: the simulation drops it) or whose standard error is
    undetermined (it moves nothing) comes first."""
    spec = fit.model.spec
    wald = []
    for n in terms:
        name = spec.parameter_name(n)
        value, error = fit.parameters.get(name, 0.0), fit.standard_errors.get(name, np.nan)
        wald.append(abs(value) / error if error > 0 and value != 0 else 0.0)
    return [terms[i] for i in np.argsort(wald, kind="stable")]


def _without(model: IdentifiedModel, term: str) -> IdentifiedModel:
    """``model`` with ``term`` dropped and every other coefficient kept (a warm start; its
    lambda and notes too)."""
    spec = model.spec.with_library(Library([t for t in model.spec.library if t.name != term]))
    return IdentifiedModel(spec, {n: model.coefficients.get(n, 0.0) for n in spec.column_names}, model.lam,
                           model.info, model.tau)


def _trial(model: IdentifiedModel, experiment: Experiment, step: float, iterations: int = 30):
    """The output-error fit from ``model`` (None and inf when every simulation diverges)."""
    try:
        with warnings.catch_warnings():  # trial fits: their intermediate delays may be anything
            warnings.simplefilter("ignore", CvxidWarning)
            fit = output_error(model, experiment, step=step, max_iterations=iterations)
    except CvxidError:
        return None, np.inf
    return fit, fit.rms_after if np.isfinite(fit.rms_after) else np.inf


def _addition(pool, spec, family, fit, current, names, train, step, needed, exact, noise):
    """The forward step: (term, converged fit, its simulation error) of the candidate whose
    ranking fit lowers the simulation error most, if its converged fit is below ``needed``;
    else None.  The :data:`SCREEN` best by the score test are fitted first; only when the
    best of them is not enough are the others fitted too, and the best of all is tried (a
    poor current fit ranks badly, and the search must not stop earlier than a trial of
    every candidate would).  While the current fit is far from the data (above
    :data:`SCREEN_BELOW` times the ``noise`` level, or diverged), or when no more than
    :data:`SCREEN` candidates are left, every candidate is fitted at once."""
    tau = _delay(fit, exact)
    regression = family.at(tau if exact else None)
    rest = [n for n in names if n not in current]
    screened = fit.rms_after <= SCREEN_BELOW * noise and len(rest) > SCREEN
    batches = _screen(spec, fit, rest, train, 2 * step) if screened else rest
    trials: dict[str, tuple] = {}
    converged: set[str] = set()
    for batch in (batches[:SCREEN], batches[SCREEN:]) if screened else (batches,):
        trials.update(zip(batch, pool(delayed(_trial)(_start(spec, regression, current + [n], tau), train, 2 * step,
                                                      RANKING)
                                      for n in progress(batch, f"stepwise: adding term {len(current) + 1}"))))
        name = min(trials, key=lambda n: trials[n][1])
        if trials[name][0] is None or name in converged:  # every one diverged, or the best was tried and fell short
            continue
        converged.add(name)
        chosen, score = _trial(trials[name][0].model, train, step)  # converge the best
        if chosen is not None and score < needed:
            return name, chosen, score
    return None


def _backward(pool, fit, rms, current, base, train, step, floor, tolerance, rows):
    """Drop terms while the simulation error stays within ``tolerance`` of the larger of
    itself and the noise ``floor``; ``current`` and ``rows`` are updated in place.  The
    :data:`REMOVALS` least significant terms are tried first, the others only when
    neither may go."""
    while True:
        ordered = _least_significant([n for n in current if n not in base], fit)
        trials: dict[str, tuple] = {}
        for batch in (ordered[:REMOVALS], ordered[REMOVALS:]) if len(ordered) > REMOVALS else (ordered,):
            trials.update(zip(batch, pool(delayed(_trial)(_without(fit.model, n), train, step) for n in batch)))
            name = min(trials, key=lambda n: trials[n][1]) if trials else None
            if name is not None and trials[name][1] <= max((1 + tolerance) * rms, floor):
                break
        else:
            return fit, rms
        current.remove(name)
        fit, rms = trials[name]
        rows.append({"step": len(rows), "action": "remove", "term": name, "rms": rms})


@one_blas_thread
def stepwise_output_error(spec: ModelSpec, family: RegressionBuilder, train: Experiment, base: Sequence[str] | None = None,
                          min_gain: float = 0.01, tolerance: float = 0.005, step: float = 1e-3,
                          n_jobs: int = 1) -> Stepwise:
    """Select the library terms of ``spec`` by simulation error on ``train`` (see the
    module docstring).  ``family`` builds the equation-error regression of the whole
    library (at the current delay, for an exact delay); ``base`` are the terms always kept
    (default: the library's linear terms, e.g. ``x`` and ``x'``)."""
    start = time.perf_counter()
    names = spec.library.names
    if base is None:
        base = [n for n in spec.linear_terms if n in names]
    unknown = set(base) - set(names)
    if unknown:
        raise CvxidError(f"stepwise base term(s) {', '.join(sorted(unknown))} are not in the library")
    base = list(base)
    sigma = noise_level(train.output(spec.coordinate))
    step = max(step, train.dt)
    exact = spec.delay is not None and spec.delay.exact
    tau = None
    if exact:  # the delay of the base support; the output-error fits move it, the final profile checks it
        keep = [c.name in base or c.penalty == 0 for c in spec.columns]
        tau = profile_delay(family, support=keep, nonnegative=spec.nonnegative).estimate
    with warnings.catch_warnings():  # the base fit's first (Taylor) delay may have the wrong sign
        warnings.simplefilter("ignore", CvxidWarning)
        fit = output_error(_start(spec, family.at(tau), base, tau), train, step=step, max_iterations=25)
    current, rms = list(base), fit.rms_after
    rows = [{"step": 0, "action": "start", "term": ", ".join(base) or "(none)", "rms": rms}]
    with Parallel(n_jobs=n_jobs) as pool:
        while len(current) < len(names):
            added = _addition(pool, spec, family, fit, current, names, train, step, (1 - min_gain) * rms, exact,
                              sigma)
            if added is None:
                break
            name, fit, rms = added
            current.append(name)
            rows.append({"step": len(rows), "action": "add", "term": name, "rms": rms})
        fit, rms = _backward(pool, fit, rms, current, base, train, step, (1 + tolerance) * sigma, tolerance, rows)
    final = _polished(fit, train, step, rows)
    info = dict(final.model.info, selection="stepwise output error")
    chosen = IdentifiedModel(final.model.spec, final.model.coefficients, 0.0, info, final.model.tau)
    return Stepwise(chosen, pd.DataFrame(rows), sigma, time.perf_counter() - start, final)


@dataclass(frozen=True)
class Pruning:
    """The backward half of the search run on a model selected by equation error and
    polished: the terms it removed, each step's simulation error, and the pruned model
    polished again (``polish``; the given one when nothing was removed)."""

    history: pd.DataFrame  # step, action, term, rms
    noise: float
    seconds: float
    polish: PolishResult

    @property
    def removed(self) -> list[str]:
        return [row.term for row in self.history.itertuples() if row.action == "remove"]

    def __repr__(self) -> str:
        removed = ", ".join(self.removed) or "nothing"
        lines = [f"Pruning by simulation error ({self.seconds:.1f} s, noise level {self.noise:.4g}): removed {removed}"]
        lines += ["  " + line for line in self.history.to_string(index=False).splitlines()]
        return "\n".join(lines)


@one_blas_thread
def prune_by_simulation(polished: PolishResult, train: Experiment, removable: Sequence[str], step: float = 1e-3,
                        tolerance: float = 0.005) -> Pruning:
    r"""Drop the ``removable`` terms of a polished model that the simulation error does not
    need: the backward steps of :func:`stepwise_output_error` (a term goes while :math:`J`
    without it, the others refitted, stays within ``tolerance`` of :math:`\max(J, \hat\sigma)`,
    :math:`J` the error before that step), from the polished fit refitted on the search's
    step; the pruned model is polished again (its delay profiled) and keeps the whole
    library, the dropped terms at 0.  A selection by equation error keeps terms that a
    velocity estimated from noisy x makes look useful; their simulation error shows they are
    not."""
    start = time.perf_counter()
    model = polished.model
    current = [n for n in model.spec.library.names if model.coefficients.get(n, 0.0) != 0.0]
    sigma = noise_level(train.output(model.spec.coordinate))
    rows = []
    if any(n in current for n in removable):
        step = max(step, train.dt)
        spec = model.spec.with_library(Library([t for t in model.spec.library if t.name in current]))
        fit, rms = _trial(IdentifiedModel(spec, model.coefficients, model.lam, model.info, model.tau), train, step)
        rows.append({"step": 0, "action": "start" if fit is not None else "start: its simulation diverged, nothing "
                     "pruned", "term": ", ".join(current), "rms": rms})
        if fit is not None:
            kept = [n for n in current if n not in removable]
            with Parallel(n_jobs=1) as pool:
                fit, rms = _backward(pool, fit, rms, current, kept, train, step, (1 + tolerance) * sigma, tolerance,
                                     rows)
    if len(rows) > 1:
        pruned = _polished(fit, train, step, rows)
        final = pruned.model  # back on the whole library: the diagnosis's candidates are what it lacks
        whole = IdentifiedModel(model.spec, {n: final.coefficients.get(n, 0.0) for n in model.spec.column_names},
                                final.lam, final.info, final.tau)
        polished = replace(pruned, system=replace(pruned.system, models={model.spec.coordinate: whole}))
    return Pruning(pd.DataFrame(rows, columns=["step", "action", "term", "rms"]), sigma,
                   time.perf_counter() - start, polished)
