r"""The regression builder: one equation's data transformed once, regressions of any
library at any delay.

The algebraic operation (:mod:`cvxid.regression.algebraic`) turns every term into a
column.  A :class:`RegressionBuilder` holds the transforms of the data (per experiment and
gap-free segment, on the windows of :mod:`cvxid.regression.windows`) and transforms each
term the first time a regression
asks for it, so the λ path, the bootstrap, the order search, the delay profile and every
candidate of the diagnosis read the same transformed columns: the data are transformed
once per run.  :meth:`RegressionBuilder.at` adds the delayed signal
:math:`x^{(q)}(t-\tau)` (a cubic spline of the record), as a column when the gain is
unknown or moved into the target when it is known; the target is the transform of the
input as the model receives it, :math:`u(t-\tau_u)` (one transform per input delay asked).

With an exact delay every experiment's rows start at ``tau_max`` (the first ``tau_max``
seconds are the measured history the delayed signal reads; no window needs its own), so
regressions at different delays share their rows and their errors compare.

:class:`SystemBuilder` stacks the builders of several equations into one block regression
(columns ``"coordinate:term"``) with a shared delay.
"""

from __future__ import annotations

import warnings

import numpy as np
from scipy.interpolate import CubicSpline

from cvxid.data.experiment import Experiment
from cvxid.errors import CvxidError, CvxidWarning
from cvxid.model.equation import ModelSpec
from cvxid.model.terms import DelayedSignal, Expression, InputRate, Term
from cvxid.regression.algebraic import AlgebraicOrders, AlgebraicTransform, RestartTransform, WindowedTransform
from cvxid.regression.memory import check_memory
from cvxid.regression.regression import Regression
from cvxid.regression.velocity import estimate_velocity
from cvxid.regression.windows import Windows, history_seconds, holding, resolve_window


ROWS = 2000
"""Windowed rows wanted per record: one every tenth of a window, denser on short records."""
TARGETS = 8
"""Regression targets (one per input delay) a block keeps; more are made again when asked."""
DELAYED_FLOATS = 4_000_000
"""Numbers each block of each equation's builder keeps of its delayed signal's columns, by
delay (32 MB; a record cut by gaps into S stretches, of N equations, may keep N S times
that): the delay profiles of one run (the whole library's, each candidate's refit) ask for
the same grid of delays again and again; when full the cache starts over."""


def _transform(time: np.ndarray, orders: AlgebraicOrders, windows: Windows | None):
    """The algebraic operation on the ``windows``, or on the whole record (``None``)."""
    if windows is None:
        return AlgebraicTransform(time, orders)
    dt = float((time[-1] - time[0]) / (time.size - 1))
    length = int(round(windows.seconds / dt))
    if windows.kind == "restart":
        return RestartTransform(time, orders, length)
    length = length // 2 * 2 + 1
    return WindowedTransform(time, orders, length, max(1, min((length - 1) // 10, (time.size - length) // ROWS)))


POLE_PEAK = 100.0
"""A term is refused when, next to a sample where its divisor crosses 0, it exceeds this
many times its median magnitude (``1/x`` of a noisy x: about 700 at 1 kHz; a bounded
quotient, ``tanh(x)/x`` or ``(1 - cos(x))/x``, stays below its median there)."""


def _refuse_pole(term, states, signal: np.ndarray, sample, experiment: str) -> None:
    """A clear error when ``term`` divides by a quantity that crosses 0 on these samples
    and peaks next to the crossing (``sample``: a position in ``signal`` -> the record's
    sample)."""
    if not isinstance(term, Expression):
        return
    magnitude = np.abs(signal)
    median = float(np.median(magnitude))
    if not magnitude.max(initial=0.0) > POLE_PEAK * median:  # (no peak at all: the divisors are not evaluated)
        return
    at = term.crossings(states)
    if at.size == 0:
        return
    near = np.unique(np.clip(np.concatenate([at, at + 1]), 0, magnitude.size - 1))  # both sides of each
    i = int(near[np.argmax(magnitude[near])])
    if not magnitude[i] > POLE_PEAK * median:
        return
    raise CvxidError(
        f"term '{term.name}' is unbounded on these data: it divides by a quantity that crosses 0 (near sample "
        f"{sample(i)} of '{experiment}'), where it reaches {magnitude[i]:.3g} against a median {median:.3g}; a few "
        "samples near each crossing would decide its coefficient. Write it so that it is bounded where the state "
        "goes (x/(x^2 + 0.01) for 1/x), or drop it")


class _Block:
    """One gap-free segment: its transform, the first sample it reads (the samples before
    are the delayed signal's measured history), cached columns and targets (by input
    delay)."""

    def __init__(self, transform, first: int, segment: int):
        self.transform, self.first, self.segment = transform, first, segment
        self.columns: dict[str, np.ndarray] = {}
        self.targets: dict[float, np.ndarray] = {}
        self.delayed: dict[tuple[float, int], np.ndarray] = {}


def no_measured_velocity(record: str, table: str, coordinates) -> str:
    """The error of ``[fit] velocity = "measured"`` on a record (``table``: its ``[data.*]``
    table's name) without these coordinates' measured velocities: both keys that fix it."""
    return (f"[fit] velocity = \"measured\" reads each coordinate's velocity from the records, and {record} has none "
            f"of {', '.join(repr(c) for c in coordinates)}: name its column ([data.{table}] velocity = \"v\"; from "
            "Python, a column " + ", ".join(f"{c}'" for c in coordinates) + "), or choose an estimator ([fit] "
            "velocity = \"savgol\")")


def usable_segments(experiments: list[Experiment], shortest: float, runs=Experiment.segments) -> list[Experiment]:
    """The gap-free stretches of the records (``runs``: the stretches of one, by default
    :meth:`~cvxid.data.experiment.Experiment.segments`); with gaps, stretches shorter than
    ``shortest`` seconds (twice ``tau_max``: the delayed signal's history and as many rows)
    are left out with a warning, unless none would remain."""
    out, dropped = [], []
    for e in experiments:
        segments = runs(e)
        if len(segments) == 1:
            out += segments
            continue
        keep = [s for s in segments if s.duration >= shortest]
        dropped += [s.name for s in segments if s.duration < shortest]
        out += keep
    if dropped and out:
        warnings.warn(f"{len(dropped)} stretch(es) between gaps shorter than {shortest:g} s left out ({', '.join(dropped[:3])}"
                      f"{', …' if len(dropped) > 3 else ''})", CvxidWarning, stacklevel=3)
    return out or [s for e in experiments for s in runs(e)]


class RegressionBuilder:
    """Regressions of one equation's data, for ``model`` and any model that differs from it
    only in its library (the coordinate, input, inertia, delay and algebraic orders fix the
    transform)."""

    def __init__(self, model: ModelSpec, experiments, velocity: str = "savgol", window: float | str | None = "auto",
                 allow_large: bool = False):
        if not isinstance(model, ModelSpec):
            raise CvxidError(f"the model must be a ModelSpec (a spec's .model), got {type(model).__name__}")
        self.model = model
        self.velocity = velocity
        try:
            exps = [experiments] if isinstance(experiments, Experiment) else list(experiments)
        except TypeError:  # (not a sequence)
            exps = []
        if not exps or not all(isinstance(e, Experiment) for e in exps):
            raise CvxidError(f"the records must be an Experiment or a list of them (cvxid.Experiment(t, {{\"x\": x}}, "
                             f"{{\"f\": f}}), cvxid.from_frame(...)), got {type(experiments).__name__}")
        exact = model.delay is not None and model.delay.exact
        self.start = history_seconds(model)
        self.experiments = usable_segments(exps, 2 * self.start)  # integrals restart after gaps
        self.window = resolve_window(window, model, self.experiments)
        self.experiments = holding(self.experiments, self.window, model)
        check_memory(sum(e.n for e in self.experiments), len(model.column_names), self.window is not None, allow_large)
        orders = AlgebraicOrders.for_model(model)
        self._states: list[dict[str, np.ndarray]] = []
        self._splines: list[CubicSpline | None] = []
        self.blocks: list[_Block] = []
        for i, e in enumerate(self.experiments):
            if exact and e.duration < 2 * self.start:
                raise CvxidError(
                    f"experiment '{e.name}' lasts {e.duration:g} s, too short for delays up to "
                    f"tau_max = {self.start:g} s (it needs at least twice that); lower "
                    "[model.delay] tau_max or use a longer record"
                )
            if exact and self.start < e.dt:
                raise CvxidError(
                    f"[model.delay] tau_max = {self.start:g} s is shorter than one sample of experiment '{e.name}' "
                    f"(dt = {e.dt:g} s): no delay can be resolved; raise tau_max, or check the time column's units "
                    f"(seconds: one that counts milliseconds needs [data.{e.name}] time_unit = \"ms\")"
                )
            e.check_signals([model.input], model.coordinates)
            self._states.append({c: e.output(c) for c in model.coordinates})
            self._splines.append(CubicSpline(e.time, e.output(model.delay.coordinate)) if exact else None)
            first = int(np.searchsorted(e.time, e.time[0] + self.start - 1e-9 * e.dt))  # the delayed signal is measured
            self.blocks.append(_Block(_transform(e.time[first:], orders, self.window), first, i))

        if exact and not any(e.forced_after(model.input, self.start) for e in self.experiments):
            raise CvxidError(
                f"input '{model.input}' acts only in the first tau_max = {self.start:g} s of "
                f"{'the record' if len(self.experiments) == 1 else 'each gap-free stretch of the records'}, which the "
                "exact delay reads as the measured history and no fit sees: after them the motion is free, with no "
                "force to scale the inertia by; start the record earlier before the excitation (a longer "
                "pre-trigger), or lower [model.delay] tau_max")

    @property
    def delay(self):
        """The model's delayed feedback (its bounds are the delay profile's)."""
        return self.model.delay

    # ------------------------------------------------------------------ states and columns
    def _state(self, segment: int, symbol: str) -> np.ndarray:
        """A position, or a velocity (measured or estimated on the whole segment, so the
        windows see no edge effects), computed once."""
        states = self._states[segment]
        if symbol not in states:
            coord = symbol[:-1]
            e = self.experiments[segment]
            if not symbol.endswith("'") or coord not in self.model.coordinates:
                raise CvxidError(f"no signal '{symbol}' in experiment '{e.name}'")
            if self.velocity == "measured":
                if coord not in e.velocities:
                    raise CvxidError(no_measured_velocity(f"experiment '{e.name}'", "*", [coord]))
                states[symbol] = e.velocities[coord]
            else:
                states[symbol] = estimate_velocity(states[coord], e.time, self.velocity)
        return states[symbol]

    def _target(self, block: _Block, model: ModelSpec) -> np.ndarray:
        """The transform of the input the model receives (minus a known inertia's share)."""
        tau_u = model.input_tau
        if tau_u not in block.targets:
            if len(block.targets) >= TARGETS:  # a profile over the input delay asks for many, once each
                block.targets.clear()
            e = self.experiments[block.segment]
            p = block.transform.column(model.received_input(e)[block.first:])
            if not model.inertia:
                p = p - model.mass * block.transform.column(e.output(model.coordinate)[block.first:], 2)
            block.targets[tau_u] = p
        return block.targets[tau_u]

    def _column(self, block: _Block, term: Term) -> np.ndarray:
        if term.name not in block.columns:
            symbols = list(self.model.coordinates)  # positions always; velocities where the column needs them
            if term.needs_velocity:
                symbols += sorted(s for s in term.symbols if s.endswith("'"))
            states = {s: self._state(block.segment, s)[block.first:] for s in symbols}

            def read(index):  # the term on the block's samples at index only
                with np.errstate(all="ignore"):
                    pieces = {s: v[index] for s, v in states.items()}
                    signal = np.broadcast_to(term.regression_signal(pieces), next(iter(pieces.values())).shape)
                def sample(at):  # a position in the signal -> the record's sample
                    return block.first + (index.start + at if isinstance(index, slice) else int(index[at]))

                if not np.all(np.isfinite(signal)):
                    raise CvxidError(
                        f"term '{term.name}' is not finite on these data (first at sample "
                        f"{sample(int(np.argmax(~np.isfinite(signal))))} of "
                        f"'{self.experiments[block.segment].name}': a fractional power or square root of a negative "
                        "value, a division by zero, an overflow); write it so that it is defined everywhere the state "
                        "goes, e.g. abs(x)^1.5 for x^1.5")
                _refuse_pole(term, pieces, signal, sample, self.experiments[block.segment].name)
                return signal

            block.columns[term.name] = block.transform.rows(read, term.regression_order)
        return block.columns[term.name]

    def _delayed(self, block: _Block, tau: float, derivative: int) -> np.ndarray:
        """The column of the delayed signal's ``derivative`` at the delay ``tau`` (kept: see
        :data:`DELAYED_FLOATS`)."""
        key = (float(tau), int(derivative))
        column = block.delayed.get(key)
        if column is None:
            t, spline = self.experiments[block.segment].time[block.first:], self._splines[block.segment]
            column = block.transform.rows(lambda index: spline(t[index] - tau), derivative)
            if len(block.delayed) * column.size >= DELAYED_FLOATS:
                block.delayed.clear()
            block.delayed[key] = column
        return column

    def _input_rate(self, block: _Block, model: ModelSpec) -> np.ndarray:
        """The column of the received input's rate (a diagnosis candidate: a missing input delay)."""
        return block.transform.column(model.received_input(self.experiments[block.segment])[block.first:], 1)

    def _check(self, model: ModelSpec):
        same = (model.coordinates, model.input, model.inertia, model.mass, model.delay, model.orders,
                model.keep_initial_conditions)  # the input's delay may differ: its target is one transform
        mine = (self.model.coordinates, self.model.input, self.model.inertia, self.model.mass, self.model.delay,
                self.model.orders, self.model.keep_initial_conditions)
        if same != mine:
            raise CvxidError("this regression builder was made for another coordinate, input, inertia or delay; "
                             "build one for the new model")

    # ------------------------------------------------------------------ regressions
    def at(self, tau: float | None = None, model: ModelSpec | None = None) -> Regression:
        """The regression of ``model`` (the builder's own by default) at the delay ``tau``
        (an exact delay needs one)."""
        model = self.model if model is None else model
        self._check(model)
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
        for block in self.blocks:
            p = self._target(block, model)
            if exact and model.delay.gain is not None:
                for q, gain in zip(model.delay.orders, model.delay.gains):
                    if gain is not None:  # (a given gain's signal moves to the target)
                        p = p + gain * self._delayed(block, tau, q)
            Ps.append(np.column_stack([
                self._delayed(block, tau, c.term.derivative) if isinstance(c.term, DelayedSignal)
                else self._input_rate(block, model) if isinstance(c.term, InputRate)
                else self._column(block, c.term) for c in cols
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


def build_regression(model: ModelSpec, experiments, velocity: str = "savgol", tau: float | None = None,
                     window: float | str | None = "auto") -> Regression:
    """Transform one or several experiments (stacked) into a regression for ``model`` (for
    an exact delay, at the delay ``tau``)."""
    return RegressionBuilder(model, experiments, velocity, window).at(tau)


class SystemBuilder:
    r"""The regressions of :math:`N \ge 1` equations (one :class:`RegressionBuilder` each,
    sharing one delay): for several, one block regression with columns
    ``"coordinate:term"``; for one, that equation's regression with bare column names."""

    def __init__(self, specs: dict[str, ModelSpec], experiments, velocity: str = "savgol",
                 window: float | str | None = "auto", allow_large: bool = False):
        self.specs = dict(specs)
        self.builders = {}
        for label, spec in specs.items():  # every equation on the first one's windows
            self.builders[label] = RegressionBuilder(spec, experiments, velocity, window, allow_large)
            window = self.builders[label].window or "record"

    @classmethod
    def of(cls, builder: "RegressionBuilder | SystemBuilder") -> "SystemBuilder":
        """One equation's builder as the system of one equation (its columns shared, not
        computed again); a system's builder as it is."""
        if isinstance(builder, SystemBuilder):
            return builder
        system = cls.__new__(cls)
        system.specs = {builder.model.coordinate: builder.model}
        system.builders = {builder.model.coordinate: builder}
        return system

    @property
    def window(self) -> Windows | None:
        """The algebraic operation's windows (``None``: the whole record)."""
        return next(iter(self.builders.values())).window

    @property
    def delay(self):
        """The shared delayed feedback (its bounds are the delay profile's)."""
        return next(iter(self.specs.values())).delay

    def at(self, tau: float | None = None, model: dict[str, ModelSpec] | None = None) -> Regression:
        """The regression of ``model`` (equation label → model; the builder's own by
        default) at the delay ``tau``."""
        model = self.specs if model is None else model
        if len(model) == 1:
            ((label, spec),) = model.items()
            return self.builders[label].at(tau, spec)
        return Regression.block({label: self.builders[label].at(tau, spec) for label, spec in model.items()})
