r"""Compare a model with measurements, see where it fails, name the missing effect.

* :func:`compare` — free-run and k-step-ahead simulation against the measured output:
  fit % :math:`= 100\,(1 - \|y-\hat y\|/\|y-\bar y\|)` and NRMSE.
* :func:`residuals` — the equation error in force units,
  :math:`r = m\ddot x + \sum c_i g_i - f - b\,x(t-\tau)` (derivatives from a smoothing
  estimate), in time and binned against :math:`x` and :math:`\dot x`, with its
  auto-correlation and its cross-correlation with the input; the confidence bound accounts
  for the residual's own colour, :math:`\mathrm{var}\,\hat\rho_{ru}(k) \approx
  \frac1N\sum_j \rho_{rr}(j)\rho_{uu}(j)` (the white-noise bound :math:`1.96/\sqrt N` is
  wrong for equation errors, which are coloured even for the right model).
* :func:`diagnose` — each candidate effect's column goes through the same algebraic
  operation as the model's, is orthogonalised against them and scored by the share of the
  residual it explains, the error-reduction ratio
  :math:`\mathrm{ERR} = (g_\perp^T r)^2 / (g_\perp^T g_\perp\; r^T r)`, and by the drop of
  the validation error when it is added and the model refitted.  Candidates nearly
  collinear with each other are reported as one group, never as a false single winner.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field, replace
from typing import Sequence

import numpy as np
import pandas as pd
from scipy.interpolate import CubicSpline
from scipy.signal import savgol_filter

from cvxid.data.experiment import Experiment
from cvxid.diagnosis.acceptance import accepted, inclusion, stop_reason, stopped_at
from cvxid.errors import CvxidError, CvxidWarning
from cvxid.identified import IdentifiedModel, IdentifiedSystem
from cvxid.initial_state import check_initial_state, free_run
from cvxid.identify.selection import Selection
from cvxid.identify.problem import Problem
from cvxid.identify.profile import profile_delay, profile_input_delay
from cvxid.metrics import fit_percent, noise_ceiling_percent
from cvxid.model.equation import ModelSpec
from cvxid.model.library import CATALOGUE, effect, resolve_term
from cvxid.model.input_delay import InputDelay, record_bound
from cvxid.model.terms import DelayedSignal, InputRate, Term
from cvxid.progress import progress
from cvxid.regression.builder import RegressionBuilder
from cvxid.regression.history import start_index
from cvxid.regression.velocity import savgol_window
from cvxid.simulate import SimulationDiverged, integrate

COLLINEAR = 0.9
"""Candidates whose orthogonalised columns correlate above this form one group."""


# ---------------------------------------------------------------------- compare
@dataclass(frozen=True)
class Comparison:
    """Simulated against measured output.

    ``free_run`` starts from ``initial_state`` (position, velocity), found the way
    ``initial`` says: ``"estimated"`` (least squares over the compared record,
    :mod:`cvxid.initial_state`), ``"record"`` (the record's smoothed first
    state) or ``"given"``; ``record_fit_percent`` is the fit from the record's own start,
    kept beside an estimated one; ``ceiling_percent`` is the fit a perfect model would reach
    under the record's measurement noise (:func:`~cvxid.metrics.noise_ceiling_percent`)."""

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
        rows = {"free run": [self.fit_percent, self.nrmse]}
        if self.initial == "estimated":
            rows["free run from the record's start"] = [self.record_fit_percent, None]
        rows[f"{self.k_step}-step ahead"] = [self.k_step_fit_percent, None]
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
                f"{self.table().to_string(float_format=lambda v: f'{v:.2f}')}")
        return text + (f"\n  {self.message}" if self.message else "")


def compare(model: IdentifiedModel, experiment: Experiment, k_step: int | None = None,
            x0: float | None = None, v0: float | None = None, initial: str = "estimated") -> Comparison:
    """Free-run and ``k_step``-ahead fit of ``model`` on ``experiment`` (k-step default:
    a tenth of a second of samples).  The free run starts where the simulation starts (at
    the record's start, or with the measured history at :math:`t_0 + \\tau_{\\max}`; the
    comparison covers the simulated samples only) from the state ``(x0, v0)`` when given,
    else the state ``initial`` names: ``"estimated"`` (least squares over the compared
    record, as MATLAB's ``compare`` does; the fit from the record's own start is kept
    beside it) or ``"record"`` (the record's smoothed first state).  An identified system
    of one equation is its model; a coupled one compares with its own
    :meth:`~cvxid.identified.IdentifiedSystem.compare`."""
    if isinstance(model, IdentifiedSystem):
        if model.single is None:
            raise CvxidError(f"compare takes one equation's model; this system has {len(model.models)} coupled "
                             "equations: use system.compare(experiment), the fit of every coordinate")
        model = model.single
    check_initial_state(initial)
    experiment, note = longest_stretch(experiment)
    y = experiment.output(model.spec.coordinate)
    k = k_step or k_step_samples(experiment.dt)
    start = start_index(experiment, model.spec.delay)
    coord, measured = model.spec.coordinate, y[start:]
    given = x0 is not None or v0 is not None
    initial = "given" if given else initial
    record_fit = record_sim = state = None
    try:
        run = model.simulator(experiment)
        guess = model.initial_state(experiment)
        own = (guess[0] if x0 is None else x0, guess[1] if v0 is None else v0)
        starts, sims, record = free_run(lambda s: {coord: run(*s[coord])[0][start:]}, {coord: measured},
                                        {coord: own}, "record" if given else initial)
        state, sim = starts[coord], sims[coord]
        if record is not None:
            record_sim = record[coord]
            record_fit = fit_percent(measured, record_sim)
        free, nrmse, message = fit_percent(measured, sim), float(np.linalg.norm(measured - sim)
                                                                / np.linalg.norm(measured - measured.mean())), ""
    except SimulationDiverged as exc:
        sim, free, nrmse, message = None, None, None, f"free run: {exc}"
    try:
        ahead = fit_percent(y, k_step_prediction(model, experiment, k))
    except SimulationDiverged as exc:
        ahead = None
        message = (message + "; " if message else "") + f"k-step: {exc}"
    message = "; ".join(m for m in (note, message) if m)
    return Comparison(experiment.time[start:], measured, sim, free, nrmse, k, ahead, message,
                      initial, state, record_fit, record_sim, noise_ceiling_percent(measured))


def longest_stretch(experiment: Experiment) -> tuple[Experiment, str]:
    """A record with gaps (NaN samples) is compared on its longest gap-free stretch (a free
    run cannot cross a gap); the note says which."""
    segments = experiment.segments()
    if len(segments) == 1 and segments[0] is experiment:
        return experiment, ""
    longest = max(segments, key=lambda s: s.n)
    return longest, f"compared on the longest gap-free stretch, {longest.name} ({longest.n} of {experiment.n} samples)"


K_STEP_SECONDS = 0.1
"""The horizon of the k-step-ahead check (a tenth of a second of samples, at least 2)."""


def k_step_samples(dt: float) -> int:
    return max(2, int(round(K_STEP_SECONDS / dt)))


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
    feedback = _measured_delayed(numeric.tau, numeric.history, numeric.derivative, t, smooth[d], vel[d])
    first = int(np.argmax(np.isfinite(feedback)))  # a measured history: predictions start where it is known
    splines = [CubicSpline(t[first:], (m.spec.received_input(experiment) + eq.delay_gain * feedback)[first:])
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


def _measured_delayed(tau: float, history: str, derivative: int, t: np.ndarray, x: np.ndarray,
                      v: np.ndarray) -> np.ndarray:
    r"""The delayed signal :math:`x^{(q)}(t-\tau)` read from (smoothed) measurements; before
    the record NaN (``history = "measured"``: unknown), zero, or the first sample
    (``"initial"``)."""
    lagged = np.interp(t - tau, t, x if derivative == 0 else v)
    lagged[t - t[0] < tau - 1e-9 * (t[1] - t[0])] = {"measured": np.nan, "zero": 0.0}.get(history, x[0])
    return lagged


def _measured_feedback(system, t: np.ndarray, x: np.ndarray, v: np.ndarray) -> np.ndarray:
    r"""The delayed feedback :math:`b\,x^{(q)}(t-\tau)` read from (smoothed) measurements."""
    if not system.gain:
        return np.zeros_like(t)
    return system.gain * _measured_delayed(system.tau, system.history, system.derivative, t, x, v)


# ---------------------------------------------------------------------- residuals
@dataclass(frozen=True)
class Residuals:
    """The equation error in force units and its views."""

    time: np.ndarray
    residual: np.ndarray
    position: np.ndarray
    velocity: np.ndarray
    input: np.ndarray

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


def residuals(model: IdentifiedModel, experiment: Experiment) -> Residuals:
    """The equation error of ``model`` on ``experiment`` (see the module docstring); a
    record with gaps gives the errors of its gap-free runs one after another (each smoothed
    on its own: a smoothing window must not cross a gap)."""
    segments = experiment.segments()
    if len(segments) > 1:
        parts = [_residuals(model, s) for s in segments]
        return Residuals(*(np.concatenate([getattr(r, f) for r in parts])
                           for f in ("time", "residual", "position", "velocity", "input")))
    return _residuals(model, experiment)


def _residuals(model: IdentifiedModel, experiment: Experiment) -> Residuals:
    spec = model.spec
    y = experiment.output(spec.coordinate)
    w = savgol_window(y)
    x = savgol_filter(y, w, 3, mode="interp")
    v = savgol_filter(y, w, 3, deriv=1, delta=experiment.dt, mode="interp")
    a = savgol_filter(y, w, 3, deriv=2, delta=experiment.dt, mode="interp")
    system = model.system()
    states = {spec.coordinate: x, spec.coordinate + "'": v}
    u = spec.received_input(experiment)
    r = system.mass * a - u
    for term, c in zip(system.terms, np.atleast_1d(system.coefficients)):
        r = r + c * term.evaluate(states)
    r = r - _measured_feedback(system, experiment.time, x, v)
    known = np.isfinite(r)  # a measured history: rows whose delayed argument precedes the record are dropped
    return Residuals(experiment.time[known], r[known], x[known], v[known], u[known])


# ---------------------------------------------------------------------- diagnosis
@dataclass
class Diagnosis:
    """Candidate effects ranked by how much of the residual they explain."""

    ranking: pd.DataFrame
    groups: list[list[str]] = field(default_factory=list)
    residual: np.ndarray | None = None  # the model's (scaled) equation-error residual
    columns: dict[str, np.ndarray] = field(default_factory=dict)  # orthogonalised candidates

    def plot(self, top: int = 3):
        """Partial-residual (added-variable) plots of the top candidates."""
        from cvxid.plots import partial_residual_figure

        return partial_residual_figure(self, top)

    @property
    def top(self) -> str:
        """The best-scoring candidate (by validation drop when known, else by ERR; among
        collinear rivals, by the free run when :meth:`decided` was called)."""
        return str(self.ranking.index[0])

    def decided(self, fits: dict[str, float | None]) -> Diagnosis:
        """This diagnosis with collinear rivals decided by their test free-run fits
        (``fits``: rival -> fit %, None when its free run diverged): a ``free_run_fit``
        column, and the best rival first."""
        best = max(fits, key=lambda g: fits[g] if fits[g] is not None and np.isfinite(fits[g]) else -np.inf)
        ranking = self.ranking.assign(free_run_fit=pd.Series({g: np.nan if f is None else f for g, f in fits.items()},
                                                             dtype=float))
        ranking = pd.concat([ranking.loc[[best]], ranking.drop(index=best)])
        return replace(self, ranking=ranking)

    def records(self) -> list[dict]:
        out = []
        for name, row in self.ranking.iterrows():
            rec = {"effect": str(name)}
            rec.update({k: (None if pd.isna(v) else (float(v) if not isinstance(v, str) else v)) for k, v in row.items()})
            out.append(rec)
        return out

    def __repr__(self) -> str:
        text = "Diagnosis: missing effects, best first\n" + self.ranking.to_string(float_format=lambda v: f"{v:.4g}")
        shared = [g for g in self.groups if len(g) > 1]
        if shared:
            text += "\n  nearly collinear (the data cannot tell them apart by ERR alone): "
            text += "; ".join(" ~ ".join(g) for g in shared)
        if "free_run_fit" in self.ranking:
            text += ("\n  free_run_fit: the test record's free-run fit (%) of each collinear rival refitted; "
                     "the best is ranked first")
        return text


def default_candidates(spec: ModelSpec) -> list[str]:
    """The catalogue and the spec's own effects minus what the model already has
    (``delay``: for exact-delay models)."""
    exact = spec.delay is not None and spec.delay.exact
    return [name for name in {**CATALOGUE, **spec.effects} if missing(spec, name) and (name != "delay" or exact)]


def missing(spec: ModelSpec, name: str) -> bool:
    """Whether the effect or term ``name`` is missing from ``spec`` (an input delay is
    missing unless the spec has one, estimated or known)."""
    if name == "input_delay":
        return spec.input_delay is None
    return resolve_term(name, (spec.coordinate,), spec.effects).name not in spec.column_names


def _candidate_terms(spec: ModelSpec, candidates: Sequence[str]) -> dict[str, Term]:
    out = {}
    for name in candidates:
        if not missing(spec, name):
            continue
        term = resolve_term(name, (spec.coordinate,), spec.effects)
        if name == "input_delay":
            term = InputRate(spec.input)  # the received input's rate
        if name == "delay":
            if not (spec.delay is not None and spec.delay.exact):
                raise CvxidError("the 'delay' candidate needs a model with an exact delay ([model.delay] method = 'exact')")
            term = DelayedSignal(spec.delay.coordinate, spec.delay.derivative + 1)  # d/dtau of the feedback
        out[name] = term
    if not out:
        raise CvxidError("no candidate effect is missing from the model; nothing to diagnose")
    return out


def diagnose(
    model: IdentifiedModel,
    train: Experiment,
    test: Experiment | None = None,
    candidates: Sequence[str] | None = None,
    velocity: str = "savgol",
    window: float | str | None = "auto",
    builders: tuple[RegressionBuilder, RegressionBuilder | None] | None = None,
) -> Diagnosis:
    """Rank ``candidates`` (catalogue names or term names) missing from ``model``
    (``velocity`` and restart ``window`` as in :class:`~cvxid.regression.builder.RegressionBuilder`;
    ``builders`` of the train and test data may be passed to reuse their columns)."""
    spec = model.spec
    terms = _candidate_terms(spec, candidates if candidates is not None else default_candidates(spec))
    # the candidates are scored as candidates, a linear one too (kept, it would be in every refit)
    extended = replace(spec, library=spec.library + list(terms.values()), keep_linear=False)
    train_rows, test_rows = builders or (None, None)
    train_rows = _builder(spec, train, velocity, window, train_rows)
    reg = train_rows.at(model.tau, extended)
    names = list(reg.names)
    used = [names.index(n) for n in spec.column_names if model.coefficients.get(n, 0.0) != 0.0]
    scale = np.sqrt(np.mean(reg.P**2, axis=0))
    P, p = reg.P / scale, reg.p / np.sqrt(np.mean(reg.p**2))
    Q, _ = np.linalg.qr(P[:, used])
    r = p - Q @ (Q.T @ p)
    ortho, err = {}, {}
    for name, term in terms.items():
        g = P[:, names.index(term.name)]
        g = g - Q @ (Q.T @ g)
        ortho[name] = g
        err[name] = float((g @ r) ** 2 / max((g @ g) * (r @ r), 1e-300))
    drops = {}
    if test is not None:
        treg = _builder(spec, test, velocity, train_rows.window, test_rows).at(model.tau, extended)
        with warnings.catch_warnings():
            # a candidate may repeat a model column (the delay's derivative at tau = 0 is x'):
            # its ERR and its group say so, the rank warning would only alarm
            warnings.filterwarnings("ignore", message="the regression is rank-deficient", category=CvxidWarning)
            base = Problem.from_regression(reg, spec.nonnegative)
        mask = np.zeros(len(names), bool)
        mask[used] = True
        val_before = treg.mse(base.refit(mask).coefficients)
        for name, term in progress(terms.items(), "diagnosis: candidates", total=len(terms)):
            m2 = mask.copy()
            m2[names.index(term.name)] = True
            drops[name] = val_before / max(treg.mse(base.refit(m2).coefficients), 1e-300)
    ranking = pd.DataFrame(
        {
            "term": [terms[n].name for n in terms],
            "meaning": [terms[n].meaning for n in terms],
            "err": [err[n] for n in terms],
            "validation_ratio": [drops.get(n, np.nan) for n in terms],
        },
        index=pd.Index(list(terms), name="effect"),
    )
    key = "validation_ratio" if test is not None else "err"
    ranking = ranking.sort_values([key, "err"], ascending=False)
    return Diagnosis(ranking, _groups(ortho, list(ranking.index)), r, ortho)


def _groups(ortho: dict[str, np.ndarray], order: list[str]) -> list[list[str]]:
    groups: list[list[str]] = []
    for name in order:
        g = ortho[name]
        for group in groups:
            h = ortho[group[0]]
            corr = abs(g @ h) / max(np.linalg.norm(g) * np.linalg.norm(h), 1e-300)
            if corr > COLLINEAR:
                group.append(name)
                break
        else:
            groups.append([name])
    return groups


def with_effect(spec: ModelSpec, name: str) -> ModelSpec:
    """``spec`` with a catalogue effect (or a term) added, its sign constraint included."""
    if name == "delay":
        raise CvxidError("the delay is not added but estimated again: refit the model (refit() profiles tau)")
    if name == "input_delay":
        raise CvxidError("an input delay is not a term: give the spec one to estimate (with_input_delay)")
    term = resolve_term(name, (spec.coordinate,), spec.effects)
    if term.name in spec.column_names:
        raise CvxidError(f"the model already has {term.name} ({name})")
    nonneg = spec.nonnegative
    if name in {**CATALOGUE, **spec.effects} and effect(name, spec.effects).nonnegative:
        nonneg = nonneg + (term.name,)
    return replace(spec, library=spec.library + [term], nonnegative=nonneg)


def with_input_delay(spec: ModelSpec, train: Experiment) -> ModelSpec:
    """``spec`` with an input delay to estimate, from 0 to a quarter period of the training
    output's band edge (:func:`~cvxid.model.input_delay.default_bound`)."""
    return replace(spec, input_delay=InputDelay(0.0, 0.0, record_bound([train.output(spec.coordinate)], train.dt)))


# ---------------------------------------------------------------------- the loop
@dataclass(frozen=True)
class RefineStep:
    """One accepted addition and the errors around it."""

    added: str
    term: str
    group: list[str]
    inclusion: float
    """Its inclusion probability over halves of the training rows (the acceptance rule)."""
    test_mse_before: float
    test_mse_after: float
    fit_before: float | None
    fit_after: float | None

    def as_dict(self) -> dict:
        return dict(self.__dict__)


@dataclass
class Refinement:
    """The diagnose → add → refit loop: its steps, diagnoses and final model."""

    model: IdentifiedModel
    steps: list[RefineStep]
    diagnoses: list[Diagnosis]
    comparisons: list[Comparison] = field(default_factory=list)
    """The test record's free runs: the starting model's, then one after each added effect
    (empty when nothing was added)."""
    start: IdentifiedModel | None = None
    """The model the loop started from."""
    stopped: dict | None = None
    """Why the loop stopped at its last diagnosis's best candidate, when it did (not for
    lack of candidates or steps): ``effect``, ``validation_ratio``, whether the refitted
    model's test ``errors_fall`` (equation and simulation), and its ``inclusion``
    (null when an earlier condition failed first)."""

    def table(self) -> pd.DataFrame:
        return pd.DataFrame([s.as_dict() for s in self.steps]).set_index("added") if self.steps else pd.DataFrame()

    @property
    def labels(self) -> list[str]:
        """``start``, then ``+ effect`` for each added effect."""
        return ["start"] + [f"+ {s.added}" for s in self.steps]

    def plot(self):
        """The error history: the test record's equation-error MSE and free-run error
        (:math:`1 - \\text{fit}/100`) before and after each added effect."""
        from cvxid.plots import refinement_figure

        steps = self.steps
        if not steps:
            raise CvxidError("nothing to plot: the refinement added no effect")
        series = {"test equation-error MSE": [steps[0].test_mse_before] + [s.test_mse_after for s in steps]}
        fits = [steps[0].fit_before] + [s.fit_after for s in steps]
        if all(f is not None for f in fits):
            series["test free-run error (1 - fit)"] = [1.0 - f / 100.0 for f in fits]
        return refinement_figure(self.labels, series)

    def plot_responses(self):
        """The test record's free run before and after each added effect, over the
        measurement, one panel each (the fit in each title)."""
        from cvxid.plots import responses_figure

        if not self.comparisons:
            raise CvxidError("nothing to plot: the refinement added no effect")
        return responses_figure(self.labels, self.comparisons)

    def plot_residuals(self, experiment: Experiment, bins: int = 21):
        """Where the starting model fails: its equation error on ``experiment`` in time and
        binned against position and velocity (a step at x' = 0 is a dry friction, a slope
        in x a stiffness, a level an offset)."""
        if self.start is None:
            raise CvxidError("nothing to plot: this refinement does not know the model it started from")
        return residuals(self.start, experiment).plot(bins, title="where the starting model fails: its equation "
                                                                  f"error on '{experiment.name}'")

    def __repr__(self) -> str:
        head = "Refinement" if self.steps else "Refinement: nothing added"
        lines = [head] + ([self.table().to_string(float_format=lambda v: f"{v:.4g}")] if self.steps else [])
        if self.stopped is not None:
            lines.append(stop_reason(self.stopped))
        return "\n".join(lines)


def refit(spec: ModelSpec, train: Experiment, support: Sequence[str], tau: float | None,
          velocity: str = "savgol", lam: float = 0.0, window: float | str | None = "auto",
          builder: RegressionBuilder | None = None) -> IdentifiedModel:
    """Least squares of ``spec`` on the named columns (plus the unpenalised ones); an exact
    delay and an input delay to estimate are profiled again on that support (``builder``:
    the train data's, to reuse)."""
    family = _builder(spec, train, velocity, window, builder)
    names = spec.column_names
    mask = np.array([n in support for n in names]) | np.array([c.penalty == 0 for c in spec.columns])
    exact = spec.delay is not None and spec.delay.exact
    if exact:
        tau = profile_delay(family, support=mask, nonnegative=spec.nonnegative, model=spec).estimate
    if spec.input_delay is not None and spec.input_delay.free:  # then the fed-back delay again at it
        spec = spec.with_input_tau(profile_input_delay(family, spec, tau, mask, spec.nonnegative).estimate)
        if exact:
            tau = profile_delay(family, support=mask, nonnegative=spec.nonnegative, model=spec).estimate
    fit = Problem.from_regression(family.at(tau, spec), spec.nonnegative).refit(mask)
    coefs = {n: float(c) if m else 0.0 for n, c, m in zip(names, fit.coefficients, mask)}
    return IdentifiedModel(spec, coefs, lam, tau=tau)


def refine(
    model: IdentifiedModel,
    train: Experiment,
    test: Experiment,
    candidates: Sequence[str] | None = None,
    max_steps: int = 5,
    velocity: str = "savgol",
    window: float | str | None = "auto",
    builders: tuple[RegressionBuilder, RegressionBuilder] | None = None,
    selection: Selection | None = None,
) -> Refinement:
    """Repeat diagnose → add the best effect → refit while the best effect passes the
    acceptance rule of :mod:`cvxid.diagnosis.acceptance` (it lowers the test equation
    error, halves of the training rows keep choosing it, and the refitted model's test
    equation error and free run fall).  ``builders`` of the train and test data may be
    passed to reuse their columns.

    The refit keeps the model's terms and adds the effect's; with a ``selection`` and a
    library to select from, the library is selected anew beside the effect (kept, as a
    listed term): a term the first selection dropped may return, and one that only stood in
    for the missing effect may leave.  When the best candidate has collinear rivals (its
    group in :attr:`Diagnosis.groups`) that lower the test equation error too, each is
    refitted and the test record's free run chooses (:meth:`Diagnosis.decided`): the
    equation error cannot tell a quadratic from a cubic damping, a simulation can."""
    train_rows, test_rows = builders or (None, None)
    train_rows = _builder(model.spec, train, velocity, window, train_rows)
    test_rows = _builder(model.spec, test, velocity, train_rows.window, test_rows)
    steps, diagnoses, comparisons, start, stopped = [], [], [], model, None
    candidates = list(candidates) if candidates is not None else None
    for _ in progress(range(max_steps), "refine: diagnose, add, refit"):
        pool = candidates if candidates is not None else default_candidates(model.spec)
        pool = [c for c in pool if missing(model.spec, c)]
        if not pool:
            break
        dx = diagnose(model, train, test, pool, velocity, window, (train_rows, test_rows))
        diagnoses.append(dx)
        best = dx.top
        stopped = stopped_at(best, dx.ranking.loc[best, "validation_ratio"])
        if not dx.ranking.loc[best, "validation_ratio"] > 1:  # (NaN: no evidence either)
            break
        # (the model's test error and free run: those of the last accepted step, else computed once)
        before = steps[-1].test_mse_after if steps else _test_mse(model, test_rows)
        old_cmp = comparisons[-1] if comparisons else compare(model, test, initial="record")
        group = next(g for g in dx.groups if best in g)
        # the equation error cannot tell a collinear group's members apart: of those that
        # lower it, the free run of the test record chooses
        rivals = [best] if best in ("delay", "input_delay") else [
            g for g in group if g not in ("delay", "input_delay") and dx.ranking.loc[g, "validation_ratio"] > 1]
        tried = {g: _with_candidate(model, g, dx, train, velocity, window, train_rows, test_rows, selection)
                 for g in rivals}
        compared = {g: compare(m, test, initial="record") for g, m in tried.items()}
        if len(rivals) > 1:
            diagnoses[-1] = dx = dx.decided({g: c.fit_percent for g, c in compared.items()})
        best = dx.top
        new, new_cmp = tried[best], compared[best]
        after = _test_mse(new, test_rows)
        falls = after < before and _improvement(old_cmp, new_cmp) > 1  # (cheap: checked first)
        probability = _inclusion(model, new, best, dx, train_rows, test_rows) if falls else float("nan")
        stopped = stopped_at(best, dx.ranking.loc[best, "validation_ratio"], falls, probability)
        if not accepted(probability):
            break
        stopped = None
        steps.append(RefineStep(best, str(dx.ranking.loc[best, "term"]), group, probability, before, after,
                                old_cmp.fit_percent, new_cmp.fit_percent))
        comparisons += [new_cmp] if comparisons else [old_cmp, new_cmp]
        model = new
    return Refinement(model, steps, diagnoses, comparisons, start, stopped)


def _inclusion(before: IdentifiedModel, after: IdentifiedModel, name: str, dx: Diagnosis,
               train_rows: RegressionBuilder, test_rows: RegressionBuilder) -> float:
    """The candidate's inclusion probability (:func:`~cvxid.diagnosis.acceptance.inclusion`)
    in the model it joins: beside ``after``'s other terms and every unpenalised column, at
    ``after``'s delay.  A change of delay is tested where it would leave: its column beside
    ``before``'s terms, at ``before``'s delay."""
    term = str(dx.ranking.loc[name, "term"])
    if name in ("delay", "input_delay"):
        model = before
        spec = replace(before.spec, library=before.spec.library + list(_candidate_terms(before.spec, [name]).values()))
    else:
        model, spec = after, after.spec
    kept = [c.name for c in spec.columns if c.name != term
            and (c.penalty == 0 or model.coefficients.get(c.name, 0.0) != 0.0)]
    return inclusion(train_rows.at(model.tau, spec), test_rows.at(model.tau, spec), kept, [term], spec.nonnegative)


def _with_candidate(model: IdentifiedModel, name: str, dx: Diagnosis, train: Experiment, velocity: str,
                    window, train_rows: RegressionBuilder, test_rows: RegressionBuilder,
                    selection: Selection | None) -> IdentifiedModel:
    """``model`` refitted with the candidate ``name``: the delay or the input's delay
    estimated again on the same terms, or the effect's term added (and a library to select
    from selected anew beside it, with a ``selection``)."""
    support = [n for n, c in model.coefficients.items() if c != 0.0]
    if name == "delay":  # a wrong delay: estimate it again on the same terms
        return refit(model.spec, train, support, None, velocity, model.lam, window, train_rows)
    if name == "input_delay":  # the input acts late: estimate its delay on the same terms
        return refit(with_input_delay(model.spec, train), train, support, model.tau, velocity, model.lam, window,
                     train_rows)
    term = str(dx.ranking.loc[name, "term"])
    spec = with_effect(model.spec, name)
    if selection is not None and any(c.penalty > 0 for c in model.spec.columns):
        spec = replace(spec, listed=spec.listed + (term,))
        support = _selected_anew(spec, model.tau, train_rows, test_rows, selection)
    return refit(spec, train, support + [term], model.tau, velocity, model.lam, window, train_rows)


def _selected_anew(spec: ModelSpec, tau: float | None, train_rows: RegressionBuilder, test_rows: RegressionBuilder,
                   selection: Selection) -> list[str]:
    """The columns ``selection`` keeps of ``spec`` at the delay ``tau``, scored on the test rows."""
    problem = Problem.from_regression(train_rows.at(tau, spec), spec.nonnegative)
    keep = selection.choose(problem, validate=test_rows.at(tau, spec).residual).keep
    return [n for n, k in zip(problem.names, keep) if k]


def _improvement(old: Comparison, new: Comparison) -> float:
    """The larger factor by which the free-run or the k-step-ahead simulation error falls
    (a diverging simulation has an infinite error)."""
    def error(fit):
        return np.inf if fit is None else max(100.0 - fit, 1e-12)

    pairs = ((old.fit_percent, new.fit_percent), (old.k_step_fit_percent, new.k_step_fit_percent))
    with np.errstate(invalid="ignore"):
        ratios = np.array([error(a) / error(b) for a, b in pairs])
    return float(np.nanmax(np.where(np.isnan(ratios), 0.0, ratios)))


def _test_mse(model: IdentifiedModel, test_rows: RegressionBuilder) -> float:
    reg = test_rows.at(model.tau, model.spec)
    return reg.mse(np.array([model.coefficients[n] for n in reg.names]))


def _builder(spec: ModelSpec, experiment: Experiment, velocity: str, window: float | str | None,
             given: RegressionBuilder | None) -> RegressionBuilder:
    """The builder passed in, or a new one for ``spec`` on ``experiment``."""
    return given if given is not None else RegressionBuilder(spec, experiment, velocity, window)
