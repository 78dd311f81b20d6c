r"""Missing effects of a coupled model: rank, add, refit, watch the error fall.

Every candidate effect of the catalogue (Coulomb friction, damping, stiffness, offset, …)
is built for every coordinate and added to every equation with its own coefficient; the
joint least-squares fit is redone at the current delay and scored by the equation error on
the test data, :math:`\text{ratio} = \text{MSE}_\text{test}(\text{with}) /
\text{MSE}_\text{test}(\text{without})`.  One regression holding every candidate column is
built once; each candidate is a column subset of it.

:func:`refine_joint` adds the best candidate while it passes the one acceptance rule of
:mod:`cvxid.diagnosis.acceptance`: its own ratio below 1, its inclusion probability over
halves of the training rows, and a lower test equation error and free-run simulation
error (every coordinate, relative to its spread) of the re-identified model (delay
profiled again: a re-profiled delay alone can lower the errors of a spurious term).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Sequence

import numpy as np
import pandas as pd

from cvxid.data.experiment import Experiment
from cvxid.diagnosis.acceptance import accepted, inclusion, stop_reason, stopped_at
from cvxid.errors import CvxidError
from cvxid.identified import IdentifiedSystem
from cvxid.identify.problem import Problem
from cvxid.identify.system import identify_system
from cvxid.model.equation import ModelSpec
from cvxid.model.library import CATALOGUE, PARAMETERS, resolve_term
from cvxid.model.system import SystemSpec
from cvxid.model.terms import Term
from cvxid.progress import progress
from cvxid.regression.builder import SystemBuilder
from cvxid.regression.regression import Regression


def candidate_terms(specs: dict[str, ModelSpec], candidates: Sequence[str] | None = None) -> dict[str, Term]:
    """Candidate name → term: each catalogue effect for each coordinate (``"coulomb(theta)"``),
    the spec's declared effects (``[diagnose.effects]``: terms of the coordinates already),
    or the user's effect and term names; terms every equation already has are left out."""
    coords = tuple(s.coordinate for s in specs.values())
    declared = next(iter(specs.values())).effects
    names = [n for n in (*CATALOGUE, *declared) if n not in PARAMETERS] if candidates is None else list(candidates)
    out = {}
    for name in names:
        if name in declared:
            built = {name: declared[name].build(coords[0])}
        elif name in CATALOGUE:
            built = {f"{name}({c})": CATALOGUE[name].build(c) for c in coords}
        else:
            built = {name: resolve_term(name, coords)}
        for label, term in built.items():
            if not all(term.name in s.column_names for s in specs.values()):
                out[label] = term
    if not out:
        raise CvxidError("no candidate effect is missing from the coupled model; nothing to diagnose")
    return out


def _with(specs: dict[str, ModelSpec], terms: Sequence[Term]) -> dict[str, ModelSpec]:
    return {label: replace(s, library=s.library + [t for t in terms if t.name not in s.column_names])
            for label, s in specs.items()}


def diagnose_joint(result: IdentifiedSystem, train: Experiment, test: Experiment, candidates: Sequence[str] | None = None,
                   velocity: str = "savgol", window: float | str | None = "auto",
                   builders: tuple[SystemBuilder, SystemBuilder] | None = None) -> pd.DataFrame:
    """The candidates ranked by the test equation error of the joint refit with each one
    (column ``ratio``: below 1 the effect explains part of the error).  ``builders`` of
    the train and test data may be passed to reuse their columns."""
    specs = result.specs
    terms = candidate_terms(specs, candidates)
    union = _with(specs, list(terms.values()))
    train_rows, test_rows = builders or _builders(specs, train, test, velocity, window)
    fitted = train_rows.at(result.tau, union)
    scored = test_rows.at(result.tau, union)
    base = [f"{label}:{n}" for label, s in specs.items() for n in s.column_names]
    nonnegative = [f"{label}:{n}" for label, s in specs.items() for n in s.nonnegative]

    def score(names):
        problem = Problem.from_regression(fitted.subset(names), nonnegative, ties=result.ties)
        fit = problem.refit(np.ones(problem.k, bool))
        return scored.subset(names).mse(fit.coefficients)

    before = score(base)
    rows = []
    for label, term in progress(terms.items(), "diagnosis: candidates", total=len(terms)):
        added = [f"{eq}:{term.name}" for eq, s in specs.items() if term.name not in s.column_names]
        after = score(base + added)
        rows.append({"candidate": label, "term": term.name, "meaning": term.meaning, "test_mse": after,
                     "ratio": after / before})
    frame = pd.DataFrame(rows).sort_values("ratio").set_index("candidate")
    frame.attrs["test_mse_before"] = before
    return frame


def equation_mse(result: IdentifiedSystem, rows: SystemBuilder) -> float:
    """Mean squared equation error of ``result`` on the data of ``rows``, all equations
    stacked."""
    regression = rows.at(result.tau, result.specs)
    coefficients = result.coefficients
    return regression.mse(np.array([coefficients.get(n, 0.0) for n in regression.names]))


def simulation_error(result: IdentifiedSystem, experiment: Experiment) -> float:
    """Mean over coordinates of the free-run RMS error relative to the coordinate's
    standard deviation (inf when the simulation diverges)."""
    table = result.compare(experiment, initial="record")
    spread = np.array([np.std(experiment.output(c)) for c in table.index])
    return float(np.mean(table["rms"].to_numpy() / spread))


@dataclass
class JointRefinement:
    """The diagnose → add → refit loop: its steps, rankings and final result."""

    result: IdentifiedSystem
    steps: list[dict] = field(default_factory=list)
    rankings: list[pd.DataFrame] = field(default_factory=list)
    stopped: dict | None = None
    """Why the loop stopped at its last ranking's best candidate, when it did
    (:func:`~cvxid.diagnosis.acceptance.stopped_at`)."""

    def table(self) -> pd.DataFrame:
        return pd.DataFrame(self.steps)

    def plot(self):
        from cvxid.plots import refinement_figure

        steps = self.steps
        labels = ["start"] + [s["added"] for s in steps]
        series = {
            "test equation-error MSE": [steps[0]["test_mse_before"]] + [s["test_mse_after"] for s in steps],
            "test simulation error (relative)": [steps[0]["simulation_error_before"]]
            + [s["simulation_error_after"] for s in steps],
        } if steps else {}
        return refinement_figure(labels, series)

    def __repr__(self) -> str:
        if not self.rankings:
            return "Joint refinement: not run"
        lines = ["Joint diagnosis (test equation error with each candidate added, ratio < 1 helps):"]
        lines += ["  " + line for line in self.rankings[0].head(5)[["term", "ratio"]].to_string().splitlines()]
        if self.steps:
            lines.append("Refinement:")
            lines += ["  " + line for line in self.table().to_string(index=False).splitlines()]
        else:
            lines.append("Refinement: no candidate passed the acceptance rule; the model is kept")
        if self.stopped is not None:
            lines.append(stop_reason(self.stopped))
        return "\n".join(lines)


def refine_joint(result: IdentifiedSystem, train: Experiment, test: Experiment, candidates: Sequence[str] | None = None,
                 max_steps: int = 5, velocity: str = "savgol", window: float | str | None = "auto",
                 builders: tuple[SystemBuilder, SystemBuilder] | None = None) -> JointRefinement:
    """Add the best-ranked effect and re-identify (delay profiled again) while it passes
    the acceptance rule (:mod:`cvxid.diagnosis.acceptance`).  ``builders`` of the train and
    test data may be passed to reuse their columns."""
    out = JointRefinement(result)
    train_rows, test_rows = builders or _builders(result.specs, train, test, velocity, window)
    equation_error = equation_mse(result, test_rows)
    sim_error = simulation_error(result, test)
    for _ in progress(range(max_steps + 1), "refine: diagnose, add, refit"):
        try:
            ranking = diagnose_joint(out.result, train, test, candidates, velocity, window, (train_rows, test_rows))
        except CvxidError:
            break
        out.rankings.append(ranking)
        if len(out.steps) >= max_steps:
            break
        best = ranking.index[0]
        term = ranking.loc[best, "term"]
        out.stopped = stopped_at(best, 1 / ranking["ratio"].iloc[0])
        if not ranking["ratio"].iloc[0] < 1:  # (NaN: no evidence either)
            break
        specs = _with(out.result.specs, [resolve_term(term, tuple(out.result.specs))])
        trial = identify_system(SystemSpec(specs, out.result.ties), train_rows)
        new_equation = equation_mse(trial, test_rows)
        new_sim = simulation_error(trial, test)
        falls = new_equation < equation_error and new_sim < sim_error
        probability = _inclusion(out.result, trial, term, train_rows, test_rows) if falls else float("nan")
        out.stopped = stopped_at(best, 1 / ranking["ratio"].iloc[0], falls, probability)
        if not accepted(probability):
            break
        out.stopped = None
        out.steps.append({"added": best, "term": term, "test_mse_before": equation_error, "test_mse_after": new_equation,
                          "inclusion": probability, "simulation_error_before": sim_error,
                          "simulation_error_after": new_sim,
                          "tau": trial.tau})
        out.result, equation_error, sim_error = trial, new_equation, new_sim
    return out


def _inclusion(before: IdentifiedSystem, trial: IdentifiedSystem, term: str, train_rows: SystemBuilder,
               test_rows: SystemBuilder) -> float:
    """The inclusion probability of ``term`` in the model it joins, ``trial`` (at its
    delay), in every equation of ``before`` that lacked it, beside every other column
    (:func:`~cvxid.diagnosis.acceptance.inclusion`; each half the same stretches of time of
    every equation)."""
    kept = [f"{label}:{n}" for label, s in before.specs.items() for n in s.column_names]
    added = [f"{label}:{term}" for label, s in before.specs.items() if term not in s.column_names]
    nonnegative = [f"{label}:{n}" for label, s in trial.specs.items() for n in s.nonnegative]
    fitted = {label: train_rows.builders[label].at(trial.tau, spec) for label, spec in trial.specs.items()}
    return inclusion(Regression.block(fitted), test_rows.at(trial.tau, trial.specs), kept, added, nonnegative,
                     trial.ties, parts=[r.shape[0] for r in fitted.values()])


def _builders(specs, train, test, velocity, window) -> tuple[SystemBuilder, SystemBuilder]:
    """The train and test builders, the test data on the training data's windows."""
    rows = SystemBuilder(specs, train, velocity, window)
    return rows, SystemBuilder(specs, test, velocity, rows.window)
