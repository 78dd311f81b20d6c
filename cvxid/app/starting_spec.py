"""``cvxid init DATA -o SPEC``: a commented starting spec for a user's own record.

It reads the file (``.csv``, ``.mat``, ``.npz``), finds the time, output and input columns
(by their names, else by their shape: the time is the increasing column with even steps,
the output the one of the two others whose spectrum above its noise floor sits lower, as a
mechanical system filters its input: :func:`spectral_centroid`) or
takes them from the options, and writes a spec that runs as written: a linear model
``m x'' + c x' + k x = u + b x(t - tau)`` with an exact delay of unknown gain, the
diagnosis on, the output-error polish on (intervals for every parameter), and comments
saying what each key does and what to try next.  Without a test record it splits the one record: the first 80 % to train, the last 20 % to test.
"""

from __future__ import annotations

import json
import os
import re
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cvxid.data.experiment import (READERS, TIME_UNITS, counts_milliseconds, first_step_back, first_text,
                                   missing_rows, restarted, seconds_per, step_back_fix)
from cvxid.data.hold import HELD_CHECKED, looks_held
from cvxid.errors import CvxidError, CvxidWarning
from cvxid.metrics import band_edge
from cvxid.spec.load import parse_problem
from cvxid.spec.toml import tomllib
from scipy.signal import welch

TIME_NAMES = ("t", "time", "times", "timestamp", "seconds", "sec", "s")
INPUT_NAMES = ("u", "f", "force", "input", "voltage", "volt", "torque", "command", "cmd", "current", "drive")
OUTPUT_NAMES = ("x", "y", "theta", "th", "q", "position", "pos", "angle", "output", "displacement", "out")
TRAIN_FRACTION = 0.8
"""Share of a single record used to train when no test record is given."""


@dataclass(frozen=True)
class Columns:
    """The columns chosen and why."""

    time: str | None
    output: str
    input: str
    dt: float
    samples: int
    why: str
    median_period: float = 0.0
    """The period of the output's median frequency (half its variance lies below it, above
    the noise floor: :func:`~cvxid.metrics.band_edge`), in seconds."""
    gaps: bool = False
    """Whether the output or the input has missing (empty or NaN) samples: the spec loads
    them as gaps (``gaps = true``)."""
    time_unit: str = "s"
    """The time column's unit (``--time-unit``, or read off its name: ``time_ms``,
    ``t [us]``); ``dt`` and ``median_period`` are in seconds."""
    held: bool = False
    """Whether the input is level between single-sample jumps, as a command held between
    samples is (:func:`~cvxid.data.hold.looks_held`): the spec offers ``hold = true``."""
    unit_said: bool = False
    """Whether the unit was given (``--time-unit``): the spec writes it, even seconds (a step
    of a second or more on whole numbers is otherwise a warning that it may count ms)."""


def _numeric(columns: dict) -> dict[str, np.ndarray]:
    out = {}
    for name, values in columns.items():
        try:
            array = np.asarray(values, float).ravel()
        except (TypeError, ValueError):
            continue
        if array.size > 1 and np.isfinite(array).mean() > 0.5:
            out[name] = array
    return out


def _words(name: str) -> list[str]:
    """A column name's words, its units dropped: ``"time [s]"`` -> ``["time"]``,
    ``"motor_cmd"`` -> ``["motor", "cmd"]``."""
    plain = re.sub(r"[\[(].*?[\])]", " ", name.lower())
    return [w for w in re.split(r"[^a-z0-9]+", plain) if w]


UNIT_NAMES = {"ms": ("ms", "msec", "millis", "millisecond", "milliseconds"),
              "us": ("us", "usec", "micros", "microsecond", "microseconds")}
"""A time column's name words that give its unit (its bracketed unit may be any of
:data:`~cvxid.data.experiment.TIME_UNITS`: ``t [min]``)."""


def unit_of(name: str) -> str:
    """The unit a time column's name gives: a bracketed one (``"t [ms]"``, ``"time (min)"``,
    ``"t [µs]"``), else a word of it (``"time_ms"``, ``"timeMs"``, ``"millis"``); seconds
    when it names none."""
    plain = re.sub(r"[µμ]s", "us", name)
    bracketed = re.search(r"[\[(]\s*([A-Za-z]+)\s*[\])]", plain)
    if bracketed and bracketed.group(1).lower() in TIME_UNITS:
        return bracketed.group(1).lower()
    words = re.split(r"[^a-z0-9]+", re.sub(r"([a-z0-9])([A-Z])", r"\1 \2", plain).lower())
    return next((unit for unit, names in UNIT_NAMES.items() if any(w in names for w in words)), "s")


def _named(names, wanted, what: str | None = None) -> str | None:
    """The column named by a word in ``wanted``: a whole name (``theta``) before one word
    of several (``theta_dot``), then by the word's rank in ``wanted``; None when none is.
    Two whole names (or, without one, two word matches) are an error naming both (``what``:
    the option that picks one): a file with a force ``f`` and a reference ``u`` took ``u``
    by its rank in ``wanted``."""
    whole = [n for n in names if any(_words(n) == [w] for w in wanted)]
    found = whole or [n for n in names if any(_matches(_words(n), w) for w in wanted)]
    if len(found) > 1 and what is not None:
        raise CvxidError(f"the columns {', '.join(found)} are each named like an {what}: say which one with --{what}")
    return min(found, key=lambda n: min(wanted.index(w) for w in wanted if _matches(_words(n), w)), default=None)


def _matches(words: list[str], word: str) -> bool:
    """Whether a column's ``words`` name ``word`` (the whole name, or one of several words
    longer than a letter)."""
    return words == [word] or (len(words) > 1 and word in words and len(word) > 1)


def spectral_centroid(values: np.ndarray) -> float:
    r"""The power-weighted mean frequency (cycles per sample) of ``values``' spectrum above
    its noise floor,

    .. math:: \bar f = \frac{\sum_f f\,(P(f) - 4P_0)_+}{\sum_f (P(f) - 4P_0)_+},

    :math:`P` Welch's estimate, :math:`P_0` its median over the upper half of the band (white
    measurement noise).  Unlike a noise level it does not take a noisy measured position for
    the rougher signal beside a clean command: on 40 random delayed oscillators (20 s, noise
    0.01 or 0.001 on the position, the force clean or noisy) the output's is the lower on 36,
    the noise level's ratio to the spread on none (the forces are larger numbers;
    ``python examples/init_columns.py``)."""
    finite = values[np.isfinite(values)]
    freq, power = welch(finite - finite.mean(), nperseg=min(finite.size, 4096))
    signal = np.clip(power - 4 * np.median(power[freq > freq[-1] / 2]), 0.0, None)
    return float(np.sum(freq * signal) / np.sum(signal)) if signal.sum() > 0 else np.inf


def _listing(numeric: dict, dropped: dict) -> str:
    """The file's numeric columns, and those that are not (text, or mostly empty), each
    with its first cell that is not a number (``dropped``: name -> values)."""
    text = f"numeric columns: {', '.join(sorted(numeric)) or 'none'}"
    return text + (f"; not numeric (text, or mostly empty): "
                   f"{', '.join(name + first_text(values) for name, values in dropped.items())}" if dropped else "")


def detect_columns(columns: dict, time: str | None = None, output: str | None = None, input: str | None = None,
                   dt: float | None = None, time_unit: str | None = None) -> Columns:
    """The time, output and input columns (see the module docstring); ``time_unit`` the
    time column's (default: read off its name, :func:`unit_of`)."""
    rows = max((np.size(v) for v in columns.values()), default=0)
    if rows < 2:
        raise CvxidError(f"the file has {rows} data row{'s' if rows != 1 else ''}: nothing to identify")
    numeric = _numeric(columns)
    dropped = {n: v for n, v in columns.items() if n not in numeric}
    listing = _listing(numeric, dropped)
    for given, what in ((time, "time"), (output, "output"), (input, "input")):
        if given is not None and given not in numeric:
            raise CvxidError(f"--{what} '{given}' is not a numeric column of the file; {listing}")
    if time is not None and dt is not None:
        raise CvxidError(f"give the time column (--time {time}) or the sample step (--dt {dt:g}), not both")
    if dt is not None and not (np.isfinite(dt) and dt > 0):
        raise CvxidError(f"--dt must be the sample step, a positive number of seconds, got {dt:g}")
    if dt is not None and time_unit is not None:
        raise CvxidError(f"--time-unit is the time column's unit, and --dt is in seconds: give --dt {dt:g} in "
                         "seconds without --time-unit")
    reasons, given_unit = [], time_unit is not None
    if given_unit:
        seconds_per(time_unit)  # (a wrong unit before the file is read through)
    if time is None and dt is None:
        time = _time_column(numeric)
        if time is None:
            raise CvxidError(f"no time column found ({listing}): name it with --time, or give the sample step with "
                             "--dt when the file has none")
        reasons.append(f"time '{time}'")
    others = [n for n in numeric if n != time]
    said = {"output": "given", "input": "given"}
    if output is None and (found := _named([n for n in others if n != input], OUTPUT_NAMES, "output")):
        output, said["output"] = found, "by its name"
    if input is None and (found := _named([n for n in others if n != output], INPUT_NAMES, "input")):
        input, said["input"] = found, "by its name"
    rest = [n for n in others if n not in (output, input)]
    if output is None and input is None:
        if len(rest) != 2:
            raise CvxidError(f"cannot tell the output and the input apart among {', '.join(rest) or 'no column'} "
                             f"({listing}): name them with --output and --input")
        output, input = sorted(rest, key=lambda n: spectral_centroid(numeric[n]))
        said = {"output": "the lower spectrum, as a mechanical system filters its input; a guess: swap with "
                          "--output/--input if wrong",
                "input": "the higher spectrum, a guess"}
    elif output is None or input is None:
        missing = "output" if output is None else "input"
        if not rest:
            raise CvxidError(f"no {missing} column: the file's signals beside the time are "
                             f"{', '.join(others) or 'none'} ({listing}); cvxid needs a measured output and an input")
        if len(rest) != 1:
            raise CvxidError(f"no {missing} column found by its name among {', '.join(rest)}: name it with --{missing}")
        said[missing] = "the only other column, a guess: name it with --" + missing + " if wrong"
        output, input = (rest[0], input) if output is None else (output, rest[0])
    reasons.append(f"output '{output}' ({said['output']}); input '{input}' ({said['input']})")
    stamps = _time_column(numeric) if dt is not None else None
    if stamps is not None and stamps not in (output, input) and _check_step(dt, stamps, numeric[stamps]):
        reasons.append(f"the sample step given with --dt, which the column '{stamps}' agrees with (not read)")
    if len(others) > 2:
        reasons.append(f"not used: {', '.join(n for n in others if n not in (output, input))}")
    samples = numeric[output].size
    lost = None
    if dt is None:
        t = numeric[time]
        row = first_step_back(t)
        if row is not None:
            raise CvxidError(f"the time column '{time}' does not increase from data row {row + 1} to {row + 2} "
                             f"({t[row]:.10g}, then {t[row + 1]:.10g}): {step_back_fix(t, row)}" + (
                                 "" if restarted(t, row) else "; if the stamps repeat because they are rounded "
                                 "(epoch seconds need more than 10 digits), give the sample step with --dt instead "
                                 "of a time column"))
        lost = missing_rows(t)  # rows lost from a uniform record: the median step, and gaps where they were
        dt = float((t[-1] - t[0]) / (t.size - 1)) if lost is None else float(np.median(np.diff(t)))
        time_unit = time_unit or unit_of(time)
        if time_unit != "s":
            dt *= seconds_per(time_unit)
            how = "--time-unit" if given_unit else "by the column's name"
            reasons.append(f"the time counts {time_unit} ({how}), read as seconds")
        elif not given_unit and counts_milliseconds(t):
            said = (f"the time column '{time}' steps by {dt:g} on whole numbers, read as seconds: if it counts "
                    "milliseconds, write the spec again with --time-unit ms (or set time_unit = \"ms\" in its "
                    "[data] tables and scale its delay range); if seconds, --time-unit s says so")
            reasons.append(said)
            warnings.warn(said, CvxidWarning, stacklevel=2)
        if lost is not None:
            reasons.append(f"{int(lost[-1]) + 1 - t.size} rows missing from the time column, loaded as gaps")
            samples = int(lost[-1]) + 1  # (the record's grid: its duration and delay range count the lost rows)
    y = numeric[output][np.isfinite(numeric[output])]
    median_period = 2 * np.pi / band_edge(y, dt, share=0.5) if y.size > 16 else 0.0
    gaps = not (np.isfinite(numeric[output]).all() and np.isfinite(numeric[input]).all())
    if gaps:
        reasons.append("missing samples in the output or the input, loaded as gaps")
    gaps = gaps or lost is not None
    return Columns(time, output, input, float(dt), samples, "; ".join(reasons), float(median_period), gaps,
                   time_unit or "s", looks_held(numeric[input][:HELD_CHECKED]), given_unit and time is not None)


def _relative(path: Path, folder: Path) -> str:
    """``path`` as the spec in ``folder`` names it."""
    return Path(os.path.relpath(path.resolve(), folder.resolve())).as_posix()


def _identifier(name: str, fallback: str) -> str:
    """``name`` if it is a plain ASCII identifier (a coordinate's name in terms), else ``fallback``."""
    return name if re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", name) else fallback


def _quoted(text: str) -> str:
    """``text`` as a TOML basic string (JSON's escapes are TOML's)."""
    return json.dumps(str(text))


def _time_column(numeric: dict) -> str | None:
    """The file's time column: named as one (:data:`TIME_NAMES`), or the only column that
    rises in steady steps (within 1 %); None when there is none."""
    time = _named(numeric, TIME_NAMES)
    if time is None:
        steady = [n for n, v in numeric.items() if np.all(np.diff(v) > 0)
                  and np.ptp(np.diff(v)) <= 0.01 * np.mean(np.diff(v))]
        time = steady[0] if len(steady) == 1 else None
    return time


def _check_step(dt: float, name: str, stamps: np.ndarray) -> bool:
    """Whether the file's own time column ``name`` agrees with ``--dt`` (within 1 %, in
    seconds or in another unit of :data:`~cvxid.data.experiment.TIME_UNITS`: a column in
    ms), a clear error when it rises in steady steps that do not (a seventh outside check's
    ``--dt`` ten times off was taken, the column left out unsaid); False, and nothing
    checked, when its stamps do not rise in steps (rounded epoch seconds repeat: ``--dt`` is
    then the way in)."""
    finite = stamps[np.isfinite(stamps)]
    steps = np.diff(finite)
    if finite.size < 2 or not np.all(steps > 0):
        return False
    step = float(np.median(steps))
    if any(abs(step * seconds / dt - 1) <= 0.01 for seconds in TIME_UNITS.values()):
        return True
    raise CvxidError(f"--dt {dt:g} s disagrees with the file's time column '{name}', whose samples are {step:g} "
                     f"(of its unit) apart: leave out --dt to read that column (--time {name}, with --time-unit "
                     "if it does not count seconds), or correct --dt")


def _data_table(which: str, file: str, columns: Columns, coordinate: str, force: str,
                fraction: tuple[float, float] | None) -> str:
    lines = [f"[data.{which}]", f"file = {_quoted(file)}"]
    lines.append(f"time = {_quoted(columns.time)}" if columns.time else f"dt = {columns.dt:g}                       "
                 "# the sample step in seconds (no time column read)")
    if columns.time_unit != "s" or columns.unit_said:
        lines.append(f'time_unit = "{columns.time_unit}"                # the time column counts {columns.time_unit}: '
                     "cvxid reads it as seconds")
    lines.append(f"output = {{ {coordinate} = {_quoted(columns.output)} }}")
    lines.append(f"input = {{ {force} = {_quoted(columns.input)} }}")
    if fraction:
        lines.append(f"fraction = [{fraction[0]:g}, {fraction[1]:g}]           # the part of the record used here")
    lines.append('faults = "warn"                  # clipped, frozen or outlier samples: "warn", "gap" or "ignore"')
    if columns.gaps:
        lines.append("gaps = true                      # missing (empty or NaN) samples: the integrals and the "
                     "simulations restart after each gap")
    if columns.held:
        lines.append("# hold = true                    # the input is level between single-sample jumps: if the plant "
                     "received it held (a controller's or a DAQ's command), say so; hold = false: a smooth signal")
    return "\n".join(lines)


def longest_delay(median_period: float, usable: float) -> float:
    """The starting spec's ``tau_max``: an eighth of the period of the output's median
    frequency (:attr:`Columns.median_period`), at least 0.5, at most a tenth of the
    ``usable`` record, in seconds (3 significant digits).  A slow plant's
    delay may be seconds; an ordinary one keeps the documented 0.5 s
    (``examples/init_delay_range.py``)."""
    return float(f"{min(usable / 10, max(0.5, median_period / 8)):.3g}")


def starting_spec(data: Path, columns: Columns, test: Path | None, spec_folder: Path) -> str:
    """The text of a starting spec (see the module docstring)."""
    coordinate = _identifier(columns.output, "x")
    force = _identifier(columns.input, "u")
    if force == coordinate:
        force = "u" if coordinate != "u" else "f"
    duration = (columns.samples - 1) * columns.dt
    train_part = None if test else (0.0, TRAIN_FRACTION)
    usable = duration * (TRAIN_FRACTION if test is None else 1.0)
    tau_max = longest_delay(columns.median_period, usable)
    why = columns.why.replace("\n", " ")
    parts = [
        f"# A starting spec written by `cvxid init {data.name}`: {columns.samples:,} samples, dt = {columns.dt:g} s "
        f"({duration:g} s).",
        f"# Columns: {why}.",
        "# Run it with `cvxid run THIS_FILE --out out/`; docs/spec.md explains every key.",
        f"name = {_quoted(data.stem)}",
        f'description = "{coordinate}\'\' + c {coordinate}\' + k {coordinate} = {force} + b {coordinate}(t - tau), '
        'a linear start; the diagnosis looks for what is missing"',
        "",
        _data_table("train", _relative(data, spec_folder), columns, coordinate, force, train_part),
        "",
        _data_table("test", _relative(test or data, spec_folder), columns, coordinate, force,
                    None if test else (TRAIN_FRACTION, 1.0)),
        "",
        "[model]",
        f'coordinate = "{coordinate}"',
        f'input = "{force}"',
        "",
        "[model.library]",
        f'terms = ["{coordinate}", "{coordinate}\'"]           # listed terms are estimated, never dropped; '
        'add your own, e.g. "sin(theta)"',
        "",
        "[model.delay]                        # a delayed feedback b x(t - tau); remove this table if there is none",
        f'signal = "{coordinate}"                         # or ["{coordinate}", "{coordinate}\'"]: position and velocity fed '
        'back (b0, b1)',
        'method = "exact"',
        f"tau_max = {tau_max:g}                       # the longest delay searched (s): an eighth of the period of",
        "#                                    # the output's median frequency, at least 0.5 s, at most a tenth of the record",
        "# gain = 1.0                         # the feedback gain b, if known: give it. Estimated, it often trades",
        "#                                    # with the stiffness (b x(t - tau) = b x - b tau x' + ...; the run warns)",
        "",
        "[model.constraints]",
        f'nonnegative = ["{coordinate}\'\'"]               # a positive inertia',
        "",
        "[fit]",
        'estimator = "lstsq"                  # every listed term estimated; "lasso" selects from a library',
        'refine = "output_error"              # then polish by simulation error: intervals for every parameter',
        '                                     # and the delay (slower: comment it out for a first quick look)',
        "",
        "[diagnose]                           # rank the missing physical effects on the test data",
        "refine = true                        # add the best one and refit while the error falls",
        "",
    ]
    return "\n".join(parts)


def init(data, out, test=None, time=None, output=None, input=None, dt=None, overwrite: bool = False,
         time_unit: str | None = None) -> Path:
    """Write the starting spec for ``data`` to ``out`` (refusing to replace a file unless
    ``overwrite``); returns its path."""
    data, out = Path(data), Path(out)
    test = Path(test) if test else None
    for path in (data, test):
        if path is None:
            continue
        if path.suffix.lower() not in READERS:
            raise CvxidError(f"{path}: unknown data format '{path.suffix}'; use a .csv, .mat or .npz file")
        if not path.is_file():
            raise CvxidError(f"data file not found: {path}")
    if out.exists() and not overwrite:
        raise CvxidError(f"{out} exists; choose another -o or pass --force to replace it")
    columns = detect_columns(READERS[data.suffix.lower()][0](data), time, output, input, dt, time_unit)
    text = starting_spec(data, columns, test, out.parent)
    out.parent.mkdir(parents=True, exist_ok=True)  # (the spec's paths are relative to it)
    try:  # the records as cvxid run will read them: a spec that runs as written, or the reason now
        spec = parse_problem(tomllib.loads(text), out.parent.resolve(), out.stem)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", CvxidWarning)  # (cvxid run says them)
            for which in spec.data:
                spec.experiment(which).check_signals(sorted({e.input_column for e in spec.equations.values()}),
                                                     spec.coordinates)
    except CvxidError as exc:
        raise CvxidError(f"no spec written: {str(exc).removeprefix('spec: ')}") from None
    out.write_text(text)
    return out
