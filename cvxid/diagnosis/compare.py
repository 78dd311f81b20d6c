r"""Compare a model with measurements: free-run and k-step-ahead simulation against the
measured output of every coordinate.

The fit of a simulated output :math:`\hat y` to the measured :math:`y` is

.. math::

    \text{fit} = 100\,\Big(1 - \frac{\|y-\hat y\|}{\|y-\bar y\|}\Big)\ \%,
    \qquad \text{NRMSE} = \frac{\|y-\hat y\|}{\|y-\bar y\|}.

:func:`compare_system` gives one :class:`Comparison` per coordinate of a system of
:math:`N \ge 1` equations, from one joint free run and one batch of k-step-ahead windows;
:func:`compare` is one equation's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy.interpolate import CubicSpline
from scipy.signal import savgol_filter

from cvxid.data.experiment import Experiment
from cvxid.errors import CvxidError
from cvxid.identified import IdentifiedModel, IdentifiedSystem
from cvxid.initial_state import check_initial_state, free_run
from cvxid.metrics import band_period, fit_percent, noise_ceiling_percent
from cvxid.regression.history import start_index
from cvxid.regression.velocity import savgol_window
from cvxid.regression.windows import longest
from cvxid.simulate import SimulationDiverged, integrate


@dataclass(frozen=True)
class Comparison:
    """Simulated against measured output.

    ``free_run`` starts from ``initial_state`` (position, velocity), found the way
    ``initial`` says: ``"estimated"`` (least squares over the compared record,
    :mod:`cvxid.initial_state`), ``"record"`` (the record's smoothed first
    state), ``"given"`` or ``"the polish's"`` (the training record's, from the output-error
    polish: ``RunResult.train_fit``); ``record_fit_percent`` is the fit from the record's own start,
    kept beside an estimated one; ``ceiling_percent`` is the fit a perfect model would reach
    under the record's measurement noise, the output's and the measured input's through the
    model (:func:`~cvxid.metrics.noise_ceiling_percent`,
    :meth:`~cvxid.identified.IdentifiedSystem.input_noise_spread`)."""

    time: np.ndarray
    measured: np.ndarray
    free_run: np.ndarray | None
    fit_percent: float | None
    nrmse: float | None
    k_step: int
    k_step_fit_percent: float | None
    message: str = ""
    initial: str = "record"
    initial_state: tuple[float, float] | None = None
    record_fit_percent: float | None = None
    record_free_run: np.ndarray | None = None
    ceiling_percent: float | None = None

    @property
    def rms(self) -> float | None:
        """Root-mean-square error of the free run over the samples it covers (the output's
        units: the benchmarks' "simulation RMSE")."""
        if self.free_run is None:
            return None
        covered = np.isfinite(self.free_run)
        return float(np.sqrt(np.mean((self.free_run[covered] - self.measured[covered]) ** 2)))

    def table(self) -> pd.DataFrame:
        r"""Fit (%) and NRMSE (:math:`1 - \text{fit}/100`) of each simulation compared."""
        fits = {"free run": self.fit_percent}
        if self.initial == "estimated":
            fits["free run from the record's start"] = self.record_fit_percent
        fits[f"{self.k_step}-step ahead"] = self.k_step_fit_percent
        rows = {k: [v, None if v is None else 1.0 - v / 100.0] for k, v in fits.items()}
        return pd.DataFrame.from_dict(rows, orient="index", columns=["fit %", "NRMSE"])

    def title(self) -> str:
        """One line: the free-run fit and where its simulation started."""
        if self.fit_percent is None:
            return "free run: " + self.message
        text = f"free-run fit {self.fit_percent:.1f} % (the noise allows {self.ceiling_percent:.1f} %; initial state {self.initial}"
        if self.initial == "estimated" and self.record_fit_percent is not None:
            text += f"; {self.record_fit_percent:.1f} % from the record's own start"
        return text + ")"

    def plot(self):
        from cvxid.plots import comparison_figure

        if self.free_run is None:
            raise CvxidError(f"nothing to plot: {self.message}")
        return comparison_figure(self.time, self.measured, self.free_run, self.title(),
                                 self.record_free_run if self.initial == "estimated" else None)

    def __repr__(self) -> str:
        text = (f"Comparison (free run from the {self.initial} initial state)\n"
                f"{self.table().to_string(formatters={'fit %': _shown('{:.2f}'), 'NRMSE': _shown('{:.4g}')})}")
        return text + (f"\n  {self.message}" if self.message else "")


def _shown(form: str):
    """A table cell's format, "–" where there is no value (a free run that diverged)."""
    return lambda v: "–" if v is None or not np.isfinite(v) else form.format(v)


def compare(model: IdentifiedModel, experiment: Experiment, k_step: int | None = None,
            x0: float | None = None, v0: float | None = None, initial: str = "estimated") -> Comparison:
    """Free-run and ``k_step``-ahead fit of ``model`` on ``experiment`` (k-step default:
    :func:`k_step_samples`).  The free run starts where the simulation starts (at
    the record's start, or with the measured history at :math:`t_0 + \\tau_{\\max}`; the
    comparison covers the simulated samples only) from the state ``(x0, v0)`` when given,
    else the state ``initial`` names: ``"estimated"`` (least squares over the compared
    record, as MATLAB's ``compare`` does; the fit from the record's own start is kept
    beside it) or ``"record"`` (the record's smoothed first state).  An identified system
    of one equation is its model; a coupled one compares with :func:`compare_system`."""
    if isinstance(model, IdentifiedSystem):
        if model.single is None:
            raise CvxidError(f"compare takes one equation's model; this system has {len(model.models)} coupled "
                             "equations: use system.compare(experiment), the fit of every coordinate, or "
                             "cvxid.compare_system(system, experiment), each coordinate's Comparison")
        model = model.single
    given = None if x0 is None and v0 is None else {model.spec.coordinate: (x0, v0)}
    return compare_system(model, experiment, k_step, initial, given)[model.spec.coordinate]


def longest_stretch(experiment: Experiment) -> tuple[Experiment, str]:
    """A record with gaps (NaN samples) is compared on its longest gap-free stretch (a free
    run cannot cross a gap); the note says which."""
    segments = experiment.segments()
    if len(segments) == 1 and segments[0] is experiment:
        return experiment, ""
    stretch = longest(segments)
    return stretch, f"compared on the longest gap-free stretch, {stretch.name} ({stretch.n} of {experiment.n} samples)"


K_STEP_PERIODS = 0.05
"""The horizon of the k-step-ahead check, in periods of the compared output's 95 % band
edge (:func:`~cvxid.metrics.band_period`; at least 2 samples): 0.1 s, 100 samples, on
``hidden_friction``'s record.  (A tenth of a second whatever the plant was 2 samples of a
plant 100 times faster and 30,000 of one 300 times slower.)  On the held-out diagnosis
benchmark (report seeds 1000-1009, noise 0.01 and 0.001, 100 systems) its ranked-first,
added-first and wrong-addition figures were those of the tenth of a second
(docs/benchmarks.md)."""


def k_step_samples(experiment: Experiment, coordinates) -> int:
    """The k-step check's horizon on ``experiment`` (:data:`K_STEP_PERIODS`)."""
    period = band_period(map(experiment.output, coordinates), experiment.dt)
    return max(2, int(round(K_STEP_PERIODS * period / experiment.dt)))


def k_step_prediction(model: IdentifiedModel, experiment: Experiment, k: int) -> np.ndarray:
    """Each window of ``k`` samples simulated from the measured (smoothed) state at its
    start, with the delayed feedback taken from the measured output."""
    return k_step_predictions(IdentifiedSystem.of(model), experiment, k)[model.spec.coordinate]


def k_step_predictions(system: IdentifiedSystem, experiment: Experiment, k: int) -> dict[str, np.ndarray]:
    """:func:`k_step_prediction` of every coordinate of a system of N >= 1 equations: the
    windows run as one batch through the integrator, each from the smoothed measured states
    at its start, every equation driven by its input and its feedback read from the
    measured (smoothed) delayed coordinate."""
    t, coords = experiment.time, system.coordinates
    smooth, vel = {}, {}
    for c in coords:
        y = experiment.output(c)
        smooth[c] = savgol_filter(y, savgol_window(y), 3, mode="interp")
        vel[c] = savgol_filter(y, savgol_window(y), 3, deriv=1, delta=experiment.dt, mode="interp")
    numeric = system.system()
    d = numeric.delayed
    feedback = measured_delayed(numeric.tau, numeric.history, numeric.derivative, t, smooth[d], vel[d])
    rate = measured_delayed(numeric.tau, numeric.history, 1, t, smooth[d], vel[d])  # (the paper's x'(t - tau))
    first = int(np.argmax(np.isfinite(feedback)))  # a measured history: predictions start where it is known
    splines = [CubicSpline(t[first:], (m.spec.received_input(experiment) + eq.delay_gain * feedback
                                       + (eq.delay_rate_gain * rate if eq.delay_rate_gain else 0.0))[first:])
               for m, eq in zip(system.models.values(), numeric.equations)]
    starts = np.arange(first, len(t) - 1, k)
    local = t[: k + 1] - t[0]
    B, C = starts.size, len(coords)
    coefs, mass, _ = numeric.arrays()

    def forces(fine: np.ndarray, h: float) -> np.ndarray:
        at = np.minimum(t[starts][None, :] + fine[:, None], t[-1])  # the last window's unused tail: no extrapolation
        return np.stack([spline(at) for spline in splines], axis=1)  # (S, C, B)

    X, _ = integrate(local, forces, coords, [eq.terms for eq in numeric.equations], np.repeat(coefs, B, axis=1),
                     np.repeat(mass, B, axis=1), np.zeros((C, B)), np.zeros(B),
                     np.array([smooth[c][starts] for c in coords]), np.array([vel[c][starts] for c in coords]), 0)
    out = {}
    for j, c in enumerate(coords):
        pred = np.full_like(t, np.nan)
        pred[first] = smooth[c][first]
        for b, s in enumerate(starts):
            stop = min(s + k, len(t) - 1)
            pred[s + 1 : stop + 1] = X[1 : stop - s + 1, j, b]
        out[c] = pred
    return out


def measured_delayed(tau: float, history: str, derivative: int, t: np.ndarray, x: np.ndarray,
                     v: np.ndarray) -> np.ndarray:
    r"""The delayed signal :math:`x^{(q)}(t-\tau)` read from (smoothed) measurements; before
    the record NaN (``history = "measured"``: unknown), zero, or the first sample
    (``"initial"``)."""
    lagged = np.interp(t - tau, t, x if derivative == 0 else v)
    held = x[0] if derivative == 0 else 0.0  # ("initial": the position held, so no velocity)
    lagged[t - t[0] < tau - 1e-9 * (t[1] - t[0])] = {"measured": np.nan, "zero": 0.0}.get(history, held)
    return lagged


def compare_system(system: IdentifiedModel | IdentifiedSystem, experiment: Experiment, k_step: int | None = None,
                   initial: str = "estimated", given: dict[str, tuple[float | None, float | None]] | None = None
                   ) -> dict[str, Comparison]:
    """:func:`compare` for every coordinate of a system of :math:`N \\ge 1` equations, by
    coordinate: one free run of all coordinates together from the start ``initial`` names
    (estimated jointly, :mod:`cvxid.initial_state`) or from the state ``given`` (coordinate
    -> (position, velocity); a None is the record's own), and the k-step-ahead windows of
    :func:`k_step_predictions`."""
    system = IdentifiedSystem.of(system)
    check_initial_state(initial)
    experiment, note = longest_stretch(experiment)
    coords = system.coordinates
    k = k_step or k_step_samples(experiment, coords)
    start = start_index(experiment, next(iter(system.specs.values())).delay)
    measured = {c: experiment.output(c)[start:] for c in coords}
    run, own, message = system.simulator(experiment), system.initial_state(experiment), ""
    if given:
        own = {c: tuple(o if g is None else g for o, g in zip(own[c], given.get(c, (None, None)))) for c in coords}
        initial = "given"
    state, sims, record = None, None, None
    try:
        state, sims, record = free_run(lambda s: {c: v[start:] for c, v in run(s).items()}, measured, own,
                                       "record" if given else initial)
    except SimulationDiverged as exc:
        message = f"free run: {exc}"
    try:
        ahead = k_step_predictions(system, experiment, k)
    except SimulationDiverged as exc:
        ahead = None
        message = (message + "; " if message else "") + f"k-step: {exc}"
    message = "; ".join(m for m in (note, message) if m)
    driven = {} if sims is None else system.input_noise_spread(experiment, state, sims)
    out = {}
    for c in coords:
        y, sim = measured[c], None if sims is None else sims[c]
        nrmse = None if sim is None else float(np.linalg.norm(y - sim) / np.linalg.norm(y - y.mean()))
        out[c] = Comparison(experiment.time[start:], y, sim, None if sim is None else fit_percent(y, sim), nrmse, k,
                            None if ahead is None else fit_percent(experiment.output(c), ahead[c]), message, initial,
                            None if state is None else state[c], None if record is None else fit_percent(y, record[c]),
                            None if record is None else record[c], noise_ceiling_percent(y, driven.get(c, 0.0)))
    return out


def free_run_residual(system: IdentifiedModel | IdentifiedSystem, experiment: Experiment) -> np.ndarray | None:
    """The free run's error on ``experiment`` (from the initial state :func:`compare_system`
    estimates), every coordinate's one after another, its finite samples (None when it
    diverges)."""
    compared = compare_system(system, experiment)
    if any(c.free_run is None for c in compared.values()):
        return None
    return np.concatenate([(c.free_run - c.measured)[np.isfinite(c.free_run)] for c in compared.values()])


def mean_fit(comparisons: dict[str, Comparison], which: str = "fit_percent") -> float | None:
    """The mean over coordinates of a fit (``"fit_percent"``, the free run's, or
    ``"k_step_fit_percent"``); None when any coordinate's simulation diverged."""
    fits = [getattr(c, which) for c in comparisons.values()]
    return None if any(f is None for f in fits) else float(np.mean(fits))
