r"""The linear regression :math:`P c \approx p` that the algebraic operation produces.

Rows are samples of the transformed signals, one column per model column.  Before any solver
sees it, the regression is *reduced*: columns and target are scaled to unit root-mean-square
and a QR factorisation of :math:`[\tilde P\;\tilde p]` gives

.. math::

    \|\tilde P \tilde c - \tilde p\|^2 = \|R \tilde c - r\|^2 + \rho^2,

with :math:`R` a small upper-triangular :math:`k \times k` factor.  Every solve works on
:math:`(R, r)`, so its cost does not grow with the record length.  Row weights (the
bootstrap's row counts) enter as :math:`\sqrt{w_i}` row factors.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
import pandas as pd

from cvxid.errors import CvxidError, CvxidWarning

RANK_TOL = 1e-10
"""A scaled column whose QR pivot is below this share of the largest is dependent."""


@dataclass(frozen=True)
class Reduced:
    """A regression reduced to its triangular factor, in scaled units."""

    R: np.ndarray
    r: np.ndarray
    rho2: float
    rows: float
    column_scale: np.ndarray
    target_scale: float

    def to_physical(self, scaled: np.ndarray) -> np.ndarray:
        return np.asarray(scaled) * self.target_scale / self.column_scale

    def mse(self, scaled: np.ndarray) -> float:
        """Mean squared equation error of scaled coefficients, in physical units."""
        resid = self.R @ np.asarray(scaled, dtype=float) - self.r
        return float((resid @ resid + self.rho2) / self.rows * self.target_scale**2)



@dataclass(frozen=True)
class Regression:
    """Columns ``P`` (n × k), target ``p``, column names, groups and L1 weights; for
    several equations stacked (:meth:`block`) ``parts``, the row count of each in order
    (rows are never sliced, only weighted, so it holds for every subset of columns)."""

    P: np.ndarray
    p: np.ndarray
    names: tuple[str, ...]
    groups: tuple[str, ...]
    penalties: np.ndarray
    experiments: tuple[str, ...] = ()
    parts: tuple[int, ...] = ()

    @classmethod
    def block(cls, regressions: dict[str, "Regression"]) -> "Regression":
        """Several equations as one regression: block-diagonal columns named
        ``"equation:column"``, rows stacked.  Each block is divided by its target's RMS so
        every equation weighs the same in the joint objective (coefficients are unchanged).
        With ties (``Problem(..., ties=…)``) coefficients shared across equations are
        estimated once from all of them."""
        if not regressions:
            raise CvxidError("block needs at least one regression")
        rows = sum(r.shape[0] for r in regressions.values())
        cols = sum(r.shape[1] for r in regressions.values())
        P, p = np.zeros((rows, cols)), np.zeros(rows)
        names, groups, penalties = [], [], []
        i = j = 0
        for label, reg in regressions.items():
            n, k = reg.shape
            scale = float(np.sqrt(np.mean(reg.p**2))) or 1.0
            P[i:i + n, j:j + k] = reg.P / scale
            p[i:i + n] = reg.p / scale
            names += [f"{label}:{c}" for c in reg.names]
            groups += list(reg.groups)
            penalties += list(reg.penalties)
            i, j = i + n, j + k
        return cls(P, p, tuple(names), tuple(groups), np.array(penalties), tuple(regressions),
                   tuple(r.shape[0] for r in regressions.values()))

    def subset(self, names) -> "Regression":
        """The regression restricted to the named columns (nested libraries share columns)."""
        index = {n: i for i, n in enumerate(self.names)}
        missing = [n for n in names if n not in index]
        if missing:
            raise CvxidError(f"the regression has no column(s) {', '.join(missing)}")
        idx = [index[n] for n in names]
        return Regression(
            self.P[:, idx], self.p, tuple(names), tuple(self.groups[i] for i in idx),
            self.penalties[idx], self.experiments, self.parts,
        )

    @property
    def shape(self) -> tuple[int, int]:
        return self.P.shape

    def residual(self, coefficients: np.ndarray) -> np.ndarray:
        return self.P @ np.asarray(coefficients) - self.p

    def mse(self, coefficients: np.ndarray) -> float:
        """Mean squared equation error :math:`\\|Pc - p\\|^2/n` (the paper's eq. 16)."""
        return float(np.mean(self.residual(coefficients) ** 2))

    def nmse(self, coefficients: np.ndarray) -> float:
        """Equation error relative to the target's mean square (dimensionless)."""
        return self.mse(coefficients) / float(np.mean(self.p**2))

    def reduce(self, row_weights: np.ndarray | None = None) -> Reduced:
        """Scale, then QR-reduce (optionally with row weights, e.g. bootstrap counts)."""
        P, p = self.P, self.p
        rows = float(len(p))
        if row_weights is not None:
            w = np.asarray(row_weights, dtype=float)
            keep = w > 0
            root = np.sqrt(w[keep])
            P, p, rows = P[keep] * root[:, None], p[keep] * root, float(w.sum())
        scale = np.sqrt(np.sum(P**2, axis=0) / rows)
        zero = scale == 0
        if zero.any():
            bad = [n for n, z in zip(self.names, zero) if z]
            raise CvxidError(
                f"regression column(s) {', '.join(bad)} are identically zero (a constant or "
                "absent signal?); drop those terms or use richer data"
            )
        tscale = float(np.sqrt(np.sum(p**2) / rows))
        if tscale == 0:
            raise CvxidError("the regression target is identically zero: the input carries no signal")
        R = np.linalg.qr(np.column_stack([P / scale, p / tscale]), mode="r")
        k = len(self.names)
        diag = np.abs(np.diag(R)[:k])
        dependent = [n for n, d in zip(self.names, diag) if d < RANK_TOL * diag.max()]
        if dependent:
            warnings.warn(
                f"the regression is rank-deficient: column(s) {', '.join(dependent)} are (nearly) "
                "linear combinations of earlier ones; their coefficients are not identifiable from "
                "these data (drop them or use richer data)",
                CvxidWarning,
                stacklevel=2,
            )
        return Reduced(R[:k, :k], R[:k, k], float(R[k, k] ** 2), rows, scale, tscale)

    def table(self) -> pd.DataFrame:
        return pd.DataFrame(
            {
                "group": self.groups,
                "penalty": self.penalties,
                "rms": np.sqrt(np.mean(self.P**2, axis=0)),
            },
            index=pd.Index(self.names, name="column"),
        )

    def __repr__(self) -> str:
        n, k = self.shape
        return (
            f"Regression: {n} rows × {k} columns (experiments: {', '.join(self.experiments)}), "
            f"target rms {np.sqrt(np.mean(self.p ** 2)):.3e}\n"
            + self.table().to_string(float_format=lambda v: f"{v:.3e}")
        )
