r"""A sweep over :math:`\lambda`: the :class:`Path`.

One :class:`~cvxid.identify.problem.Problem` is re-solved for each value of its ``lambda``
parameter (canonicalised once).  With ``debias`` each solution is refitted by least squares
on its support (the paper's "keep the selected and the delay terms, refit" step), so the
path explores *supports* and the coefficients carry no shrinkage.  Each solution is scored
on the training data and, when a validation function is given, on held-out data.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, replace
from typing import Callable

import numpy as np
import pandas as pd

from cvxid.errors import CvxidError, CvxidWarning
from cvxid.identify.problem import Fit, Problem
from cvxid.identify.stlsq import stlsq

ESTIMATORS = ("lasso", "adaptive_lasso", "stlsq", "lstsq")
"""Selectors along a path: the weighted lasso, the lasso with adaptive weights
(:meth:`~cvxid.identify.problem.Problem.adaptive`, from the least squares of the rows it is
given: each cross-validation fold weighs its own), thresholded least squares; ``lstsq``
selects nothing: every column at every lambda."""
SELECTING = ("lasso", "adaptive_lasso", "stlsq")
"""The estimators that select terms (``lstsq`` keeps every column)."""
SELECTION_RULES = ("min", "1se")
EXTEND_DECADES = 2.0
"""How far past its edge a grid is extended when the rule chose that edge (:func:`select`)."""
EXTENSIONS = 3
BLOCKS = 20
"""Contiguous blocks of validation residuals used for the standard error (residuals of
neighbouring samples are strongly correlated, so single samples would understate it)."""


def _sweep(problem: Problem, lambdas: np.ndarray, estimator: str, debias: bool) -> list[Fit]:
    if estimator == "lstsq":
        fit = problem.refit(np.ones(problem.k, dtype=bool))
        return [replace(fit, lam=float(lam)) for lam in lambdas]
    if estimator == "adaptive_lasso":
        problem = problem.adaptive()
    fits = []
    for lam in lambdas:
        if estimator == "stlsq":
            fit = stlsq(problem, lam)
        else:
            fit = problem.solve(lam)
            if debias:
                fit = problem.refit(fit.support, lam)
        fits.append(fit)
    return fits


def _cross_validated(problem: Problem, lambdas, folds: int, estimator: str, debias: bool) -> "Path":
    """Blocked k-fold over time: each fold leaves out one contiguous block of rows, so
    neighbouring (strongly correlated) samples never sit on both sides."""
    reg = problem.regression
    if reg is None:
        raise CvxidError("cross-validation needs the rows: build the problem with from_regression or from_arrays")
    if folds < 2:
        raise CvxidError(f"folds must be at least 2, got {folds}")
    blocks = np.array_split(np.arange(reg.shape[0]), folds)
    errors = np.zeros((folds, lambdas.size))
    for j, rows in enumerate(blocks):
        weights = np.ones(reg.shape[0])
        weights[rows] = 0.0
        sub = Problem.from_regression(reg, problem.nonnegative, problem.solver, row_weights=weights, ties=problem.ties)
        P, p = reg.P[rows], reg.p[rows]
        errors[j] = [np.mean((P @ f.coefficients - p) ** 2) for f in _sweep(sub, lambdas, estimator, debias)]
    fits = _sweep(problem, lambdas, estimator, debias)
    return Path(problem, fits, errors.mean(axis=0), errors.std(axis=0, ddof=1) / np.sqrt(folds))


def validation_score(residual: np.ndarray) -> tuple[float, float]:
    """Mean squared residual and its block standard error."""
    sq = np.asarray(residual, dtype=float) ** 2
    blocks = np.array([b.mean() for b in np.array_split(sq, BLOCKS)])
    return float(sq.mean()), float(blocks.std(ddof=1) / np.sqrt(BLOCKS))


@dataclass
class Path:
    """Solutions of one problem over a grid of :math:`\\lambda` (largest first)."""

    problem: Problem
    fits: list[Fit]
    validation: np.ndarray  # validation MSE per lambda (nan without validation)
    validation_se: np.ndarray  # its standard error, from contiguous blocks of residuals

    @classmethod
    def compute(
        cls,
        problem: Problem,
        lambdas,
        validate: Callable[[np.ndarray], np.ndarray] | None = None,
        estimator: str = "lasso",
        debias: bool = True,
        folds: int | None = None,
    ) -> "Path":
        """Sweep ``lambdas`` (validated by ``validate`` or by blocked ``folds``-fold CV)."""
        lambdas = np.sort(np.atleast_1d(np.asarray(lambdas, dtype=float)))[::-1]
        if lambdas.ndim != 1 or lambdas.size == 0 or not np.all(np.isfinite(lambdas)) or np.any(lambdas < 0):
            raise CvxidError("lambdas must be a non-empty list of finite numbers >= 0 (np.logspace(-6, 0, 30))")
        if validate is not None and not callable(validate):
            raise CvxidError(f"validate must be a function of the coefficients (a test Regression's .residual), got "
                             f"{type(validate).__name__}")
        if estimator not in ESTIMATORS:
            raise CvxidError(f"unknown estimator '{estimator}'; use one of {', '.join(ESTIMATORS)}")
        if folds is not None:
            if validate is not None:
                raise CvxidError("give either a validation function or folds, not both")
            return _cross_validated(problem, lambdas, int(folds), estimator, debias)
        fits = _sweep(problem, lambdas, estimator, debias)
        scores = [validation_score(validate(f.coefficients)) if validate else (np.nan, np.nan) for f in fits]
        return cls(problem, fits, np.array([s[0] for s in scores]), np.array([s[1] for s in scores]))

    @property
    def pareto(self) -> pd.DataFrame:
        """The Pareto front: for each number of terms, the least training error."""
        frame = self.table().reset_index()
        front = frame.loc[frame.groupby("terms")["train_mse"].idxmin()]
        return front.set_index("terms")[["lambda", "train_mse", "validation_error"]]

    def plot(self, selected: float | None = None):
        """Coefficient traces and validation error against log lambda (a matplotlib figure)."""
        from cvxid.plots import path_figure

        return path_figure(self, selected)

    @property
    def lambdas(self) -> np.ndarray:
        return np.array([f.lam for f in self.fits])

    @property
    def names(self) -> tuple[str, ...]:
        return self.problem.names

    @property
    def coefficients(self) -> pd.DataFrame:
        """Coefficients (physical units): one row per lambda, one column per term."""
        return pd.DataFrame(
            [f.coefficients for f in self.fits],
            index=pd.Index(self.lambdas, name="lambda"),
            columns=list(self.names),
        )

    @property
    def support_size(self) -> np.ndarray:
        return np.array([int(f.support.sum()) for f in self.fits])

    def table(self) -> pd.DataFrame:
        return pd.DataFrame(
            {
                "terms": self.support_size,
                "train_mse": [f.train_mse for f in self.fits],
                "validation_error": self.validation,
                "validation_se": self.validation_se,
            },
            index=pd.Index(self.lambdas, name="lambda"),
        )

    def best(self, rule: str = "min") -> Fit:
        """The selected solution.

        ``"min"``: least validation error (among equal errors, the largest lambda);
        ``"1se"``: the largest lambda whose validation error is within one standard error of
        the least (the sparsest model the data cannot tell apart from the best).
        """
        return self.fits[int(self._accepted(rule)[0])]

    def _accepted(self, rule: str) -> np.ndarray:
        """Indices (largest lambda first) whose validation error the rule accepts."""
        return np.flatnonzero(self.validation <= self.bound(rule))

    def bound(self, rule: str = "min") -> float:
        """The largest validation error ``rule`` accepts: the least (``"min"``), or the least
        plus its block standard error (``"1se"``)."""
        if rule not in SELECTION_RULES:
            raise CvxidError(f"unknown selection rule '{rule}'; use one of {', '.join(SELECTION_RULES)}")
        if np.all(np.isnan(self.validation)):
            raise CvxidError("this path has no validation error; give a validation experiment")
        i = int(np.nanargmin(self.validation))
        return float(self.validation[i] * (1 + 1e-9) + (self.validation_se[i] if rule == "1se" else 0.0))

    def open_edge(self, rule: str = "min") -> str | None:
        """Where the rule's choice may lie beyond the grid: ``"top"`` when it chooses the
        largest lambda and that fit keeps a candidate (penalised) term; ``"bottom"`` when the
        least validation error reaches the smallest lambda (whatever the rule: the 1se rule's
        reference is that least error) and that fit leaves out a candidate least squares
        keeps; else None (an interior choice, or an edge where the path ends).  A candidate
        tied to an unpenalised term is not one here: the tie keeps it wherever that term is
        (a seventh outside check: ``x^3`` tied to ``x`` kept the top open through three
        extensions, lambda 2.3e8, and a warning that the selection was not settled)."""
        candidates = (self.problem.penalties > 0) & ~self.problem.held_by_ties
        if not candidates.any() or len(self.fits) < 2:
            return None
        if self._accepted(rule)[0] == 0 and (self.fits[0].support & candidates).any():
            return "top"
        last = self.fits[-1]
        full = self.problem.refit(np.ones(self.problem.k, dtype=bool)).support  # least squares' own support
        if self._accepted("min")[-1] == len(self.fits) - 1 and last.lam > 0 \
                and (full & ~last.support & candidates).any():
            return "bottom"
        return None

    def __repr__(self) -> str:
        return f"Path over {len(self.fits)} lambdas\n{self.table().to_string(float_format=lambda v: f'{v:.4g}')}"


def select(problem: Problem, lambdas, validate: Callable[[np.ndarray], np.ndarray] | None = None,
           estimator: str = "lasso", debias: bool = True, folds: int | None = None,
           rule: str = "min") -> tuple[Path, Fit]:
    """The path and the fit its ``rule`` selects, the grid (duplicates dropped) extended by
    :data:`EXTEND_DECADES` (at most :data:`EXTENSIONS` times) while the rule accepts an
    *open* edge of it (:meth:`Path.open_edge`): the largest lambda with a candidate term
    still in, or the smallest with a candidate still out.  An edge that ends the path (no
    candidate left at the top, every one in at the bottom) is a real answer, not the grid's
    limit.  A warning says when the rule still chose an open edge after the last extension.
    ``stlsq``'s lambda is a threshold on coefficients, not a penalty: its grid is kept."""
    lambdas = np.unique(np.asarray(lambdas, dtype=float))[::-1]
    for extension in range(EXTENSIONS + 1):
        path = Path.compute(problem, lambdas, validate, estimator, debias, folds)
        side = None if estimator in ("lstsq", "stlsq") else path.open_edge(rule)
        if side is None:
            return path, path.best(rule)
        if extension < EXTENSIONS:
            lambdas = _extended(lambdas, side)
    best = path.best(rule)
    warnings.warn(
        f"the lambda rule chose the {side} of its grid (lambda = {best.lam:.3g}) after extending it "
        f"{EXTENSIONS} times by {EXTEND_DECADES:g} decades: the validation error still falls toward it, so the "
        f"selection is not settled; give [fit] lambdas a wider range, or check the candidate terms", CvxidWarning,
        stacklevel=2)
    return path, best


def _extended(lambdas: np.ndarray, side: str) -> np.ndarray:
    """``lambdas`` (largest first) with :data:`EXTEND_DECADES` more at ``side``, at the
    grid's own log spacing (a tenth of a decade for a single lambda)."""
    logs = np.log10(np.maximum(lambdas, 1e-300))
    step = max(float(np.median(-np.diff(logs))), 0.01) if lambdas.size > 1 else 0.1
    count = max(1, int(np.ceil(EXTEND_DECADES / step)))
    more = step * np.arange(1, count + 1)
    added = 10 ** (logs[0] + more) if side == "top" else 10 ** (logs[-1] - more)
    return np.sort(np.concatenate([lambdas, added]))[::-1]
