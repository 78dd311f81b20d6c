r"""Output-error polish: from the convex estimate to the least simulation error, for
:math:`N \ge 1` coordinates.

Starting from an identified system and its support, every equation's inertia, the
coefficients of its selected terms and an unknown feedback gain, the shared delay
:math:`\tau` and each experiment's initial state :math:`(q_0, \dot q_0)` of every
coordinate are adjusted to minimise

.. math::

    \sum_{e,i,k} \big(q_{i,\mathrm{measured}}^{(e)}(t_k)
        - q_{i,\mathrm{simulated}}^{(e)}(t_k;\theta)\big)^2

with scipy's ``least_squares`` (ties between columns hold: a tied coefficient is a
multiple of its partner).  The equation-error estimate is biased by noise in the velocity
columns and by nearly collinear columns; the simulation error is not, because only the
measured coordinates are compared.  The Jacobian (forward differences, central in
:math:`\tau`) needs one simulation per parameter: they run as one batch through the
compiled integrator, so a Jacobian costs about one simulation's Python overhead.  With the measured history
(:mod:`cvxid.regression.history`) every simulation starts at :math:`t_0 + \tau_{\max}` from
the measured past, so the simulation error is smooth in :math:`\tau` and so is its
derivative.  The simulation uses a step of about ``step``
seconds (a whole number of samples), which keeps RK4 accurate while the record is long,
and is compared with every measured sample, interpolated between its steps
(:func:`between_steps`).
Standard errors come from the Jacobian at the optimum, :math:`\sigma^2 (J^T J)^{-1}\, n/n_{\rm eff}`,
where :math:`n_{\rm eff}` counts the independent residuals (their autocorrelation, as in
the delay profile): a model error or a smoothed measurement colours the residual, and
white-noise standard errors would then be far too small.  The polish's final fit adds the
spread that the noise on the measured inputs gives (:func:`input_noise_covariance`, from
synthetic noise records of each input's own noise level): the residual shows that noise
only in part, and on long records of lightly damped systems it dominates.

Parameters are physical (a Taylor delay's shares are written back into its columns).  For
one equation they are named ``m``, the terms' physical names, ``tau``, ``gain``, ``x0`` and
``v0``; for several, ``"coordinate:column"``, ``tau``, ``"coordinate:gain"`` and
``"q0[e]"``, ``"q'0[e]"`` for experiment ``e``.  An input delay to estimate
(:mod:`cvxid.model.input_delay`) is ``tau_u``: the simulation reads the input through a
cubic spline of the record at :math:`t - \tau_u`, so the error is smooth in it and its
derivative is a central difference.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, replace
from typing import Sequence

import numpy as np
import pandas as pd
from scipy.interpolate import CubicSpline
from scipy.ndimage import uniform_filter1d
from scipy.optimize import least_squares
from scipy.stats import chi2, norm

from cvxid.data.experiment import Experiment
from cvxid.data.remembered import remembered
from cvxid.errors import CvxidError, CvxidWarning
from cvxid.identified import IdentifiedModel, IdentifiedSystem
from cvxid.identify.aliases import LongerDelay, alias_starts, with_gain_sign
from cvxid.identify.profile import DelayProfile, effective_rows
from cvxid.metrics import SpectralPeak, band_period, measurement_noise, spectral_peak
from cvxid.model.symbols import velocity_symbol
from cvxid.parallel import one_blas_thread
from cvxid.progress import progress
from cvxid.regression.history import simulation_start
from cvxid.regression.velocity import initial_state
from cvxid.regression.builder import usable_segments
from cvxid.regression.windows import history_seconds
from cvxid.simulate import SimulationDiverged, delay_substeps, half_steps, hermite_weights, integrate, substeps_for

JACOBIAN_STEP = 1e-5
"""Relative step of the finite-difference Jacobian."""
AT_BOUND = 1e-6
"""How near its bound, as a share of its natural size in the data's units
(:func:`typical_states`), a parameter is held there (:func:`linearisation`)."""
PRESSED = 1e-8
r"""... and how large its gradient :math:`J_i^T r`, as a share of :math:`\|J_i\|\,\|r\|`,
must be to press it there (round-off does not)."""
GRADIENT_TOLERANCE = 1e-8
"""The solver's gradient test (scipy's ``gtol``, absolute: in the squared units of the
residual) on residuals divided by the power of two nearest the outputs' spread: in
micrometres the absolute test stopped every fit at its start.  (Divided by the spread
itself, the residuals' rounding moved the fits' paths at ordinary scales: a coupled
system's fit with a candidate added stopped at 6 times its noise level; scaling the
tolerance instead fell below the machine's epsilon, which scipy disables.)"""
STEP_FLOOR = 1e-3
"""The smallest size a parameter's finite-difference step is relative to, as a share of
the parameter's natural size in the data's units (:func:`typical_states`): a state's
spread, a coefficient's force per unit of its term, a delay's band period
(:func:`~cvxid.metrics.band_period`).  (An absolute floor of 1e-3 left a coefficient that
starts at 0 unmoved in data written in micrometres, and a delay near 0 at the round-off of
a slow plant's.)"""
GRID = 21
"""Delays of the output-error profile across ``[tau_min, tau_max]``, more in a narrow-band
record (:data:`SPACING`; then a finer grid around its best point).  The simulation error
has local minima in :math:`\tau`, and with an unknown gain whole ranges of delays fit
equally well: a local fit cannot see either."""
PROFILE_ITERATIONS = 12
"""Iterations of each fixed-delay fit of the profile (warm-started from its neighbour)."""

BOUND_SNAP = 1e-9
"""A parameter this close to one of its bounds is reported at the bound (the solver keeps
its iterates strictly inside, e.g. a delay of 1e-10 for 0)."""

REPAIR = 2.0
"""A profile point whose simulation RMS is more than this many times its neighbour's
towards the best is fitted again from that neighbour (a walk that started far from the
data, e.g. from a runaway gain, leaves stranded fits behind it)."""

MIN_COMPARED = 2000
"""The fewest steps the coarse fits (the polish's delay profile and first fit, the stepwise
search's) simulate.  The polish's compare every sample (:func:`between_steps`), the
search's the steps' own (:class:`Step`); when this cap was set, every coarse fit compared
the steps' own samples, and their step of about ``coarse_step`` seconds was a cost cap for a densely sampled record,
not a time scale of the plant, and in a plant 100 times faster than a second (0.12 s
records at 100 kHz) it kept 120 samples, the intervals four times wider; 1,000 times
faster, 12 samples and every profile fit diverged.  (5,000 made the stepwise search's
ranking fits, on twice the step, compare every sample of an 8 s record at 1 kHz instead of
every second: slower, and another path on a tuning system.)"""
FINE = 7
"""Delays of the finer grid around the profile's best point (between its two neighbours)."""

EDGE_RESOLUTION = 0.5
"""The profile's points around each edge of the delay's interval are at most this share of
the interval's width apart (:func:`_resolve_edges`; the chord between them, convex
below it, puts the edge at most about a sixteenth of the width inside)."""
EDGE_EXCESS = 4.0
"""... and the outside one's squared error exceeds the bound by at most this many times the
bound's own margin over the least (a quadratic profile's point half a width past the edge:
3; a point far above it is a steep rise the chord misplaces)."""
BISECTIONS = 3
"""Points added at most at each edge of the delay's interval (the gap shrinks 8-fold)."""
RESTARTS = 2
"""Times at most the polish fits every parameter again from a profile point that fits better
than its estimate, by more than :data:`RESTART_SHARE` of the margin of the interval's bound
over the least squared error (the points its interval's edges added; a stick-slip friction's
simulation error bends at every switch, and a local fit stops short: held-out tuning seed
17, Coulomb friction, 46 s, stopped at a delay 4.5 % short where the profile's edge found a
point 16 noise units of squared error lower; from there 0.9 % from the truth)."""
RESTART_SHARE = 0.25
"""A profile point that fits better than the estimate by less than this share of the
interval's margin moves the estimate by little within its interval, and is not worth a fit
of every parameter."""

INPUT_NOISE_DRAWS = 8
"""Synthetic noise records of the measured inputs from which :func:`input_noise_covariance`
estimates the spread that the inputs' noise gives the parameters."""
DIVERGED = 1e6
"""The residual a diverged simulation is filled with, in units of the records' largest
output when that is more than 1 (:attr:`_Problem.wall`): a fixed 1e6 was less than the
residual of a good fit of a record in micrometres, 1e9 times larger, and every profile
fit read as diverged."""
ROUGH_STEP = 10.0
"""How many times longer a step the final fit's second Jacobian takes (see :data:`ROUGH`)."""
ROUGH = 1.25
"""The largest factor between standard errors from the two Jacobians of the final fit
before they are said to depend on the step (the larger of each pair is then reported)."""


@dataclass(frozen=True)
class PolishResult:
    """The polished system, its parameter table and how the fit went."""

    system: IdentifiedSystem
    parameters: dict[str, float]
    standard_errors: dict[str, float]
    rms_before: float
    rms_after: float
    initial: tuple[dict[str, tuple[float, float]], ...]  # per experiment: coordinate -> (position, velocity)
    iterations: int
    seconds: float
    profile: DelayProfile | None = None  # the output-error profile over the delay
    effective_rows: float = 0.0  # independent residuals (their autocorrelation)
    jacobian_spread: float = 1.0  # standard errors' largest change with a 10x longer derivative step (1: smooth)
    jacobian_spread_at: str = ""  # the parameter whose standard error changes most
    input_noise_inflation: float = 1.0  # the delay's variance with the inputs' noise / from the residual alone
    # (both from the solver's Jacobian, whichever standard error is reported)
    states: frozenset = frozenset()  # the names of the initial-state parameters among ``parameters``
    longer_delay: LongerDelay | None = None  # a delay past the search range that fits better (its alias is this)

    def __repr__(self) -> str:
        shown = [n for n in self.parameters if n not in self.states]
        frame = pd.DataFrame({"estimate": [self.parameters[n] for n in shown],
                              "std error": [self.standard_errors.get(n, np.nan) for n in shown],
                              "95 % low": [self.interval(n)[0] for n in shown],
                              "95 % high": [self.interval(n)[1] for n in shown]},
                             index=pd.Index(shown, name="parameter"))
        return (f"PolishResult (output-error polish): simulation RMS {self.rms_before:.4g} -> {self.rms_after:.4g} "
                f"in {self.iterations} iterations, {self.seconds:.1f} s"
                + ("" if self.profile is None else ", the delay profiled") + "\n"
                + frame.to_string(float_format=lambda v: f"{v:.5g}"))

    @property
    def model(self) -> IdentifiedModel:
        """The polished equation (a system of one)."""
        if self.system.single is None:
            raise CvxidError("a coupled polish has several models: use .system")
        return self.system.single

    @property
    def x0(self) -> float:
        return next(iter(self.initial[0].values()))[0]

    @property
    def v0(self) -> float:
        return next(iter(self.initial[0].values()))[1]

    def summary(self) -> str:
        """One line: the simulation error before and after, the time, and whether the
        standard errors depend on the finite-difference step (see :data:`ROUGH`)."""
        before, after = (f"{v:.4g}" if np.isfinite(v) else "diverged" for v in (self.rms_before, self.rms_after))
        line = f"output-error polish: simulation RMS {before} -> {after} in {self.seconds:.1f} s"
        if self.jacobian_spread > ROUGH:
            line += (f"; standard errors depend on the finite-difference step (up to {self.jacobian_spread:.2g}x "
                     f"for {self.jacobian_spread_at}): the larger of the two are reported")
        return line

    def interval(self, name: str, z: float = 1.96) -> tuple[float, float]:
        """The 95 % interval (``z`` = 1.96: the standard error's part; the profile's is its
        95 % set) from the standard error, hulled with the delay's profile (when there is
        one) and kept within a delay's bounds:

        * the delay: the hull of that and of the profile's interval (every delay whose
          refitted simulation error is not significantly worse);
        * every other parameter: the hull of that and of its interval at each of those
          delays (refitted there, its standard error with the delay held), the profile's
          projection.  Where the delay trades with a parameter (a free gain against the
          stiffness, a delay against a damping) the local standard error sees one point of
          a long valley and its interval can miss the truth by many standard errors; the
          profile walks the valley, and at each delay the parameters that trade with one
          another (a free gain with the stiffness) keep their own spread."""
        value, se = self.parameters[name], self.standard_errors[name]
        low, high = value - z * se, value + z * se
        if self.profile is not None:  # (a standard error that is NaN leaves the profile's part)
            part = self.profile.ranges.get(name, self.profile.interval if name == "tau" else (low, high))
            low, high = np.nanmin([low, part[0]]), np.nanmax([high, part[1]])
            if not np.isfinite(se) and not high > low:  # (the value alone, no interval: a twelfth outside check's
                low = high = np.nan                     # diverged fit gave m [0.000379, 0.000379] in result.json)
        if name == "tau_u":  # within the input delay's bounds
            delay = next(m.spec.input_delay for m in self.system.models.values() if m.spec.input_delay is not None)
        elif name == "tau":  # within the delays searched
            delay = next(iter(self.system.specs.values())).delay
        else:
            return float(low), float(high)
        return max(float(low), delay.tau_min), min(float(high), delay.tau_max)


    def physical_interval(self, name: str, z: float = 1.96) -> tuple[float, float]:
        """:meth:`interval` in the physical parameter's sign: a coefficient the spec names
        negated (``k_s = "-alpha"``) has its interval negated, as its physical value is
        (:attr:`parameters` hold the coefficients)."""
        low, high = self.interval(name, z)
        return (-high, -low) if self.negated(name) else (low, high)

    def negated(self, name: str) -> bool:
        """Whether the parameter ``name`` (a physical name, or ``label:column`` in a coupled
        system) is minus its coefficient."""
        for label, model in self.system.models.items():
            for term in model.spec.library.names:
                physical, sign = model.spec.named_parameter(term)
                if sign < 0 and name in (physical, f"{label}:{term}"):
                    return True
        return False


def _experiments(experiments: Experiment | Sequence[Experiment], shortest: float = 0.0) -> list[Experiment]:
    """The records as stretches whose inputs are known (a simulation cannot cross a gap of
    its input, and runs through one of the outputs alone:
    :meth:`~cvxid.data.experiment.Experiment.driven`), each with its own initial state;
    with gaps, stretches shorter than ``shortest`` seconds are left out.  (Split at every
    gap of the outputs too, a dropout of 20 samples gave each stretch a free initial state
    that traded with the damping and the delay: on held-out tuning systems one in the
    middle of an 8 s record took the median delay error from 0.8 to 2.1 %.)"""
    return usable_segments([experiments] if isinstance(experiments, Experiment) else list(experiments), shortest,
                           Experiment.driven)


def _shortest(system: IdentifiedSystem) -> float:
    """The shortest gap-free stretch a polish uses: twice ``tau_max`` with an exact delay
    (its measured history and as long again), else any (:class:`_Problem` still asks for
    20 simulated samples)."""
    return 2 * history_seconds(next(iter(system.specs.values())))


PROFILE_PHASE = 0.05
r"""The phase :math:`\omega_{95} h` of one step of the polish's coarse fits (the delay
profile, the first fit) at the records' band edge (RK4's error there about
:math:`(\omega h)^5/120` a step); their step was 1 ms whatever the plant: every sample of
a 1 kHz record, 60 s of a plant with a 5 s period took 57 s to polish (an eleventh outside
check).  The last fit is at the sample step."""


def profile_step(system: IdentifiedSystem, experiments: list[Experiment]) -> float:
    r"""The polish's coarse step for ``experiments``: :data:`PROFILE_PHASE` over the
    highest band edge of the coordinates' records (:func:`~cvxid.metrics.band_period`), at
    least the sample step (the fits simulate at least :data:`MIN_COMPARED` steps whatever
    it is, :func:`_stride`).  On the held-out diagnosis benchmark (100 systems, report
    seeds) the estimates and intervals were those of the 1 ms step within a few digits,
    the benchmark 31 % faster."""
    return max(experiments[0].dt, PROFILE_PHASE * _band_period(system, experiments) / (2 * np.pi))


def _band_period(system: IdentifiedSystem, experiments) -> float:
    """The shortest band period of the coordinates' records (:func:`~cvxid.metrics.band_period`),
    each computed once per record (:func:`~cvxid.data.remembered.remembered`)."""
    return min(remembered(e, ("band period", tuple(system.coordinates)),
                          lambda e=e: band_period([e.output(c) for c in system.coordinates], e.dt))
               for e in experiments)


@one_blas_thread
def polish(fitted: IdentifiedModel | IdentifiedSystem, experiments, coarse_step: float | Step | None = None,
           final: bool = True, max_iterations: int = 200, grid: int = GRID, final_iterations: int = 50,
           initial=None) -> PolishResult:
    """Output-error polish.  With a fed-back delay, first its profile: the simulation
    error refitted at ``grid`` delays (more in a narrow-band record, whose basins are then
    fitted with the delay free: :func:`_grid`, :func:`_basin_fits`) across
    ``[tau_min, tau_max]`` (each fit warm-started
    from its neighbour, on a simulation step of about ``coarse_step``, by default
    :func:`profile_step` of the records) and on a finer grid
    around the best; then every parameter from the best delay, refined at the sample step
    with ``final_iterations`` more (unless ``final`` is false), and again from a profile
    point that the profile's refined edges find to fit better (:data:`RESTARTS`).
    ``grid = 0`` fits from the estimated delay only.  ``initial``: each experiment's
    starting states (see :func:`output_error`)."""
    start = time.perf_counter()
    system, given = IdentifiedSystem.of(fitted), initial
    experiments = _experiments(experiments, _shortest(system))
    coarse_step = profile_step(system, experiments) if coarse_step is None else coarse_step
    start_from = without_cancelling_gain(system) if grid else system
    points = _delay_profile(start_from, experiments, initial, coarse_step, grid) if grid else {}
    if points:
        tau = min(points, key=lambda t: points[t][0])
        origin = with_tau(points[tau][1].system, tau)
        initial = points[tau][1].initial
    else:
        origin = system
    try:
        best = output_error(origin, experiments, initial, step=coarse_step, max_iterations=max_iterations,
                            input_noise=not final)
    except CvxidError as exc:
        raise CvxidError(f"the output-error polish failed ({exc})") from exc
    before = output_rms(system, experiments)
    if points and not best.rms_after <= before:  # the profile's basin fits worse than the start: fit from the start
        try:
            own = output_error(system, experiments, given, step=coarse_step, max_iterations=max_iterations,
                               input_noise=not final)
        except CvxidError:
            own = None
        if own is not None and own.rms_after < best.rms_after:
            best = own
    best, level = _finished(best, experiments, coarse_step, final, final_iterations)
    profile = None
    if points:
        for restart in range(RESTARTS + 1):
            points[level.parameters["tau"]] = (level.rms_after, level)
            _resolve_edges(points, best, experiments, coarse_step)
            _, rms, bound, _ = _inside(points, best)
            lowest = points[min(points, key=lambda t: points[t][0])][1]
            if level.rms_after**2 - rms.min() ** 2 <= RESTART_SHARE * (bound - rms.min() ** 2) or restart == RESTARTS:
                break
            try:  # a profile point fits better than the estimate: every parameter again from there
                again = _finished(output_error(lowest.system, experiments, lowest.initial, step=coarse_step,
                                               max_iterations=max_iterations, input_noise=not final),
                                  experiments, coarse_step, final, final_iterations)
            except CvxidError:
                break
            if not again[1].rms_after < level.rms_after:
                break
            best, level = again
        profile = _interval(points, best)
    if not best.rms_after <= before:
        tried = "from the delay profile's best delay and from the start's own" if points else "from the start"
        warnings.warn(
            f"the output-error polish ended with a larger simulation error than its start (RMS {before:.4g} -> "
            f"{best.rms_after:.4g}), fitted {tried}: the simulation error has another basin the fit cannot leave "
            "(an estimated gain trading with the stiffness?); read the polished model with care, or give the gain "
            "([model.delay] gain)", CvxidWarning, stacklevel=2)
    return replace(best, rms_before=before, seconds=time.perf_counter() - start, profile=profile)


def _finished(fit: PolishResult, experiments, coarse_step: float | Step, final: bool, iterations: int):
    """The polish's last fit from ``fit`` (at the sample step with ``iterations`` more when
    ``final``), and the fit on the delay profile's own simulation step that the profile is
    read against (the last fit itself when the sample step is the profile's step)."""
    if not final:
        return fit, fit
    last = output_error(fit.system, experiments, fit.initial, step=experiments[0].dt, max_iterations=iterations,
                        input_noise=True)
    return last, last if _stride(coarse_step, experiments) == 1 else fit


SMOOTHING_PERIODS = 0.05
"""The moving average that :func:`typical_states` differentiates spans this share of the
period at the output's band edge (a scale of the velocity, not an estimate of it)."""


def typical_states(experiment: Experiment, start: int, coordinates, period: float) -> dict[str, np.ndarray]:
    """Every coordinate's measured position, and the slope of its moving average over
    :data:`SMOOTHING_PERIODS` of ``period`` (the record's :func:`~cvxid.metrics.band_period`),
    from sample ``start`` on: the states the parameters' natural sizes are read from (two
    passes over the record: a Savitzky–Golay velocity with its noise-adapted window took
    10 s on 192,000 samples at 20 kHz)."""
    width = max(1, int(round(SMOOTHING_PERIODS * period / experiment.dt)))
    states = {}
    for c in coordinates:
        y = experiment.output(c)[start:]
        finite = np.where(np.isfinite(y), y, np.nanmean(y))
        smooth = uniform_filter1d(finite, min(width, finite.size))
        states[c], states[velocity_symbol(c)] = finite, np.gradient(smooth, experiment.dt)
    return states


def typical_size(values) -> float:
    """The root mean square of ``values``, 1 where it is 0 or not finite (no size to read)."""
    rms = float(np.sqrt(np.mean(np.square(values))))
    return rms if np.isfinite(rms) and rms > 0 else 1.0


def typical_spread(values) -> float:
    """The standard deviation of ``values``, their NaN gaps left out; 1 where it is 0 or
    not finite (no size to read): an input's natural size."""
    finite = np.asarray(values, float)
    finite = finite[np.isfinite(finite)]
    spread = float(np.std(finite)) if finite.size else 0.0
    return spread if np.isfinite(spread) and spread > 0 else 1.0


def natural_inertia(force: float, position: float, period: float) -> float:
    r"""An inertia's natural size in the data's units, :math:`\sigma_f / (\omega^2
    \sigma_x)` with :math:`\omega = 2\pi / T` (``period``: the record's band period,
    ``force`` and ``position`` the input's and the output's spreads): the inertia whose
    force at the record's fastest motion is the input's size."""
    return force * (period / (2 * np.pi)) ** 2 / position


INERTIA_FLOOR = 1e-9
"""The output-error polish's lower bound of an inertia, in the data's units (a bound of
1e-9 of :func:`natural_inertia` sent one of ``duffing_delay``'s stepwise candidate fits
down another path: six more steps, 5.5 s for 3.7 s, the same model; a true inertia below
1e-9 in the data's units is not reached)."""
TINY = np.finfo(float).tiny
"""The least inertia a simulation is given (a tied inertia's product may round below its
bound)."""


@dataclass(frozen=True)
class Step:
    """A fit's simulation step of about ``seconds``, compared with the steps' own samples
    alone: cheaper where a record is sampled far above its band (the stepwise search's
    many fits of the paper's 5 kHz record: 6 s a run, 10.5 s comparing every sample).  A
    step given as a plain number compares every sample (:func:`between_steps`)."""

    seconds: float


def _stride(step: float | Step, experiments: list[Experiment]) -> int:
    """Samples per simulation step of about ``step``, at least 1, and at most what leaves
    :data:`MIN_COMPARED` steps in the records."""
    seconds = step.seconds if isinstance(step, Step) else step
    return max(1, min(int(round(seconds / experiments[0].dt)), sum(e.n for e in experiments) // MIN_COMPARED))


def _profile_fit(origin: IdentifiedSystem, tau: float, experiments, states, step: float | Step) -> PolishResult | None:
    """The profile's fit at the fixed delay ``tau``, started from ``origin`` (a neighbour's
    fit) and ``states``; where that start's simulation diverges (its estimated gain unstable
    at this delay), started again from its net model with a small gain
    (:func:`without_cancelling_gain`).  None when the fit fails."""
    try:
        fit = output_error(with_tau(origin, tau), experiments, states, step=step,
                           max_iterations=PROFILE_ITERATIONS, fixed_tau=tau)
        if not np.isfinite(fit.rms_after) and any(estimated_gain(m) for m in origin.models.values()):
            fit = output_error(without_cancelling_gain(with_tau(origin, tau), every=True), experiments, None,
                               step=step, max_iterations=PROFILE_ITERATIONS, fixed_tau=tau)
        elif any(_cancelling(m) for m in fit.system.models.values()):
            # a gain that cancels its signal's coefficient holds the walk in that valley: its net model with a
            # small gain is tried as well, and the better fit kept (a tenth outside check's 50 Hz record, the
            # gain free: every fit of the walk at k -245, gain -250, while from the truth's side the
            # simulation error at 0.15 s is lower, k 7.4, gain 2.9, for 6 and 1.5)
            other = output_error(without_cancelling_gain(fit.system), experiments, None, step=step,
                                 max_iterations=PROFILE_ITERATIONS, fixed_tau=tau)
            fit = other if other.rms_after < fit.rms_after else fit
    except CvxidError:
        return None
    return fit


SPACING = 1 / 8
"""In a narrow-band record (:func:`narrow_band`) the output-error profile's delays are at
most this share of its band period apart (:func:`~cvxid.metrics.band_period`: its basins
are as narrow as its highest frequencies make them), at least :data:`GRID` of them, at
most :data:`MAX_GRID`: its simulation error has basins half a period apart
(:mod:`cvxid.identify.aliases`), and a grid coarser than that steps over the true one (the
chatter benchmark's tuning seed 5: 0.03 s apart at a band period of 0.10 s, the delay 14 %
off in another basin; ``examples/narrow_band_delays.py``)."""
MAX_GRID = 81


def _grid(system: IdentifiedSystem, experiments, least: int) -> int:
    """The profile's delays: ``least``, or in a narrow-band record (:func:`narrow_band`)
    as many as leave them :data:`SPACING` of the records' band period apart (at most
    :data:`MAX_GRID`)."""
    if narrow_band(system, experiments) is None:
        return least
    delay = next(iter(system.specs.values())).delay
    spacing = SPACING * _band_period(system, experiments)
    return max(least, min(MAX_GRID, int(np.ceil((delay.tau_max - delay.tau_min) / spacing)) + 1))


def _delay_profile(system: IdentifiedSystem, experiments, initial, step: float | Step, grid: int) -> dict:
    """Delay -> (simulation RMS, fit) with every other parameter refitted, on ``grid``
    delays across the delay's range walked outwards from the estimate (each fit starts from
    its neighbour's, :func:`_profile_fit`), the stranded ones refitted from their
    neighbour towards the best and from its net model with a small gain (:data:`REPAIR`,
    :func:`_repair_starts`), a narrow-band record's basins fitted with
    the delay free (:func:`_basin_fits`), then on a finer grid around the best.
    Empty without a fed-back delay."""
    delay = next(iter(system.specs.values())).delay
    numeric = [m.system() for m in system.models.values()]
    if delay is None or not any(float(s.gain) or float(s.rate_gain) for s in numeric):
        return {}
    taus = np.linspace(delay.tau_min, delay.tau_max, _grid(system, experiments, grid))
    grid = taus.size
    first = system.tau if system.tau is not None else system.physical.get("tau", taus[0])
    points: dict[float, tuple[float, PolishResult]] = {}
    bar = progress(desc="polish: output-error delay profile", total=grid + FINE)

    def walk(sequence, origin, states):
        for tau in sequence:
            bar.update()
            fit = _profile_fit(origin, tau, experiments, states, step)
            if fit is None:
                continue
            points[float(tau)] = (fit.rms_after, fit)
            if np.isfinite(fit.rms_after):  # (a diverged fit, an infinite error, is no start for the next delay)
                origin, states = fit.system, fit.initial

    i = int(np.argmin(np.abs(taus - first)))
    walk(taus[i:], system, initial)
    walk(taus[:i][::-1], system, initial)
    if not points:
        raise CvxidError("the output-error polish failed at every delay of its profile (diverging simulations)")
    best = min(points, key=lambda t: points[t][0])
    for side in (-1, 1):  # each point far worse than its neighbour towards the best: again from that neighbour
        inner = best
        for tau in sorted((t for t in points if (t - best) * side > 0), key=lambda t: abs(t - best)):
            near = points[inner][1]
            for origin in _repair_starts(near.system):  # (until the point is no longer stranded)
                if points[tau][0] <= REPAIR * points[inner][0]:
                    break
                fit = _profile_fit(origin, tau, experiments, near.initial, step)
                if fit is not None and fit.rms_after < points[tau][0]:
                    points[tau] = (fit.rms_after, fit)
            if np.isfinite(points[tau][0]):  # (a diverged point is no start, nor a measure, for the next)
                inner = tau
    _basin_fits(points, experiments, step)
    best = min(points, key=lambda t: points[t][0])
    spacing = taus[1] - taus[0] if grid > 1 else 0.0
    fine = np.linspace(max(best - spacing, delay.tau_min), min(best + spacing, delay.tau_max), FINE + 2)[1:-1]
    walk([t for t in fine if t > best], points[best][1].system, points[best][1].initial)
    walk([t for t in fine[::-1] if t < best], points[best][1].system, points[best][1].initial)
    bar.close()
    return points


def _repair_starts(near: IdentifiedSystem):
    """The starts a stranded profile point is fitted again from: its neighbour towards the
    best, then, where a gain is estimated, the neighbour's net model with a small gain
    (:func:`without_cancelling_gain`): a fourteenth outside check's nearly undamped plant
    walked the profile along a gain of -61 (k -36), whose fits past 0.043 s stalled at 400
    times the noise, while at its true delay of 0.05 s a gain of 0.5 (k 25) fits to the
    noise; the delay's interval closed below the truth and nothing was said."""
    yield near
    if any(estimated_gain(m) for m in near.models.values()):
        yield without_cancelling_gain(near, every=True)


ALIAS_ITERATIONS = 30
"""Iterations of each fit with the delay free from a basin of the profile (:func:`_basin_fits`)
or an alias past its range (:func:`longer_delay`)."""


def _peak(system: IdentifiedSystem, experiments) -> SpectralPeak:
    """The spectral peak of the fed-back coordinate's first record (:func:`~cvxid.metrics.spectral_peak`)."""
    coordinate, e = next(iter(system.specs.values())).delay.coordinate, experiments[0]
    return remembered(e, ("spectral peak", coordinate), lambda: spectral_peak(e.output(coordinate), e.dt))


NARROW_SHARE = 0.3
"""A record is narrow-band when this share of its variance (or more) lies near its spectral
peak (:func:`~cvxid.metrics.spectral_peak`): 0.40–1.0 on the chatter benchmark's 20
records (``examples/narrow_band_delays.py``, tuning and report seeds), 0.13 on a stranger's
fast plant driven by a chirp and sines (whose profile's 81 delays and basins' fits took 2.4
times as long for the same estimate).  The held-out benchmark's oscillators hold 0–0.93,
but their periods are seconds: the range (0.5 s) spans half of one on few of them."""


def narrow_band(system: IdentifiedSystem, experiments) -> SpectralPeak | None:
    """The records' spectral peak when the delay's aliases matter (:mod:`cvxid.identify.aliases`):
    one equation, a narrow-band response (:data:`NARROW_SHARE`) and a delay range that spans
    half its peak period or more; else None."""
    delay = next(iter(system.specs.values())).delay
    if system.single is None or delay is None:
        return None
    peak = _peak(system, experiments)
    return peak if peak.share >= NARROW_SHARE and delay.tau_max - delay.tau_min >= peak.period / 2 else None


BASINS = 8
"""Local minima of a narrow-band record's output-error profile fitted with the delay free,
the lowest first (:func:`_basin_fits`)."""


def _basin_fits(points: dict, experiments, step: float | Step) -> None:
    """In a narrow-band record (:func:`narrow_band`), fits with the delay free from the
    profile's local minima (at most :data:`BASINS`, the lowest first; a plateau's points
    are none), each added to the profile at the delay it reaches (the least simulation error
    near that delay, as a fixed-delay point's is at its own; the other parameters' standard
    errors then count the delay's spread too, a wider hull).  The profile's fits are short
    (:data:`PROFILE_ITERATIONS`) and start from their neighbour: where the simulation error
    has narrow basins half a period apart they stop at different depths of their basins,
    and the lowest profile point need not be in the lowest basin (a twelfth outside check:
    0.561 s reported, with the gain's sign flipped, where 0.72 fitted better; the chatter
    benchmark's tuning seed 9: 0.290 for 0.205)."""
    best = min(points, key=lambda t: points[t][0])
    if narrow_band(points[best][1].system, experiments) is None:
        return
    taus = np.array(sorted(points))
    rms = np.array([points[t][0] for t in taus])
    left, right = np.concatenate([[np.inf], rms[:-1]]), np.concatenate([rms[1:], [np.inf]])
    minima = np.flatnonzero(np.isfinite(rms) & (rms <= left) & (rms <= right) & ((rms < left) | (rms < right)))
    for i in minima[np.argsort(rms[minima])][:BASINS]:
        near = points[taus[i]][1]
        try:
            again = output_error(near.system, experiments, near.initial, step=step, max_iterations=ALIAS_ITERATIONS)
        except CvxidError:
            continue
        at = float(again.parameters["tau"])
        if np.isfinite(again.rms_after) and (at not in points or again.rms_after < points[at][0]):
            points[at] = (again.rms_after, again)


LONGEST_SHARE = 0.5
"""A delay past the search range is looked for only where the shortest record holds this
share of itself after the delay (the simulations start that late)."""


def longer_delay(best: PolishResult, experiments) -> LongerDelay | None:
    """A delay past the search range whose fit simulates the training records better than
    ``best``'s beyond chance, in a narrow-band record (:func:`narrow_band`): the aliases of
    ``best``'s delay up to two periods past it (:data:`~cvxid.identify.aliases.BEYOND`)
    that lie past the range's top, each fitted with the delay free above the top, against
    ``best`` refitted at its own delay, on the same samples (those a simulation with the
    longest alias can start from), the same step and iterations.  Beyond chance: the
    profile's likelihood-ratio bound (:func:`_inside`) at a 5 % level shared by the aliases
    tried (Bonferroni), on the refit's effective rows; and at least an eighth of a period
    past the top (a fit that slid back to the top is the range's own).  Only where each
    record holds :data:`LONGEST_SHARE` of itself after the longest alias.  The run calls it
    on its final polish (``cvxid.app.run``)."""
    system = best.system
    peak = narrow_band(system, experiments) if np.isfinite(best.rms_after) and "tau" in best.parameters else None
    if peak is None:
        return None
    delay, tau, period = system.single.spec.delay, best.parameters["tau"], peak.period
    shortest = min(e.time[-1] - e.time[0] for e in experiments)
    starts = alias_starts(tau, period, delay.tau_max + period / 8, (1 - LONGEST_SHARE) * shortest - period / 4,
                          delay.gain is None)
    if not starts:
        return None
    step = profile_step(system, experiments)
    reach = max(a for a, _ in starts) + period / 4
    try:
        estimate = output_error(_with_delay(system, replace(delay, tau_max=reach)), experiments, None, step=step,
                                max_iterations=ALIAS_ITERATIONS, fixed_tau=tau)
    except CvxidError:
        return None
    if not np.isfinite(estimate.rms_after):
        return None
    past = _with_delay(system, replace(delay, tau_min=delay.tau_max, tau_max=reach))
    chance = 1 + best.input_noise_inflation * chi2.ppf(1 - 0.05 / len(starts), 1) / estimate.effective_rows
    found = None
    for alias, sign in starts:
        try:
            fit = output_error(with_gain_sign(with_tau(past, alias), sign), experiments, None, step=step,
                               max_iterations=ALIAS_ITERATIONS)
        except CvxidError:
            continue
        better = fit.rms_after**2 * chance < estimate.rms_after**2 and fit.parameters["tau"] >= \
            delay.tau_max + period / 8
        if better and (found is None or fit.rms_after < found.rms_after):
            found = fit
    if found is None:
        return None
    return LongerDelay(float(found.parameters["tau"]), found.parameters.get("gain"), found.rms_after,
                       estimate.rms_after, period, delay.tau_max)


def _with_delay(system: IdentifiedSystem, delay) -> IdentifiedSystem:
    """``system`` with each equation's delay specification ``delay`` (a wider range)."""
    return replace(system, models={label: replace(m, spec=replace(m.spec, delay=delay))
                                   for label, m in system.models.items()})


def _interval(points: dict, best: PolishResult, level: float = 0.95) -> DelayProfile:
    r"""The profile's delays whose refitted squared simulation error stays within
    :math:`\kappa\,\chi^2_1(\text{level})/n_{\rm eff}` of its least (hull, linear
    crossings); each other parameter's range is the hull of its refits there (± their
    standard errors) and of its values at the crossings, interpolated the same way between
    the two fits on either side.  Every point is on the profile's own simulation step (a record sampled
    faster than that step has a slightly different error at its sample step, and the two
    must not be compared).  :math:`\kappa` is the best fit's
    ``input_noise_inflation``: the noise on the measured inputs spreads the delay
    :math:`\kappa` times as much as the residual says, and the profile's likelihood ratio,
    read in the residual's units, is :math:`\kappa\,\chi^2_1` distributed (to first
    order)."""
    taus, rms, bound, inside = _inside(points, best, level)
    tau = best.parameters["tau"]
    fits = [points[t][1] for t in taus[inside]]
    z = float(norm.ppf(0.5 + level / 2))

    def spread(fit, name):  # (a standard error that is not finite leaves the value)
        se = fit.standard_errors.get(name, 0.0)
        return z * se if np.isfinite(se) else 0.0

    def crossing(i, j):  # from inside point i towards outside neighbour j: the delay there, the share of the way
        if j < 0 or j >= taus.size:
            return taus[i], 0.0
        if not np.isfinite(rms[j]):  # its fit diverged: no measure of where the bound is crossed, up to it
            return taus[j], float("nan")
        a, b = rms[i] ** 2, rms[j] ** 2
        share = (bound - a) / (b - a) if b > a else 1.0
        return taus[i] + (taus[j] - taus[i]) * share, share

    (low, low_share), (high, high_share) = crossing(inside[0], inside[0] - 1), crossing(inside[-1], inside[-1] + 1)

    def edges(name):  # each parameter where the delay's interval ends, between the same two fits (a tenth
        #              outside check: c 0.929, 0.814 … 1.044, for 0.8, the delay's interval reaching 0.077 for
        #              0.08: the inside fits ended at 0.082)
        out = []
        for i, j, share in ((inside[0], inside[0] - 1, low_share), (inside[-1], inside[-1] + 1, high_share)):
            if share > 0:  # (0 at the profile's end, NaN beside a diverged fit: nothing to interpolate)
                near, far = points[taus[i]][1], points[taus[j]][1]
                if name in far.parameters:
                    value = near.parameters[name] + share * (far.parameters[name] - near.parameters[name])
                    out += [value - spread(near, name), value + spread(near, name)]
        return out

    ranges = {}
    for name in best.parameters:
        if name != "tau" and all(name in f.parameters for f in fits):
            ends = [f.parameters[name] + side * spread(f, name) for f in fits for side in (-1, 1)] + edges(name)
            ranges[name] = (min(ends), max(ends))
    return DelayProfile(taus, rms, tau, (float(min(low, tau)), float(max(high, tau))), best.effective_rows,
                        "output_error", ranges)


def _inside(points: dict, best: PolishResult, level: float = 0.95):
    """The profile's delays and RMS errors in order, the bound on the squared error of
    :func:`_interval` and the indices of the delays within it."""
    taus = np.array(sorted(points))
    rms = np.array([points[t][0] for t in taus])
    bound = rms.min() ** 2 * (1 + best.input_noise_inflation * chi2.ppf(level, 1) / best.effective_rows)
    return taus, rms, bound, np.flatnonzero(rms**2 <= bound)  # (the least point at least)


def _resolve_edges(points: dict, best: PolishResult, experiments, step: float | Step) -> None:
    """Add profile points (:func:`_profile_fit`, from the nearest point inside) halfway
    between each edge of the interval's inside points and its outside neighbour until they
    are at most :data:`EDGE_RESOLUTION` of the interval's width apart and the outside one
    at most :data:`EDGE_EXCESS` margins above the bound (at most :data:`BISECTIONS` a
    side, never closer than two samples): a profile whose points are coarse
    against its interval reads the edge from a chord, and on a profile flat over a long
    stretch that ends steeply (a gain that trades with the delay) that chord put the edge
    next to the estimate, far inside."""
    shortest = experiments[0].dt  # (the delay moves smoothly within a step: the samples, not the step, resolve it)
    for side in (-1, 1):
        for _ in range(BISECTIONS):
            taus, rms, bound, inside = _inside(points, best)
            edge = inside[0] if side < 0 else inside[-1]
            if not 0 <= edge + side < taus.size:
                break
            low, high = _interval(points, best).interval
            gap = abs(taus[edge + side] - taus[edge])
            close = gap <= EDGE_RESOLUTION * (high - low)
            if gap < 2 * shortest or close and rms[edge + side] ** 2 - bound <= EDGE_EXCESS * (bound - rms.min() ** 2):
                break
            near = points[taus[edge]][1]
            fit = _profile_fit(near.system, 0.5 * (taus[edge] + taus[edge + side]), experiments, near.initial, step)
            if fit is None:
                break
            points[float(fit.parameters["tau"])] = (fit.rms_after, fit)


def output_rms(fitted: IdentifiedModel | IdentifiedSystem, experiments) -> float:
    """Root-mean-square free-run simulation error of every coordinate on the experiments
    (from the states estimated at their starts; inf if a simulation diverges)."""
    system = IdentifiedSystem.of(fitted)
    errors = []
    for e in _experiments(experiments):
        try:
            sim = system.simulate(e.filled())
        except SimulationDiverged:
            return float("inf")
        errors += [(sim[c] - e.output(c))[np.isfinite(sim[c]) & np.isfinite(e.output(c))] for c in system.coordinates]
    return float(np.sqrt(np.mean(np.concatenate(errors) ** 2)))


CANCELLING = 0.05
r"""An estimated feedback gain :math:`b` and the coefficient :math:`k` of its own signal
cancel when :math:`|k - b|` is under this share of the larger: a short delay's
:math:`x(t-\tau)` and :math:`x` fitted by equation error as nearly one column with huge
opposite coefficients (an outside check: :math:`1275\,x` against :math:`1271\,x(t - 0.02)`
for a truth of 5 and 1.2), a basin of the simulation error the polish could not leave."""


SMALL_GAIN = 0.1
"""The feedback gain a cancelling fit restarts from, as a share of its net stiffness."""


def estimated_gains(model: IdentifiedModel) -> list[tuple[str, str, float]]:
    """(signal, its delayed column, the estimated gain) of each fed-back signal of
    ``model`` whose gain is estimated and that is a library term too (the delayed column
    carries minus the gain): the position, and with the paper's feedback its velocity."""
    spec = model.spec
    if spec.delay is None:
        return []
    return [(signal, term.name, -model.coefficients.get(term.name, 0.0))
            for signal, term in zip(spec.delay.signals, spec.delayed_terms) if signal in spec.confounded_signals]


def estimated_gain(model: IdentifiedModel) -> float | None:
    """The first of :func:`estimated_gains` (None: no delay, the gains given, or no fed-back
    signal that is a library term, whose gain then trades with no coefficient)."""
    found = estimated_gains(model)
    return found[0][2] if found else None


def _cancelling(model: IdentifiedModel) -> list[tuple[str, str, float]]:
    """The :func:`estimated_gains` of ``model`` that nearly cancel the coefficient of their
    own signal (:data:`CANCELLING`)."""
    out = []
    for signal, column, gain in estimated_gains(model):
        k = model.coefficients.get(signal, 0.0)
        if abs(k - gain) < CANCELLING * max(abs(k), abs(gain)):
            out.append((signal, column, gain))
    return out


def cancelling_gain(model: IdentifiedModel) -> float | None:
    """The estimated feedback gain of ``model``'s fed-back position when it and the
    coefficient of its own signal nearly cancel (:data:`CANCELLING`), else None."""
    return next((gain for signal, _, gain in _cancelling(model) if signal == model.spec.confounded_signal), None)


def without_cancelling_gain(fitted: IdentifiedModel | IdentifiedSystem, every: bool = False) -> IdentifiedSystem:
    r"""A start for the polish: each estimated gain that cancels its signal's coefficient
    (:func:`_cancelling`) as the net model with a small feedback,

    .. math:: (k - b + b_0)\,x + (c + (b - b_0)\,\tau)\,\dot x = \dots + b_0\,x(t - \tau),
              \qquad b_0 = \beta\,|k - b|\,\mathrm{sign}\,b,

    from :math:`b\,x(t-\tau) \approx b\,x - b\,\tau\,\dot x` (:math:`\beta` =
    :data:`SMALL_GAIN`; a fed-back velocity's gain likewise against the damping, its share
    of the inertia :math:`b_1\tau`); the delay profile's fits then size the gain at each
    delay.  The others as they are; with ``every``, every estimated gain (the profile's
    restart where its neighbour's gain makes the simulation diverge)."""
    system = IdentifiedSystem.of(fitted)
    models = {}
    for label, model in system.models.items():
        restarted = estimated_gains(model) if every else _cancelling(model)
        coefs = dict(model.coefficients)
        for signal, column, gain in restarted:
            small = SMALL_GAIN * (abs(coefs[signal] - gain) or abs(gain)) * np.sign(gain)  # (never 0: it is profiled)
            rate = signal + "'"
            if rate in coefs and system.tau is not None:
                coefs[rate] = coefs[rate] + (gain - small) * system.tau
            coefs[signal] = coefs[signal] - gain + small
            coefs[column] = -small
        models[label] = IdentifiedModel(model.spec, coefs, model.lam, dict(model.info), model.tau) if restarted \
            else model
    return replace(system, models=models)


def with_tau(fitted: IdentifiedModel | IdentifiedSystem, tau: float):
    """``fitted`` with its physical parameters kept and the delay set to ``tau`` (a Taylor
    model's delay shares rewritten into its columns)."""
    if isinstance(fitted, IdentifiedModel):
        system = fitted.system()
        params = {fitted.spec.parameter_name(t.name): c for t, c in zip(system.terms, np.atleast_1d(system.coefficients))}
        params["m"] = float(system.mass)
        params["tau"] = float(tau)
        return _updated(fitted, system, params)
    models = {label: with_tau(m, tau) for label, m in fitted.models.items()}
    return replace(fitted, models=models, tau=float(tau) if fitted.tau is not None else None)


@one_blas_thread
def output_error(fitted: IdentifiedModel | IdentifiedSystem, experiments, initial=None, step: float | Step = 1e-3,
                 max_iterations: int = 30, fixed_tau: float | None = None, input_noise: bool = False) -> PolishResult:
    """Polish ``fitted`` on ``experiments`` by output error from its own delay (see the
    module docstring; :func:`polish` profiles the delay first).  ``initial``: each
    experiment's starting states (coordinate → (position, velocity)), estimated from the
    data by default; ``fixed_tau``: keep the delay at this value; ``input_noise``: the
    standard errors include the spread from the measured inputs' noise
    (:func:`input_noise_covariance`)."""
    start = time.perf_counter()
    system = IdentifiedSystem.of(fitted)
    problem = _Problem(system, _experiments(experiments, _shortest(system)), step, initial, fixed_tau)
    cache: dict[bytes, np.ndarray] = {}

    def fun(theta):
        key = theta.tobytes()
        if key not in cache:
            cache.clear()
            cache[key] = problem.residuals(theta[None, :])[:, 0]
        return cache[key]

    central = [problem.names.index(n) for n in ("tau", "tau_u") if n in problem.names]

    def jac(theta, relative=JACOBIAN_STEP):  # forward differences, central in the delay
        h = relative * np.maximum(np.abs(theta), STEP_FLOOR * problem.natural)
        steps = np.diag(h)
        here = cache.get(theta.tobytes())  # the solver asks at the point it has just evaluated
        if here is not None and not problem.same_steps(theta, theta - steps[central]):
            here = None  # the batch reaches a shorter delay, integrated in more sub-steps
        if here is None:
            r = problem.residuals(np.vstack([theta, theta + steps, theta - steps[central]]))
        else:
            r = np.column_stack([here, problem.residuals(np.vstack([theta + steps, theta - steps[central]]))])
        cache.clear()
        cache[theta.tobytes()] = r[:, 0]
        k = theta.size
        J = (r[:, 1:k + 1] - r[:, :1]) / h
        J[:, central] = (r[:, 1:k + 1][:, central] - r[:, k + 1:]) / (2 * h[central])
        return J

    before = float(np.sqrt(np.mean(fun(problem.start) ** 2)))
    scale = 2.0 ** np.round(np.log2(problem.scale))  # (a power of two: every iterate the same, in other units)
    sol = least_squares(lambda theta: fun(theta) / scale, problem.start, jac=lambda theta: jac(theta) / scale,
                        bounds=problem.bounds, method="trf", x_scale="jac", max_nfev=max_iterations,
                        gtol=GRADIENT_TOLERANCE)
    jacobian = sol.jac * scale
    lower, upper = problem.bounds  # the solver stays strictly inside: a bound it reached is the bound
    theta = np.where(np.abs(sol.x - lower) <= BOUND_SNAP, lower, np.where(np.abs(sol.x - upper) <= BOUND_SNAP,
                                                                          upper, sol.x))
    r = fun(theta)
    after = float(np.sqrt(np.mean(r**2))) if not np.any(r == problem.wall) else float("inf")  # (not the fill's RMS)
    n_eff = effective_rows(r)
    extra = input_noise_covariance(problem, theta, r, jacobian) if input_noise else None
    errors = dict(zip(problem.names, map(float, standard_errors(jacobian, r, n_eff, extra))))
    inflation, spread, at = 1.0, 1.0, ""
    if input_noise:  # the final fit
        alone = standard_errors(jacobian, r, n_eff)  # from the residual alone
        if extra is not None and "tau" in problem.names and alone[problem.names.index("tau")] > 0:
            inflation = float((errors["tau"] / alone[problem.names.index("tau")]) ** 2)
        coarse = jac(theta, ROUGH_STEP * JACOBIAN_STEP)  # are its standard errors those of a smooth simulation?
        spread, at = _jacobian_spread(problem, standard_errors(coarse, r, n_eff), alone)
        if spread > ROUGH:  # the derivative depends on its step: the larger errors (see summary())
            errors = {n: float(np.fmax(e, c))
                      for (n, e), c in zip(errors.items(), standard_errors(coarse, r, n_eff, extra))}
    errors.update({a: abs(f) * errors[b] for a, (b, f) in problem.tied.items()})
    if fixed_tau is not None and problem.delay is not None:
        errors["tau"] = 0.0
    return PolishResult(problem.result(theta), problem.values(theta), errors, before, after,
                        problem.initial(theta), int(sol.nfev), time.perf_counter() - start,
                        effective_rows=n_eff, states=frozenset(problem.state_names), jacobian_spread=spread,
                        jacobian_spread_at=at, input_noise_inflation=inflation)


def _jacobian_spread(problem: "_Problem", coarse: np.ndarray, fine: np.ndarray) -> tuple[float, str]:
    r"""The largest factor between the model parameters' standard errors ``fine`` (from the
    solver's Jacobian) and ``coarse`` (from one at a step :data:`ROUGH_STEP` times longer),
    and the parameter it is found at.  A simulation smooth and well
    conditioned in its parameters gives the same derivatives at both steps (measured:
    within 1.03 on 60 tuning systems without friction, the feedback gain known).  A friction
    that switched inside a step bent the simulation error at every switch, and its
    derivatives depended on the scale they were taken at (factors 1.0–6.4 on 20 report
    systems with Coulomb friction; 4–17 with a Stribeck friction); since the integrator
    splits its steps where sliding stops, within 1.016.  A nearly singular fit (a free gain
    that trades with the stiffness) moves them (1.29 on tuning seed 1 without friction)."""
    keep = [i for i, n in enumerate(problem.names) if n not in problem.state_names]
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = coarse[keep] / fine[keep]
        factor = np.where(np.isfinite(ratio) & (ratio > 0), np.maximum(ratio, 1 / ratio), np.nan)
    if not np.any(np.isfinite(factor)):
        return 1.0, ""
    i = int(np.nanargmax(factor))
    return float(factor[i]), problem.names[keep[i]]


def standard_errors(jacobian: np.ndarray, residual: np.ndarray, n_eff: float | None = None,
                    extra: np.ndarray | None = None) -> np.ndarray:
    r"""The parameters' standard errors from the simulation residual :math:`r` and its
    Jacobian :math:`J`,

    .. math:: \operatorname{se} = \sqrt{\operatorname{diag}\big(\hat\sigma^2 (J^T J)^{-1}\,
       n / n_{\rm eff} + \Sigma_u\big)}, \qquad \hat\sigma^2 = \frac{r^T r}{n - p},

    where :math:`n_{\rm eff}` counts the independent residuals (coloured residuals carry
    fewer than they have; :func:`~cvxid.identify.profile.effective_rows` by default) and
    :math:`\Sigma_u` (``extra``, zero by default) is the covariance from the inputs' noise
    (:func:`input_noise_covariance`).  A parameter that moves nothing (a delay below the
    simulator's resolution) and a singular :math:`J^T J` give NaN."""
    r = np.asarray(residual, float)
    n_eff = effective_rows(r) if n_eff is None else n_eff
    se = np.full(jacobian.shape[1], np.nan)
    seen = np.any(jacobian != 0, axis=0)
    dof = max(r.size - jacobian.shape[1], 1)
    try:
        J = jacobian[:, seen]
        cov = np.linalg.inv(J.T @ J) * float(r @ r) / dof * r.size / n_eff
        if extra is not None:
            cov = cov + extra[np.ix_(seen, seen)]
        se[seen] = np.sqrt(np.clip(np.diag(cov), 0, None))
    except np.linalg.LinAlgError:
        pass
    return se


def delay_standard_error(fitted: IdentifiedModel | IdentifiedSystem, experiments, tau: float, initial=None) -> float:
    r"""The standard error of the delay that an output-error fit would report at the delay
    ``tau``: every other parameter (and each experiment's initial state) refitted with the
    delay held at ``tau``, then the standard error of :func:`standard_errors` from the
    Jacobian there, the delay free, plus the spread from the inputs' noise
    (:func:`input_noise_covariance`).  At the true delay it is the asymptotic spread of an
    output-error estimate of :math:`\tau` on this record (a local linearisation, with the
    output's noise level estimated from the residual; the Cramér–Rao bound when the noise
    is white and on the output alone): ``cvxid bench --heldout`` compares each error with it."""
    step = _experiments(experiments, _shortest(IdentifiedSystem.of(fitted)))[0].dt
    fit = output_error(with_tau(fitted, tau), experiments, initial, step=step, max_iterations=100, fixed_tau=tau)
    problem = _problem_at(fit.system, experiments, fit.initial, None)
    if "tau" not in problem.names:
        raise CvxidError("delay_standard_error: the model has no fed-back delay to estimate")
    r, J = _linearise(problem)
    se = standard_errors(J, r, extra=input_noise_covariance(problem, problem.start, r, J))
    return float(se[problem.names.index("tau")])


def input_noise_covariance(problem: "_Problem", theta: np.ndarray, residual: np.ndarray, jacobian: np.ndarray,
                           draws: int = INPUT_NOISE_DRAWS) -> np.ndarray | None:
    r"""The covariance that the noise on the measured inputs gives the fitted parameters.

    The simulation reads the measured input :math:`u + n`, so its residual (simulated minus
    measured, ``residual`` at ``theta``, Jacobian :math:`J`) carries the model's response
    :math:`G_\theta n`, and to first order the fit moves by
    :math:`\delta = -(J^T J)^{-1} J^T G_\theta n`.  The residual at the optimum shows that
    response only in part: the fit absorbs what lies along the columns of :math:`J`, and a
    lightly damped system's response to force noise sits at its resonance, where those
    columns are too.  So :math:`n` is drawn ``draws`` times as white noise of the level each
    input the model reads carries (:func:`~cvxid.metrics.noise_level`), each draw simulated
    at ``theta``, and

    .. math:: \Sigma_u = \frac{1}{K} \sum_k \delta_k \delta_k^T .

    * An upper estimate: the part of :math:`G_\theta n` the fit leaves in the residual is
      counted by :func:`standard_errors` as well.  With :data:`INPUT_NOISE_DRAWS` draws
      its standard errors carry a sampling error of about 25 %.
    * An input whose white "noise" exceeds :data:`~cvxid.metrics.INPUT_NOISE_SHARE` of its standard
      deviation is taken as broadband excitation (white noise, a PRBS), not as noise on a
      smooth signal, and left out: :func:`~cvxid.metrics.noise_level` cannot tell the two
      apart.
    * A draw whose simulation diverges is left out.

    Seeded: the same record gives the same errors.  None when no input counts."""
    experiments = problem.records
    read = {m.spec.input_column for m in problem.base.models.values()}
    levels = []
    for e in experiments:
        each = {name: measurement_noise(e.inputs[name]) for name in read & set(e.inputs)}  # (as sampled: a held one too)
        levels.append({n: v for n, v in each.items() if v > 0})
    if not any(levels):
        return None
    seen = np.any(jacobian != 0, axis=0)
    try:
        influence = np.zeros((theta.size, jacobian.shape[0]))
        influence[seen] = -np.linalg.solve(jacobian[:, seen].T @ jacobian[:, seen], jacobian[:, seen].T)
    except np.linalg.LinAlgError:
        return None
    rng = np.random.default_rng(0)
    step = experiments[0].dt * problem.stride if problem.every else Step(experiments[0].dt * problem.stride)
    moves = []
    for _ in range(draws):
        noisy = [replace(e, inputs={**e.inputs, **{name: e.inputs[name] + level * rng.standard_normal(e.time.size)
                                                   for name, level in each.items()}})
                 for e, each in zip(experiments, levels)]
        again = _Problem(problem.base, noisy, step, problem.initial(theta), problem.fixed_tau)
        response = again.residuals(theta[None, :])[:, 0] - residual
        if np.all(np.isfinite(response)) and np.max(np.abs(response), initial=0.0) < problem.wall / 2:
            moves.append(influence @ response)
    if not moves:
        return None
    moves = np.array(moves)
    return moves.T @ moves / len(moves)


def linearisation(fitted: IdentifiedModel | IdentifiedSystem, experiments, initial=None,
                  step: float | Step | None = None, pressed: bool = True) -> tuple[list[str], np.ndarray, np.ndarray]:
    """The simulation residual at ``fitted``'s own parameters and its forward-difference
    Jacobian, with the parameters' names (as :func:`output_error` names them): one batch
    of simulations.  ``step``: the simulation step (the sample step by default).

    Unless ``pressed`` is false, a parameter held at a bound that the simulation error
    presses against (its gradient :math:`J^T r` points out of the bounds: the fit would move
    it past) is left out, name and column: it is not free, and a score test that projected a
    new column on it would credit it with moving where it cannot (an outside check's delay
    held at ``tau_min`` absorbed most of a late input's column and hid it).  Dropping it
    understates, slightly, a candidate that would pull it back inside (a conservative
    test)."""
    problem = _problem_at(fitted, experiments, initial, step)
    r, J = _linearise(problem)
    free = ~_pressed(problem, r, J) if pressed else np.ones(len(problem.names), bool)
    return [n for n, f in zip(problem.names, free) if f], r, J[:, free]


def _pressed(problem: "_Problem", r: np.ndarray, J: np.ndarray) -> np.ndarray:
    """Which parameters sit at a bound (within :data:`AT_BOUND` of their natural size) that
    the simulation error's gradient :math:`J^T r` presses them against."""
    lower, upper = problem.bounds
    theta, gradient, near = problem.start, J.T @ r, AT_BOUND * problem.natural
    firm = np.abs(gradient) > PRESSED * np.linalg.norm(J, axis=0) * np.linalg.norm(r)
    return firm & (((theta <= lower + near) & (gradient > 0)) | ((theta >= upper - near) & (gradient < 0)))


def _linearise(problem: "_Problem") -> tuple[np.ndarray, np.ndarray]:
    """The residual at ``problem``'s start and its forward-difference Jacobian."""
    theta = problem.start
    h = JACOBIAN_STEP * np.maximum(np.abs(theta), STEP_FLOOR * problem.natural)
    r = problem.residuals(np.vstack([theta, theta + np.diag(h)]))
    return r[:, 0], (r[:, 1:] - r[:, :1]) / h


def residual(fitted: IdentifiedModel | IdentifiedSystem, experiments, initial=None,
             step: float | Step | None = None) -> np.ndarray:
    """The simulation residual of :func:`linearisation` alone (one simulation)."""
    problem = _problem_at(fitted, experiments, initial, step)
    return problem.residuals(problem.start[None, :])[:, 0]


def _problem_at(fitted, experiments, initial, step) -> "_Problem":
    system = IdentifiedSystem.of(fitted)
    experiments = _experiments(experiments, _shortest(system))
    return _Problem(system, experiments, step or experiments[0].dt, initial)


def between_steps(X: np.ndarray, V: np.ndarray, stride: int, h: float) -> np.ndarray:
    r"""Positions ``X`` ``(m, C, B)`` at steps of ``h``, with their velocities ``V``, at
    every sample between them (``stride`` samples a step; ``(stride (m - 1) + 1, C, B)``)
    by the cubic Hermite interpolant, whose error, :math:`(\omega h)^4/384` of the motion,
    is below RK4's own.  A coarse simulation is so compared with every measured sample:
    compared at its steps alone, the delay profile of 8 s records at a 4 ms step lost three
    quarters of the data, and on held-out systems whose delay is weakly determined it
    moved to another basin."""
    if stride == 1:
        return X
    w = hermite_weights(np.arange(stride) / stride, h)[:, :, None, None]  # (the integrator's own basis)
    inner = w[:, 0] * X[:-1, None] + w[:, 1] * V[:-1, None] + w[:, 2] * X[1:, None] + w[:, 3] * V[1:, None]
    return np.concatenate([inner.reshape(-1, *X.shape[1:]), X[-1:]])


def _rooted(tied: dict[str, tuple[str, float]]) -> dict[str, tuple[str, float]]:
    """Ties ``left -> (right, factor)`` with every chain followed to its free end (``a = 2 b``
    and ``b = 3 c`` give ``a = 6 c``): each tied parameter a multiple of a fitted one."""
    out = {}
    for a, (b, f) in tied.items():
        seen = {a}
        while b in tied and b not in seen:
            seen.add(b)
            b, f = tied[b][0], f * tied[b][1]
        out[a] = (b, f)
    return out


class _Problem:
    """Parameters ↔ simulations of the system for :func:`output_error`."""

    def __init__(self, system: IdentifiedSystem, experiments: list[Experiment], step: float | Step, initial,
                 fixed_tau: float | None = None):
        self.records = experiments  # (as given: a gap of the outputs is compared where measured)
        measured = [{c: np.isfinite(e.output(c)) for c in system.coordinates} for e in experiments]
        experiments = [e.filled() for e in experiments]
        self.base, self.experiments = system, experiments
        self._inputs: dict[tuple, np.ndarray] = {}  # each experiment's inputs at the RK4 nodes
        self.one = system.single is not None
        self.stride = _stride(step, experiments)
        self.every = not isinstance(step, Step)  # every sample compared (else the steps' own)
        self.systems = {label: m.system() for label, m in system.models.items()}
        self.coordinates = system.coordinates
        gains = [float(g) for s in self.systems.values() for g in (s.gain, s.rate_gain)]
        delay = next(iter(system.specs.values())).delay
        self.delay = delay if delay is not None and any(gains) else None
        self.fixed_tau = fixed_tau if self.delay is not None else None
        history = next(iter(self.systems.values())).history
        past = None if self.delay is None else (self.delay.tau_max, self.delay.coordinate, self.delay.orders,
                                                self.delay.history)
        self.starts, self.pasts = zip(*(remembered(e, ("start", past, history),
                                                   lambda e=e: simulation_start(e, self.delay, history))
                                        for e in experiments))
        self.substeps = [remembered(e, ("substeps", tuple(self.coordinates), k, self.stride), lambda e=e, k=k: max(
            substeps_for(e.output(c)[k::self.stride], e.dt * self.stride) for c in self.coordinates))
                         for e, k in zip(experiments, self.starts)]
        for e, k in zip(experiments, self.starts):
            if e.time[k::self.stride].size < 20:
                raise CvxidError(f"experiment '{e.name}' is too short for the output-error polish")
        # every sample from the start to the last simulated step is compared (between steps, by interpolation)
        self.spans = [self.stride * (e.time[k::self.stride].size - 1) + 1 for e, k in zip(experiments, self.starts)]
        self.compared = 1 if self.every else self.stride  # (samples a comparison steps over)
        compared = (np.column_stack([m[c][k:k + n:self.compared] for c in self.coordinates])
                    for m, k, n in zip(measured, self.starts, self.spans))
        self.measured = [None if seen.all() else seen for seen in compared]  # (samples, coordinates); None: every one
        largest = max(float(np.nanmax(np.abs(e.output(c)), initial=0.0)) for e in experiments for c in self.coordinates)
        self.wall = DIVERGED * max(1.0, largest)  # a diverged simulation's residual (:data:`DIVERGED`)
        coefficients = system.coefficients
        periods = [remembered(e, ("period", tuple(self.coordinates), k),
                              lambda e=e, k=k: band_period([e.output(c)[k:] for c in self.coordinates], e.dt))
                   for e, k in zip(experiments, self.starts)]
        measured = [remembered(e, ("typical", tuple(self.coordinates), k),
                               lambda e=e, k=k, p=p: typical_states(e, k, self.coordinates, p))
                    for e, k, p in zip(experiments, self.starts, periods)]
        typical, period = measured[0], periods[0]
        columns = {}  # system column -> parameter slot
        names, start, lower, natural, gains = [], [], [], [], []  # gains: (label, name, natural size) of each free one
        for label, model in system.models.items():
            spec, s = model.spec, self.systems[label]
            if spec.inertia:
                columns[system.column(label, spec.inertia_term.name)] = self._name(label, "m", spec.inertia_term.name)
            for term in s.terms:
                columns[system.column(label, term.name)] = self._name(label, spec.parameter_name(term.name), term.name)
            if self.delay is not None:
                for name, term, free in zip(spec.gain_names, spec.delayed_terms, spec.delay.estimated):
                    if free:
                        columns[system.column(label, term.name)] = self._name(label, name, name)
        self.tied = _rooted({columns[a]: (columns[b], f) for a, b, f in system.ties
                             if a in columns and b in columns and coefficients.get(a) and coefficients.get(b)})
        for label, model in system.models.items():
            spec, s = model.spec, self.systems[label]
            force = typical_spread(spec.received_input(experiments[0])[self.starts[0]:])
            if spec.inertia:
                names.append(self._name(label, "m", spec.inertia_term.name))
                start.append(float(s.mass))
                lower.append(INERTIA_FLOOR)
                natural.append(abs(float(s.mass)))
            for term, c in zip(s.terms, np.atleast_1d(s.coefficients)):
                names.append(self._name(label, spec.parameter_name(term.name), term.name))
                start.append(float(c))
                lower.append(0.0 if term.name in spec.nonnegative else -np.inf)  # the spec's signs hold
                natural.append(force / remembered(experiments[0], ("size", term, tuple(self.coordinates), self.starts[0]),
                                                  lambda term=term: typical_size(term.evaluate(typical))))
            if self.delay is not None:
                signals = (self.delay.coordinate, velocity_symbol(self.delay.coordinate))
                for name, signal, free in zip(spec.gain_names, signals, spec.delay.estimated):
                    if free:
                        gains.append((label, name, self._name(label, name, name),
                                      force / typical_size(typical[signal])))
        if self.delay is not None and self.fixed_tau is None:
            names.append("tau")
            start.append(float(next(s.tau for s in self.systems.values())))
            lower.append(self.delay.tau_min)
            natural.append(period)
        lagged = [m.spec.input_delay for m in system.models.values() if m.spec.input_delay is not None]
        self.input_delay = lagged[0] if lagged else None
        if self.input_delay is not None and self.input_delay.free:
            names.append("tau_u")
            start.append(self.input_delay.value)
            lower.append(self.input_delay.tau_min)
            natural.append(period)
        self.input_splines = [[CubicSpline(e.time, e.input(m.spec.input)) for m in system.models.values()]
                              for e in experiments] if self.input_delay is not None else None
        if self.delay is not None:
            for label, gain, name, scale in gains:  # (a coupled equation's given gain has none: one given, one free)
                names.append(name)
                start.append(float(getattr(self.systems[label], gain)))
                lower.append(-np.inf)
                natural.append(scale)
        for i, e in enumerate(experiments):
            k = self.starts[i]
            guess = initial[i] if initial is not None else {  # at the full sample rate
                c: remembered(e, ("initial", c, k), lambda e=e, c=c, k=k: initial_state(e.time[k:], e.output(c)[k:]))
                for c in self.coordinates}
            states = measured[i]
            for c in self.coordinates:
                names += [self._state(c, i, 0), self._state(c, i, 1)]
                start += list(guess[c])
                lower += [-np.inf, -np.inf]
                natural += [typical_size(states[c]), typical_size(states[velocity_symbol(c)])]
        keep = [i for i, n in enumerate(names) if n not in self.tied]
        self.natural = np.array(natural, float)[keep]  # each parameter's size in the data's units
        self.scale = float(np.sqrt(np.mean([typical_spread(e.output(c)[k:]) ** 2 for e, k in
                                            zip(experiments, self.starts) for c in self.coordinates])))  # spread
        self.names = [names[i] for i in keep]
        self.state_names = {self._state(c, i, o) for c in self.coordinates for i in range(len(experiments))
                            for o in (0, 1)}
        lower = np.array(lower)[keep]
        upper = np.full(len(self.names), np.inf)
        if "tau" in self.names:
            upper[self.names.index("tau")] = self.delay.tau_max
        if "tau_u" in self.names:
            upper[self.names.index("tau_u")] = self.input_delay.tau_max
        self.bounds = (lower, upper)
        # every start inside its bounds (least_squares refuses one outside), and said so
        wanted = np.array(start, float)[keep]
        self.start = np.clip(wanted, lower, upper)
        moved = [f"{n} = {w:.4g} (set to {s:.4g})" for n, w, s in zip(self.names, wanted, self.start)
                 if not np.isclose(w, s, rtol=1e-6, atol=0)]  # (a start at its bound but for rounding: quiet)
        if moved:
            warnings.warn("the output-error polish started outside its bounds: " + ", ".join(moved)
                          + "; the equation-error estimate it starts from is far off (check the model and the data)",
                          CvxidWarning, stacklevel=3)

    def same_steps(self, theta: np.ndarray, others: np.ndarray) -> bool:
        """Whether a batch of ``theta`` and ``others`` integrates every experiment in the
        sub-steps ``theta`` alone does (the shortest delay of a batch sets them)."""
        if self.delay is None or self.fixed_tau is not None:
            return True
        i = self.names.index("tau")
        taus = np.maximum(np.r_[theta[i], others[:, i]], 0.0)
        return all(delay_substeps(taus[:1], e.dt * self.stride, n) == delay_substeps(taus, e.dt * self.stride, n)
                   for e, n in zip(self.experiments, self.substeps))

    def _name(self, label: str, physical: str, column: str) -> str:
        return physical if self.one else f"{label}:{column}"

    def _state(self, coordinate: str, experiment: int, order: int) -> str:
        if self.one:
            return ("x0", "v0")[order] + ("" if experiment == 0 else f"[{experiment}]")
        return f"{coordinate}{chr(39) * order}0[{experiment}]"

    def values(self, theta: np.ndarray) -> dict[str, float]:
        return {k: float(v[0]) for k, v in self._values(theta[None, :]).items()}

    def _values(self, thetas: np.ndarray) -> dict[str, np.ndarray]:
        values = dict(zip(self.names, thetas.T))
        if self.fixed_tau is not None:
            values["tau"] = np.full(thetas.shape[0], float(self.fixed_tau))
        for a, (b, f) in self.tied.items():
            values[a] = f * values[b]
        return values

    def residuals(self, thetas: np.ndarray) -> np.ndarray:
        values = self._values(thetas)
        C, B = len(self.coordinates), thetas.shape[0]
        signals = len(self.delay.orders) if self.delay is not None else 1
        mass, gain, coefs, terms = np.ones((C, B)), np.zeros((signals, C, B)), [], []
        for i, (label, model) in enumerate(self.base.models.items()):
            spec, s = model.spec, self.systems[label]
            mass[i] = np.maximum(values[self._name(label, "m", spec.inertia_term.name)], TINY) if spec.inertia \
                else spec.mass
            coefs += [values[self._name(label, spec.parameter_name(t.name), t.name)] for t in s.terms]
            terms.append(tuple(s.terms))
            if self.delay is not None:
                for q, (name, free) in enumerate(zip(spec.gain_names, spec.delay.estimated)):
                    gain[q, i] = values[self._name(label, name, name)] if free else getattr(s, name)
        coefs = np.array(coefs, float).reshape(-1, B)
        tau = np.maximum(values["tau"], 0.0) if self.delay is not None else np.zeros(B)
        any_system = next(iter(self.systems.values()))
        delayed = self.coordinates.index(self.delay.coordinate) if self.delay is not None else 0
        out = []
        for i, e in enumerate(self.experiments):
            k, n = self.starts[i], self.spans[i]
            t = e.time[k:k + n:self.stride]
            x0 = np.array([values[self._state(c, i, 0)] for c in self.coordinates])
            v0 = np.array([values[self._state(c, i, 1)] for c in self.coordinates])
            Y = np.column_stack([e.output(c)[k:k + n:self.compared] for c in self.coordinates])
            seen = self.measured[i]
            try:
                X, V = integrate(
                    t, self._forces(i, t, values, B), self.coordinates, terms, coefs, mass, gain, tau, x0, v0, delayed,
                    any_system.derivative, any_system.history, self.substeps[i], past=self.pasts[i])
                X = between_steps(X, V, self.stride, e.dt * self.stride) if self.every else X
                out.append((X - Y[:, :, None]).reshape(-1, B) if seen is None else (X - Y[:, :, None])[seen])
            except SimulationDiverged:
                out.append(np.full((Y.size if seen is None else int(seen.sum()), B), self.wall))
        return np.vstack(out)

    def _forces(self, i: int, t: np.ndarray, values: dict, B: int):
        """Experiment ``i``'s inputs at the RK4 nodes, ``(S, C, 1)``, or ``(S, C, B)`` when
        the input's delay differs across the batch (read at :math:`t - \\tau_u`; before
        the record, its first sample)."""
        if self.input_splines is None:  # the same at every call: interpolated once, through the compared samples
            k, n = self.starts[i], self.spans[i]
            sampled = self.experiments[i].time[k:k + n:self.compared]
            inputs = [e_input[k:k + n:self.compared] for e_input in
                      (self.experiments[i].input(m.spec.input) for m in self.base.models.values())]

            def at_nodes(fine: np.ndarray, h: float) -> np.ndarray:
                key = (i, h, fine.size)
                if key not in self._inputs:
                    self._inputs[key] = np.column_stack([half_steps(u, sampled, h, fine.size // 2)
                                                         for u in inputs])[:, :, None]
                return self._inputs[key]

            return at_nodes
        taus = np.broadcast_to(values.get("tau_u", self.input_delay.value), (B,))
        first = self.experiments[i].time[0]

        def forces(fine: np.ndarray, h: float) -> np.ndarray:
            out = {}
            for tau_u in np.unique(taus):
                at = np.maximum(fine - tau_u, first)
                out[tau_u] = np.column_stack([spline(at) for spline in self.input_splines[i]])
            return np.stack([out[tau_u] for tau_u in taus], axis=2)

        return forces

    def initial(self, theta: np.ndarray) -> tuple[dict[str, tuple[float, float]], ...]:
        values = self.values(theta)
        return tuple({c: (values[self._state(c, i, 0)], values[self._state(c, i, 1)]) for c in self.coordinates}
                     for i in range(len(self.experiments)))

    def result(self, theta: np.ndarray) -> IdentifiedSystem:
        values = self.values(theta)
        models = {}
        for label, model in self.base.models.items():
            spec, s = model.spec, self.systems[label]
            params = {spec.parameter_name(t.name): values[self._name(label, spec.parameter_name(t.name), t.name)]
                      for t in s.terms}
            if spec.inertia:
                params["m"] = values[self._name(label, "m", spec.inertia_term.name)]
            if self.delay is not None:
                params["tau"] = values["tau"]
                params.update({name: values[self._name(label, name, name)]
                               for name, free in zip(spec.gain_names, spec.delay.estimated) if free})
            models[label] = _updated(model, s, params)
            if "tau_u" in values and spec.input_delay is not None:
                models[label] = replace(models[label], spec=spec.with_input_tau(values["tau_u"]))
        tau = values["tau"] if self.delay is not None else self.base.tau
        return replace(self.base, models=models, tau=tau if self.base.tau is not None else None,
                       info=dict(self.base.info, method="output_error"))


def _updated(model: IdentifiedModel, system, params: dict) -> IdentifiedModel:
    """The identified model with the polished physical parameters written back into its
    regression coefficients (the delay's Taylor share re-added where it has one)."""
    spec = model.spec
    coefs = dict(model.coefficients)
    for term in system.terms:
        coefs[term.name] = params[spec.parameter_name(term.name)]
    if spec.inertia:
        coefs[spec.inertia_term.name] = params["m"]
    tau = params.get("tau", model.tau)
    for name, term in zip(spec.gain_names, spec.delayed_terms if spec.delay is not None else ()):
        if name in params:
            coefs[term.name] = -params[name]
    if spec.delay is not None and not spec.delay.exact:
        for t in spec.delay.taylor_terms():
            if t.name in coefs:
                physical = t.name in spec.library or (spec.inertia and t.name == spec.inertia_term.name)
                base = coefs[t.name] if physical else 0.0  # (a given mass's x'' is the delay's column alone)
                coefs[t.name] = base + spec.delay.contribution(t.order, tau)
    return IdentifiedModel(spec, coefs, model.lam, dict(model.info, refined="output_error"), tau)
