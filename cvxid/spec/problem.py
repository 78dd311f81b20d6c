"""Problem specs: declarative TOML files (see ``docs/spec.md``), read without ``eval``.

Every table and key is checked: an unknown key, a wrong type or a missing file is a
:class:`~cvxid.errors.CvxidError` that names the key and the fix.  Numbers are numbers and
strings are names; nothing in a spec is ever executed.
"""

from __future__ import annotations

import re
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from cvxid.data.excitation import excitation
from cvxid.data.experiment import TIME_UNITS, Experiment, counts_milliseconds, from_frame, load, part_bounds
from cvxid.data.overlap import copied_share
from cvxid.data.sensor import FAULT_HANDLING
from cvxid.errors import CvxidError, CvxidWarning
from cvxid.identify.bootstrap import RESAMPLE, BootstrapSettings
from cvxid.identify.selection import StabilitySettings
from cvxid.identify.path import ESTIMATORS as PATH_ESTIMATORS
from cvxid.identify.path import SELECTING, SELECTION_RULES
from cvxid.identify.problem import SOLVERS
from cvxid.model.delay import ASSUMED, HISTORIES, METHODS, DelayedFeedback
from cvxid.model.input_delay import InputDelay
from cvxid.model.equation import ModelSpec
from cvxid.model.library import CATALOGUE, PARAMETERS, Effect, Library, coordinate_effect, declared_effect, resolve_term
from cvxid.model.system import SystemSpec
from cvxid.model.terms import DELAYED, Derivative, parse_term
from cvxid.parallel import BACKENDS, check_backend
from cvxid.regression.velocity import ESTIMATORS
from cvxid.regression.windows import KINDS, WINDOWS, Windows
from cvxid.simulate import CoupledSystem, Equation, SimulationDiverged, simulate_coupled

Table = Mapping[str, Any]


# ---------------------------------------------------------------------- checking helpers
MAX_ORDER = 8
"""The largest polynomial library order: (N + 1)^2 - 1 terms, 80 at N = 8."""
ORDER_FIX = ("a polynomial library of order N has (N + 1)^2 - 1 nearly collinear terms; add single terms with "
             "extra = [...] instead")
MAX_SOLVES = 200_000
"""Convex solves a spec may ask for without ``[fit] allow_large = true`` (minutes, at a few
milliseconds each)."""
ALGEBRA_FIX = "the defaults (n = highest derivative, m = n + 1) remove every initial condition"


def _table(parent: Table, key: str, where: str, allowed: set[str], required: bool = False) -> dict:
    value = parent.get(key)
    path = f"{where}.{key}" if where else key
    if value is None:
        if required:
            raise CvxidError(f"spec: missing section [{path}]")
        return {}
    if not isinstance(value, Mapping):
        raise CvxidError(f"spec: [{path}] must be a table of keys, got {type(value).__name__}")
    unknown = set(value) - allowed
    if unknown:
        raise CvxidError(
            f"spec: unknown key(s) {', '.join(sorted(unknown))} in [{path}]; allowed: {', '.join(sorted(allowed))}"
        )
    return dict(value)


def _number(table: Table, key: str, where: str, default=None, positive=False, integer=False,
            within: tuple[float | None, float | None] = (None, None), fix: str = ""):
    """A finite number (``integer``: whole; ``positive``: > 0; ``within``: inclusive bounds,
    either None), else an error naming the key, the value, the allowed range and ``fix``."""
    value = table.get(key, default)
    if value is None:
        raise CvxidError(f"spec: [{where}] needs '{key}'")
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise CvxidError(f"spec: [{where}] {key} must be a number, got {value!r}")
    if not np.isfinite(value):
        raise CvxidError(f"spec: [{where}] {key} must be finite, got {value!r}")
    if integer and int(value) != value:
        raise CvxidError(f"spec: [{where}] {key} must be a whole number, got {value!r}")
    if positive and value <= 0:
        raise CvxidError(f"spec: [{where}] {key} must be positive, got {value!r}")
    low, high = within
    if (low is not None and value < low) or (high is not None and value > high):
        allowed = (f"{low:g} to {high:g}" if low is not None and high is not None
                   else f"at least {low:g}" if low is not None else f"at most {high:g}")
        raise CvxidError(f"spec: [{where}] {key} = {value!r} is out of range (allowed: {allowed})"
                         + (f"; {fix}" if fix else ""))
    return int(value) if integer else float(value)


def _string(table: Table, key: str, where: str, default=None, choices=None) -> str:
    value = table.get(key, default)
    if value is None:
        raise CvxidError(f"spec: [{where}] needs '{key}'")
    if not isinstance(value, str):
        raise CvxidError(f"spec: [{where}] {key} must be a string, got {value!r}")
    if choices and value not in choices:
        raise CvxidError(f"spec: [{where}] {key} must be one of {', '.join(choices)}, got '{value}'")
    return value


def _strings(table: Table, key: str, where: str) -> list[str]:
    value = table.get(key, [])
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise CvxidError(f"spec: [{where}] {key} must be a list of strings, got {value!r}")
    return list(value)


def _is_number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and bool(np.isfinite(float(value)))


def _bool(table: Table, key: str, where: str, default: bool) -> bool:
    value = table.get(key, default)
    if not isinstance(value, bool):
        raise CvxidError(f"spec: [{where}] {key} must be true or false, got {value!r}")
    return value


# ---------------------------------------------------------------------- the spec
@dataclass(frozen=True)
class Truth:
    """The true system of a simulated problem (also the reference in reports): its
    equations, the input that drives them and its physical parameters."""

    system: CoupledSystem
    input: str
    physical: dict[str, float]
    input_delay: float = 0.0  # the system receives the input this late (single-equation truths)


@dataclass(frozen=True)
class FitSettings:
    estimator: str = "adaptive_lasso"  # (cvxid bench --heldout --mode selection: it, with 1se, wins)
    lambdas: np.ndarray = field(default_factory=lambda: np.logspace(-6, 2, 50))
    velocity: str = "savgol"
    solver: str = "CLARABEL"
    debias: bool = True
    selection: str = "1se"
    bootstrap: "BootstrapSettings | None" = None
    stability: "StabilitySettings | None" = None  # a spec's default: on for lasso and adaptive_lasso
    orders: tuple[int, ...] = ()
    refine: str | None = None
    window: float | str = "auto"
    loss: str = "squared"
    allow_large: bool = False  # jobs above MAX_SOLVES, builds above the memory available
    backend: str = "loky"  # where joblib's work runs (cvxid.parallel)
    scheduler: str | None = None  # a dask or ray cluster's address
    prune: bool = True  # the selected terms pruned by simulation error after the polish (cvxid.identify.stepwise)
    n_jobs: int = 1  # joblib workers: bootstrap samples (also in BootstrapSettings), the diagnosis's candidate fits


COPIED = 0.1
"""The share of a test record's stretches found verbatim in the training record from which
it is said to repeat it (:meth:`ProblemSpec.warn_overlap`)."""


def _same_file(folder: Path, table: Table, other: Table) -> bool:
    """Whether two data tables read the same file."""
    try:
        return (folder / str(table["file"])).resolve() == (folder / str(other["file"])).resolve()
    except (KeyError, TypeError, OSError):  # (a record given from Python has no file)
        return False


@dataclass(frozen=True)
class ProblemSpec:
    """A parsed problem: name, the system of N >= 1 equations, fit settings, data
    descriptions and the truth."""

    name: str
    folder: Path
    system: SystemSpec
    fit: FitSettings
    data: dict[str, dict | Experiment]
    """``[data]``'s tables by record (``train``, ``test``), or the records themselves
    when Python gave them (:meth:`with_data`)."""
    truth: Truth | None
    description: str = ""
    polynomials: dict[str, tuple[int, bool, tuple[str, ...]]] = field(default_factory=dict)
    """(order, cross, extra) of each equation whose library is an order's polynomial, by coordinate."""
    diagnose: "DiagnoseSettings | None" = None
    notes: tuple[str, ...] = ()
    """What reading the spec warned of (a retired key): a run repeats it in its warnings."""

    @property
    def model(self) -> ModelSpec:
        """The equation of a one-equation spec."""
        if self.system.single is None:
            raise CvxidError(f"spec '{self.name}' has {len(self.equations)} coupled equations: use spec.system")
        return self.system.single

    @property
    def equations(self) -> dict[str, ModelSpec]:
        return self.system.equations

    @property
    def coordinates(self) -> tuple[str, ...]:
        return tuple(self.equations)

    def libraries(self, order: int) -> dict[str, Library]:
        """Every polynomial library of the spec at another order, by coordinate (for the
        order search; an equation whose terms are listed keeps them)."""
        if not self.polynomials:
            raise CvxidError("the order search needs a polynomial library ([model.library] order = …), not a term list")
        out = {}
        for coord, (_, cross, extra) in self.polynomials.items():
            coords = (coord, *(c for c in self.coordinates if c != coord))
            out[coord] = Library.polynomial(order, cross, coord) + [resolve_term(e, coords) for e in extra]
        return out

    def at_order(self, system: SystemSpec, order: int) -> SystemSpec:
        """``system`` (this spec's, with whatever the run resolved in it) with its
        polynomial libraries at ``order``; a term a tie names stays at every order (the tie
        says it belongs)."""
        tied = {name for a, b, _ in system.ties for name in (a, b)}
        libraries = {label: library + [t for t in system.equations[label].library
                                       if system.column(label, t.name) in tied and t.name not in library.names]
                     for label, library in self.libraries(order).items()}
        return system.with_libraries(libraries)

    def experiment(self, which: str) -> Experiment:
        """Load or simulate the ``train`` or ``test`` experiment."""
        if which not in self.data:
            raise CvxidError(f"spec '{self.name}' has no [data.{which}] section: add one (a file or a simulation), "
                             f"or give the record from Python (cvxid.run(spec, {which}=…))")
        table, where = self.data[which], f"data.{which}"
        if isinstance(table, Experiment):  # given from Python (with_data)
            return table
        if "simulate" not in table:
            return self._loaded(which, table, where)
        if self.fit.velocity not in VELOCITIES:
            raise _unknown_velocity(self.fit.velocity, f"[{where}] is simulated (velocity = 'measured' reads the "
                                                       "simulator's own velocity)")
        try:
            experiment = _simulated(self, which, _table(table, "simulate", where, SIM_KEYS))
        except SimulationDiverged as exc:
            raise CvxidError(f"spec: [{where}.simulate] the [truth] system cannot be simulated under this input "
                             f"({exc}): its coefficients and delay gain make an unstable loop; check [truth], or lower "
                             "the input's amplitude or the record's duration") from None
        if "samples" not in table and "fraction" not in table:
            return experiment
        return experiment.slice(*part_bounds(experiment.n, table.get("samples"), table.get("fraction"), where))

    def with_data(self, train, test=None) -> "ProblemSpec":
        """This spec with its records given from Python, in place of its ``[data]``.

        Parameters
        ----------
        train, test : Experiment or pandas.DataFrame
            The training record and (optional; a ``[diagnose]`` needs it) the test
            record.  An :class:`~cvxid.data.experiment.Experiment` is taken as given (its
            outputs must hold the spec's coordinates, its inputs the equations' inputs); a
            DataFrame is read by the spec's names (a time column ``t``, a column per
            coordinate and input, and with ``velocity = "measured"`` the velocity ``x'``)
            and its outputs checked for sensor faults, as a file's.
        """
        records = {"train": train} if test is None else {"train": train, "test": test}
        data = {which: self._given(which, record) for which, record in records.items()}
        needs = [why for why, needed in (("[diagnose] compares the models", self.diagnose is not None),
                                         ('velocity = "auto" chooses an estimator', self.fit.velocity == "auto"),
                                         ("[fit] orders chooses an order", bool(self.fit.orders))) if needed]
        if test is None and needs:
            raise CvxidError(f"with_data: the spec's {needs[0]} on a test record: pass test=… (an Experiment or a "
                             "DataFrame)")
        return replace(self, data=data)

    def _given(self, which: str, record) -> Experiment:
        """A record given from Python (:meth:`with_data`) as a checked Experiment."""
        import pandas as pd

        inputs = sorted({s.input_column for s in self.equations.values()})
        measured = self.fit.velocity == "measured" or self.fit.velocity not in VELOCITIES  # (or a column's name)
        if isinstance(record, pd.DataFrame):
            # measured velocities: [fit] velocity's column (one equation), else x' for each coordinate x
            velocities = {self.coordinates[0]: self.fit.velocity} if self.fit.velocity not in VELOCITIES else \
                {c: f"{c}'" for c in self.coordinates} if measured else {}
            columns = ["t", *self.coordinates, *inputs, *velocities.values()]
            try:
                record = from_frame(record, time="t", outputs=list(self.coordinates), inputs=inputs,
                                    velocities=velocities or None, name=which,
                                    hold=(self.data.get(which) or {}).get("hold"))
            except CvxidError as exc:
                said = str(exc).removeprefix("DataFrame: ")
                fix = (f"name its columns as the spec does ({', '.join(columns)})" if "no column named" in said else
                       "or read it yourself with cvxid.from_frame(frame, time=…, outputs=…, inputs=…, gaps=…, "
                       "time_unit=…) and pass the Experiment")
                raise CvxidError(f"with_data: {which} (a DataFrame): {said}; {fix}") from None
        if not isinstance(record, Experiment):
            raise CvxidError(f"with_data: {which} must be a cvxid.Experiment or a pandas DataFrame, got "
                             f"{type(record).__name__}")
        for group, names, what in (("outputs", self.coordinates, "coordinate"), ("inputs", inputs, "input"),
                                   ("velocities", self.coordinates if measured else (), "measured velocity")):
            missing = [n for n in names if n not in getattr(record, group)]
            if missing:
                raise CvxidError(f"with_data: {which} has no {what} {', '.join(map(repr, missing))} in its {group} "
                                 f"(it has {', '.join(map(repr, getattr(record, group))) or 'none'}); name them as "
                                 "the spec's [model] does")
        return record if record.name != Experiment.name else replace(record, name=which)

    def warn_overlap(self, train: Experiment, test: Experiment) -> None:
        """Warn when ``test``, read from ``train``'s own output columns of its file, holds
        samples of ``train``'s part of it, or, read from other columns, another file or
        given from memory, repeats ``train`` sample for sample on :data:`COPIED` of its
        stretches or more (:func:`~cvxid.data.overlap.copied_share`: an outside check's
        renamed copy of the training file was reported as a held-out fit): the test figures,
        and the diagnosis's choices, are then on data the fit saw."""
        tables = self.data.get("train", {}), self.data.get("test", {})
        if _same_file(self.folder, *tables) and self._outputs(tables[0], "data.train") == \
                self._outputs(tables[1], "data.test"):
            shared = np.count_nonzero((test.time >= train.time[0]) & (test.time <= train.time[-1]))
            said = (f"reads {shared} of its {test.n} samples ({100 * shared / test.n:.3g} %) from the part of the same "
                    "file that [data.train] reads") if shared else ""
        else:
            share = copied_share(train, test)
            said = (f"repeats [data.train] sample for sample on {100 * share:.3g} % of the stretches checked (a copy of "
                    "the training record, or of part of it, under another name; or the same motion repeated, which "
                    "the noise does not change between the records: a quantised one)") if share >= COPIED else ""
        if said:
            warnings.warn(f"spec: [data.test] {said}: the test figures (and the diagnosis's choices) are then on data "
                          "the fit saw; give another record, or split one into parts that do not overlap (samples or "
                          "fraction)", CvxidWarning, stacklevel=2)

    def _loaded(self, which: str, table: Table, where: str) -> Experiment:
        inputs = sorted({s.input_column for s in self.equations.values()})
        velocity = table.get("velocity")
        if velocity is None and self.fit.velocity not in VELOCITIES:
            velocity = self.fit.velocity  # [fit] velocity names a measured column
        first = self.coordinates[0]
        try:
            experiment = self._load(which, table, where, inputs, velocity, first)
        except CvxidError as exc:  # the file's own message, and the spec's table that named it
            if velocity == self.fit.velocity and f"no column named '{velocity}'" in str(exc):
                raise _unknown_velocity(velocity, f"[{where}]'s file has no such column: {exc}") from None
            raise exc if str(exc).startswith("spec:") else CvxidError(f"spec: [{where}] {exc}") from None
        if "time_unit" not in table and "dt" not in table and counts_milliseconds(experiment.time):
            warnings.warn(f"[{where}] is sampled every {experiment.dt:g} s over {experiment.duration:g} s: if its "
                          f"time column counts milliseconds, set [{where}] time_unit = \"ms\" (cvxid reads seconds; "
                          "read so, every inertia, delay and window is in the wrong units); if it counts seconds, "
                          "time_unit = \"s\" says so", CvxidWarning,
                          stacklevel=2)
        return experiment

    def _outputs(self, table: Table, where: str = "data") -> dict[str, str]:
        """The file's columns a data table reads as the outputs, by coordinate (as
        :meth:`_load` reads them: a table that leaves ``output`` out reads each
        coordinate's own name).  Two tables of one file whose outputs are other columns
        (the paper's ``.mat`` holds its training and test records side by side, ``x_tr``
        and ``x_tst``) read two records, whatever their samples."""
        return _names(table.get("output", {c: c for c in self.coordinates}), self.coordinates[0], where, "output")

    def _load(self, which: str, table: Table, where: str, inputs: list[str], velocity, first: str) -> Experiment:
        return load(
            self.folder / _string(table, "file", where),
            time=None if "dt" in table else _string(table, "time", where, "t"),
            dt=table.get("dt"),
            outputs=self._outputs(table, where),
            inputs=_names(table.get("input", {i: i for i in inputs}), inputs[0], where, "input"),
            velocities=_names(velocity, first, where, "velocity") if velocity else None,
            name=which,
            gaps=_bool(table, "gaps", where, False),
            faults=_string(table, "faults", where, "warn", choices=FAULT_HANDLING),
            samples=table.get("samples"),
            fraction=table.get("fraction"),
            time_unit=_string(table, "time_unit", where, "s"),
            hold=table.get("hold"),
        )

    def __repr__(self) -> str:
        if self.system.single is not None:
            head = f"ProblemSpec '{self.name}' ({self.folder})\n{self.model!r}"
        else:
            lines = [f"ProblemSpec '{self.name}' ({self.folder}): {len(self.equations)} coupled equations"]
            lines += [f"  {s!r}".replace("\n", "\n  ") for s in self.equations.values()]
            lines += [f"  tie: {a} = {f:g} {b}" for a, b, f in self.system.ties]
            head = "\n".join(lines)
        return (f"{head}\n  fit: {self.fit.estimator}, {len(self.fit.lambdas)} lambdas, velocity {self.fit.velocity}, "
                f"solver {self.fit.solver}\n  data: {', '.join(self.data)}")


TOP_KEYS = {"name", "description", "truth", "data", "model", "fit", "diagnose"}
VELOCITIES = ESTIMATORS + ("measured", "auto")
"""``[fit] velocity`` values that are not a measured column's name."""


def _unknown_velocity(velocity: str, why: str) -> CvxidError:
    return CvxidError(f"spec: [fit] velocity '{velocity}' is neither an estimator ({', '.join(VELOCITIES)}) nor a "
                      f"measured column: {why}")


DATA_KEYS = {"file", "time", "dt", "output", "input", "velocity", "simulate", "gaps", "faults", "fraction", "samples",
             "time_unit", "hold"}
SIM_KEYS = {"duration", "dt", "x0", "v0", "seed", "noise", "input"}
MODEL_KEYS = {"coordinate", "input", "inertia", "mass", "library", "delay", "constraints", "names", "algebraic", "tie",
              "input_delay"}
SELECTORS = PATH_ESTIMATORS + ("stepwise_oe",)
"""One equation's ``[fit] estimator`` values: the path's selectors and the stepwise search."""
FIT_KEYS = {"estimator", "lambdas", "velocity", "solver", "debias", "selection", "bootstrap", "orders", "n_jobs",
            "refine", "window", "loss", "allow_large", "backend", "scheduler", "stability", "prune"}


def parse_single_problem(raw: Table, folder: Path, default_name: str = "problem",
                         data_required: bool = True) -> ProblemSpec:
    """A :class:`ProblemSpec` from a spec with one ``[model]`` table (without ``[data]``
    when ``data_required`` is false: :func:`data_sections`)."""
    unknown = set(raw) - TOP_KEYS
    if unknown:
        raise CvxidError(
            f"spec: unknown top-level key(s) {', '.join(sorted(unknown))}; allowed: {', '.join(sorted(TOP_KEYS))}"
        )
    name = _string(raw, "name", "", default_name)
    model_table = _table(raw, "model", "", MODEL_KEYS, required=True)
    _check_coordinate(model_table, raw.get("data"))
    model, polynomial = _model(model_table)
    ties = ties_of(model_table, model.column_names, "as the terms, e.g. \"x'\"")
    fit = _fit(_table(raw, "fit", "", FIT_KEYS))
    check_selection(fit, {model.coordinate: model}, {} if polynomial is None else {model.coordinate: polynomial})
    data = data_sections(raw, data_required)
    truth = _truth(raw, model) if "truth" in raw else None
    if truth is None and any("simulate" in t for t in data.values()):
        raise CvxidError("spec: simulated data needs a [truth] section describing the true system")
    model = replace(model, effects=declared_effects(raw, model))
    diag = diagnose_settings(raw, {model.coordinate: model}) if "diagnose" in raw else None
    return ProblemSpec(name, folder, SystemSpec({model.coordinate: model}, ties), fit, data, truth,
                       str(raw.get("description", "")), {} if polynomial is None else {model.coordinate: polynomial},
                       diag)


def _check_coordinate(model: Table, data) -> None:
    """The model's coordinate among the outputs each ``[data]`` table names (an eleventh
    outside check's ``coordinate = "y"`` beside ``output = { x = "x" }`` was refused as the
    term ``x``, not as the mismatch it was)."""
    coordinate = model.get("coordinate", "x")
    for which, table in (data or {}).items() if isinstance(data, Mapping) else ():
        outputs = table.get("output") if isinstance(table, Mapping) else None
        if isinstance(outputs, Mapping) and outputs and coordinate not in outputs:
            named = ", ".join(map(str, outputs))
            which_one = f"\"{named}\"" if len(outputs) == 1 else f"one of {named}"
            raise CvxidError(
                f"spec: [model] coordinate = \"{coordinate}\" is not an output of [data.{which}], whose output "
                f"table names {named}: write the model in the data's coordinate ([model] coordinate = {which_one} "
                f"and terms of it), or name the column for it (output = {{ {coordinate} = "
                f"\"{next(iter(outputs.values()))}\" }})")


def check_selection(fit: FitSettings, equations: dict[str, ModelSpec], polynomials: dict) -> None:
    """A terms list offered for selection (``select = true``) with an estimator that selects
    nothing is refused: it would keep every term, silently."""
    offered = [label for label, s in equations.items() if label not in polynomials and len(s.library) and not s.listed]
    if fit.estimator == "lstsq" and offered:
        where = "[model.library]" if len(equations) == 1 else f"the library of equation '{offered[0]}'"
        raise CvxidError(f'spec: {where} has select = true, a selection, and [fit] estimator = "lstsq" selects '
                         'nothing (it would keep every term): choose estimator = "adaptive_lasso", "lasso", "stlsq" '
                         'or "stepwise_oe", or remove select to estimate the terms as listed')


def ties_of(model: Table, columns: list[str], written: str) -> tuple[tuple[str, str, float], ...]:
    """The checked ``[[model.tie]]`` tables: ``left = factor * right``, two columns of the
    system (``written`` says how columns are named); ties that contradict each other are
    refused.  Chains are returned as stars: every tied column as a multiple of its chain's
    last column (``x^3 = 0.5 x`` and ``x = 15 x'`` become ``x^3 = 7.5 x'`` and
    ``x = 15 x'``), so that no column is tied twice, the form the output-error fit reads."""
    tables = model.get("tie", [])
    if not isinstance(tables, list) or not all(isinstance(t, Mapping) for t in tables):
        raise CvxidError("spec: ties are [[model.tie]] tables with left, right and factor")
    named: list[str] = []  # the tied columns, in the order they were first named
    ratio: dict[str, tuple[str, float]] = {}  # column -> (its chain's root, column / root)

    def root(c: str) -> tuple[str, float]:
        r, f = ratio.get(c, (c, 1.0))
        if r == c:
            return c, 1.0
        top, g = root(r)
        return top, f * g

    for i, t in enumerate(tables):
        where = f"model.tie[{i}]"
        t = _table({f"tie[{i}]": t}, f"tie[{i}]", "model", {"left", "right", "factor"})
        left, right = _string(t, "left", where), _string(t, "right", where)
        for side in (left, right):
            if side not in columns:
                raise CvxidError(f"spec: [{where}] '{side}' is not a column; columns are written {written}, one of: "
                                 f"{', '.join(sorted(columns))}")
        if left == right:
            raise CvxidError(f"spec: [{where}] ties '{left}' to itself; name two different columns")
        factor = float(_number(t, "factor", where, 1.0))
        if factor == 0:
            raise CvxidError(f"spec: [{where}] factor = 0 forces '{left}' to 0: remove its term from the library "
                             "instead of tying it")
        (a, fa), (b, fb) = root(left), root(right)
        if a == b:  # already joined by other ties: this one must say the same
            if abs(fa - factor * fb) > 1e-9 * max(abs(fa), abs(factor * fb)):
                raise CvxidError(f"spec: [{where}] contradicts the ties before it: they give {left} = "
                                 f"{fa / fb:.6g} * {right}, this one {factor:g} (together they force both to 0); "
                                 "remove one")
            continue  # (the same statement again adds nothing)
        ratio[a] = (b, factor * fb / fa)
        named += [c for c in (left, right) if c not in named]
    stars = []
    for c in named:
        top, f = root(c)
        if top != c:
            stars.append((c, top, f))
    return tuple(stars)


def data_sections(raw: Table, required: bool = True) -> dict[str, dict]:
    """The checked ``[data.train]`` (required) and ``[data.test]`` tables: each a file or a
    simulation; ``[data.test]`` required by a ``[diagnose]``.  With ``required`` false a
    spec may have no ``[data]`` (its records are given from Python:
    :meth:`ProblemSpec.with_data`)."""
    if "data" not in raw:
        if not required:
            return {}
        raise CvxidError("spec: missing section [data]: add [data.train] (a file, or a [data.train.simulate] table); "
                         "from Python the records may be given instead: cvxid.run(spec, train=…, test=…)")
    data_table = _table(raw, "data", "", {"train", "test"}, required=True)
    data = {k: _table(data_table, k, "data", DATA_KEYS) for k in data_table}
    if "train" not in data:
        raise CvxidError("spec: missing section [data.train]")
    for which, table in data.items():
        if ("file" in table) == ("simulate" in table):
            raise CvxidError(f"spec: [data.{which}] needs exactly one of 'file' or a [data.{which}.simulate] table")
        where = f"data.{which}"
        if "dt" in table:
            if "time" in table:
                raise CvxidError(f"spec: [{where}] gives both time and dt: the time column, or dt for a file without one")
            _number(table, "dt", where, positive=True, within=(None, 1e6), fix="the seconds between samples")
        if "fraction" in table:
            part = table["fraction"]
            if (not isinstance(part, list) or len(part) != 2 or not all(_is_number(v) for v in part)
                    or not 0 <= part[0] < part[1] <= 1):
                raise CvxidError(f"spec: [{where}] fraction must be [start, end] with 0 <= start < end <= 1 (the part "
                                 f"of the record used, e.g. [0, 0.8] to train and [0.8, 1] to test), got {part!r}")
        if "samples" in table:
            part = table["samples"]
            if (not isinstance(part, list) or len(part) != 2 or not all(isinstance(v, int) and not isinstance(v, bool)
                                                                      for v in part) or not 0 <= part[0] < part[1]):
                raise CvxidError(f"spec: [{where}] samples must be [first, end] sample indices with 0 <= first < end (the "
                                 f"samples used, end excluded, e.g. [40650, 105712]), got {part!r}")
        if "time_unit" in table:
            if "file" not in table or "dt" in table:
                raise CvxidError(f"spec: [{where}] time_unit is the unit of a file's time column (dt is in seconds, "
                                 "a simulation's time too): remove it, or give the time column")
            _string(table, "time_unit", where, choices=tuple(TIME_UNITS))
        if "faults" in table:
            if "simulate" in table:
                raise CvxidError(f"spec: [data.{which}] faults is for measured data (a file); a simulation has none")
            _string(table, "faults", f"data.{which}", choices=FAULT_HANDLING)
        if "hold" in table and "simulate" in table:
            raise CvxidError(f"spec: [data.{which}] hold says how a measured input was held between its samples; a "
                             "simulation's input is a function of time: remove it")
    if "diagnose" in raw and "test" not in data and required:  # (else with_data checks it)
        raise CvxidError("spec: [diagnose] compares the models on a test record: add [data.test] (another file, or "
                         "the training file with fraction = [0.8, 1] and fraction = [0, 0.8] in [data.train]), or "
                         "remove [diagnose]")
    return data


@dataclass(frozen=True)
class DiagnoseSettings:
    candidates: tuple[str, ...] | None = None  # None: the catalogue minus the model
    refine: bool = False
    max_steps: int = 5
    simulation: bool = True  # after the output-error polish, the diagnosis by simulation error


def declared_effects(raw: Table, model: ModelSpec) -> dict[str, Effect]:
    """``[diagnose.effects]``: the spec's own effects, ``name = "term"`` or ``name = { term =
    "…", meaning = "…", nonnegative = false }``, each a diagnosis candidate beside the
    catalogue's."""
    d = raw.get("diagnose")
    if not isinstance(d, Mapping) or "effects" not in d:
        return {}
    table = d["effects"]
    if not isinstance(table, Mapping):
        raise CvxidError('spec: [diagnose.effects] is a table of name = "term" (e.g. unbalance = "cos(theta)")')
    effects = {}
    for name, value in table.items():
        where = f"diagnose.effects.{name}"
        if isinstance(value, str):
            value = {"term": value}
        value = _table({name: value}, name, "diagnose.effects", {"term", "meaning", "nonnegative"})
        effects[name] = declared_effect(name, _string(value, "term", where), (model.coordinate, *model.others),
                                        value.get("meaning") and _string(value, "meaning", where),
                                        _bool(value, "nonnegative", where, False))
    return effects


def retired_min_improvement(d: Table) -> None:
    """Specs written before the acceptance rule may still set ``[diagnose]
    min_improvement``: they load, and a warning says the key no longer does anything."""
    if "min_improvement" in d:
        warnings.warn("spec: [diagnose] min_improvement is no longer used (an effect is added by one stated rule "
                      "for every spec: it must lower the test equation error, be kept on 70 % of halves of the "
                      "training record, and lower the test simulation error; see cvxid.diagnosis.acceptance); "
                      "remove the key", CvxidWarning, stacklevel=3)


def diagnose_settings(raw: Table, equations: dict[str, ModelSpec]) -> DiagnoseSettings:
    """``[diagnose]`` of a system of these equations (their declared effects set)."""
    d = _table(raw, "diagnose", "", {"candidates", "refine", "min_improvement", "max_steps", "effects", "simulation"})
    retired_min_improvement(d)
    if "max_steps" in d and not _bool(d, "refine", "diagnose", False):
        raise CvxidError("spec: [diagnose] max_steps limits the effects refine = true adds, and refine is false (the "
                         "default: the effects are ranked, none added); add refine = true, or remove max_steps")
    candidates = None
    first = next(iter(equations.values()))
    if "candidates" in d:
        candidates = tuple(_strings(d, "candidates", "diagnose"))
        coords = tuple(s.coordinate for s in equations.values())
        if not candidates:
            raise CvxidError("spec: [diagnose] candidates is empty: name the effects to try, or remove the key for "
                             "the whole catalogue")
        for c in candidates:
            effect_name, _, rest = c.partition("(")
            if effect_name in PARAMETERS and rest:
                raise CvxidError(f"spec: [diagnose] candidates: '{c}': the delay and the input's delay are the "
                                 f"system's, one each; write '{effect_name}'")
            if effect_name in CATALOGUE and rest.endswith(")") and coordinate_effect(c, coords) is None:
                raise CvxidError(f"spec: [diagnose] candidates: '{c}' names no coordinate of the model; write "
                                 f"{effect_name}(coordinate) with one of {', '.join(coords)}, or '{effect_name}' for "
                                 "every coordinate's")
            if coordinate_effect(c, coords) is None:
                resolve_term(c, coords, first.effects)  # unknown names fail here, with the catalogue
    return DiagnoseSettings(
        candidates=candidates,
        refine=_bool(d, "refine", "diagnose", False),
        max_steps=_number(d, "max_steps", "diagnose", 5, integer=True, within=(1, 20),
                          fix="each step adds one effect"),
        simulation=_bool(d, "simulation", "diagnose", True),
    )


def _constrained(name: str, coordinates: tuple[str, ...]) -> str:
    """A ``nonnegative`` entry's column name: a term's, or the delayed feedback's as written
    (:class:`~cvxid.model.equation.ModelSpec` refuses a sign on it, by name)."""
    bare = re.sub(r"\s+", "", name)
    return bare if bare.endswith(DELAYED) else parse_term(name, coordinates).name


def _model(table: Table, where: str = "model", others: tuple[str, ...] = ()) -> tuple[ModelSpec, tuple | None]:
    """One equation's model; in a coupled spec ``others`` are the coordinates its terms and
    its delayed feedback may read."""
    coord = _string(table, "coordinate", where, "x")
    if not coord.isidentifier():
        raise CvxidError(f"spec: [{where}] coordinate = '{coord}' is not a name: use letters, digits and _ (x, "
                         "theta, x1); several coordinates are several [[model.equation]] tables")
    if coord == str(table.get("input", "f")).replace(" ", "").lstrip("-"):
        raise CvxidError(f"spec: [{where}] coordinate = '{coord}' is also the input: the coordinate is the measured "
                         "output the model explains, the input the force or command that drives it; name each its "
                         "own (the [data.*] output and input tables map them to the file's columns)")
    coords = (coord, *others)
    lib_t = _table(table, "library", where, {"order", "cross", "extra", "terms", "select", "keep_linear"})
    extra = tuple(_strings(lib_t, "extra", f"{where}.library"))
    polynomial, listed = None, ()
    if "terms" in lib_t:
        both = sorted({"order", "cross"} & set(lib_t))
        if both:
            raise CvxidError(f"spec: [{where}.library] gives terms and {' and '.join(both)}: a terms list, or an "
                             "order's polynomial library (extra adds effects to either); remove one")
        terms = _strings(lib_t, "terms", f"{where}.library")
        if not terms and not extra:
            raise CvxidError(f"spec: [{where}.library] terms is empty: list the terms (e.g. [\"{coord}\", "
                             f"\"{coord}'\"]), or remove terms for an order's polynomial library")
        parsed = [parse_term(t, coords) for t in terms]
        names = [t.name for t in parsed]
        twice = next((n for i, n in enumerate(names) if n in names[:i]), None)
        if twice is not None:
            raise CvxidError(f"spec: [{where}.library] terms lists {twice} twice (as written: "
                             f"{', '.join(repr(t) for t, n in zip(terms, names) if n == twice)}); list each term once")
        library = Library(parsed)
        second = [t for t in library if isinstance(t, Derivative) and t.order >= 2]
        if second:
            what = "the inertia: it is always in the model (its coefficient is m, or give [model] mass)" if \
                (second[0].coordinate, second[0].order) == (coord, 2) else \
                f"a derivative of order {second[0].order}, which no simulation can evaluate"
            raise CvxidError(f"spec: [{where}.library] terms lists {second[0].name}, {what}; list terms of the "
                             f"positions and velocities only (\"{coord}\", \"{coord}'\", …)")
        if not _bool(lib_t, "select", f"{where}.library", False):
            listed = tuple(library.names)  # the user's terms are estimated, not selected away
    elif "select" in lib_t:
        raise CvxidError(f"spec: [{where}.library] select applies to a terms list (an order's library is always "
                         "selected); remove it or list the terms")
    else:
        order = _number(lib_t, "order", f"{where}.library", 3, integer=True, within=(1, MAX_ORDER),
                        fix=ORDER_FIX)
        polynomial = (order, _bool(lib_t, "cross", f"{where}.library", True), extra)
        library = Library.polynomial(order, polynomial[1], coord)
    library = library + [resolve_term(e, coords) for e in extra]
    delay = None
    if "delay" in table:
        dw = f"{where}.delay"
        d = _table(table, "delay", where, {"signal", "gain", "taylor_order", "method", "tau_min", "tau_max", "history"})
        fed_back, derivative, rate, gain = _fed_back(d, dw, coords)
        delay = DelayedFeedback(
            coordinate=fed_back,
            derivative=derivative,
            rate=rate,
            gain=gain,
            taylor_order=_number(d, "taylor_order", dw, 3, integer=True, within=(1, 7),
                                 fix="higher Taylor orders amplify the noise; use method = 'exact' instead"),
            method=_string(d, "method", dw, "taylor", choices=METHODS),
            tau_min=_number(d, "tau_min", dw, 0.0, within=(0, None), fix="a delay cannot be negative"),
            tau_max=_number(d, "tau_max", dw, 0.5, positive=True, within=(None, 1e4),
                            fix="the record must last at least twice tau_max"),
            history=_string(d, "history", dw, "measured", choices=HISTORIES),
        )
        if delay.exact and "taylor_order" in d:
            raise CvxidError(f"spec: [{dw}] taylor_order has no meaning with method = 'exact'; remove it")
    input_delay = _input_delay(table, where) if "input_delay" in table else None
    cons = _table(table, "constraints", where, {"nonnegative"})
    names_t = table.get("names", {})
    if not isinstance(names_t, Mapping):
        raise CvxidError(f"spec: [{where}.names] must be a table of parameter = \"term\"")
    names = {}
    for k, v in names_t.items():
        if not isinstance(v, str):
            raise CvxidError(f"spec: [{where}.names] {k} must be a term name string, got {v!r}")
        names[k] = v
    alg = _table(table, "algebraic", where, {"n", "m", "keep_initial_conditions"})
    nonneg = tuple(_constrained(n, coords) for n in _strings(cons, "nonnegative", f"{where}.constraints"))
    columns = set(library.names) | {coord + "''"}
    for pname, tname in names.items():
        if parse_term(tname.lstrip("- "), coords).name not in columns:
            raise CvxidError(f"spec: [{where}.names] {pname} = '{tname}' is not a term of the library")
    inertia = _bool(table, "inertia", where, True)
    if inertia == ("mass" in table):
        raise CvxidError(f"spec: [{where}] mass is the known mass of inertia = false; remove it (the mass is "
                         "estimated)" if inertia else f"spec: [{where}] inertia = false needs the known mass: add "
                         "mass = <value> (or remove inertia = false to estimate it)")
    return ModelSpec(
        library=library,
        coordinate=coord,
        input=_string(table, "input", where, "f"),
        inertia=inertia,
        mass=_number(table, "mass", where, 1.0, positive=True),
        delay=delay,
        nonnegative=nonneg,
        names=names,
        orders=(
            _number(alg, "n", f"{where}.algebraic", integer=True, within=(0, 10), fix=ALGEBRA_FIX) if "n" in alg else None,
            _number(alg, "m", f"{where}.algebraic", integer=True, within=(1, 12), fix=ALGEBRA_FIX) if "m" in alg else None,
        ),
        keep_initial_conditions=_bool(alg, "keep_initial_conditions", f"{where}.algebraic", False),
        others=tuple(others),
        listed=listed,
        keep_linear=_bool(lib_t, "keep_linear", f"{where}.library", True),
        input_delay=input_delay,
    ), polynomial


def _fed_back(d: Table, where: str, coords: tuple[str, ...],
              estimable: bool = True) -> tuple[str, int, bool, float | tuple | None]:
    """A delay table's ``signal`` and ``gain``: (coordinate, derivative order, whether its
    rate is fed back too, the gain(s) or None).  ``signal = "x"`` or ``"x'"`` with one gain;
    ``signal = ["x", "x'"]`` (the paper's :math:`b_0 x(t-\\tau) + b_1 \\dot x(t-\\tau)`)
    with ``gain = [b0, b1]``; ``estimable``: a model's gains may be left out (a truth's not)."""
    written = d.get("signal", coords[0])
    signals = written if isinstance(written, list) else [written]
    choices = " or ".join(f"'{c}' or \"{c}'\"" for c in coords)
    pairs = (f"[\"{coords[0]}\", \"{coords[0]}'\"] (a position and its velocity, the paper's b0 x(t - tau) + "
             "b1 x'(t - tau))")
    if not signals or len(signals) > 2 or not all(isinstance(s, str) for s in signals):
        raise CvxidError(f"spec: [{where}] signal must be {choices}, or the pair {pairs}; got {written!r}")
    for signal in signals:
        if signal.strip().rstrip("'") not in coords or len(signal) - len(signal.rstrip("'")) > 1:
            raise CvxidError(f"spec: [{where}] signal must be {choices}, or the pair {pairs}; got {signal!r}")
    signals = [s.strip() for s in signals]
    coordinate, derivative = signals[0].rstrip("'"), len(signals[0]) - len(signals[0].rstrip("'"))
    rate = len(signals) == 2
    if rate and signals != [coordinate, coordinate + "'"]:
        raise CvxidError(f"spec: [{where}] signal = {written!r}: two fed-back signals are a position and its "
                         f"velocity, in that order: {pairs}")
    if "gain" not in d:
        return coordinate, derivative, rate, None
    if not rate:
        if isinstance(d["gain"], list):
            raise CvxidError(f"spec: [{where}] gain lists {len(d['gain'])} gains for one fed-back signal "
                             f"('{signals[0]}'): give one number, or list the signals (signal = {pairs})")
        return coordinate, derivative, rate, _number(d, "gain", where)
    gains = d["gain"]
    if not isinstance(gains, list) or len(gains) != 2:
        raise CvxidError(f"spec: [{where}] gain must list one gain for each fed-back signal, in the order of signal "
                         f"(gain = [b0, b1] for {signals}), got {gains!r}" + (
                             "; leave gain out with method = 'exact' to estimate both" if estimable else ""))
    return coordinate, derivative, rate, tuple(_number({"gain": g}, "gain", where) for g in gains)


def _input_delay(table: Table, where: str) -> InputDelay:
    """``input_delay = 0.03`` (known, seconds) or ``[model.input_delay]`` with optional
    ``tau_min`` and ``tau_max`` (estimated; ``tau_max`` by default a quarter period of the
    output's band edge)."""
    iw = f"{where}.input_delay"
    if not isinstance(table["input_delay"], Mapping):
        return InputDelay.known(_number(table, "input_delay", where, within=(0, 10.0),
                                        fix="a known input delay in seconds, or a table [model.input_delay] with "
                                            "tau_min and tau_max to estimate it"))
    d = _table(table, "input_delay", where, {"tau_min", "tau_max"})
    low = _number(d, "tau_min", iw, 0.0, within=(0, 10.0), fix="a delay cannot be negative")
    high = _number(d, "tau_max", iw, positive=True, within=(0, 10.0)) if "tau_max" in d else np.inf
    if not high > low:
        raise CvxidError(f"spec: [{iw}] needs tau_min < tau_max, got {low:g} and {high:g}")
    return InputDelay(low, low, high)


def _fit(table: Table, default_estimator: str = "adaptive_lasso") -> FitSettings:
    """``[fit]``; ``default_estimator``: a one-equation spec selects by default, a coupled
    one fits its listed terms by least squares."""
    where = "fit"
    lambdas = np.logspace(-6, 2, 50)
    if "lambdas" in table:
        lt = _table(table, "lambdas", where, {"min", "max", "count"})
        lo = _number(lt, "min", "fit.lambdas", positive=True, within=(1e-16, 1e12))
        hi = _number(lt, "max", "fit.lambdas", positive=True, within=(1e-16, 1e12),
                     fix="the data are scaled to unit size: lambdas past 100 keep no term")
        count = _number(lt, "count", "fit.lambdas", 50, integer=True, within=(1, 1000),
                        fix="each lambda is a convex solve; 30 to 200 resolve a path")
        if lo > hi:
            raise CvxidError(f"spec: [fit.lambdas] min ({lo:g}) is larger than max ({hi:g})")
        lambdas = np.logspace(np.log10(lo), np.log10(hi), count)
    velocity = _string(table, "velocity", where, "savgol")
    solver = _string(table, "solver", where, "CLARABEL").upper()
    if solver not in SOLVERS:
        raise CvxidError(f"spec: [fit] solver must be one of {', '.join(SOLVERS)}, got '{solver}'")
    backend = _string(table, "backend", where, "loky", choices=BACKENDS)
    scheduler = table.get("scheduler")
    if scheduler is not None:
        scheduler = _string(table, "scheduler", where, "")
    check_backend(backend, scheduler, where=f"spec: [{where}] backend")
    estimator = _string(table, "estimator", where, default_estimator, choices=SELECTORS)
    settings = FitSettings(
        backend=backend,
        scheduler=scheduler,
        estimator=estimator,
        lambdas=lambdas,
        velocity=velocity,
        solver=solver,
        debias=_bool(table, "debias", where, True),
        selection=_string(table, "selection", where, "1se", choices=SELECTION_RULES),
        bootstrap=_bootstrap(table),
        stability=_stability(table, estimator),
        orders=_orders(table),
        refine=_string(table, "refine", where, "none", choices=("none", "output_error")).replace("none", "") or None,
        window=_window(table, where),
        loss=_string(table, "loss", where, "squared", choices=("squared", "huber")),
        allow_large=_bool(table, "allow_large", where, False),
        prune=_bool(table, "prune", where, True),
        n_jobs=n_jobs(table),
    )
    if "stability" in table and settings.stability is not None and settings.bootstrap is not None:
        raise CvxidError("spec: [fit] stability and bootstrap both select on resampled records, and with bootstrap "
                         "its mean is the estimate (stability selection is not run): remove one of them")
    if "prune" in table and settings.prune and (settings.refine is None or estimator not in SELECTING):
        missing, fix = ("refine = \"output_error\"", "add it") if settings.refine is None else (
            f"an estimator that selects (lasso, adaptive_lasso, stlsq), not '{estimator}'", "choose one")
        raise CvxidError(f"spec: [{where}] prune removes selected terms the output-error polish does not need: it "
                         f"needs {missing}; remove prune, or {fix}")
    solves = len(lambdas) * (settings.bootstrap.samples if settings.bootstrap else 1) * max(len(settings.orders), 1)
    if settings.velocity == "auto":
        solves *= 3
    if solves > MAX_SOLVES and not settings.allow_large:
        raise CvxidError(
            f"spec: [fit] asks for {solves:,} convex solves (lambdas count x bootstrap samples x orders"
            f"{' x 3 velocity estimators' if settings.velocity == 'auto' else ''}), hours of work; reduce them, or "
            "set allow_large = true in [fit] to run it anyway"
        )
    return settings


def _window(table: Table, where: str) -> float | str | Windows:
    """``[fit] window``: ``"auto"`` (from the data), ``"record"`` (the whole record), seconds
    (sliding windows) or ``{ restart = seconds }`` / ``{ sliding = seconds }``."""
    value = table.get("window", "auto")
    if isinstance(value, str):
        return _string(table, "window", where, "auto", choices=WINDOWS)
    if isinstance(value, Mapping):
        kinds = _table(table, "window", where, set(KINDS))
        if len(kinds) != 1:
            raise CvxidError(f"spec: [{where}] window as a table names one kind: {{ restart = 0.05 }} or "
                             "{ sliding = 0.5 }")
        ((kind, _),) = kinds.items()
        return Windows(_number(kinds, kind, f"{where}.window", positive=True, within=(None, 1e6)), kind)
    return _number(table, "window", where, positive=True, within=(None, 1e6))


CONVEX_SELECTORS = ("lasso", "adaptive_lasso")
"""The selectors stability selection is on for by default (the paper's ``stlsq`` keeps its
own rule unless a spec asks)."""


def _stability(table: Table, estimator: str) -> StabilitySettings | None:
    """``[fit] stability``: ``true`` (the default settings), ``false`` (off) or a table of
    ``samples``, ``blocks``, ``threshold``, ``seed``; absent: on for :data:`CONVEX_SELECTORS`."""
    value = table.get("stability", estimator in CONVEX_SELECTORS)
    if "stability" in table and value is not False and estimator not in SELECTING:
        raise CvxidError(f"spec: [fit] stability repeats a selection, and estimator = '{estimator}' selects nothing "
                         "on a lambda path; remove stability, or choose lasso, adaptive_lasso or stlsq")
    if isinstance(value, bool):
        return StabilitySettings() if value else None
    if not isinstance(value, Mapping):
        raise CvxidError(f"spec: [fit] stability is true, false or a table {{ samples = 20, blocks = 10, "
                         f"threshold = 0.7, seed = 0 }}, got {value!r}")
    t = _table(table, "stability", "fit", {"samples", "blocks", "threshold", "seed"})
    return StabilitySettings(
        samples=_number(t, "samples", "fit.stability", 20, integer=True, within=(2, 1000),
                        fix="halves of the record, each selected once"),
        blocks=_number(t, "blocks", "fit.stability", 10, integer=True, within=(4, 100),
                       fix="an even number of contiguous blocks the record's rows are cut into; each half keeps "
                           "half of them"),
        threshold=_number(t, "threshold", "fit.stability", 0.7, within=(0.5, 1),
                          fix="the share of halves that must keep a term"),
        seed=_number(t, "seed", "fit.stability", 0, integer=True, within=(0, 2**32 - 1)),
    )


def _bootstrap(table: Table) -> BootstrapSettings | None:
    if "bootstrap" not in table:
        return None
    b = _table(table, "bootstrap", "fit", {"samples", "fraction", "seed", "resample"})
    return BootstrapSettings(
        samples=_number(b, "samples", "fit.bootstrap", 30, integer=True, within=(2, 10_000),
                        fix="a few hundred resamples give stable spreads"),
        fraction=_number(b, "fraction", "fit.bootstrap", 0.5, positive=True, within=(None, 1),
                         fix="the share of rows in each resample"),
        seed=_number(b, "seed", "fit.bootstrap", 0, integer=True, within=(0, 2**32 - 1)),
        n_jobs=n_jobs(table),
        resample=_string(b, "resample", "fit.bootstrap", "blocks", choices=RESAMPLE),
    )


def n_jobs(table: Table) -> int:
    """``[fit] n_jobs``: parallel workers, -1 for every core (joblib's convention)."""
    value = _number(table, "n_jobs", "fit", 1, integer=True, within=(-1, 256),
                    fix="-1 uses every core, 1 runs serially")
    if value == 0:
        raise CvxidError("spec: [fit] n_jobs = 0 is no worker; use 1 (serial), a count, or -1 (every core)")
    return value


def _orders(table: Table) -> tuple[int, ...]:
    if "orders" not in table:
        return ()
    o = _table(table, "orders", "fit", {"min", "max"})
    lo = _number(o, "min", "fit.orders", 1, integer=True, within=(1, MAX_ORDER), fix=ORDER_FIX)
    hi = _number(o, "max", "fit.orders", integer=True, within=(1, MAX_ORDER), fix=ORDER_FIX)
    if lo > hi:
        raise CvxidError(f"spec: [fit.orders] min ({lo}) is larger than max ({hi})")
    return tuple(range(lo, hi + 1))


def _truth(raw: Table, model: ModelSpec) -> Truth:
    where = "truth"
    t = _table(raw, "truth", "", {"mass", "coefficients", "delay", "history", "input_delay"})
    coord = model.coordinate
    coefs_t = t.get("coefficients", {})
    if not isinstance(coefs_t, Mapping):
        raise CvxidError("spec: [truth] coefficients must be a table of term = value")
    terms, values = [], []
    for name, value in coefs_t.items():
        terms.append(resolve_term(name, (coord,)))
        values.append(_number(coefs_t, name, "truth.coefficients"))
    mass = _number(t, "mass", where, 1.0, positive=True)
    gains, tau, derivative = (0.0, 0.0), 0.0, 0
    if "delay" in t:
        d = _table(t, "delay", where, {"signal", "gain", "tau"})
        if "gain" not in d:
            raise CvxidError("spec: [truth.delay] needs 'gain' (the true feedback gain, one for each signal)")
        _, derivative, _, gain = _fed_back(d, "truth.delay", (coord,), estimable=False)
        gains = (*np.atleast_1d(gain), 0.0)
        tau = _number(d, "tau", "truth.delay")
        if tau < 0:
            raise CvxidError(f"spec: [truth.delay] tau must be >= 0, got {tau}")
    history = _string(t, "history", where, "zero", choices=ASSUMED)
    system = CoupledSystem((Equation(coord, mass, tuple(terms), tuple(values), 1.0, float(gains[0]),
                                     float(gains[1])),), coord, tau, history, derivative)
    physical = {"m": mass}
    for term, value in zip(terms, values):
        pname, sign = model.named_parameter(term.name)
        physical[pname] = sign * value
    if "delay" in t:
        physical["tau"] = tau
        if model.delay is not None and model.delay.gain is None:  # estimated: beside its estimate
            physical.update(zip(model.gain_names, map(float, gains)))
    input_delay = _number(t, "input_delay", where, 0.0, within=(0, 10.0), fix="the input's delay in seconds")
    if input_delay:
        physical["tau_u"] = input_delay
    return Truth(system, model.input, physical, input_delay)


# ---------------------------------------------------------------------- experiments
def _names(value, default_key: str, where: str, key: str) -> dict[str, str]:
    if isinstance(value, str):
        return {default_key: value}
    if isinstance(value, Mapping) and all(isinstance(v, str) for v in value.values()):
        return dict(value)
    raise CvxidError(f"spec: [{where}] {key} must be a column name or a table of names, got {value!r}")


def _per_coordinate(sim: Table, key: str, where: str, coords: tuple[str, ...]) -> dict[str, float]:
    """An initial state: one number for every coordinate, or a table by coordinate."""
    value = sim.get(key, 0.0)
    if isinstance(value, Mapping):
        unknown = set(value) - set(coords)
        if unknown:
            raise CvxidError(f"spec: [{where}] {key} names unknown coordinate(s) {', '.join(sorted(unknown))}")
        return {c: float(_number(value, c, f"{where}.{key}", 0.0)) for c in coords}
    return {c: float(_number(sim, key, where, 0.0)) for c in coords}


def _simulated(spec: ProblemSpec, which: str, sim: Table) -> Experiment:
    where = f"data.{which}.simulate"
    t, force, sx, sf, rng = simulation_setup(sim, where)
    coords = spec.coordinates
    late = spec.truth.input_delay
    x, v = simulate_coupled(spec.truth.system, t, (lambda s: force(s - late)) if late else force,
                            _per_coordinate(sim, "x0", where, coords), _per_coordinate(sim, "v0", where, coords))
    outputs = {c: x[c] + sx * rng.standard_normal(t.size) for c in coords}
    # the simulator's true velocities travel along, for velocity = "measured"
    return Experiment(t, outputs, {spec.truth.input: force(t) + sf * rng.standard_normal(t.size)}, name=which,
                      velocities=v)


def simulation_setup(sim: Table, where: str):
    """Time grid, input function, output and input noise levels and the seeded generator
    of a ``[data.*.simulate]`` table."""
    duration = _number(sim, "duration", where, positive=True, within=(None, 1e6))
    dt = _number(sim, "dt", where, positive=True, within=(1e-9, None))
    n = int(round(duration / dt)) + 1
    if n < 20 or n > 5_000_000:
        raise CvxidError(f"spec: [{where}] duration/dt gives {n} samples; use between 20 and 5,000,000")
    components = sim.get("input")
    if not isinstance(components, list) or not all(isinstance(c, Mapping) for c in components):
        raise CvxidError(f"spec: [{where}] input must be a list of tables like {{kind = \"sine\", ...}}")
    force = excitation(components, where + ".input")
    noise = _table(sim, "noise", where, {"output", "input"})
    rng = np.random.default_rng(_number(sim, "seed", where, 0, integer=True, within=(0, 2**32 - 1)))
    return (np.arange(n) * dt, force, _number(noise, "output", where + ".noise", 0.0, within=(0, None)),
            _number(noise, "input", where + ".noise", 0.0, within=(0, None)), rng)
