r"""The linear regression :math:`P c \approx p` that the algebraic operation produces.

Rows are samples of the transformed signals, one column per model column.  Before any solver
sees it, the regression is *reduced*: columns and target are scaled to unit root-mean-square
and a QR factorisation of :math:`[\tilde P\;\tilde p]` gives

.. math::

    \|\tilde P \tilde c - \tilde p\|^2 = \|R \tilde c - r\|^2 + \rho^2,

with :math:`R` a small upper-triangular :math:`k \times k` factor.  Every solve works on
:math:`(R, r)`, so its cost does not grow with the record length.  Row weights (the
bootstrap's multinomial counts) enter as :math:`\sqrt{w_i}` row factors.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy.interpolate import CubicSpline

from cvxid.data.experiment import Experiment
from cvxid.errors import CvxidError, CvxidWarning
from cvxid.model.equation import ModelSpec
from cvxid.model.terms import DelayedSignal, velocity_symbol
from cvxid.regression.algebraic import AlgebraicOrders, AlgebraicTransform
from cvxid.regression.velocity import estimate_velocity

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



@dataclass(frozen=True)
class Regression:
    """Columns ``P`` (n × k), target ``p``, column names, groups and L1 weights."""

    P: np.ndarray
    p: np.ndarray
    names: tuple[str, ...]
    groups: tuple[str, ...]
    penalties: np.ndarray
    experiments: tuple[str, ...] = ()

    @classmethod
    def build(
        cls,
        model: ModelSpec,
        experiments: Experiment | list[Experiment],
        velocity: str = "savgol",
        tau: float | None = None,
    ) -> "Regression":
        """Transform one or several experiments (stacked) into a regression for ``model``
        (for an exact delay, at the delay ``tau``)."""
        return DelayFamily(model, experiments, velocity).at(tau)

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
        return cls(P, p, tuple(names), tuple(groups), np.array(penalties), tuple(regressions))

    def subset(self, names) -> "Regression":
        """The regression restricted to the named columns (nested libraries share columns)."""
        index = {n: i for i, n in enumerate(self.names)}
        missing = [n for n in names if n not in index]
        if missing:
            raise CvxidError(f"the regression has no column(s) {', '.join(missing)}")
        idx = [index[n] for n in names]
        return Regression(
            self.P[:, idx], self.p, tuple(names), tuple(self.groups[i] for i in idx),
            self.penalties[idx], self.experiments,
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


def states_of(model: ModelSpec, experiment: Experiment, velocity: str) -> dict[str, np.ndarray]:
    """Positions of every coordinate the model reads and, where a column needs one, their
    velocities (measured or estimated)."""
    states = {c: experiment.output(c) for c in model.coordinates}
    for coord in model.coordinates:
        symbol = velocity_symbol(coord)
        if not any(c.term.needs_velocity and symbol in c.term.symbols for c in model.columns):
            continue
        if velocity == "measured":
            if coord not in experiment.velocities:
                raise CvxidError(
                    f"velocity = 'measured' but experiment '{experiment.name}' has no measured "
                    f"velocity of '{coord}'; name its column or use an estimator"
                )
            states[symbol] = experiment.velocities[coord]
        else:
            states[symbol] = estimate_velocity(states[coord], experiment.time, velocity)
    return states


def _windows(experiment: Experiment, window: float | None) -> list[np.ndarray]:
    """Sample indices of consecutive restart windows (the whole record without ``window``).

    The integrals of the algebraic operation restart in each window, so their polynomial
    weights stay bounded on long records (and any offset cannot grow over the whole record).
    """
    n = experiment.n
    if window is None:
        return [np.arange(n)]
    length = int(round(window / experiment.dt))
    if length < 10:
        raise CvxidError(f"the restart window ({window:g} s) holds fewer than 10 samples; lengthen it")
    return [np.arange(s, min(s + length, n)) for s in range(0, n - length // 2, length)]


class DelayFamily:
    """Regressions of one model and data over the delay :math:`\tau`.

    Columns that do not depend on the delay are transformed once; :meth:`at` adds the
    delayed signal :math:`x^{(q)}(t-\tau)` (interpolated by a cubic spline), as a column
    when the gain is unknown or moved into the target when it is known.  With an exact
    delay every experiment (and every restart window) restarts its integrals at
    ``tau_max`` (the first ``tau_max`` seconds serve as the delayed signal's history), so
    regressions at different delays share their rows and their errors compare.  With
    ``window`` (seconds) the integrals restart in consecutive windows (stacked rows).
    """

    def __init__(self, model: ModelSpec, experiments, velocity: str = "savgol", window: float | None = None):
        self.model = model
        exps = [experiments] if isinstance(experiments, Experiment) else list(experiments)
        exps = [segment for e in exps for segment in e.segments()]  # integrals restart after gaps
        self.experiments = exps
        exact = model.delay is not None and model.delay.exact
        self.start = model.delay.tau_max if exact else 0.0
        if window is not None and not window > 2 * self.start:
            raise CvxidError(
                f"the restart window ({window:g} s) must be longer than twice tau_max ({self.start:g} s)"
            )
        self.blocks = []
        cols = [c for c in model.columns if not isinstance(c.term, DelayedSignal)]
        for e in exps:
            if exact and e.duration < 2 * self.start:
                raise CvxidError(
                    f"experiment '{e.name}' lasts {e.duration:g} s, too short for delays up to "
                    f"tau_max = {self.start:g} s (it needs at least twice that); lower "
                    "[model.delay] tau_max or use a longer record"
                )
            if np.ptp(e.input(model.input)) == 0:
                raise CvxidError(
                    f"experiment '{e.name}': input '{model.input}' is constant, so it does not "
                    "excite the system; identification needs a varying input"
                )
            states = states_of(model, e, velocity)  # on the whole record: no edge effects per window
            spline = CubicSpline(e.time, e.output(model.delay.coordinate)) if exact else None
            for rows in _windows(e, window):
                keep = rows[e.time[rows] >= e.time[rows[0]] + self.start - 1e-9 * e.dt]
                transform = AlgebraicTransform(e.time[keep], AlgebraicOrders.for_model(model))
                sliced = {k: v[keep] for k, v in states.items()}
                base = {c.name: transform.column(*c.term.regression_signal(sliced)) for c in cols}
                p = transform.column(e.input(model.input)[keep])
                if not model.inertia:
                    p = p - model.mass * transform.column(sliced[model.coordinate], 2)
                self.blocks.append((transform, base, p, spline, e.time[keep]))

    def at(self, tau: float | None = None) -> Regression:
        model = self.model
        exact = model.delay is not None and model.delay.exact
        if exact:
            if tau is None:
                raise CvxidError("an exact-delay regression needs a delay tau")
            if not model.delay.tau_min <= tau <= model.delay.tau_max:
                raise CvxidError(
                    f"tau = {tau:g} is outside [tau_min, tau_max] = [{model.delay.tau_min:g}, "
                    f"{model.delay.tau_max:g}]"
                )
        cols = model.columns
        Ps, ps = [], []
        for transform, base, p, spline, t in self.blocks:
            if exact:
                shifted = spline(t - tau)
                if model.delay.gain is not None:
                    p = p + model.delay.gain * transform.column(shifted, model.delay.derivative)
            Ps.append(np.column_stack([
                transform.column(shifted, c.term.derivative) if isinstance(c.term, DelayedSignal) else base[c.name]
                for c in cols
            ]))
            ps.append(p)
        return Regression(
            P=np.vstack(Ps),
            p=np.concatenate(ps),
            names=tuple(c.name for c in cols),
            groups=tuple(c.group for c in cols),
            penalties=np.array([c.penalty for c in cols]),
            experiments=tuple(e.name for e in self.experiments),
        )
