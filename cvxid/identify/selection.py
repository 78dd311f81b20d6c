r"""Choosing the terms: a selector, its :math:`\lambda` rule and stability selection.

A :class:`Selection` runs the path (:func:`~cvxid.identify.path.select`) on the whole
training record, then, with :class:`StabilitySettings`, again on :math:`K` halves of it.
The regression's rows are windows that overlap, so neighbouring rows share their noise:
the record's rows are cut into :math:`B` contiguous blocks and each sample keeps
:math:`B/2` of them, drawn without replacement; each half is validated as the whole record
is, by the test record (without one there is nothing to check the stable support by, and
the whole record's selection is kept).  A term's inclusion probability is the
share of samples whose selection kept it,

.. math::

    \hat\pi_j = \frac{1}{K}\sum_{k=1}^{K} \mathbf 1\{c^{(k)}_j \ne 0\},

and the stable support is :math:`\{j : \hat\pi_j \ge \pi_{\text{thr}}\}` plus every
unpenalised column (Meinshausen and Bühlmann's stability selection, here with the run's
own selector and :math:`\lambda` rule on each half rather than a fixed :math:`\lambda`).
A term that only fits one stretch's noise (a velocity term standing in for the velocity
estimate's error) enters on some halves and not on others; a true term enters on nearly
all.  The coefficients are the least squares of the stable support on every row (whatever
``debias``).  With a
test record the stable support is taken only when its validation error is one the
:math:`\lambda` rule accepts on the whole record's path (within the least error, plus its
standard error for ``1se``): a half has less power to tell a damping from the delay
(:math:`b\,x(t-\tau) \approx b\,x - b\tau\,x'`), and a support that dropped a term the test
record needs is not "as good as the best".

Measured on the held-out benchmark's selection mode (tuning seeds 0–9, 18 candidate terms,
the adaptive lasso with the 1se rule): exactly the true terms in 56 → 76 % of the systems
at noise 0.01 and 64 → 88 % at 0.001 with :math:`K = 20`, :math:`B = 10`,
:math:`\pi_{\text{thr}} = 0.7` (0.6–0.8 within 4 points of each other).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from typing import Callable, Iterator, Sequence

import numpy as np
import pandas as pd

from cvxid.errors import CvxidError, CvxidWarning
from cvxid.identify.path import Path, select
from cvxid.identify.problem import Fit, Problem


@dataclass(frozen=True)
class StabilitySettings:
    """``samples`` halves of the record, cut into ``blocks`` contiguous blocks; a term is
    kept when at least ``threshold`` of the samples kept it; ``seed`` of the draws."""

    samples: int = 20
    blocks: int = 10
    threshold: float = 0.7
    seed: int = 0

    def __post_init__(self):
        if isinstance(self.samples, bool) or not isinstance(self.samples, int) or not 2 <= self.samples <= 1000:
            raise CvxidError(f"[fit] stability samples must be a whole number from 2 to 1000, got {self.samples!r}")
        if isinstance(self.blocks, bool) or not isinstance(self.blocks, int) or not 4 <= self.blocks <= 100 \
                or self.blocks % 2:
            raise CvxidError(f"[fit] stability blocks must be an even whole number from 4 to 100 (each half keeps "
                             f"half of them), got {self.blocks!r}")
        if isinstance(self.threshold, bool) or not isinstance(self.threshold, (int, float)) \
                or not 0.5 <= self.threshold <= 1.0:
            raise CvxidError(f"[fit] stability threshold must lie in 0.5 … 1 (a share of the samples), "
                             f"got {self.threshold!r}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            raise CvxidError(f"[fit] stability seed must be a whole number >= 0, got {self.seed!r}")

    def as_dict(self) -> dict:
        return {"samples": self.samples, "blocks": self.blocks, "threshold": self.threshold, "seed": self.seed}

    def halves(self, n: int, parts: Sequence[int] | None = None) -> Iterator[np.ndarray]:
        """``samples`` row masks of ``n`` rows, each keeping ``blocks / 2`` of the
        ``blocks`` contiguous blocks, drawn without replacement (seeded).  Rows stacked from
        several equations (``parts``: the row count of each, in order) keep the same blocks
        of each, so a half is the same stretch of time for every equation."""
        parts = [n] if parts is None else list(parts)
        if sum(parts) != n:  # (a caller's mistake, not a user's)
            raise ValueError(f"the parts' rows ({'+'.join(map(str, parts))}) must add up to the {n} rows")
        if min(parts) < 2 * self.blocks:
            raise CvxidError(f"[fit] stability: {min(parts)} regression rows cannot be cut into {self.blocks} blocks "
                             "of two rows or more; lower blocks or give a longer record")
        starts = np.cumsum([0] + parts[:-1])
        edges = [start + np.linspace(0, m, self.blocks + 1).astype(int) for start, m in zip(starts, parts)]
        rng = np.random.default_rng(self.seed)
        for _ in range(self.samples):
            rows = np.zeros(n, bool)
            for block in rng.choice(self.blocks, self.blocks // 2, replace=False):
                for edge in edges:
                    rows[edge[block]:edge[block + 1]] = True
            yield rows


@dataclass
class Stability:
    """Each candidate's inclusion probability over the halves, and the settings."""

    inclusion: pd.Series
    settings: StabilitySettings
    accepted: bool = True
    """False when the stable support's validation error lay beyond the lambda rule's bound
    (the whole record's selection was kept)."""
    candidates: tuple[str, ...] = ()
    """The penalised columns (the printout lists these; the others are always kept)."""

    @property
    def support(self) -> np.ndarray:
        """The candidates kept on at least ``threshold`` of the halves (a boolean mask)."""
        return self.inclusion.to_numpy() >= self.settings.threshold - 1e-12

    def as_dict(self) -> dict:
        return {**self.settings.as_dict(), "accepted": self.accepted,
                "inclusion": {k: float(v) for k, v in self.inclusion.items()}}

    def __repr__(self) -> str:
        s = self.settings
        listed = self.inclusion.index.isin(self.candidates) if self.candidates else np.ones(len(self.inclusion), bool)
        shown = self.inclusion[listed]
        kept = ", ".join(shown.index[self.support[listed]]) or "none"
        verdict = "" if self.accepted else " (not taken: its validation error is beyond the lambda rule's bound)"
        return (f"Stability selection ({s.samples} halves of {s.blocks} blocks, candidates kept at >= "
                f"{s.threshold:g}): {kept}{verdict}\n"
                + shown.sort_values(ascending=False).to_string(float_format=lambda v: f"{v:.2f}"))


@dataclass
class Choice:
    """What a :class:`Selection` chose: the whole record's path and fit, the columns kept
    (unpenalised ones included), the fit reported (the path's, or the least squares of the
    stable support when stability selection's was taken) and, with stability selection, the
    inclusion probabilities."""

    path: Path
    fit: Fit
    keep: np.ndarray
    reported: Fit
    stability: Stability | None = None

    def __repr__(self) -> str:
        kept = [n for n, k in zip(self.path.names, self.keep) if k]
        text = (f"Choice: lambda = {self.fit.lam:.3g} on a path of {len(self.path.lambdas)}, keeps {len(kept)} of "
                f"{len(self.path.names)} columns: {', '.join(kept)} (.path, .fit, .reported, .stability)")
        return text + ("" if self.stability is None else "\n" + repr(self.stability))


@dataclass(frozen=True)
class Selection:
    """A selector, its lambda rule and (optionally) stability selection: the run's choice
    of terms, and the diagnosis's when it selects the library anew beside an effect."""

    estimator: str = "adaptive_lasso"
    lambdas: np.ndarray = field(default_factory=lambda: np.logspace(-6, 2, 50))
    rule: str = "1se"
    stability: StabilitySettings | None = None

    def choose(self, problem: Problem, validate: Callable[[np.ndarray], np.ndarray] | None = None,
               folds: int | None = None, debias: bool = True) -> Choice:
        """Select on ``problem`` (validated by ``validate``, or by ``folds``-fold
        cross-validation over time), then, with :attr:`stability`, on halves of its rows
        (a problem built by :meth:`~cvxid.identify.problem.Problem.from_regression`)."""
        path, fit = select(problem, self.lambdas, validate, self.estimator, debias, folds, self.rule)
        free = problem.penalties == 0
        if self.stability is None or free.all() or validate is None:  # (no test record: nothing to check it by)
            return Choice(path, fit, fit.support | free, fit)
        stability = self._stability(problem, validate, debias)
        keep = stability.support | free
        # the stable support, refitted by least squares, must be one the lambda rule accepts
        stable = problem.refit(keep)
        stability.accepted = float(np.mean(validate(stable.coefficients) ** 2)) <= path.bound(self.rule)
        if stability.accepted:
            return Choice(path, fit, keep, stable, stability)
        return Choice(path, fit, fit.support | free, fit, stability)

    def _stability(self, problem: Problem, validate, debias: bool) -> Stability:
        settings, regression = self.stability, problem.regression
        if regression is None:
            raise CvxidError("stability selection needs the rows: build the problem with Problem.from_regression")
        n = regression.shape[0]
        kept, halves = np.zeros(problem.k), 0
        for rows in settings.halves(n, regression.parts or None):  # (stacked equations: the same stretches)
            with warnings.catch_warnings():  # a half's warnings (its grid's edge) are the whole record's, said once
                warnings.simplefilter("ignore", CvxidWarning)
                try:  # (the half as 0/1 row weights, as the bootstrap's samples are)
                    half = Problem.from_regression(regression, problem.nonnegative, problem.solver,
                                                   row_weights=rows.astype(float), ties=problem.ties)
                except CvxidError:  # a column zero on this half (a record whose forcing starts late): skip it
                    continue
                _, fit = select(half, self.lambdas, validate, self.estimator, debias, None, self.rule)
            kept += fit.support
            halves += 1
        if halves == 0:
            raise CvxidError("[fit] stability: no half of the record can be fitted on its own (a column is zero on "
                             "each); set stability = false")
        return Stability(pd.Series(kept / halves, index=list(problem.names)), settings,
                         candidates=tuple(n for n, w in zip(problem.names, problem.penalties) if w > 0))
