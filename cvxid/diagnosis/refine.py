r"""The add-an-effect loop: diagnose, add the best effect, refit, and keep it only when the
data agree — the same loop for one equation and for a system of :math:`N \ge 1`.

Each round ranks the candidates the model lacks (:func:`~cvxid.diagnosis.ranking.diagnose`),
refits the model with the best one (its delay profiled again; with a selection and a
library to select from, the library selected anew beside it, so that a term the first
selection dropped may return and one that only stood in for the missing effect may leave),
and adds it when it passes the one acceptance rule of :mod:`cvxid.diagnosis.acceptance`:
it lowers the test record's equation error, halves of the training rows keep choosing it,
and the refitted model's test equation error and a simulation of the test record (its
free run or its k-step-ahead prediction, the mean fit over the coordinates) fall.  When
the best candidate has collinear rivals that lower the test equation error too, each is
refitted and the free run of the test record chooses: the equation error cannot tell a
quadratic from a cubic damping, a simulation can.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field, replace
from typing import Sequence

import numpy as np
import pandas as pd

from cvxid.data.experiment import Experiment
from cvxid.diagnosis.acceptance import accepted, chance_fall, inclusion, stop_reason, stopped_at
from cvxid.diagnosis.candidates import default_candidates, lacks_delay, missing, with_candidate, with_input_delay
from cvxid.diagnosis.compare import Comparison, compare_system, mean_fit
from cvxid.diagnosis.ranking import Diagnosis, builders_for, by_fit, diagnose, feedback_builders
from cvxid.diagnosis.residuals import residuals
from cvxid.errors import CvxidError, CvxidWarning
from cvxid.identified import IdentifiedModel, IdentifiedSystem
from cvxid.identify.output_error import output_error
from cvxid.identify.problem import Problem
from cvxid.identify.profile import profile_delay, profile_input_delay, with_input_tau
from cvxid.identify.selection import Selection
from cvxid.identify.system import identify_system
from cvxid.model.equation import ModelSpec
from cvxid.model.system import SystemSpec
from cvxid.progress import progress
from cvxid.regression.builder import RegressionBuilder, SystemBuilder


@dataclass(frozen=True)
class RefineStep:
    """One accepted addition and the errors around it: the test record's equation-error
    MSE and its free-run fit (%, the mean over coordinates) before and after, and the delay
    after it with its 95 % interval (``tau_interval``, from the equation error's profile: an
    interval spanning most of the delay's range says the equation error does not determine
    the delay at that step); ``columns``: the columns it added (none for a delay estimated
    again)."""

    added: str
    term: str
    group: list[str]
    inclusion: float
    """Its inclusion probability over halves of the training rows (the acceptance rule)."""
    test_mse_before: float
    test_mse_after: float
    fit_before: float | None
    fit_after: float | None
    tau: float | None = None
    columns: tuple[str, ...] = ()
    tau_interval: tuple[float, float] | None = None
    polished: bool = False
    """The free runs that decided (``fit_before``, ``fit_after``) are of the two models
    polished by output error: the refit's equation-error model simulated apart from the data
    while the equation error and the halves chose the effect (:func:`_polished`)."""

    @property
    def simulation_error_before(self) -> float | None:
        """The free run's RMS error relative to the output's spread, :math:`1 - \\text{fit}/100`."""
        return None if self.fit_before is None else 1.0 - self.fit_before / 100.0

    @property
    def simulation_error_after(self) -> float | None:
        return None if self.fit_after is None else 1.0 - self.fit_after / 100.0

    def as_dict(self) -> dict:
        return dict(self.__dict__, columns=list(self.columns),
                    tau_interval=None if self.tau_interval is None else list(self.tau_interval),
                    simulation_error_before=self.simulation_error_before,
                    simulation_error_after=self.simulation_error_after)


@dataclass
class Refinement:
    """The diagnose → add → refit loop: its steps, diagnoses and final system."""

    system: IdentifiedSystem
    steps: list[RefineStep]
    diagnoses: list[Diagnosis]
    comparisons: list[dict[str, Comparison]] = field(default_factory=list)
    """The test record's free runs by coordinate: the starting model's, then one after each
    added effect (empty when nothing was added); a step judged by polished models
    (:attr:`RefineStep.polished`) shows its polished model (and the first, the polished
    start)."""
    start: IdentifiedSystem | None = None
    """The model the loop started from."""
    stopped: dict | None = None
    """Why the loop stopped at its last diagnosis's best candidate, when it did (not for
    lack of candidates or steps): ``effect``, ``validation_ratio``, whether the refitted
    model's test ``errors_fall`` (equation and simulation), and its ``inclusion``
    (null when an earlier condition failed first)."""
    builders: tuple | None = None
    """The train and test data's builders of :attr:`system` (with the fed-back delay the
    loop added, when it added one)."""
    ranking_only: bool = False
    """No step was asked for (``[diagnose] refine = false``, the default): the loop ranked
    the effects and added none by design."""

    def __post_init__(self):
        self.system = IdentifiedSystem.of(self.system)
        self.start = None if self.start is None else IdentifiedSystem.of(self.start)

    @property
    def model(self) -> IdentifiedModel:
        """The final model of one equation (a system of several: :attr:`system`)."""
        if self.system.single is None:
            raise CvxidError(f"this refinement is of {len(self.system.models)} coupled equations: use .system")
        return self.system.single

    def table(self) -> pd.DataFrame:
        """One row per added effect; the delay's interval as ``tau_low`` and ``tau_high``."""
        def row(step):
            low, high = step.tau_interval or (None, None)
            return dict({k: v for k, v in step.__dict__.items() if k not in ("columns", "tau_interval")},
                        **({"tau_low": low, "tau_high": high} if low is not None else {}))

        return pd.DataFrame([row(s) for s in self.steps]).set_index("added") if self.steps else pd.DataFrame()

    @property
    def labels(self) -> list[str]:
        """``start``, then ``+ effect`` for each added effect; ``(polished)`` after a model
        shown polished (a step judged so, :attr:`RefineStep.polished`, and the start before
        a first step judged so)."""
        mark = lambda polished: " (polished)" if polished else ""  # noqa: E731
        return [f"start{mark(bool(self.steps) and self.steps[0].polished)}"] + [
            f"+ {s.added}{mark(s.polished)}" for s in self.steps]

    def plot(self, final: dict | None = None, final_mse: float | None = None, label: str | None = None):
        """The error history: the test record's equation-error MSE and free-run error
        (:math:`1 - \\text{fit}/100`) before and after each added effect, and with
        ``final`` (coordinate → :class:`~cvxid.diagnosis.compare.Comparison` of the run's
        final model, after the output-error polish) and its equation-error MSE a last
        point for it, labelled ``label`` (:func:`final_label`; :data:`FINAL` by default)."""
        from cvxid.plots import refinement_figure

        steps = self.steps
        if not steps:
            raise CvxidError("nothing to plot: the refinement added no effect")
        labels = self.labels
        mse = [steps[0].test_mse_before] + [s.test_mse_after for s in steps]
        # a fed-back delay added is scored on its own rows (they start later): a line of its own from there
        moved = next((i for i in range(1, len(steps)) if not np.isclose(
            steps[i].test_mse_before, steps[i - 1].test_mse_after, rtol=1e-9, atol=0)), None)
        if moved is None:
            series = {"test equation-error MSE": mse}
        else:
            series = {"test equation-error MSE": mse[:moved + 1] + [np.nan] * (len(mse) - moved - 1),
                      "the same, on the rows of the added delay": [np.nan] * moved + [steps[moved].test_mse_before]
                      + mse[moved + 1:]}
        fits = [steps[0].fit_before] + [s.fit_after for s in steps]
        last = _drawable(final)
        if last is not None:
            labels = labels + [label or FINAL]
            for values in series.values():
                values.append(np.nan)
            list(series.values())[-1][-1] = np.nan if final_mse is None else final_mse
            fits.append(mean_fit(last))
        if all(f is not None for f in fits):
            series["test free-run error (1 - fit)"] = [1.0 - f / 100.0 for f in fits]
        return refinement_figure(labels, series)

    def plot_responses(self, final: dict | None = None, label: str | None = None):
        """The test record's free run before and after each added effect, over the
        measurement, one panel each (a column per coordinate; the fit in each title), and
        with ``final`` (coordinate → comparison of the run's final model) a last row for
        it, from the initial state the run estimated (its reported fit; a stick-slip record's
        own first state can be far from the model's: the held-out report seed 1005's final
        model fits 98.9 % from it, 81.7 % from the record's)."""
        from cvxid.plots import responses_figure

        if not self.comparisons:
            raise CvxidError("nothing to plot: the refinement added no effect")
        last = _drawable(final)
        if last is None:
            return responses_figure(self.labels, self.comparisons)
        return responses_figure(self.labels + [label or FINAL], self.comparisons + [last])

    def plot_residuals(self, experiment: Experiment, bins: int = 21):
        """Where the starting model fails: each equation's error on ``experiment`` in time and
        binned against its position and velocity (a step at x' = 0 is a dry friction, a
        slope in x a stiffness, a level an offset)."""
        from cvxid.plots import residual_figure

        if self.start is None:
            raise CvxidError("nothing to plot: this refinement does not know the model it started from")
        views = {label: residuals(self.start, experiment, label) for label in self.start.models}
        return residual_figure(views if len(views) > 1 else next(iter(views.values())), bins, title="where the starting model fails: its equation error on "
                                                  f"'{experiment.name}'")

    def __repr__(self) -> str:
        if self.ranking_only:
            return ("Refinement: not asked for ([diagnose] refine = false, the default): the ranking adds nothing; "
                    "refine = true adds the best effect while it passes the acceptance rule")
        head = "Refinement" if self.steps else "Refinement: nothing added"
        lines = [head] + ([self.table().to_string(float_format=lambda v: f"{v:.4g}")] if self.steps else [])
        if self.stopped is not None:
            lines.append(stop_reason(self.stopped))
        return "\n".join(lines)


FINAL = "final (polished)"
"""The label of the run's final model in the refinement's figures."""


def final_label(added: list[str] = (), removed: list[str] = ()) -> str:
    """The final model's label when the stages after the loop changed its effects:
    ``added`` by the diagnosis by simulation error, ``removed`` (set to 0) by the
    output-error polish (an eleventh outside check: the figures said ``+ cubic_damping``
    where the final model had ``x'|x'|`` in its place)."""
    changes = [f"+ {name}" for name in added] + [f"\u2212 {name}" for name in removed]
    return FINAL if not changes else f"{FINAL}:\n{', '.join(changes)}"


def zeroed(steps, coefficients: dict) -> list:
    """The loop's ``steps`` whose every column ``coefficients`` hold at 0: effects the
    diagnosis added that a later fit (the output-error polish, at a sign constraint's
    bound) set to 0 (a delay estimated again adds no column, and is not among them)."""
    return [s for s in steps if s.columns and all(coefficients.get(c, 0.0) == 0.0 for c in s.columns)]


def _drawable(final: dict | None) -> dict | None:
    """The final model's comparisons when each has a free run (from the initial state the
    run estimated on the test record, as its reported fit), else None."""
    if not final or any(c.free_run is None for c in final.values()):
        return None
    return final


def refit_system(system: SystemSpec, rows: SystemBuilder, support: Sequence[str], tau: float | None,
                 lam: float = 0.0) -> IdentifiedSystem:
    """Least squares of ``system`` on the named columns (plus the unpenalised ones), signs
    and ties kept; an exact delay and an input delay to estimate are profiled again on that
    support (``rows``: the training data's builder)."""
    keep = np.array([n in support for n in system.column_names])
    if any(s.input_delay is not None and s.input_delay.free for s in system.equations.values()):
        at = profile_delay(rows, support=keep, nonnegative=system.nonnegative, model=system.equations,
                           ties=system.ties).estimate if system.exact else tau
        late = profile_input_delay(rows, system.equations, at, keep, system.nonnegative, ties=system.ties)
        system = SystemSpec(with_input_tau(system.equations, late.estimate), system.ties)
    return identify_system(system, rows, keep, lam=lam, tau=None if system.exact else tau)


def refit(spec: ModelSpec, train: Experiment, support: Sequence[str], tau: float | None,
          velocity: str = "savgol", lam: float = 0.0, window: float | str | None = "auto",
          builder: SystemBuilder | RegressionBuilder | None = None) -> IdentifiedModel:
    """:func:`refit_system` of one equation: least squares of ``spec`` on the named columns
    (plus the unpenalised ones), an exact delay and an input delay to estimate profiled
    again on that support (``builder``: the train data's, to reuse)."""
    rows = SystemBuilder.of(builder) if builder is not None else SystemBuilder({spec.coordinate: spec}, train, velocity,
                                                                                window)
    return refit_system(SystemSpec.of(spec), rows, support, tau, lam).single


def refine(
    model: IdentifiedModel | IdentifiedSystem,
    train: Experiment,
    test: Experiment,
    candidates: Sequence[str] | None = None,
    max_steps: int = 5,
    velocity: str = "savgol",
    window: float | str | None = "auto",
    builders: tuple[SystemBuilder, SystemBuilder] | None = None,
    selection: Selection | None = None,
) -> Refinement:
    """Repeat diagnose → add the best effect → refit while the best effect passes the
    acceptance rule (see the module docstring), for one equation or a system of several.
    ``builders`` of the train and test data may be passed to reuse their columns;
    ``selection`` selects the library anew beside each effect (when there is one to select
    from)."""
    system = start = IdentifiedSystem.of(model)
    train_rows, test_rows = builders_for(system.specs, train, test, velocity, window, builders)
    fed_rows = None  # the builders with a fed-back delay added, made when the delay is a candidate
    steps, diagnoses, comparisons, stopped = [], [], [], None
    baseline = None  # the model's own test comparisons (unpolished): what the next refits are judged against
    candidates = list(candidates) if candidates is not None else None
    for _ in progress(range(max_steps), "refine: diagnose, add, refit"):
        pool = candidates if candidates is not None else default_candidates(system.specs)
        pool = [c for c in pool if missing(system.specs, c)]
        if not pool:
            break
        if "delay" in pool and lacks_delay(system.specs) and fed_rows is None:
            try:
                fed_rows = feedback_builders(system.specs, train, test, velocity, train_rows.window)
            except CvxidError as exc:  # (said once; the loop goes on without it)
                warnings.warn(f"the diagnosis leaves out the fed-back delay: {exc}", CvxidWarning, stacklevel=2)
                candidates = [c for c in (candidates if candidates is not None else pool) if c != "delay"]
                pool = [c for c in pool if c != "delay"]
                if not pool:
                    break
        dx = diagnose(system, train, test, pool, velocity, window, (train_rows, test_rows), fed_rows)
        diagnoses.append(dx)
        best = dx.top
        stopped = stopped_at(best, dx.ranking.loc[best, "validation_ratio"])
        if not dx.ranking.loc[best, "validation_ratio"] > 1:  # (NaN: no evidence either)
            break
        lacking = lacks_delay(system.specs)

        def rows_for(name):  # a fed-back delay to add is scored on its own rows, the model without it too
            return fed_rows if name == "delay" and lacking else (train_rows, test_rows)

        old = baseline or compare_system(system, test)
        group = next(g for g in dx.groups if best in g)
        # the equation error cannot tell a collinear group's members apart: of those that
        # lower it, the free run of the test record chooses
        # (terms against terms; a delay estimated again alone; an input delay against a fed-back delay to add)
        rivals = [g for g in group if g == best or dx.ranking.loc[g, "validation_ratio"] > 1 and (
            not dx.candidates[g].reestimated and not dx.candidates[best].reestimated
            or lacking and {g, best} == {"delay", "input_delay"})]
        tried = {g: _with_candidate(system, g, dx, train, *rows_for(g), selection) for g in rivals}
        compared = {g: compare_system(m, test) for g, m in tried.items()}
        fits = {g: mean_fit(c) for g, c in compared.items()}
        if len(rivals) > 1:
            diagnoses[-1] = dx = dx.decided(fits)
        # the best rival first; one the rule refuses gives way to the next (a quadratic damping whose
        # refit simulates worse than its cubic rival's may still be the one whose errors fall)
        refusal, polished_old = None, UNPOLISHED
        for best in by_fit(fits):
            rows = rows_for(best)
            # (the model's test error: that of the last accepted step on the same rows, else computed)
            before = steps[-1].test_mse_after if steps and rows[1] is test_rows else _test_mse(system, rows[1])
            new, new_cmp = tried[best], compared[best]
            after = _test_mse(new, rows[1])
            falls = after < before and _improvement(old, new_cmp) > 1  # (cheap: checked first)
            a_term = not dx.candidates[best].reestimated  # (a term's refit may be judged polished, below)
            probability = _inclusion(system, new, best, dx, *rows) if falls or after < before and a_term \
                else float("nan")
            judged = (old, new_cmp)
            if after < before and not falls and a_term and accepted(probability):
                # a term the equation error and the halves chose: the simulations of both models polished decide
                if polished_old is UNPOLISHED:  # (once a round; a failed polish is None, not tried again)
                    polished_old = _polished(system, train, test)
                judged = (polished_old, _polished(new, train, test))
                falls = None not in judged and _improvement(*judged, ("fit_percent",)) > 1
            polished = judged[1] is not new_cmp
            if falls and accepted(probability):
                break
            refusal = refusal or stopped_at(best, dx.ranking.loc[best, "validation_ratio"], falls,
                                            probability if falls or polished else float("nan"), polished)
        else:
            stopped = refusal
            break
        stopped = None
        joined = dx.candidates[best]
        steps.append(RefineStep(best, str(dx.ranking.loc[best, "term"]), group, probability, before, after,
                                mean_fit(judged[0]), mean_fit(judged[1]), new.tau,
                                () if joined.reestimated and not (best == "delay" and lacking) else tuple(  # (added)
                                    new.spec.column(label, joined.term.name) for label in joined.equations),
                                _interval(new), polished))
        comparisons = (comparisons or [judged[0]]) + [judged[1]]  # (each added effect's model as it was judged)
        baseline = new_cmp
        system, (train_rows, test_rows) = new, rows
    return Refinement(system, steps, diagnoses, comparisons, start, stopped, (train_rows, test_rows))


UNPOLISHED = object()
"""The round's model not polished yet (:func:`_polished` is None when its polish failed)."""


def _polished(system: IdentifiedSystem, train: Experiment, test: Experiment) -> dict[str, Comparison] | None:
    """The test record's comparisons of ``system`` polished by output error on ``train``
    (its delay free, no profile), or None when the polish fails.  Where the refit with a
    term simulates apart from the data (a dry friction's stick phases: its delay and damping
    from the equation error are poor) the free runs of the two polished models decide (a
    ninth outside check's stick-slip record, 8 s: its Coulomb friction, validation ratio 4.0
    and kept on the halves, simulated to 32.9 % unpolished and was refused against 59.5 %;
    polished, 90.0 % against 60.9 %, the noise allowing 89.9 %).  Not for a delay to
    estimate again or an input's delay, which an unprofiled polish trades with the fed-back
    delay (on stick-slip records an input delay of 0.3 s stood in for a fed-back delay the
    equation error had put at 0, and was added beside the friction)."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", CvxidWarning)
            fit = output_error(system, train, step=train.dt)
    except CvxidError:
        return None
    return compare_system(fit.system, test)


def _interval(system: IdentifiedSystem) -> tuple[float, float] | None:
    """The delay's 95 % interval from ``system``'s equation-error profile, if it has one."""
    interval = system.info.get("tau_interval")
    return None if interval is None else (float(interval[0]), float(interval[1]))


def _inclusion(before: IdentifiedSystem, after: IdentifiedSystem, name: str, dx: Diagnosis,
               train_rows: SystemBuilder, test_rows: SystemBuilder) -> float:
    """The candidate's inclusion probability (:func:`~cvxid.diagnosis.acceptance.inclusion`)
    in the model it joins: its column in each equation it joins, beside ``after``'s other
    terms and every unpenalised column, at ``after``'s delay (each half the same stretches
    of time of every equation).  A change of delay is tested where it would leave: its
    column beside ``before``'s terms, at ``before``'s delay."""
    candidate = dx.candidates[name]
    if candidate.reestimated and not (name == "delay" and lacks_delay(before.specs)):  # (an added delay: a term)
        model = before
        specs = {label: replace(s, library=s.library + [candidate.term]) if label in candidate.equations else s
                 for label, s in before.specs.items()}
    else:
        model, specs = after, after.specs
    system = SystemSpec(specs, model.ties)
    added = [system.column(label, candidate.term.name) for label in candidate.equations]
    coefficients = model.coefficients
    kept = [system.column(label, c.name) for label, s in specs.items() for c in s.columns
            if system.column(label, c.name) not in added
            and (c.penalty == 0 or coefficients.get(system.column(label, c.name), 0.0) != 0.0)]
    return inclusion(train_rows.at(model.tau, specs), test_rows.at(model.tau, specs), kept, added,
                     system.nonnegative, model.ties)


def _with_candidate(system: IdentifiedSystem, name: str, dx: Diagnosis, train: Experiment,
                    train_rows: SystemBuilder, test_rows: SystemBuilder,
                    selection: Selection | None) -> IdentifiedSystem:
    """``system`` refitted with the candidate ``name``: the delay or the input's delay
    estimated again on the same terms, or the candidate's term added to its equations (and
    a library to select from selected anew beside it, with a ``selection``)."""
    support = [n for n, c in system.coefficients.items() if c != 0.0]
    lam = next(iter(system.models.values())).lam
    spec = system.spec
    if name == "delay" and lacks_delay(system.specs):  # a fed-back delay: added, its gain and delay estimated
        fed = SystemSpec({label: replace(s, delay=train_rows.delay) for label, s in system.specs.items()}, system.ties)
        delayed = [fed.column(label, dx.candidates[name].term.name) for label in fed.equations]
        return refit_system(fed, train_rows, support + delayed, None, lam)
    if name == "delay":  # a wrong delay: estimate it again on the same terms
        return refit_system(spec, train_rows, support, None, lam)
    if name == "input_delay":  # the input acts late: estimate its delay on the same terms
        late = SystemSpec(with_input_delay(spec.equations, train), spec.ties)
        return refit_system(late, train_rows, support, system.tau, lam)
    candidate = dx.candidates[name]
    joined = SystemSpec(with_candidate(system.specs, candidate), system.ties)
    added = [joined.column(label, candidate.term.name) for label in candidate.equations]
    if selection is not None and any(c.penalty > 0 for s in system.specs.values() for c in s.columns):
        joined = SystemSpec({label: replace(s, listed=s.listed + (candidate.term.name,)) if label in candidate.equations
                             else s
                             for label, s in joined.equations.items()}, system.ties)
        support = _selected_anew(joined, system.tau, train_rows, test_rows, selection)
    return refit_system(joined, train_rows, support + added, system.tau, lam)


def _selected_anew(system: SystemSpec, tau: float | None, train_rows: SystemBuilder, test_rows: SystemBuilder,
                   selection: Selection) -> list[str]:
    """The columns ``selection`` keeps of ``system`` at the delay ``tau``, scored on the test rows."""
    problem = Problem.from_regression(train_rows.at(tau, system.equations), system.nonnegative, ties=system.ties)
    keep = selection.choose(problem, validate=test_rows.at(tau, system.equations).residual).keep
    return [n for n, k in zip(problem.names, keep) if k]


def _improvement(old: dict[str, Comparison], new: dict[str, Comparison],
                 measures: Sequence[str] = ("fit_percent", "record_fit_percent", "k_step_fit_percent")) -> float:
    """The largest factor by which a simulation error of the test record (the mean over
    coordinates) falls, each over the fall that chance gives one added parameter
    (:func:`~cvxid.diagnosis.acceptance.chance_fall` of the new model's error): the free
    run's from the estimated initial state or from the record's own, or the k-step-ahead
    prediction's (a diverging simulation has an infinite error; the prediction's chance is
    read off the free run's error, whose samples are the more correlated).  From the
    record's own start a heavily damped wrong model forgets the start's error where the
    right one carries it; on short stretches between gaps the estimated start fits any
    model.  ``measures``: the errors compared (two polished models, :func:`_polished`, by
    their free runs from the estimated start alone: near the noise, the record's own start
    and the short predictions of two polished models differ by their first states)."""
    def error(fit):
        return np.inf if fit is None else max(100.0 - fit, 1e-12)

    def misses(run):  # (the model with the effect: chance_fall reads the larger model's error)
        return [None if getattr(c, run) is None else c.measured - getattr(c, run) for c in new.values()]

    free = chance_fall(misses("free_run"))
    chance = {"fit_percent": free, "record_fit_percent": chance_fall(misses("record_free_run")),
              "k_step_fit_percent": free}
    with np.errstate(invalid="ignore"):
        ratios = np.array([error(mean_fit(old, which)) / error(mean_fit(new, which)) / chance[which]
                           for which in measures])
    return float(np.nanmax(np.where(np.isnan(ratios), 0.0, ratios)))


def _test_mse(system: IdentifiedSystem, test_rows: SystemBuilder) -> float:
    """The test rows' equation-error MSE of ``system``; on the rows of a model with a
    fed-back delay added (``test_rows`` built for it), a model without one is that model
    with a gain of 0 (at the profile's least delay: the rows do not depend on it then)."""
    specs = system.specs
    if lacks_delay(specs) and test_rows.delay is not None:
        specs = {label: replace(s, delay=test_rows.delay) for label, s in specs.items()}
    reg = test_rows.at(system.tau if system.tau is not None or test_rows.delay is None else test_rows.delay.tau_min,
                       specs)
    coefficients = system.coefficients
    return reg.mse(np.array([coefficients.get(n, 0.0) for n in reg.names]))
