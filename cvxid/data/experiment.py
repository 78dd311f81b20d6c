"""Measured data: the :class:`Experiment` and its loaders.

An experiment is a uniform time grid with named outputs (the measured coordinates, e.g.
``x``), named inputs (e.g. the force ``f``) and, when a user has them, measured velocities.
Everything is validated on construction, so later stages can trust the arrays.
"""

from __future__ import annotations

import csv
import re
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np
from scipy.interpolate import CubicSpline

from cvxid.data.hold import HELD_CHECKED, looks_held
from cvxid.data.sensor import checked
from cvxid.errors import CvxidError, CvxidWarning
from cvxid.metrics import noise_level

MIN_SAMPLES = 20
"""Fewest samples an experiment may have (the algebraic operation needs a record)."""

UNIFORM_RTOL = 1e-6
"""Largest relative deviation of a time step from the mean step taken as rounding."""

JITTER_RTOL = 0.01
"""Largest relative deviation of a time step from the mean step that is logger jitter
(a step of 0.00100003 s for a mean of 0.001 s): the record is resampled onto the uniform
grid of the mean step, with a warning that says by how much.  Above it the time is not
uniform (a missing sample, a changed rate) and the record is refused."""


def first_text(values) -> str:
    """Where a column that should hold numbers does not: ``" (data row 12001: '-')"``, the
    first data row (counted from 1) whose cell is not a number (an empty cell is a missing
    sample, not text), or ``""``."""
    import pandas as pd

    cells = pd.Series(np.ravel(np.asarray(values, dtype=object)))
    text = pd.to_numeric(cells, errors="coerce").isna() & cells.notna()
    if not text.any():
        return ""
    row = int(np.argmax(text.to_numpy()))
    return f" (data row {row + 1}: {str(cells.iloc[row])[:20]!r})"


def _as_signal(name: str, values, experiment: str, allow_nan: bool = False) -> np.ndarray:
    try:
        arr = np.asarray(values, dtype=float)
    except (TypeError, ValueError) as exc:
        raise CvxidError(
            f"experiment '{experiment}': signal '{name}' is not numeric{first_text(values)} ({exc}); "
            "give a 1-D array of numbers (repair or remove that row; an empty cell reads as a missing sample)"
        ) from None
    arr = np.squeeze(arr)
    if arr.ndim != 1:
        raise CvxidError(
            f"experiment '{experiment}': signal '{name}' has shape {np.shape(values)}; "
            "give a 1-D array (one value per sample)"
        )
    bad = np.isinf(arr) | (np.isnan(arr) if not allow_nan else False)
    if bad.any():
        first = int(np.argmax(bad))
        raise CvxidError(
            f"experiment '{experiment}': signal '{name}' has {int(bad.sum())} NaN/inf "
            f"value(s), the first at sample {first}; repair them, or for missing samples (NaN) "
            "load with gaps = true so that the integrals restart after each gap"
        )
    size = float(max(np.nanmax(arr), -np.nanmin(arr))) if not np.isnan(arr).all() else 0.0  # (no copy of arr)
    if size > MAGNITUDES[1] or 0 < size < MAGNITUDES[0]:
        raise CvxidError(
            f"experiment '{experiment}': signal '{name}' reaches {size:.3g} in magnitude, where the squares and "
            f"integrals of the regression overflow or vanish; rescale it (other units) to lie within "
            f"{MAGNITUDES[0]:g} … {MAGNITUDES[1]:g}"
        )
    return arr


MAGNITUDES = (1e-100, 1e100)
"""The largest magnitude a signal may reach lies within these bounds (1e300 overflows the
least squares, 1e-310 is subnormal): the data are rescaled by the user, never silently."""


HISTORY_ONLY = 0.01
"""The least share of an input's energy (above its noise) that must fall after an exact
delay's measured history (:meth:`Experiment.forced_after`): an impact hammer's blow inside
it leaves a free motion with no force, whose inertia no fit can tell (an eighth outside
check's blow at the history's end gave an inertia of 1e-9)."""


def _energy(u: np.ndarray, level: float) -> float:
    """:math:`\\sum u_k^2` over the finite samples, less what white noise of ``level``
    accounts for; at least 0."""
    finite = u[np.isfinite(u)]
    return max(float(np.sum(finite**2)) - finite.size * level**2, 0.0)


@dataclass(frozen=True)
class Experiment:
    """One record of a system: time, outputs, inputs (and optional measured velocities).

    Parameters
    ----------
    time : array_like
        Strictly increasing, uniformly spaced sample times.
    outputs : mapping of str to array_like
        Measured coordinates by name (``{"x": x}``).
    inputs : mapping of str to array_like
        Measured inputs by name (``{"f": f}``).
    name : str
        Used in messages and reports.
    velocities : mapping of str to array_like, optional
        Measured velocities by coordinate name, when a user has them.
    gaps : bool
        NaN samples are gaps (the integrals restart after each).
    held : sequence of str
        Inputs held between samples (a zero-order hold: a controller's or a DAQ's command),
        read half a sample later than a smooth signal (:mod:`cvxid.data.hold`).
    """

    time: np.ndarray
    outputs: Mapping[str, np.ndarray]
    inputs: Mapping[str, np.ndarray]
    name: str = "experiment"
    velocities: Mapping[str, np.ndarray] = field(default_factory=dict)
    gaps: bool = False
    held: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        t = _as_signal("time", self.time, self.name)
        for group, example in (("outputs", '{"x": x}'), ("inputs", '{"f": f}'), ("velocities", '{"x": v}')):
            if not isinstance(getattr(self, group), Mapping):
                raise CvxidError(f"experiment '{self.name}': {group} must map names to arrays ({example}), got "
                                 f"{type(getattr(self, group)).__name__}")
        if not self.outputs:
            raise CvxidError(f"experiment '{self.name}': no output given; name at least one")
        held = (self.held,) if isinstance(self.held, str) else self.held
        if not isinstance(held, (list, tuple)) or not all(isinstance(h, str) for h in held):
            raise CvxidError(f"experiment '{self.name}': held names the inputs held between samples (a list of "
                             f"input names, e.g. [\"f\"]), got {self.held!r}")
        object.__setattr__(self, "held", tuple(held))
        unknown = [h for h in self.held if h not in self.inputs]
        if unknown:
            raise CvxidError(f"experiment '{self.name}': held names input(s) {', '.join(map(repr, unknown))} it does "
                             f"not have (it has {sorted(self.inputs)})")
        signals = {}
        for group in ("outputs", "inputs", "velocities"):
            signals[group] = {
                str(k): _as_signal(f"{group[:-1]} {k}", v, self.name, allow_nan=self.gaps)
                for k, v in getattr(self, group).items()
            }
        for group, sigs in signals.items():
            for k, v in sigs.items():
                if v.size != t.size:
                    raise CvxidError(
                        f"experiment '{self.name}': {group[:-1]} '{k}' has {v.size} samples "
                        f"but time has {t.size}; all signals must have the same length"
                    )
        if t.size < MIN_SAMPLES:
            raise CvxidError(
                f"experiment '{self.name}': only {t.size} samples; at least {MIN_SAMPLES} are needed"
            )
        steps = np.diff(t)
        k = first_step_back(t)
        if k is not None:
            raise CvxidError(
                f"experiment '{self.name}': time is not strictly increasing at sample {k + 1} "
                f"(t = {t[k]:g} then {t[k + 1]:g}); {step_back_fix(t, k)}"
            )
        dt = (t[-1] - t[0]) / (t.size - 1)
        dev = max(steps.max() - dt, dt - steps.min()) / dt
        missing = missing_rows(t) if dev > JITTER_RTOL else None
        lost = "" if missing is None else (
            f"; the time jumps by whole steps ({int(missing[-1]) + 1 - t.size} rows missing): load it with "
            "gaps = true and they become gaps")
        if missing is not None and self.gaps:  # rows lost from a uniform record: gaps where they were
            t, signals = _with_missing_rows(t, signals, missing)
            steps, lost = np.diff(t), ""
            dt = (t[-1] - t[0]) / (t.size - 1)
            dev = max(steps.max() - dt, dt - steps.min()) / dt
        if dev > JITTER_RTOL:
            k = int(np.argmax(np.abs(steps - dt)))
            raise CvxidError(
                f"experiment '{self.name}': time is not uniformly sampled (step {steps[k]:.6g} at "
                f"sample {k} against a mean step of {dt:.6g}, {100 * dev:.3g} % off{lost}; up to "
                f"{100 * JITTER_RTOL:g} % is taken as logger jitter): resample the record onto a uniform grid "
                "(e.g. numpy.interp), split it where a sample is missing, or, if the samples were taken "
                "uniformly and only the time stamps jitter, write the time as t0 + k * dt"
            )
        if dev > UNIFORM_RTOL and not _uniform_to_rounding(t):
            t, signals = _resampled(t, signals, dev, self.name)
        object.__setattr__(self, "time", t)
        for group, sigs in signals.items():
            object.__setattr__(self, group, sigs)

    # ------------------------------------------------------------------ properties
    @property
    def n(self) -> int:
        """Number of samples."""
        return int(self.time.size)

    @property
    def dt(self) -> float:
        """Sample step."""
        return float((self.time[-1] - self.time[0]) / (self.n - 1))

    @property
    def duration(self) -> float:
        return float(self.time[-1] - self.time[0])

    def output(self, name: str) -> np.ndarray:
        if name not in self.outputs:
            raise CvxidError(
                f"experiment '{self.name}' has no output '{name}' (it has {sorted(self.outputs)})"
            )
        return self.outputs[name]

    def input(self, name: str, delay: float = 0.0) -> np.ndarray:
        """The input ``name``; ``"-u"`` is minus the input ``u`` (an equation driven by the
        negated input, as the link equation of a flexible joint is).  With ``delay``
        :math:`\\tau_u > 0`, the input as the system receives it, :math:`u(t - \\tau_u)` at
        the samples: a cubic spline through the record, read :math:`\\tau_u` earlier; before
        the record's start it holds the first sample (the only value known there).  A held
        input (:attr:`held`) is read half a sample later still, by straight lines between
        its samples (a spline overshoots at a jump)."""
        if name.startswith("-") and name not in self.inputs and name[1:].strip() in self.inputs:
            return -self.input(name[1:].strip(), delay)
        if name not in self.inputs:
            raise CvxidError(
                f"experiment '{self.name}' has no input '{name}' (it has {sorted(self.inputs)})"
            )
        if not np.isfinite(delay) or delay < 0:
            raise CvxidError(f"an input delay must be a finite number >= 0, got {delay}")
        if name in self.held:  # half a sample late, and straight between samples (a spline rings at a jump)
            return np.interp(self.time - delay - 0.5 * self.dt, self.time, self.inputs[name])
        if not delay:
            return self.inputs[name]
        return CubicSpline(self.time, self.inputs[name])(np.maximum(self.time - delay, self.time[0]))

    def check_signals(self, inputs, outputs) -> None:
        """Refuse a record whose input is constant (nothing excites the system: a free decay
        too) or whose output is constant (no motion to identify)."""
        def constant(v):  # (NaN samples, gaps, do not count)
            return np.all(np.isnan(v)) or np.nanmax(v) == np.nanmin(v)

        for name in inputs:
            if constant(self.input(name)):
                raise CvxidError(
                    f"experiment '{self.name}': input '{name}' is constant, so it does not excite the system; "
                    "identification needs a varying input. A free decay (no force) cannot be identified: its "
                    "equation is homogeneous, so the parameters are defined only relative to one another, and a "
                    "decaying mode shows two numbers (its frequency and its decay rate), not a mass, damping, "
                    "stiffness, feedback gain and delay; record the force that moves the system (a hammer blow "
                    "measured by an impact hammer, a shaker's force)")
        for name in outputs:
            if constant(self.output(name)):
                raise CvxidError(f"experiment '{self.name}': output '{name}' is constant, so the record holds no "
                                 "motion to identify; check that the spec's [data] output names the measured position")

    def forced_after(self, name: str, seconds: float) -> bool:
        r"""Whether the input ``name`` acts after the record's first ``seconds``: its energy
        :math:`\sum u_k^2` there, less what its white noise accounts for, is at least
        :data:`HISTORY_ONLY` of the whole record's.  An exact delay reads those seconds as
        the measured history, and no row and no simulation fits them."""
        u = self.inputs[name.lstrip("-").strip()] if name not in self.inputs else self.inputs[name]
        first = int(np.searchsorted(self.time, self.time[0] + seconds - 1e-9 * self.dt))
        if not 0 < first < u.size:
            return True
        level = noise_level(u[np.isfinite(u)])
        return _energy(u[first:], level) >= HISTORY_ONLY * _energy(u, level)

    def slice(self, a: int, b: int, name: str | None = None) -> "Experiment":
        """Samples ``a`` (included) to ``b`` (excluded)."""
        if not 0 <= a < b <= self.n or b - a < MIN_SAMPLES:
            raise CvxidError(f"experiment '{self.name}': samples {a} … {b} of its {self.n} hold {max(b - a, 0)} "
                             f"samples; at least {MIN_SAMPLES} inside the record are needed")
        return Experiment(self.time[a:b], {k: v[a:b] for k, v in self.outputs.items()},
                          {k: v[a:b] for k, v in self.inputs.items()}, name=name or self.name,
                          velocities={k: v[a:b] for k, v in self.velocities.items()}, gaps=self.gaps,
                          held=self.held)

    def segments(self) -> list["Experiment"]:
        """The gap-free runs of the record (itself when it has no NaN samples); runs too
        short to use are dropped."""
        return self._runs([*self.outputs.values(), *self.inputs.values(), *self.velocities.values()], "gap-free")

    def driven(self) -> list["Experiment"]:
        """The runs of the record whose inputs are known, each from and to a sample where
        every output is measured (itself when its inputs have no NaN samples and its outputs
        none at its ends): a simulation needs the input, not the measurement, and runs
        through a gap of the outputs alone (:meth:`filled` for the samples it starts from)."""
        runs = self._runs(list(self.inputs.values()), "input-complete")
        out = []
        for run in runs:
            measured = np.all([np.isfinite(y) for y in run.outputs.values()], axis=0)
            first, last = np.argmax(measured), run.n - np.argmax(measured[::-1])
            if last - first >= MIN_SAMPLES and measured.any():
                out.append(run if (first, last) == (0, run.n) else run.slice(int(first), int(last),
                                                                             f"{run.name}[{first}:{last}]"))
        if not out:
            raise CvxidError(f"experiment '{self.name}': no run of {MIN_SAMPLES} samples or more with its inputs known "
                             "and its outputs measured at both ends")
        return out

    def filled(self) -> "Experiment":
        """This record with each output's missing samples drawn straight across the gap
        (linear interpolation): the states a simulation starts from and its measured history
        read it; a fit compares the measured samples alone."""
        if all(np.isfinite(y).all() for y in self.outputs.values()):
            return self
        outputs = {}
        for name, y in self.outputs.items():
            known = np.isfinite(y)
            outputs[name] = np.interp(self.time, self.time[known], y[known]) if not known.all() else y
        return Experiment(self.time, outputs, self.inputs, self.name, self.velocities, gaps=self.gaps, held=self.held)

    def _runs(self, signals: list[np.ndarray], kind: str) -> list["Experiment"]:
        """The runs of the record where none of ``signals`` is NaN, at least
        :data:`MIN_SAMPLES` long (itself when none is)."""
        missing = np.zeros(self.n, bool)
        for v in signals:
            missing |= np.isnan(v)
        if not missing.any():
            return [self]
        edges = np.flatnonzero(np.diff(np.r_[1, missing.astype(int), 1]))
        runs = [(a, b) for a, b in zip(edges[::2], edges[1::2]) if b - a >= MIN_SAMPLES]
        if not runs:
            raise CvxidError(f"experiment '{self.name}': no {kind} run of {MIN_SAMPLES} samples or more")
        return [self.slice(int(a), int(b), f"{self.name}[{a}:{b}]") for a, b in runs]

    def __repr__(self) -> str:
        parts = [
            f"Experiment '{self.name}': {self.n} samples, t = {self.time[0]:g} … "
            f"{self.time[-1]:g} s (dt = {self.dt:g} s)",
            f"  outputs: {', '.join(self.outputs)}",
            f"  inputs: {', '.join(self.inputs) or '(none)'}",
        ]
        if self.velocities:
            parts.append(f"  measured velocities: {', '.join(self.velocities)}")
        return "\n".join(parts)


RESTART_STEPS = 10
"""A time column that goes back by more than this many of its median steps restarted (a
logger's clock reset mid-file), rather than holding rows out of order (:func:`step_back_fix`)."""


def restarted(t: np.ndarray, k: int) -> bool:
    """Whether the time ``t`` goes back after sample ``k`` as a clock that restarted: by more
    than :data:`RESTART_STEPS` of its median steps, after an ordinary step into ``k`` (one
    stamp far ahead of its neighbours is a corrupted stamp, not a restart)."""
    steps = np.diff(t[np.isfinite(t)])
    typical = float(np.median(steps[steps > 0])) if np.any(steps > 0) else 0.0
    into = t[k] - t[k - 1] if k > 0 else typical
    return bool(typical > 0 and t[k] - t[k + 1] > RESTART_STEPS * typical and abs(into - typical) <= typical)


def step_back_fix(t: np.ndarray, k: int) -> str:
    """What to do where the time ``t`` does not increase after sample ``k`` (counted from the
    first sample read): a clock that restarted (:func:`restarted`) holds two records, which
    sorting would interleave (an outside check was told to sort one); a repeated stamp or a
    few rows out of order, the usual fix; one stamp far off both its neighbours, its own."""
    if restarted(t, k):
        return (f"the clock goes back by {t[k] - t[k + 1]:.6g} s there, as a logger's that restarted: the file holds "
                f"two records; cut it there into two, before and from the sample after {t[k]:.10g} s (the samples "
                "read so far hold both), rather than sorting it, which would interleave them")
    if k > 0 and t[k] - t[k - 1] > RESTART_STEPS * max(t[k + 1] - t[k - 1], 0.0):
        return f"the stamp {t[k]:.10g} is out of line with both its neighbours (a corrupted stamp): correct it or drop its row"
    return "sort the file and remove repeated rows"


def first_step_back(t: np.ndarray) -> int | None:
    """The first sample ``k`` after which the time does not increase (``t[k + 1] <= t[k]``,
    or NaN), or None."""
    back = ~(np.diff(t) > 0)
    return int(np.argmax(back)) if back.any() else None


MISSING_JUMPS = 0.01
"""The largest share of a record's steps that may jump by whole steps for the jumps to be
rows lost from a uniform record (:func:`missing_rows`): a few isolated losses, not a
changed sample rate (1 kHz, then 500 Hz: every later step "jumps" by two)."""


def missing_rows(t: np.ndarray) -> np.ndarray | None:
    """Where each sample of a uniform record sits on its grid when rows were lost (the
    time jumps by whole steps of its median step, within logger jitter, at no more than
    :data:`MISSING_JUMPS` of its steps, never twice in a row, and the lost rows no more
    than the recorded ones): the indices on the full grid; else None."""
    steps = np.diff(t)
    dt = float(np.median(steps)) if steps.size else 0.0
    if not dt > 0:
        return None
    whole = np.round(steps / dt)
    jumps = whole > 1
    if not jumps.any() or np.any(whole < 1) or np.any(np.abs(steps - whole * dt) > JITTER_RTOL * dt) \
            or jumps.sum() > MISSING_JUMPS * steps.size or np.any(jumps[1:] & jumps[:-1]) \
            or whole.sum() + 1 > 2 * t.size:
        return None
    return np.concatenate([[0], np.cumsum(whole)]).astype(np.int64)


def _with_missing_rows(t: np.ndarray, signals: dict, index: np.ndarray) -> tuple[np.ndarray, dict]:
    """The record on its full grid (``index``: :func:`missing_rows`), NaN where the rows
    were missing; the recorded times kept, the lost ones placed between their neighbours."""
    full = np.interp(np.arange(index[-1] + 1), index, t)

    def filled(v):
        out = np.full(full.size, np.nan)
        out[index] = v
        return out

    return full, {group: {k: filled(v) for k, v in sigs.items()} for group, sigs in signals.items()}


def _uniform_to_rounding(t: np.ndarray) -> bool:
    """Whether ``t`` lies on its uniform grid to within a few units of its last place: a
    time far from 0 (epoch seconds: 2.4e-7 s apart) jitters by its rounding alone, and a
    grid resampled once was resampled, and warned about, again by each part cut from it."""
    uniform = np.linspace(t[0], t[-1], t.size)
    return bool(np.max(np.abs(uniform - t)) <= 4 * np.spacing(np.max(np.abs(t[[0, -1]]))))


def _resampled(t: np.ndarray, signals: dict, deviation: float, name: str) -> tuple[np.ndarray, dict]:
    """The signals on the uniform grid of the mean step (cubic splines through the recorded
    times; a gap's NaN samples stay NaN), and a warning that says by how much."""
    uniform = np.linspace(t[0], t[-1], t.size)
    shift = float(np.max(np.abs(uniform - t)))

    def on_grid(v):
        good = np.isfinite(v)
        out = np.full(t.size, np.nan)
        out[good] = CubicSpline(t[good], v[good])(uniform[good]) if good.sum() > 3 else v[good]
        return out

    warnings.warn(
        f"experiment '{name}': the time steps jitter by up to {100 * deviation:.3g} % of the mean step "
        f"{(t[-1] - t[0]) / (t.size - 1):.6g} s; the record was resampled onto the uniform grid (largest time "
        f"shift {shift:.3g} s, cubic splines through the recorded times)", CvxidWarning, stacklevel=4)
    return uniform, {group: {k: on_grid(v) for k, v in sigs.items()} for group, sigs in signals.items()}


def part_bounds(n: int, samples: tuple[int, int] | None, fraction: tuple[float, float] | None,
                source="the record") -> tuple[int, int]:
    """The first and end sample of a record's part: ``samples = (first, end)``, then
    ``fraction = (start, end)`` of those (``0.8, 1``: their last 20 %)."""
    a, b = samples if samples is not None else (0, n)
    if not 0 <= a < b <= n:
        raise CvxidError(f"{source}: samples {a} … {b} lie outside its {n} samples")
    if fraction is not None:
        a, b = a + int(round(fraction[0] * (b - a))), a + int(round(fraction[1] * (b - a)))
    return a, b


# ---------------------------------------------------------------------- loaders
def _pick(available: Mapping[str, np.ndarray], wanted: str, what: str, source: Path):
    if wanted not in available:
        raise CvxidError(
            f"{source}: no {what} named '{wanted}'; available: {', '.join(sorted(available))}"
        )
    return available[wanted]


LARGE_CSV = 64 << 20
"""Bytes above which a CSV file is parsed a chunk of :data:`CSV_CHUNK` rows at a time: the
whole-file parser's buffers peak at about 80 bytes a sample for three columns (10^7 rows:
0.8 GB for 0.24 GB of numbers), a chunked read at the numbers and one column's copy."""
CSV_CHUNK = 1 << 20


def _csv_columns(path: Path) -> dict[str, np.ndarray]:
    """The columns of a CSV file with a header row: separated by commas, or by semicolons
    (with a decimal comma or point) or tabs (:func:`_separator`); a row of units under the
    header (text in every column) is skipped with a warning.  The format is read off the
    first rows."""
    import pandas as pd

    def read(**options):
        try:
            return pd.read_csv(path, **options)
        except Exception as exc:  # pandas raises many types for malformed files
            raise CvxidError(f"{path}: cannot be read as CSV with a header row ({exc})") from None

    head = _head(path)
    skipped, commented = _comment_lines(head)
    options = {"encoding": "utf-8-sig", **_separator(head[skipped:]),
               **({"skiprows": list(range(skipped))} if skipped else {})}
    name = (lambda c: str(c).strip().lstrip("#").strip()) if commented else (lambda c: str(c).strip())
    #       (a byte-order mark is not the first name's; numpy's savetxt writes its header as a comment, "# t,x,f")
    header = [name(n) for n in read(nrows=1, header=None, **options).iloc[0]]
    twice = sorted({n for n in header if header.count(n) > 1 and n not in ("", "nan") and not _numeric(n)})
    #              (empty fields are no names, and a line of numbers is no header: refused below)
    if twice:  # (pandas renames the second x.1: a twelfth outside check's two sensors named x, one read silently)
        where = "; ".join(f"'{n}' in columns {' and '.join(str(i + 1) for i, h in enumerate(header) if h == n)}"
                          for n in twice)
        raise CvxidError(f"{path}: the header names a column twice ({where}): rename one so that each column has "
                         "its own name, and point the spec's [data] at the one you mean")
    head = read(nrows=100, **options)
    names = [str(c).replace(",", ".") if options.get("decimal") == "," else str(c) for c in head.columns]
    default = names == [str(i) for i in range(len(names))]  # (pandas' to_csv of an unnamed frame: 0,1,2)
    if not default and all(_numeric(n) or _numeric(re.sub(r"\.\d+$", "", n)) for n in names):  # (a repeated
        # number is renamed by pandas: 0.5, 0.5.1)
        raise CvxidError(f"{path}: the first line ({', '.join(map(str, head.columns))}) is numbers, not column names: "
                         "add a header line that names the columns (t,x,f) above the data")
    if len(head) > 1 and not any(pd.api.types.is_numeric_dtype(head[c]) for c in head.columns):
        first = [str(v) for v in head.iloc[0]]
        second = [str(v).replace(",", ".") if options.get("decimal") == "," else str(v) for v in head.iloc[1]]
        if not any(_numeric(v) for v in first) and all(_numeric(v) for v in second):
            warnings.warn(f"{path}: the row under the header ({', '.join(first)}) is text in every column; it was "
                          "read as units and skipped", CvxidWarning, stacklevel=3)
            options["skiprows"] = list(range(skipped)) + [skipped + 1]
    if path.stat().st_size <= LARGE_CSV:
        frame = read(**options)
        return {name(c): frame[c].to_numpy() for c in frame.columns}
    pieces: dict[str, list[np.ndarray]] = {}
    try:
        with pd.read_csv(path, chunksize=CSV_CHUNK, **options) as chunks:
            for chunk in chunks:
                for c in chunk.columns:
                    pieces.setdefault(c, []).append(chunk[c].to_numpy())
    except Exception as exc:  # pandas raises many types for malformed files
        raise CvxidError(f"{path}: cannot be read as CSV with a header row ({exc})") from None
    return {name(c): np.concatenate(pieces.pop(c)) for c in list(pieces)}  # (as the whole file's: the last)


HEAD_LINES = 1000
"""The lines at the top of a CSV file its format is read off (:func:`_head`)."""


def _head(path: Path) -> list[str]:
    """The first :data:`HEAD_LINES` lines of a file (as read, blank ones too)."""
    try:
        with open(path, encoding="utf-8-sig", errors="replace") as file:
            return [file.readline() for _ in range(HEAD_LINES)]
    except OSError as exc:
        raise CvxidError(f"{path}: cannot be read ({exc.strerror})") from None


def _comment_lines(head: list[str]) -> tuple[int, bool]:
    """The lines at the top of a CSV file (its ``head``, :func:`_head`) that start with
    ``#`` (a logger's notes), to be skipped: all of them when a header line follows, all but
    the last when numbers follow (the last is then the header, as numpy's ``savetxt`` writes
    it: ``# t,x,f``), and whether the header is such a comment."""
    count = 0
    while count < len(head) - 1 and head[count].lstrip().startswith("#"):
        count += 1
    if count and _numbers_line(head[count]):
        return count - 1, True
    return count, False


def _numbers_line(line: str) -> bool:
    """Whether a line of a CSV file holds numbers only (a data row, not a header)."""
    fields = [f.strip() for f in re.split(r"[,;\t]", line) if f.strip()]
    return bool(fields) and all(_numeric(f.replace(",", ".")) for f in fields)


def _separator(head: list[str]) -> dict:
    """pandas' options for the file's separator, read off its ``head`` from the header
    line on (:func:`_head`, its comment lines cut: :func:`_comment_lines`): of commas,
    semicolons and tabs, the one that splits the header line and the first data rows into
    the same number of fields (more than one), commas first; with semicolons a decimal comma
    unless the first rows hold decimal points and no decimal comma (a spreadsheet writes
    ``0``, not ``0,000``).  (Read by pandas with commas first, a semicolon file's decimal
    commas split its rows into more fields than its header has, and a units row into fewer:
    no shape to recover from.)  Blank lines before the header are skipped, and a commented
    header is read without its ``#``."""
    lines = [line for line in head if line.strip()][:201]
    if not lines:
        return {}
    header, rows = lines[0].lstrip().lstrip("#"), lines[1:] or lines[:1]

    def fields(line, sep):
        return len(next(csv.reader([line], delimiter=sep)))

    for sep in (",", ";", "\t"):
        width = fields(header, sep)
        if width > 1 and all(fields(row, sep) == width for row in rows[-100:]):
            if sep != ";":
                return {} if sep == "," else {"sep": sep}
            text = "".join(rows)
            point = re.search(r"\d\.\d", text) is not None and re.search(r"\d,\d", text) is None
            return {"sep": ";"} if point else {"sep": ";", "decimal": ","}
    return {"sep": ";", "decimal": ","} if ";" in header else {"sep": "\t"} if "\t" in header else {}


def _numeric(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _mat_columns(path: Path) -> dict[str, np.ndarray]:
    from scipy.io import loadmat

    try:
        raw = loadmat(path)
    except Exception as exc:  # scipy raises many types for malformed files
        raise CvxidError(f"{path}: cannot be read as a MATLAB file ({exc})") from None
    return {k: v for k, v in raw.items() if not k.startswith("__")}


def _npz_columns(path: Path) -> dict[str, np.ndarray]:
    try:
        with np.load(path, allow_pickle=False) as archive:
            return {k: archive[k] for k in archive.files}
    except Exception as exc:  # numpy raises many types for malformed archives
        raise CvxidError(f"{path}: cannot be read as a NumPy .npz archive ({exc})") from None


READERS = {
    ".csv": (_csv_columns, "column"),
    ".mat": (_mat_columns, "variable"),
    ".npz": (_npz_columns, "array"),
}


def load(
    path,
    time: str | None,
    outputs: Mapping[str, str] | str | Sequence[str],
    inputs: Mapping[str, str] | str | Sequence[str],
    velocities: Mapping[str, str] | str | Sequence[str] | None = None,
    name: str | None = None,
    gaps: bool = False,
    faults: str = "warn",
    dt: float | None = None,
    samples: tuple[int, int] | None = None,
    fraction: tuple[float, float] | None = None,
    time_unit: str = "s",
    hold: bool | Sequence[str] | None = None,
) -> Experiment:
    """Read an experiment from a CSV file (header row names the columns), a MATLAB ``.mat``
    file or a NumPy ``.npz`` archive (variables by name), chosen by the suffix.

    ``outputs``/``inputs``/``velocities`` map the model's names (``"x"``) to column or
    variable names in the file (a name or a list of names: columns named as in the model;
    velocities: one per output, in their order; :func:`_named`); ``time = None`` with a sample step ``dt`` for a file without
    a time column.  The outputs are checked for sensor faults (clipping, a
    frozen stretch, outlier samples; :mod:`cvxid.data.sensor`): ``faults = "warn"`` warns
    about each, ``"gap"`` also makes their samples gaps, ``"ignore"`` skips the check.
    ``samples = (first, end)`` then ``fraction = (start, end)`` keep a part of the record
    (before the check: its messages count the part's samples).  ``time_unit`` is the
    time column's unit (:data:`TIME_UNITS`): the experiment's time is in seconds.  ``hold``:
    the inputs held between samples (True: every one; a list of the model's input names;
    False: none, read as smooth signals; None: none, with a warning for an input that looks
    held, :mod:`cvxid.data.hold`).
    """
    outputs, inputs, velocities = _named(outputs, inputs, velocities)
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in READERS:
        raise CvxidError(f"{path}: unknown data format '{suffix}'; use a .csv, .mat or .npz file")
    if not path.is_file():
        raise CvxidError(f"data file not found: {path}")
    reader, what = READERS[suffix]
    columns = reader(path)
    if time is None:
        if dt is None:
            raise CvxidError(f"{path}: give the time column, or the sample step dt when the file has none")
        if time_unit != "s":
            raise CvxidError(f"{path}: time_unit is the time column's unit, and dt is in seconds: give dt in "
                             "seconds without time_unit")
        first = np.ravel(_pick(columns, next(iter(outputs.values())), what, path))
        time, columns = "__time", {**columns, "__time": np.arange(first.size) * float(dt)}
    if samples is not None or fraction is not None:
        used = [time, *outputs.values(), *inputs.values(), *(velocities or {}).values()]
        a, b = part_bounds(_common_length(columns, used, what, path), samples, fraction, path)
        columns = {**columns, **{c: np.squeeze(columns[c])[a:b] for c in used}}
    return _experiment(columns, what, path, time, outputs, inputs, velocities, name or path.stem, gaps, faults,
                       time_unit, hold)


def _common_length(columns: Mapping[str, np.ndarray], used: Sequence[str], what: str, path: Path) -> int:
    """The samples of the ``used`` columns, which must be 1-D and of one length: a part
    (``samples``, ``fraction``) is cut at the same samples of every column, and a shorter
    column would be cut out of step with the others (a clear error instead)."""
    lengths = {}
    for name in dict.fromkeys(used):
        shape = np.shape(np.atleast_1d(np.squeeze(_pick(columns, name, what, path))))
        if len(shape) != 1:
            raise CvxidError(f"{path}: {what} '{name}' has shape {np.shape(columns[name])}; give a 1-D array "
                             "(one value per sample)")
        lengths[name] = shape[0]
    first = used[0]
    for name, n in lengths.items():
        if n != lengths[first]:
            raise CvxidError(f"{path}: {what} '{name}' has {n} samples but '{first}' has {lengths[first]}; all "
                             "signals must have the same length (a part of the record is cut at the same samples "
                             "of each)")
    return lengths[first]


def from_frame(frame, time: str, outputs: Mapping[str, str], inputs: Mapping[str, str],
               velocities: Mapping[str, str] | None = None, name: str = "frame", gaps: bool = False,
               faults: str = "warn", time_unit: str = "s", hold: bool | Sequence[str] | None = None) -> Experiment:
    """An experiment from a pandas DataFrame, by column names (sensor check, ``time_unit``
    and ``hold`` as :func:`load`)."""
    outputs, inputs, velocities = _named(outputs, inputs, velocities)
    columns = {str(c): frame[c].to_numpy() for c in frame.columns}
    return _experiment(columns, "column", "DataFrame", time, outputs, inputs, velocities, name, gaps, faults,
                       time_unit, hold)


TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "min": 60.0, "h": 3600.0}
"""Units a time column may count (seconds per unit); cvxid's time is in seconds."""


def counts_milliseconds(time: np.ndarray) -> bool:
    """Whether a time column read in seconds looks like milliseconds: a step of a second or
    more on whole numbers (an eleventh outside check's 500 Hz record in ms identified an
    inertia of 1e6 with no word: only a delay range shorter than a sample was an error)."""
    step = float(np.median(np.diff(time))) if time.size > 1 else 0.0
    return step >= 1.0 and bool(np.max(np.abs(time - np.round(time))) <= 1e-6 * step)  # (a uniform grid's rounding)


def seconds_per(unit: str) -> float:
    """Seconds per ``unit`` of a time column (:data:`TIME_UNITS`), or a clear error."""
    if unit not in TIME_UNITS:
        raise CvxidError(f"time_unit must be one of {', '.join(TIME_UNITS)} (the time column's unit), got {unit!r}")
    return TIME_UNITS[unit]


def _times(values, scale: float):
    """``values`` (a time column, or a velocity per time unit when ``scale`` is inverted)
    times ``scale``; as given when they are not numbers (the Experiment names them)."""
    if scale == 1.0:
        return values
    try:
        return np.asarray(values, dtype=float) * scale
    except (TypeError, ValueError):
        return values


def _named(outputs, inputs, velocities) -> tuple[dict, dict, dict | None]:
    """``outputs``, ``inputs`` and ``velocities`` as mappings model name -> column.  Each may
    be a mapping; outputs and inputs also a column name (or a list of them) that names
    itself in the model; velocities, keyed by the coordinate they belong to, also a column
    name (or a list) matched to the outputs in order."""
    def columns(names, argument: str) -> dict[str, str]:
        if isinstance(names, str):
            return {names: names}
        if isinstance(names, Mapping):
            return dict(names)
        if isinstance(names, (list, tuple)) and all(isinstance(n, str) for n in names):
            return {n: n for n in names}
        raise CvxidError(f"{argument} names the file's columns: a column name ('x'), a list of them, or a mapping "
                         f"{{model name: column}} ({{'x': 'x_measured'}}), got {names!r}")

    outputs, inputs = columns(outputs, "outputs"), columns(inputs, "inputs")
    if velocities is None or isinstance(velocities, Mapping):
        return outputs, inputs, None if velocities is None else dict(velocities)
    listed = [velocities] if isinstance(velocities, str) else velocities
    if not isinstance(listed, (list, tuple)) or len(listed) != len(outputs) or \
            not all(isinstance(n, str) for n in listed):
        raise CvxidError(f"velocities names one measured velocity column per output ({', '.join(outputs)}), in "
                         f"their order, or maps each output to its column ({{'x': 'v'}}), got {velocities!r}")
    return outputs, inputs, dict(zip(outputs, listed))


def _experiment(columns, what, source, time, outputs, inputs, velocities, name, gaps, faults,
                time_unit: str = "s", hold=None) -> Experiment:
    scale = seconds_per(time_unit)  # (a wrong unit before the record is read)
    named = [("a measured output", outputs), ("an input", inputs), ("a measured velocity", velocities or {})]
    for i, (first, a) in enumerate(named):
        for second, b in named[i + 1:]:
            clash = sorted(set(a.values()) & set(b.values()))
            if clash:
                raise CvxidError(f"{source}: {what} '{clash[0]}' is both {first} and {second}; each signal needs its "
                                 "own column (a spec's [data.*] output, input, velocity)")
    for role, signals in named:
        if isinstance(time, str) and time in signals.values():
            raise CvxidError(f"{source}: {what} '{time}' is both the time and {role}; name the signal's own column "
                             "(a spec's [data.*] output, input, velocity; cvxid init lists the file's columns)")
    t = _times(_pick(columns, time, what, source), scale)  # in seconds (and velocities per second) from here
    signals = ({k: _pick(columns, v, what, source) for k, v in outputs.items()},
               {k: _pick(columns, v, what, source) for k, v in inputs.items()},
               {k: _times(_pick(columns, v, what, source), 1.0 / scale) for k, v in (velocities or {}).items()})
    # the sensor check reads the samples as recorded (resampling a jittered time would
    # smooth a clipped top away): on the sample index first, then on the recorded time
    recorded = checked(Experiment(np.arange(np.size(t), dtype=float), signals[0], signals[1], name=name,
                                  velocities=signals[2], gaps=gaps), faults)
    experiment = Experiment(t, recorded.outputs, signals[1], name=name, velocities=signals[2], gaps=recorded.gaps)
    held = _held(hold, experiment.inputs, name)
    return replace(experiment, held=held) if held else experiment


def _held(hold, inputs: Mapping[str, np.ndarray], name: str) -> tuple[str, ...]:
    """The inputs ``hold`` names (see :func:`load`); with None, a warning for each input
    that looks held (:func:`~cvxid.data.hold.looks_held`)."""
    if hold is None:
        for k, u in inputs.items():
            if looks_held(u[:HELD_CHECKED]):
                warnings.warn(
                    f"experiment '{name}': input '{k}' is level between single-sample jumps, as a "
                    "command held between samples is (a controller's, a DAQ's); cvxid reads "
                    "it as a smooth signal, which puts each jump half a sample early and can move a fed-back delay "
                    "by several % (two steps on sample instants moved one by 7.5 %, 11 samples), which no interval "
                    "counts: "
                    "if the plant received it held, say so ([data.*] hold = true; "
                    "cvxid.load(..., hold=True)); hold = false reads it as smooth without this warning",
                    CvxidWarning, stacklevel=4)
        return ()
    if isinstance(hold, bool):
        return tuple(inputs) if hold else ()
    listed = [hold] if isinstance(hold, str) else hold
    if not isinstance(listed, (list, tuple)) or not all(isinstance(h, str) and h in inputs for h in listed):
        raise CvxidError(f"experiment '{name}': hold is true, false or a list of the inputs held between samples "
                         f"(of {sorted(inputs)}), got {hold!r}")
    return tuple(listed)
