r"""Bootstrap ensembles of sparse fits (the paper's robust sparse regression).

Each of :math:`K` samples draws :math:`L` rows with replacement, represented as row counts
:math:`w` (the rows themselves are never copied into resampled matrices).  Neighbouring
rows are not independent (a sliding window's row shares most of its data with the next;
the whole-record integrals all of it), so by default the rows are drawn in blocks
(``resample = "blocks"``, the circular block bootstrap of Politis and Romano): runs of
:math:`\ell` consecutive rows, :math:`\ell = n / n_\text{eff}` the rows per independent
residual of the least-squares fit on every column
(:func:`~cvxid.identify.profile.effective_rows`), each equation of a system the same
stretch of time.  The paper drew single rows (``resample = "rows"``): on sliding windows
that made the spreads about ten times too small (an outside check's linear oscillator, 10 s
at 1 kHz: every 95 % interval 6–10 standard deviations from the truth).  Each sample:
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
from dataclasses import dataclass, replace
from typing import Callable, Sequence

import numpy as np
import pandas as pd
from joblib import Parallel, delayed

from cvxid.errors import CvxidError, CvxidWarning
from cvxid.identify.path import select
from cvxid.identify.problem import Problem, constrained_least_squares
from cvxid.identify.profile import GRID, effective_rows
from cvxid.progress import progress
from cvxid.regression.regression import Regression


RESAMPLE = ("blocks", "rows")


@dataclass(frozen=True)
class BootstrapSettings:
    samples: int = 30
    fraction: float = 0.5
    seed: int = 0
    n_jobs: int = 1
    resample: str = "blocks"
    """``"blocks"``: runs of correlated rows drawn together (the default); ``"rows"``:
    single rows, as the paper did (spreads too small where rows are correlated)."""

    def __post_init__(self):
        if int(self.samples) < 2:
            raise CvxidError(f"bootstrap samples must be at least 2, got {self.samples}")
        if not 0 < self.fraction <= 1:
            raise CvxidError(f"bootstrap fraction must be in (0, 1], got {self.fraction}")
        if self.resample not in RESAMPLE:
            raise CvxidError(f"bootstrap resample must be one of {', '.join(map(repr, RESAMPLE))}, "
                             f"got {self.resample!r}")


def block_length(regression: Regression) -> int:
    """Rows per independent residual, :math:`\lceil n / n_\text{eff} \rceil`, of the least
    squares of every column, the largest over the stacked equations."""
    coefficients = np.linalg.lstsq(regression.P, regression.p, rcond=None)[0]
    residual = regression.residual(coefficients)
    lengths = [int(np.ceil(part.size / effective_rows(part)))
               for part in np.split(residual, np.cumsum(regression.parts)[:-1]) if part.size]
    return max(lengths)


def block_counts(parts: Sequence[int], size: int, length: int, rng: np.random.Generator) -> np.ndarray:
    """Row counts of one circular block-bootstrap sample: blocks of ``length`` rows (in
    each of the stacked ``parts``, the same stretch of time: the same share of its rows)
    drawn with replacement until about ``size`` rows of the first part are drawn."""
    first = parts[0]
    length = min(max(int(length), 1), first)
    blocks = max(1, int(round(size * first / sum(parts) / length)))
    starts = rng.random(blocks)  # (where each block starts, as a share of its part's rows)
    counts = []
    for m in parts:
        run = max(1, int(round(length * m / first)))
        rows = (np.floor(starts * m).astype(int)[:, None] + np.arange(run)) % m
        counts.append(np.bincount(rows.ravel(), minlength=m))
    return np.concatenate(counts)


@dataclass
class Bootstrap:
    """The ensemble: one row of coefficients (physical units) per sample."""

    coefficients: pd.DataFrame
    lambdas: np.ndarray
    physical: pd.DataFrame | None = None
    settings: BootstrapSettings = BootstrapSettings()
    size: int = 0
    """Rows drawn in each sample."""
    block: int = 1
    """Rows per block (1: single rows)."""
    taus: np.ndarray | None = None
    """Each sample's delay, when it was profiled again on the sample (:func:`with_delays`)."""

    def draws(self, parts: Sequence[int]) -> list[np.ndarray]:
        """Each sample's row counts, drawn again (seeded) for the regression whose stacked
        ``parts`` were resampled."""
        return _draws(parts, self.size, self.block, self.settings)

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
           lambdas=None, validate: Callable[[np.ndarray], np.ndarray] | None = None, resample: str = "blocks",
           **kw) -> "Bootstrap":
        """The bootstrap ensemble of ``problem``'s regression (its signs and solver kept),
        ``lambdas`` by default 50 from 1e-6 to 1e2; see :func:`bootstrap`."""
        if problem.regression is None:
            raise CvxidError("bootstrap needs the rows: build the problem with from_regression or from_arrays")
        lambdas = np.logspace(-6, 2, 50) if lambdas is None else lambdas
        settings = BootstrapSettings(samples, fraction, seed, n_jobs, resample)
        return bootstrap(problem.regression, lambdas, validate, settings, problem.nonnegative, problem.solver, **kw)

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
    size = max(int(round(settings.fraction * n)), regression.shape[1] + 1)
    length = 1 if settings.resample == "rows" else block_length(regression)
    draws = _draws(regression.parts or (n,), size, length, settings)
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
    return Bootstrap(coefs, np.array([r[1] for r in results]), phys, settings, size, length)


def _draws(parts: Sequence[int], size: int, length: int, settings: BootstrapSettings) -> list[np.ndarray]:
    """The samples' row counts: single rows (multinomial) or blocks of ``length`` rows."""
    rng, n = np.random.default_rng(settings.seed), sum(parts)
    if settings.resample == "rows":
        return [rng.multinomial(size, np.full(n, 1.0 / n)) for _ in range(int(settings.samples))]
    return [block_counts(parts, size, length, rng) for _ in range(int(settings.samples))]


def with_delays(ensemble: Bootstrap, regression_at: Callable[[float], Regression], bounds: tuple[float, float],
                nonnegative=(), ties=(), grid: int = GRID, show_progress: bool = True) -> Bootstrap:
    r"""``ensemble`` with each sample's exact delay profiled again on its own rows and
    support, and its coefficients refitted there: the delay's error then spreads into the
    coefficients it trades with (a damping, a stiffness), as it does in the estimate.  Each
    sample's least-squares error on its rows at ``grid`` delays across ``bounds`` (the
    regressions at those delays built once, ``regression_at``), the least refined by a
    parabola through it and its neighbours; its coefficients (signs and ties kept) on the
    regression at that delay.  On held-out oscillators with the true terms listed the
    coefficients' 95 % intervals covered their truth on about half the parameters with the
    delay held at the estimate (``examples/bootstrap_intervals.py``)."""
    taus = np.linspace(*bounds, grid)
    with warnings.catch_warnings():  # (at tau = 0 an unknown gain's column equals x: not news here)
        warnings.filterwarnings("ignore", message="the regression is rank-deficient", category=CvxidWarning)
        at_grid = [regression_at(t) for t in taus]
        names = at_grid[0].names
        draws = ensemble.draws(at_grid[0].parts or (at_grid[0].shape[0],))
        rows, delays = [], []
        for counts, (_, sample) in progress(list(zip(draws, ensemble.coefficients.iterrows())),
                                            desc="bootstrap: each sample's delay", disable=not show_progress):
            mask = (sample.to_numpy() != 0) | (at_grid[0].penalties == 0)

            def fitted(regression):
                reduced = regression.reduce(counts)
                scaled = constrained_least_squares(reduced, names, mask, nonnegative, ties)
                return reduced, scaled

            errors = np.array([reduced.mse(scaled) for reduced, scaled in map(fitted, at_grid)])
            tau = _vertex(taus, errors)
            reduced, scaled = fitted(regression_at(tau))
            rows.append(np.where(mask, reduced.to_physical(scaled), 0.0))
            delays.append(tau)
    coefficients = pd.DataFrame(rows, columns=list(names), index=ensemble.coefficients.index)
    return replace(ensemble, coefficients=coefficients, taus=np.array(delays))


def _vertex(taus: np.ndarray, errors: np.ndarray) -> float:
    """The least of ``errors`` over the grid ``taus``, refined to the vertex of the parabola
    through it and its two neighbours (within them; the grid point at an end)."""
    i = int(np.argmin(errors))
    if i == 0 or i == taus.size - 1:
        return float(taus[i])
    a, b, c = errors[i - 1:i + 2]
    curvature = a - 2 * b + c
    shift = 0.5 * (a - c) / curvature if curvature > 0 else 0.0
    return float(taus[i] + np.clip(shift, -1, 1) * (taus[1] - taus[0]))
