r"""Structure selection by simulation error: stepwise forward, then backward.

When a true term needs the velocity (:math:`\dot x^3`), every velocity estimate leaves an
in-band error that the equation-error regression turns into wrong terms, and the true
support appears nowhere on its λ path.  The simulation error compares positions only:

.. math::

    J(S) = \min_{\theta_S} \sqrt{\tfrac1n \textstyle\sum_k
        \big(x_\mathrm{measured}(t_k) - x_\mathrm{simulated}(t_k; \theta_S)\big)^2}

for a support :math:`S` of library terms (of a system of :math:`N \ge 1` equations: the
columns ``"equation:term"`` of every equation, every coordinate's error pooled, all
coordinates simulated together).  The search starts from a local output-error
fit of the base terms at the equation-error delay.  Each candidate support starts from its own
equation-error fit (the convex least squares on the same regression, which lands close
enough for a local output-error fit) and is polished by :func:`cvxid.identify.output_error.output_error`
on a coarse simulation step, compared with the steps' own samples
(:class:`~cvxid.identify.output_error.Step`: its many fits of a record sampled far above
its band would cost half again as much compared with every sample); the last fit is
polished as the run's polish is, every sample compared.

* **Forward**: from the base terms, add the term that lowers :math:`J` most, while it falls
  by at least ``min_gain``.
* **Backward**: drop a term when :math:`J` without it (warm-started from the current fit)
  stays within ``tolerance`` of :math:`\max(J, \hat\sigma)`, with :math:`\hat\sigma` the noise
  level of the measured positions (the root mean square of each coordinate's; at the noise
  floor every remaining difference is noise).
* The selected model is polished by :func:`~cvxid.identify.output_error.polish`: the
  delay profiled over its whole range on the selected terms (the search's fits are local
  in the delay, and a search started where the base terms put the delay can stay far from
  it), then every parameter at the sample step, with the delay's interval.  (A profile of
  the base terms' delay before the search, as there was, found the true support less
  often and took a quarter longer on the held-out tuning systems: 42 against 44 of 50,
  362 against 269 s.)

Once the current fit is within :data:`SCREEN_BELOW` times the noise level, each forward
step first ranks every candidate by the score test at the current fit (one batch of
simulations, :mod:`cvxid.identify.score`) and fits the :data:`SCREEN` best; each
backward step tries the :data:`REMOVALS` terms with the smallest Wald statistics; the other
candidates are fitted only when none of those will do, so the search stops where a trial
of every candidate would.  The fits run one after another by default (``n_jobs``): with a
screened handful per step, worker processes cost more to start than they save (measured on
``duffing_delay.toml``).  Use it for libraries of tens of terms, not hundreds.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, replace
from typing import Sequence

import numpy as np
import pandas as pd
from joblib import Parallel, delayed

from cvxid.data.experiment import Experiment
from cvxid.errors import CvxidError, CvxidWarning
from cvxid.identified import IdentifiedModel, IdentifiedSystem
from cvxid.identify.output_error import PolishResult, Step, linearisation, output_error, polish, with_tau
from cvxid.identify.score import block_score_gain, score_gains
from cvxid.identify.problem import Problem
from cvxid.identify.profile import chance_factor, profile_delay
from cvxid.identify.system import identified
from cvxid.model.system import SystemSpec
from cvxid.parallel import one_blas_thread
from cvxid.progress import progress
from cvxid.regression.builder import SystemBuilder
from cvxid.regression.regression import Regression
from cvxid.metrics import noise_level


@dataclass(frozen=True)
class Stepwise:
    """The selected system and every step of the search."""

    system: IdentifiedSystem
    history: pd.DataFrame  # step, action, term, rms
    noise: float
    seconds: float
    final: PolishResult  # the last fit: the delay profiled on the selected terms, its interval

    @property
    def model(self) -> IdentifiedModel:
        """The selected equation (a system of several: :attr:`system`)."""
        if self.system.single is None:
            raise CvxidError(f"this search selected {len(self.system.models)} coupled equations: use .system")
        return self.system.single

    def __repr__(self) -> str:
        lines = [f"Stepwise selection by simulation error ({self.seconds:.1f} s, noise level {self.noise:.4g}):"]
        lines += ["  " + line for line in self.history.drop(columns="columns").to_string(index=False).splitlines()]
        return "\n".join(lines)


SCREEN = 4
"""Candidates fitted at each forward step: the best by the score test at the current fit
(:func:`_screen`).  On 50 tuning systems (``cvxid bench --heldout --mode selection
--estimator stepwise_oe --seeds 0:10 --known-gain``) the term a search of every candidate
added was among the first 4 in 126 of its 141 steps, and a screen at every step (and
:data:`REMOVALS`) gave the same model on 49 of the 50 systems, in two thirds of the time."""
SCREEN_BELOW = 2.0
"""The screen is used only when the current simulation error is at most this many times
the noise level: far from the data the first-order ranking misleads (on the paper's system,
``SEEDS=8 python examples/structure_from_noisy_x.py``, screening from the start found the
true support on 4 of 8 records instead of 7, each first step taking another term)."""
REMOVALS = 2
"""Terms tried at each backward step: the least significant by their Wald statistic
(:func:`_least_significant`; on 30 tuning systems with the gain estimated, the removal a
trial of every term chose was the first of this order 27 times and the second 3 times)."""
SEED = 1e-30
"""A candidate's coefficient in the score test's simulations (zero, but simulated)."""
RANKING = 8
"""Output-error iterations when candidates are only ranked, on twice the step (the chosen
one is then converged on the step itself)."""



ANCHORED = " (tied outside the library)"
"""The name's end of the unit of columns tied to one outside the library: never removed."""


def units(system: SystemSpec, columns: Sequence[str]) -> dict[str, tuple[str, ...]]:
    """The ``columns`` as the search adds and removes them: each alone, and columns a chain
    of ties joins as one unit (a tie keeps both of its columns or neither), named by its
    columns joined with ``" = "``.  The columns tied to one outside ``columns`` (an inertia, a
    listed term) form one last unit that the search and the pruning keep in every model."""
    root = {c: c for c in columns}

    def find(c):
        while root[c] != c:
            c = root[c]
        return c

    anchored = set()
    for a, b, _ in system.ties:
        if a in root and b in root:
            root[find(a)] = find(b)
        else:
            anchored |= {a, b} & set(root)
    groups: dict[str, list[str]] = {}
    for c in columns:
        groups.setdefault(find(c), []).append(c)
    out = {" = ".join(g): tuple(g) for g in groups.values() if not anchored & set(g)}
    fixed = tuple(c for g in groups.values() if anchored & set(g) for c in g)
    return out | ({" + ".join(fixed) + ANCHORED: fixed} if fixed else {})


def _flat(keys: Sequence[str], members: dict[str, tuple[str, ...]]) -> list[str]:
    """The columns of the units ``keys``."""
    return [c for k in keys for c in members[k]]


def noise_of(train: Experiment, system: SystemSpec | IdentifiedSystem) -> float:
    """The noise level of the simulation error's residual: the root mean square of every
    coordinate's measurement noise (:func:`~cvxid.metrics.noise_level`)."""
    specs = system.equations if isinstance(system, SystemSpec) else system.specs
    return float(np.sqrt(np.mean([noise_level(train.output(s.coordinate)) ** 2 for s in specs.values()])))


def library_columns(system: SystemSpec) -> list[str]:
    """The system's library terms as columns (``"equation:term"``; bare for one equation)."""
    return [system.column(label, t.name) for label, s in system.equations.items() for t in s.library]


def parameter_of(system: IdentifiedSystem, column: str) -> str:
    """The name the output-error fit gives the coefficient of ``column``: for one
    equation its physical name (``names`` in the spec), else the column itself."""
    if system.single is not None:
        return system.single.spec.parameter_name(column)
    return column


def _system_of(models: dict[str, IdentifiedModel], ties=()) -> IdentifiedSystem:
    """A system of these models at their (shared) delay, with the first one's notes (for
    one equation: :meth:`IdentifiedSystem.of`)."""
    first = next(iter(models.values()))
    return IdentifiedSystem(models, first.tau, ties=tuple(ties), info=dict(first.info))


def _polished(fit, train: Experiment, rows: list[dict], schedule: dict | None = None) -> PolishResult:
    """The search's last fit polished as the run's polish is (by default its delay profiled
    over the range on the records' band step, every sample compared, then every parameter
    at the sample step; ``schedule``: other settings of
    :func:`~cvxid.identify.output_error.polish`): its intervals are the ones printed, and
    compared at its steps' own samples a 5 kHz record's were 2.15 times wider (a review).
    The step is recorded in ``rows``."""
    with warnings.catch_warnings():  # a start outside the bounds is the search's own, not the user's
        warnings.simplefilter("ignore", CvxidWarning)
        final = polish(fit.system, train, initial=fit.initial, **(schedule or {}))
    action = "polish (delay profiled) at the sample step" if final.profile is not None else "polish at the sample step"
    rows.append({"step": len(rows), "action": action, "term": "", "columns": [], "rms": final.rms_after})
    return final


def _start(system: SystemSpec, regression: Regression, columns: Sequence[str], tau: float | None) -> IdentifiedSystem:
    """The equation-error least-squares fit of ``system`` restricted to the library
    ``columns``, started at the delay ``tau`` (the regression's own for an exact delay; for
    a Taylor delay the coefficient map's estimate is replaced by ``tau``, the current
    output-error delay: the map's is biased and a poor start falls into another minimum of
    the simulation error)."""
    reduced = system.selected(set(columns))
    problem = Problem.from_regression(regression.subset(reduced.column_names), reduced.nonnegative, ties=reduced.ties)
    fit = problem.refit(np.ones(problem.k, bool))
    models = identified(reduced, dict(zip(problem.names, map(float, fit.coefficients))),
                        tau if system.exact else None).models
    if system.delay is not None and not system.exact and tau is not None:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", CvxidWarning)
            models = {label: with_tau(m, tau) for label, m in models.items()}
    return _system_of(models, reduced.ties)


def _delay(fit, exact: bool) -> float | None:
    """The delay of an output-error fit (None without a delay)."""
    if exact:
        return fit.system.tau
    return fit.parameters.get("tau")


def _screen(system: SystemSpec, fit, candidates: list[str], members: dict[str, tuple[str, ...]], train: Experiment,
            step: float) -> list[str]:
    """The ``candidates`` (units) ranked by the score test at the current fit
    (:mod:`cvxid.identify.score`): each one's first-order fall of the simulation error, from
    one batch of simulations (a tied unit's columns move as its one parameter)."""
    current = fit.system
    wider = system.selected(set(current.coefficients) | set(_flat(candidates, members)))
    models = {}
    for label, spec in wider.equations.items():
        model = current.models[label]
        spec = replace(spec, input_delay=model.spec.input_delay)  # the fitted input delay, if any
        models[label] = IdentifiedModel(spec, {n: model.coefficients.get(n, SEED) for n in spec.column_names},
                                        tau=model.tau)
    seeded = _system_of(models, wider.ties)
    with warnings.catch_warnings():  # as the trial fits: an early (Taylor) delay may have the wrong sign
        warnings.simplefilter("ignore", CvxidWarning)
        names, r, J = linearisation(seeded, train, fit.initial, Step(step), pressed=False)  # (candidates sit at 0)
    present = {k: [c for c in members[k] if parameter_of(seeded, c) in names] for k in candidates}  # (a tie leaves
    params = {k: [names.index(parameter_of(seeded, c)) for c in present[k]] for k in candidates}  # one of a unit's)
    others = np.delete(J, [i for k in candidates for i in params[k]], axis=1)
    single = [k for k in candidates if len(params[k]) == 1]
    gains = dict(zip(single, zip(*score_gains(r, others, J[:, [params[k][0] for k in single]])))) if single else {}
    gains |= {k: block_score_gain(r, others, J[:, params[k]]) for k in candidates if k not in gains}
    score = [0.0 if any(np.atleast_1d(gains[k][1])[i] < 0 and c in system.nonnegative for i, c in enumerate(present[k]))
             else float(gains[k][0]) for k in candidates]
    return [candidates[i] for i in np.argsort(-np.array(score), kind="stable")]


def _least_significant(keys: list[str], fit, members: dict[str, tuple[str, ...]]) -> list[str]:
    r"""The units ``keys`` ordered by the Wald statistic :math:`|\theta_j| / \mathrm{se}_j` of
    their coefficients in ``fit`` (a tied unit: its one parameter), smallest first: the
    first-order rise of the simulation error when each is dropped and the others refitted,
    least first.  A term the fit left out (its coefficient exactly 0: the simulation drops
    it) or whose standard error is undetermined (it moves nothing) comes first."""
    wald = []
    for k in keys:
        statistics = [0.0]
        for c in members[k]:
            name = parameter_of(fit.system, c)
            if name in fit.parameters:
                value, error = fit.parameters[name], fit.standard_errors.get(name, np.nan)
                statistics.append(abs(value) / error if error > 0 and value != 0 else 0.0)
        wald.append(max(statistics))
    return [keys[i] for i in np.argsort(wald, kind="stable")]


def _without(system: IdentifiedSystem, columns: Sequence[str]) -> IdentifiedSystem:
    """``system`` with the library ``columns`` (a unit) dropped and every other coefficient
    kept (a warm start; its lambda and notes too)."""
    spec = system.spec
    cut = spec.selected(set(library_columns(spec)) - set(columns))
    models = {label: IdentifiedModel(kept, {n: system.models[label].coefficients.get(n, 0.0) for n in kept.column_names},
                                     system.models[label].lam, system.models[label].info, system.models[label].tau)
              for label, kept in cut.equations.items()}
    return _system_of(models, cut.ties)


def _trial(system: IdentifiedSystem, experiment: Experiment, step: float, iterations: int = 30):
    """The output-error fit from ``system`` (None and inf when every simulation diverges)."""
    try:
        with warnings.catch_warnings():  # trial fits: their intermediate delays may be anything
            warnings.simplefilter("ignore", CvxidWarning)
            fit = output_error(system, experiment, step=Step(step), max_iterations=iterations)
    except CvxidError:
        return None, np.inf
    return fit, fit.rms_after if np.isfinite(fit.rms_after) else np.inf


def _addition(pool, system, rows, fit, current, members, train, step, needed, noise, exhaustive=True):
    """The forward step: (unit, converged fit, its simulation error) of the candidate
    whose ranking fit lowers the simulation error most, if its converged fit is below
    ``needed``; else None.  The :data:`SCREEN` best by the score test are fitted first; only
    when the best of them is not enough are the others fitted too, and the best of all is
    tried (a poor current fit ranks badly, and the search must not stop earlier than a
    trial of every candidate would).  While the current fit is far from the data (above
    :data:`SCREEN_BELOW` times the ``noise`` level, or diverged), or when no more than
    :data:`SCREEN` candidates are left, every candidate is fitted at once; not
    ``exhaustive``: only the screened best (the pruning's exchange, near the noise)."""
    tau = _delay(fit, system.exact)
    regression = rows.at(tau if system.exact else None, system.equations)  # (the spec may hold added effects)
    rest = [k for k in members if k not in current]
    screened = fit.rms_after <= SCREEN_BELOW * noise and len(rest) > SCREEN
    batches = _screen(system, fit, rest, members, train, 2 * step) if screened else rest
    trials: dict[str, tuple] = {}
    converged: set[str] = set()
    rounds = (batches[:SCREEN], batches[SCREEN:]) if screened else (batches,)
    for batch in rounds if exhaustive else rounds[:1]:
        trials.update(zip(batch, pool(delayed(_trial)(_start(system, regression, _flat(current + [n], members), tau),
                                                      train, 2 * step, RANKING)
                                      for n in progress(batch, f"stepwise: adding term {len(current) + 1}"))))
        name = min(trials, key=lambda n: trials[n][1])
        if trials[name][0] is None or name in converged:  # every one diverged, or the best was tried and fell short
            continue
        converged.add(name)
        chosen, score = _trial(trials[name][0].system, train, step)  # converge the best
        if chosen is not None and score < needed:
            return name, chosen, score
    return None


def _backward(pool, fit, rms, current, base, members, train, step, floor, tolerance, rows):
    """Drop units while the simulation error stays within ``tolerance`` of the larger of
    itself and the noise ``floor``; ``current`` and ``rows`` are updated in place (``base``:
    the units never dropped).  The :data:`REMOVALS` least significant units are tried
    first, the others only when neither may go."""
    while True:
        ordered = _least_significant([k for k in current if k not in base], fit, members)
        trials: dict[str, tuple] = {}
        for batch in (ordered[:REMOVALS], ordered[REMOVALS:]) if len(ordered) > REMOVALS else (ordered,):
            trials.update(zip(batch, pool(delayed(_trial)(_without(fit.system, members[k]), train, step)
                                          for k in batch)))
            name = min(trials, key=lambda n: trials[n][1]) if trials else None
            if name is not None and trials[name][1] <= max((1 + tolerance) * rms, floor):
                break
        else:
            return fit, rms
        current.remove(name)
        fit, rms = trials[name]
        rows.append({"step": len(rows), "action": "remove", "term": name, "columns": list(members[name]), "rms": rms})


@one_blas_thread
def stepwise_output_error(system: SystemSpec, rows: SystemBuilder, train: Experiment,
                          base: Sequence[str] | None = None, min_gain: float = 0.01, tolerance: float = 0.005,
                          step: float = 1e-3, n_jobs: int = 1, schedule: dict | None = None) -> Stepwise:
    """Select the library terms of ``system`` (one equation or several) by simulation error
    on ``train`` (see the module docstring).  ``rows`` builds the equation-error regression
    of the whole library (at the current delay, for an exact delay); ``base`` are the
    columns always kept (default: each equation's linear terms, e.g. ``x`` and ``x'``);
    columns a tie joins are added and removed together (:func:`units`).  ``schedule``: the
    final polish's settings (:func:`~cvxid.identify.output_error.polish`)."""
    start = time.perf_counter()
    names = library_columns(system)
    if base is None:
        base = [system.column(label, n) for label, s in system.equations.items() for n in s.linear_terms
                if system.column(label, n) in names]
    unknown = set(base) - set(names)
    if unknown:
        raise CvxidError(f"stepwise base term(s) {', '.join(sorted(unknown))} are not in the library")
    members = units(system, names)
    base = [k for k, m in members.items() if set(m) & set(base) or k.endswith(ANCHORED)]
    sigma = noise_of(train, system)
    step = max(step, train.dt)
    tau = None
    if system.exact:  # the delay of the base support; the output-error fits move it, the final profile checks it
        penalties = [c.penalty for s in system.equations.values() for c in s.columns]
        keep = [n in _flat(base, members) or w == 0 for n, w in zip(system.column_names, penalties)]
        tau = profile_delay(rows, support=keep, nonnegative=system.nonnegative, model=system.equations,
                            ties=system.ties).estimate
    with warnings.catch_warnings():  # the base fit's first (Taylor) delay may have the wrong sign
        warnings.simplefilter("ignore", CvxidWarning)
        fit = output_error(_start(system, rows.at(tau), _flat(base, members), tau), train, step=Step(step),
                           max_iterations=25)
    current, rms = list(base), fit.rms_after
    history = [{"step": 0, "action": "start", "term": ", ".join(_flat(base, members)) or "(none)",
                "columns": _flat(base, members), "rms": rms}]
    with Parallel(n_jobs=n_jobs) as pool:
        while len(current) < len(members):
            added = _addition(pool, system, rows, fit, current, members, train, step, (1 - min_gain) * rms, sigma)
            if added is None:
                break
            name, fit, rms = added
            current.append(name)
            history.append({"step": len(history), "action": "add", "term": name, "columns": list(members[name]),
                            "rms": rms})
        fit, rms = _backward(pool, fit, rms, current, base, members, train, step, (1 + tolerance) * sigma, tolerance,
                             history)
    final = _polished(fit, train, history, schedule)
    chosen = _system_of({label: IdentifiedModel(m.spec, m.coefficients, 0.0,
                                                dict(m.info, selection="stepwise output error"), m.tau)
                         for label, m in final.system.models.items()}, final.system.ties)
    return Stepwise(chosen, pd.DataFrame(history), sigma, time.perf_counter() - start, final)


@dataclass(frozen=True)
class Pruning:
    """The search run on a model selected by equation error and polished: the terms it
    removed and, where the model missed the record by more than the noise, the terms it
    exchanged; each step's simulation error; the result polished again (``polish``; the
    given one when nothing changed)."""

    history: pd.DataFrame  # step, action, term, rms
    noise: float
    seconds: float
    polish: PolishResult

    @property
    def removed(self) -> list[str]:
        """The columns it removed (a tied unit's every column) and did not add back."""
        return self._changed("remove")

    @property
    def added(self) -> list[str]:
        """The columns it added and did not remove again."""
        return self._changed("add")

    def _changed(self, action: str) -> list[str]:
        """The columns whose first and last step were ``action``: in the model at the start
        and not at the end (remove), or the other way round (add)."""
        first, last = {}, {}
        for row in self.history.itertuples():
            if row.action in ("add", "remove"):
                for column in row.columns:
                    first.setdefault(column, row.action)
                    last[column] = row.action
        return [c for c in first if first[c] == last[c] == action]

    def __repr__(self) -> str:
        removed = ", ".join(self.removed) or "nothing"
        added = f"; added {', '.join(self.added)}" if self.added else ""
        lines = [f"Pruning by simulation error ({self.seconds:.1f} s, noise level {self.noise:.4g}): removed {removed}"
                 f"{added}"]
        lines += ["  " + line for line in self.history.drop(columns="columns").to_string(index=False).splitlines()]
        return "\n".join(lines)


def _exchange(pool, system, rows, fit, rms, current, kept, members, train, step, sigma, tolerance):
    """One exchange of the pruning: the candidate the forward step finds best (the score
    test's :data:`SCREEN` best fitted, near the noise), then the backward steps.  Returns
    the history rows, and ``(fit, rms, units)`` when the result is another model that fits
    better than ``fit`` by more than its added parameters would by chance, the best of the
    candidates taken (:func:`~cvxid.identify.profile.chance_factor` at Bonferroni's level
    over them; any fall when it has no more parameters), else None."""
    candidates = len(members) - len(current)
    added = _addition(pool, system, rows, fit, current, members, train, step, rms, sigma, exhaustive=False)
    if added is None:
        return [{"action": "exchange: no candidate lowers the error", "term": "", "columns": [], "rms": rms}], None
    name, trial, trial_rms = added
    units = current + [name]
    steps = [{"action": "add", "term": name, "columns": list(members[name]), "rms": trial_rms}]
    trial, trial_rms = _backward(pool, trial, trial_rms, units, kept, members, train, step, (1 + tolerance) * sigma,
                                 tolerance, steps)
    extra = len(units) - len(current)  # parameters: a tied unit is one
    chance = chance_factor(trial.effective_rows, extra, candidates) if extra > 0 else 1.0
    if set(units) == set(current) or trial_rms * chance >= rms:
        dropped = [row["term"] for row in steps if row["action"] == "remove"]
        term = f"{name} (taken out again)" if name in dropped else \
            name + (f" (then without {', '.join(dropped)})" if dropped else "")
        return [{"action": "exchange refused (within chance)", "term": term, "columns": [], "rms": trial_rms}], None
    return steps, (trial, trial_rms, units)


@one_blas_thread
def prune_by_simulation(polished: PolishResult, train: Experiment, removable: Sequence[str],
                        rows: SystemBuilder | None = None, step: float = 1e-3, tolerance: float = 0.005,
                        schedule: dict | None = None) -> Pruning:
    r"""Drop the ``removable`` library columns of a polished system (one equation or
    several) that the simulation error does not need, and, while the model misses the
    record by more than its noise, exchange them for others.

    * **Backward**: the backward steps of :func:`stepwise_output_error` (a term goes while
      :math:`J` without it, the others refitted, stays within ``tolerance`` of
      :math:`\max(J, \hat\sigma)`, :math:`J` the error before that step), from the
      polished fit refitted on the search's step.
    * **Exchange** (with the equation-error ``rows``), while
      :math:`J > (1 + \text{tolerance})\,\hat\sigma`, :math:`J` on the search's step or
      read as on every sample, the larger (the search step's error times the ratio of the
      given polish's error to the start's on the search's step: a 5 kHz record's search
      step compares a fifth of its samples, whose error differed from every sample's by
      up to 1.7 % either way on the paper's system): the ``removable`` column the model
      lacks that the forward step finds best (the score test's :data:`SCREEN` best fitted;
      every candidate beyond :data:`SCREEN_BELOW` times the noise), then the backward
      steps; the result is kept when it is another model whose error :math:`J'` beats
      :math:`J` by more than its added parameters :math:`p` would by chance, the best of
      :math:`m` candidates taken,
      :math:`J' \cdot (1 + \chi^2_{p,\,1 - 0.05/m} / n_\text{eff})^{1/2} < J`
      (:func:`~cvxid.identify.profile.chance_factor`; any fall when :math:`p \le 0`).
      A refused exchange is a row of the history; the first one ends the pruning.

    The result is polished again (its delay profiled) and keeps the whole library, the
    dropped terms at 0; columns a tie joins go together, when all of them may
    (:func:`units`).  A selection by equation error keeps terms that a velocity estimated
    from noisy x makes look useful, and may take a collinear term for a true one; their
    simulation error shows both.  On the paper's system (``duffing_delay.toml``'s noise
    seeds) the adaptive lasso took ``x^3 x'`` (with ``x x'^3``) for ``x^2 x'`` on most
    records, a model about 1 % above the noise in :math:`J` that the backward steps keep
    and one exchange repairs."""
    start = time.perf_counter()
    system = polished.system
    spec = system.spec
    coefficients = system.coefficients
    current = [n for n in library_columns(spec) if coefficients.get(n, 0.0) != 0.0]
    absent = [n for n in removable if n not in current] if rows is not None else []
    sigma = noise_of(train, system)
    history = []
    if absent or any(n in current for n in removable):
        step = max(step, train.dt)
        cut = spec.selected(set(current))
        models = {label: IdentifiedModel(s, system.models[label].coefficients, system.models[label].lam,
                                         system.models[label].info, system.models[label].tau)
                  for label, s in cut.equations.items()}
        fit, rms = _trial(_system_of(models, cut.ties), train, step)
        history.append({"step": 0, "action": "start" if fit is not None else "start: its simulation diverged, "
                        "nothing pruned", "term": ", ".join(current), "columns": list(current), "rms": rms})
        if fit is not None:
            members = units(spec, current + absent)
            keys = [k for k, m in members.items() if set(m) & set(current)]
            kept = [k for k in keys if not set(members[k]) <= set(removable) or k.endswith(ANCHORED)]
            floor = (1 + tolerance) * sigma
            at_samples = polished.rms_after / rms if np.isfinite(polished.rms_after) and rms > 0 else 1.0
            with Parallel(n_jobs=1) as pool:
                fit, rms = _backward(pool, fit, rms, keys, kept, members, train, step, floor, tolerance, history)
                for _ in range(len(members)):  # (each exchange kept lowers the error)
                    if max(rms, rms * at_samples) <= floor or len(keys) == len(members):
                        break
                    steps, exchanged = _exchange(pool, spec, rows, fit, rms, keys, kept, members, train, step, sigma,
                                                 tolerance)
                    history += [dict(row, step=len(history) + i) for i, row in enumerate(steps)]
                    if exchanged is None:
                        break
                    fit, rms, keys = exchanged
    if any(row["action"] in ("add", "remove") for row in history):
        pruned = _polished(fit, train, history, schedule)
        final = pruned.system  # back on the whole library: the diagnosis's candidates are what it lacks
        whole = {label: IdentifiedModel(m.spec, {n: final.models[label].coefficients.get(n, 0.0)
                                                 for n in m.spec.column_names},
                                        final.models[label].lam, final.models[label].info, final.models[label].tau)
                 for label, m in system.models.items()}
        polished = replace(pruned, system=replace(pruned.system, models=whole, ties=system.ties))
    return Pruning(pd.DataFrame(history, columns=["step", "action", "term", "columns", "rms"]), sigma,
                   time.perf_counter() - start, polished)
