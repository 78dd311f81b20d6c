r"""Where a model fails: its equation error in force units, in time and against the state.

For equation :math:`i` of a system,

.. math::

    r_i = m_i\ddot q_i + \sum_j c_{ij}\, g_{ij}(q, \dot q) - u_i - b_i\,q_d^{(r)}(t-\tau),

with every coordinate's derivatives from a smoothing estimate (Savitzky–Golay), shown in
time and binned against the equation's own position and velocity (a step at
:math:`\dot q = 0` is a dry friction, a slope in :math:`q` a stiffness, a level an offset),
with its auto-correlation and its cross-correlation with the input; the confidence bound
accounts for the residual's own colour, :math:`\mathrm{var}\,\hat\rho_{ru}(k) \approx
\frac1N\sum_j \rho_{rr}(j)\rho_{uu}(j)` (the white-noise bound :math:`1.96/\sqrt N` is
wrong for equation errors, which are coloured even for the right model).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy.signal import savgol_filter

from cvxid.data.experiment import Experiment
from cvxid.diagnosis.compare import measured_delayed
from cvxid.errors import CvxidError
from cvxid.identified import IdentifiedModel, IdentifiedSystem
from cvxid.regression.velocity import savgol_window


@dataclass(frozen=True)
class Residuals:
    """The equation error in force units and its views."""

    time: np.ndarray
    residual: np.ndarray
    position: np.ndarray
    velocity: np.ndarray
    input: np.ndarray

    def __repr__(self) -> str:
        rms = float(np.sqrt(np.mean(np.square(self.residual))))
        return (f"Residuals: the equation error on {self.residual.size:,} samples ({self.time[0]:g} … "
                f"{self.time[-1]:g} s), RMS {rms:.4g} (force units); .binned(\"velocity\"), .correlations(), "
                ".plot()")

    def plot(self, bins: int = 21, title: str | None = None):
        """The residual in time and binned against position and velocity."""
        from cvxid.plots import residual_figure

        return residual_figure(self, bins, title)

    def binned(self, against: str = "velocity", bins: int = 21) -> pd.DataFrame:
        """Mean and spread of the residual in bins of the position or the velocity."""
        values = getattr(self, against)
        edges = np.quantile(values, np.linspace(0, 1, bins + 1))
        idx = np.clip(np.searchsorted(edges, values, side="right") - 1, 0, bins - 1)
        frame = pd.DataFrame({"bin": idx, "value": values, "residual": self.residual})
        grouped = frame.groupby("bin")
        return pd.DataFrame(
            {"center": grouped["value"].mean(), "mean": grouped["residual"].mean(), "std": grouped["residual"].std()}
        )

    def correlations(self, lags: int = 50) -> pd.DataFrame:
        """Auto-correlation of the residual, cross-correlation with the input, and the 95 %
        bound that accounts for both signals' own correlation."""
        r = (self.residual - self.residual.mean()) / self.residual.std()
        u = (self.input - self.input.mean()) / max(self.input.std(), 1e-300)
        n = r.size
        rr = np.array([np.mean(r[: n - k] * r[k:]) for k in range(lags + 1)])
        ru = np.array([np.mean(r[: n - k] * u[k:]) for k in range(lags + 1)])
        full = min(n - 1, 20 * lags)
        rr_long = np.array([np.mean(r[: n - k] * r[k:]) for k in range(0, full, max(1, full // 400))])
        uu_long = np.array([np.mean(u[: n - k] * u[k:]) for k in range(0, full, max(1, full // 400))])
        step = max(1, full // 400)
        var = (rr_long[0] * uu_long[0] + 2 * step * np.sum(rr_long[1:] * uu_long[1:])) / n
        bound = 1.96 * np.sqrt(max(var, 1.0 / n))
        return pd.DataFrame(
            {"autocorrelation": rr, "cross_correlation": ru, "bound": bound, "white_bound": 1.96 / np.sqrt(n)},
            index=pd.Index(range(lags + 1), name="lag"),
        )


def residuals(fitted: IdentifiedModel | IdentifiedSystem, experiment: Experiment,
              equation: str | None = None) -> Residuals:
    """The equation error of one equation of ``fitted`` on ``experiment`` (see the module
    docstring): of a one-equation model, or of the ``equation`` (its coordinate) of a
    system.  A record with gaps gives the errors of its gap-free runs one after another
    (each smoothed on its own: a smoothing window must not cross a gap)."""
    system = fitted if isinstance(fitted, IdentifiedSystem) else IdentifiedSystem.of(fitted)
    if equation is None:
        if system.single is None:
            raise CvxidError(f"residuals of a system of {len(system.models)} equations: name one, "
                             f"equation = one of {', '.join(system.models)}")
        equation = next(iter(system.models))
    if equation not in system.models:
        raise CvxidError(f"no equation '{equation}' in the system; its equations are {', '.join(system.models)}")
    segments = experiment.segments()
    if len(segments) > 1:
        parts = [_residuals(system, equation, s) for s in segments]
        return Residuals(*(np.concatenate([getattr(r, f) for r in parts])
                           for f in ("time", "residual", "position", "velocity", "input")))
    return _residuals(system, equation, experiment)


def _residuals(system: IdentifiedSystem, equation: str, experiment: Experiment) -> Residuals:
    model = system.models[equation]
    spec, numeric = model.spec, model.system()
    states, own = {}, {}
    for c in system.coordinates:
        y = experiment.output(c)
        w = savgol_window(y)
        states[c] = savgol_filter(y, w, 3, mode="interp")
        states[c + "'"] = savgol_filter(y, w, 3, deriv=1, delta=experiment.dt, mode="interp")
        if c == spec.coordinate:
            own = savgol_filter(y, w, 3, deriv=2, delta=experiment.dt, mode="interp")
    x, v = states[spec.coordinate], states[spec.coordinate + "'"]
    u = spec.received_input(experiment)
    r = numeric.mass * own - u
    for term, c in zip(numeric.terms, np.atleast_1d(numeric.coefficients)):
        r = r + c * term.evaluate(states)
    if spec.delay is not None:
        d = spec.delay.coordinate
        r = r - _measured_feedback(numeric, experiment.time, states[d], states[d + "'"])
    known = np.isfinite(r)  # a measured history: rows whose delayed argument precedes the record are dropped
    return Residuals(experiment.time[known], r[known], x[known], v[known], u[known])


def _measured_feedback(system, t: np.ndarray, x: np.ndarray, v: np.ndarray) -> np.ndarray:
    r"""The delayed feedback :math:`b\,x^{(q)}(t-\tau)` (with the rate, :math:`+\,b_1\dot x(t-\tau)`)
    read from (smoothed) measurements."""
    out = np.zeros_like(t)
    for gain, order in ((system.gain, system.derivative), (system.rate_gain, system.derivative + 1)):
        if gain:
            out = out + gain * measured_delayed(system.tau, system.history, order, t, x, v)
    return out
