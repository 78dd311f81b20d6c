r"""Bootstrap ensembles of sparse fits (the paper's robust sparse regression).

Each of :math:`K` samples draws :math:`L` rows with replacement, represented as multinomial
row counts :math:`w` (the rows themselves are never copied into resampled matrices):
:math:`\|W^{1/2}(Pc - p)\|^2` is reduced to its triangular factor, the :math:`\lambda` path
is swept and the selection rule applied.  Delay (and inertia) columns carry no penalty, so
the paper's rule "a dropped delay term is restored and refitted" holds by construction.
The ensemble mean is the paper's estimate (its eq. 18); the spread, percentile interval and
inclusion probability of each term come with it.  Samples run in parallel through joblib
(any joblib backend, e.g. dask or ray, via ``joblib.parallel_config``); a sample's warnings
come back with it and are said once each, with the number of samples that gave them.
"""

from __future__ import annotations

import os
import warnings
from collections import Counter
from dataclasses import dataclass
from typing import Callable

import numpy as np
import pandas as pd
from joblib import Parallel, delayed

from cvxid.errors import CvxidError
from cvxid.identify.path import select
from cvxid.identify.problem import Problem
from cvxid.progress import progress
from cvxid.regression.regression import Regression


@dataclass(frozen=True)
class BootstrapSettings:
    samples: int = 30
    fraction: float = 0.5
    seed: int = 0
    n_jobs: int = 1

    def __post_init__(self):
        if int(self.samples) < 2:
            raise CvxidError(f"bootstrap samples must be at least 2, got {self.samples}")
        if not 0 < self.fraction <= 1:
            raise CvxidError(f"bootstrap fraction must be in (0, 1], got {self.fraction}")


@dataclass
class Bootstrap:
    """The ensemble: one row of coefficients (physical units) per sample."""

    coefficients: pd.DataFrame
    lambdas: np.ndarray
    physical: pd.DataFrame | None = None

    @property
    def mean(self) -> pd.Series:
        """The ensemble mean: the paper's estimate."""
        return self.coefficients.mean()

    @property
    def inclusion(self) -> pd.Series:
        """Share of samples in which each term is selected."""
        return (self.coefficients != 0).mean()

    @classmethod
    def of(cls, problem: Problem, samples: int = 30, fraction: float = 0.5, seed: int = 0, n_jobs: int = 1,
           lambdas=None, validate: Callable[[np.ndarray], np.ndarray] | None = None, **kw) -> "Bootstrap":
        """The bootstrap ensemble of ``problem``'s regression (its signs and solver kept),
        ``lambdas`` by default 50 from 1e-6 to 1e2; see :func:`bootstrap`."""
        if problem.regression is None:
            raise CvxidError("bootstrap needs the rows: build the problem with from_regression or from_arrays")
        lambdas = np.logspace(-6, 2, 50) if lambdas is None else lambdas
        return bootstrap(problem.regression, lambdas, validate, BootstrapSettings(samples, fraction, seed, n_jobs),
                         problem.nonnegative, problem.solver, **kw)

    def summary(self) -> pd.DataFrame:
        """Mean, standard deviation, 95 % percentile interval and inclusion probability."""
        c = self.coefficients
        return pd.DataFrame(
            {
                "mean": c.mean(),
                "std": c.std(ddof=1),
                "q2.5": c.quantile(0.025),
                "q97.5": c.quantile(0.975),
                "inclusion": self.inclusion,
            }
        )

    def physical_summary(self) -> pd.DataFrame:
        if self.physical is None:
            raise CvxidError("this bootstrap has no physical parameters (no model spec was given)")
        p = self.physical
        return pd.DataFrame({"mean": p.mean(), "std": p.std(ddof=1), "q2.5": p.quantile(0.025), "q97.5": p.quantile(0.975)})

    def __repr__(self) -> str:
        return f"Bootstrap of {len(self.coefficients)} samples\n" + self.summary().to_string(
            float_format=lambda v: f"{v:.5g}"
        )


def _one_sample(regression, counts, nonnegative, solver, lambdas, validate, estimator, debias, selection, ties,
                caller):
    """One resampled path's selection; in a worker process (not the ``caller``'s) its
    warnings recorded and returned (there they would reach the worker's stderr, raw; in the
    caller's own process, a thread of it included, they are issued as they come:
    recording them is not thread-safe)."""
    if os.getpid() == caller:
        return _selected(regression, counts, nonnegative, solver, lambdas, validate, estimator, debias, selection,
                         ties) + ([],)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        coefs, lam = _selected(regression, counts, nonnegative, solver, lambdas, validate, estimator, debias,
                               selection, ties)
    return coefs, lam, list(dict.fromkeys((w.category, str(w.message)) for w in caught))


def _selected(regression, counts, nonnegative, solver, lambdas, validate, estimator, debias, selection, ties):
    problem = Problem.from_regression(regression, nonnegative, solver, row_weights=counts, ties=ties)
    if validate is None:  # out-of-bag rows validate (neighbouring rows are correlated: optimistic)
        oob = counts == 0
        P, p = regression.P[oob], regression.p[oob]
        validate = lambda c: P @ c - p  # noqa: E731
    _, fit = select(problem, lambdas, validate, estimator, debias, rule=selection)
    return np.where(fit.support | (problem.penalties == 0), fit.coefficients, 0.0), fit.lam


def bootstrap(
    regression: Regression,
    lambdas,
    validate: Callable[[np.ndarray], np.ndarray] | None,
    settings: BootstrapSettings = BootstrapSettings(),
    nonnegative=(),
    solver: str = "CLARABEL",
    estimator: str = "lasso",
    debias: bool = True,
    selection: str = "min",
    physical: Callable[[dict], dict] | None = None,
    show_progress: bool = True,
    ties=(),
) -> Bootstrap:
    """Run ``settings.samples`` resampled paths; see the module docstring.

    ``validate`` maps coefficients to validation residuals (e.g. a test regression's
    ``residual``); without it each sample is validated on its out-of-bag rows.
    """
    n = regression.shape[0]
    rng = np.random.default_rng(settings.seed)
    size = max(int(round(settings.fraction * n)), regression.shape[1] + 1)
    draws = [rng.multinomial(size, np.full(n, 1.0 / n)) for _ in range(int(settings.samples))]
    task = delayed(_one_sample)
    args = (tuple(nonnegative), solver, lambdas, validate, estimator, debias, selection, tuple(ties), os.getpid())
    # joblib's default (loky) backend limits each worker's BLAS threads to its share of
    # the cores; a user's joblib.parallel_config (dask, ray, …) applies here as well
    results = Parallel(n_jobs=settings.n_jobs)(
        task(regression, counts, *args)
        for counts in progress(draws, desc="bootstrap", disable=not show_progress)
    )
    for (category, message), count in Counter(w for r in results for w in r[2]).items():
        warnings.warn(f"{count} of {len(results)} bootstrap samples: {message}",
                      category, stacklevel=2)
    coefs = pd.DataFrame([r[0] for r in results], columns=list(regression.names))
    coefs.index.name = "sample"
    phys = None
    if physical is not None:
        phys = pd.DataFrame([physical(dict(zip(regression.names, r[0]))) for r in results])
    return Bootstrap(coefs, np.array([r[1] for r in results]), phys)
