r"""Bootstrap ensembles of sparse fits (the paper's robust sparse regression).

Each of :math:`K` samples draws :math:`L` rows (``fraction`` of them) with replacement,
represented as row counts :math:`w` (the rows themselves are never copied into resampled
matrices).  Neighbouring
rows are not independent (a sliding window's row shares most of its data with the next;
the whole-record integrals all of it), so by default the rows are drawn in blocks
(``resample = "blocks"``, the circular block bootstrap of Politis and Romano): runs of
:math:`\ell` consecutive rows, :math:`\ell = n / n_\text{eff}` the rows per independent
residual of the least-squares fit on every column
(:func:`~cvxid.identify.profile.effective_rows`), each equation of a system the same
stretch of time, the last run cut so that a sample holds :math:`L` rows.  A sample that
leaves a column without a nonzero row, or holds no more distinct rows than columns, is
drawn again.  The spreads are those of estimates from ``fraction`` of the record: about
:math:`1/\sqrt{\text{fraction}}` wider than the whole record's.  The paper drew single rows (``resample = "rows"``): on sliding windows
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
from cvxid.identify.profile import GRID, effective_rows, least_between
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


FEW_SAMPLES = 10
"""Below this many samples a warning says the intervals are rough."""
FEW_BLOCKS = 3
"""Below this many independent stretches a sample the spreads are rough, and a warning
says so (at 1 every sample is the whole record: no spread at all)."""


def block_share(regression: Regression) -> float:
    r"""The share of the record one independent residual spans: the largest over the
    stacked equations of :math:`\lceil m_i / n_{\text{eff},i} \rceil / m_i`, for the residual of
    the least squares of every column."""
    coefficients = np.linalg.lstsq(regression.P, regression.p, rcond=None)[0]
    residual = regression.residual(coefficients)
    return max(float(np.ceil(part.size / effective_rows(part)) / part.size)
               for part in np.split(residual, np.cumsum(regression.parts)[:-1]) if part.size)


def block_counts(parts: Sequence[int], size: int, share: float, rng: np.random.Generator) -> np.ndarray:
    """Row counts of one circular block-bootstrap sample: blocks spanning ``share`` of the
    record (in each of the stacked ``parts`` the same stretch of time), drawn with
    replacement, the last cut so that the sample holds ``size`` rows in all (each part its
    share of them)."""
    share = min(max(share, 0.0), 1.0)
    wanted = size / sum(parts)  # (the sample's share of each part's rows)
    blocks = max(1, int(np.ceil(wanted / share - 1e-9))) if share > 0 else 1
    starts = rng.random(blocks)  # (where each block starts, as a share of its part's rows)
    counts = []
    for m in parts:
        run = max(1, int(np.ceil(share * m - 1e-9)))
        rows = ((np.floor(starts * m).astype(int)[:, None] + np.arange(run)) % m).ravel()
        counts.append(np.bincount(rows[:max(1, int(round(wanted * m)))], minlength=m))
    return np.concatenate(counts)


def _usable(regression: Regression) -> Callable[[np.ndarray], bool]:
    """Whether a sample's counts leave every column a nonzero row and more distinct rows
    than columns (else its reduction fails: a friction column zero at rest on every drawn
    row, a short record)."""
    nonzero = regression.P != 0

    def usable(counts: np.ndarray) -> bool:
        drawn = counts > 0
        return int(drawn.sum()) > regression.shape[1] and bool(nonzero[drawn].any(axis=0).all())

    return usable


@dataclass
class Bootstrap:
    """The ensemble: one row of coefficients (physical units) per sample."""

    coefficients: pd.DataFrame
    lambdas: np.ndarray
    physical: pd.DataFrame | None = None
    settings: BootstrapSettings = BootstrapSettings()
    size: int = 0
    """Rows drawn in each sample."""
    share: float = 0.0
    """The share of the record a block spans (0: single rows)."""
    kept: tuple[int, ...] = ()
    """Which of the seeded draws were used (the others left a column without a row)."""
    taus: np.ndarray | None = None
    """Each sample's delay, when it was profiled again on the sample (:func:`with_delays`)."""

    def draws(self, parts: Sequence[int]) -> list[np.ndarray]:
        """Each sample's row counts, drawn again (seeded) for the regression whose stacked
        ``parts`` were resampled."""
        if not self.size or not self.kept:
            raise CvxidError("this bootstrap records no draws (made by bootstrap(), not by hand)")
        candidates = _candidates(parts, self.size, self.share, self.settings)
        drawn = [next(candidates) for _ in range(max(self.kept) + 1)]
        return [drawn[i] for i in self.kept]

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
    parts = regression.parts or (n,)
    size = max(int(round(settings.fraction * n)), regression.shape[1] + 1)
    share = 0.0 if settings.resample == "rows" else block_share(regression)
    if share * n > 1 and size / n / share < FEW_BLOCKS:
        warnings.warn(f"the bootstrap's residual is correlated over {100 * share:.3g} % of the record: each sample "
                      + (f"holds about {size / n / share:.2g} independent stretches" if size / n >= share else
                         "holds less than one independent stretch") + ", so its spreads and "
                      "intervals are rough (a longer record, or fraction = 1)", CvxidWarning, stacklevel=2)
    if settings.samples < FEW_SAMPLES:
        warnings.warn(f"the bootstrap has {settings.samples} samples: its 95 % intervals are their extreme values "
                      f"and its spreads rough (samples = 30, the default, or more)", CvxidWarning, stacklevel=2)
    kept, draws = _usable_draws(parts, size, share, settings, _usable(regression))
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
    return Bootstrap(coefs, np.array([r[1] for r in results]), phys, settings, size, share, kept)


def _candidates(parts: Sequence[int], size: int, share: float, settings: BootstrapSettings):
    """The seeded draws' row counts, one after another: single rows (multinomial, ``share``
    0) or blocks spanning ``share`` of the record."""
    rng, n = np.random.default_rng(settings.seed), sum(parts)
    while True:
        yield rng.multinomial(size, np.full(n, 1.0 / n)) if share == 0 else block_counts(parts, size, share, rng)


def _usable_draws(parts, size, share, settings, usable) -> tuple[tuple[int, ...], list[np.ndarray]]:
    """``settings.samples`` usable draws (:func:`_usable`) and their places among the
    seeded ones; an error when ten times as many draws leave too few."""
    kept, draws = [], []
    for i, counts in zip(range(10 * int(settings.samples)), _candidates(parts, size, share, settings)):
        if usable(counts):
            kept.append(i)
            draws.append(counts)
            if len(draws) == settings.samples:
                return tuple(kept), draws
    raise CvxidError(f"the bootstrap drew {10 * int(settings.samples)} samples and {len(draws)} left every column a "
                     f"row and more rows than columns: a column is nonzero on too little of the record, or the "
                     "record is too short (a longer record, a larger fraction, or resample = \"rows\")")


def with_delays(ensemble: Bootstrap, regression_at: Callable[[float], Regression], bounds: tuple[float, float],
                nonnegative=(), ties=(), grid: int = GRID, show_progress: bool = True) -> Bootstrap:
    r"""``ensemble`` with each sample's exact delay profiled again on its own rows and
    support, and its coefficients refitted there: the delay's error then spreads into the
    coefficients it trades with (a damping, a stiffness), as it does in the estimate.  Each
    sample's least-squares error on its rows at ``grid`` delays across ``bounds`` (each
    delay's regression built once for every sample, then dropped), the least refined
    between its neighbours by scipy's bounded scalar minimiser, as the estimate's own
    profile is (a parabola through the grid's three points put the samples' delays up to a
    bootstrap standard deviation off where the profile is narrow against the grid); its
    coefficients (signs and ties kept) on the regression at that delay.  On held-out oscillators with the
    true terms listed, the 95 % intervals held 84.5 % (noise 0.01) and 86.3 % (0.001) of true
    parameters, 55 / 51 % with the delay held (``examples/bootstrap_intervals.py``)."""
    taus = np.linspace(*bounds, grid)
    samples = list(ensemble.coefficients.iterrows())
    first = regression_at(float(taus[0]))
    names, parts = first.names, first.parts or (first.shape[0],)
    draws = ensemble.draws(parts)
    masks = [(sample.to_numpy() != 0) | (first.penalties == 0) for _, sample in samples]

    def fitted(regression, counts, mask, tau):
        with warnings.catch_warnings():
            if tau == 0.0:  # (at tau = 0 an unknown gain's column is x itself: not news here)
                warnings.filterwarnings("ignore", message="the regression is rank-deficient", category=CvxidWarning)
            reduced = regression.reduce(counts)
        return reduced, constrained_least_squares(reduced, names, mask, nonnegative, ties)

    def errors_at(tau):  # every sample's least-squares error at one delay, its regression built once
        regression = regression_at(tau)
        return [_mse(fitted(regression, c, m, tau)) for c, m in zip(draws, masks)]

    profile = np.array([errors_at(float(t)) for t in progress(taus, desc="bootstrap: each sample's delay",
                                                              disable=not show_progress)]).T
    rows, delays = [], []
    for counts, mask, errors in zip(draws, masks, profile):
        tau = least_between(lambda t: _mse(fitted(regression_at(float(t)), counts, mask, float(t))), taus, errors,
                            bounds[1])  # (refined as the estimate's own profile is)
        reduced, scaled = fitted(regression_at(tau), counts, mask, tau)
        rows.append(np.where(mask, reduced.to_physical(scaled), 0.0))
        delays.append(tau)
    coefficients = pd.DataFrame(rows, columns=list(names), index=ensemble.coefficients.index)
    return replace(ensemble, coefficients=coefficients, taus=np.array(delays))


def _mse(fit) -> float:
    reduced, scaled = fit
    return reduced.mse(scaled)
