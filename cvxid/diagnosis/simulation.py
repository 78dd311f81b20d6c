r"""The diagnosis by simulation error, after the output-error polish.

The equation-error diagnosis (:mod:`cvxid.diagnosis.ranking`) sees what its regression
sees; an effect whose force is small beside the noise of an estimated velocity (an
amplitude-dependent damping, say) can be plain in the free-run simulation and invisible
there.  This stage starts from the polished model :math:`\hat\theta` (one equation or a system
of several) and asks, for each candidate effect :math:`g_c` it lacks, the **score
(Lagrange-multiplier) test** of adding it: with :math:`r` the simulation residual on the
training record (every coordinate's), :math:`J` its Jacobian in the model's parameters and
:math:`J_c = \partial r/\partial c` at :math:`c = 0`, one column for each equation the
candidate joins (:mod:`cvxid.diagnosis.candidates`),

.. math::

    J_\perp = (I - J J^+)\, J_c, \qquad
    \mathrm{LM}_c = \frac{r^T J_\perp J_\perp^+ r}{\hat\sigma^2}\,
        \frac{n_{\rm eff}}{n}, \qquad \hat\sigma^2 = \frac{r^T r}{n - p},

which is :math:`\chi^2_k` (``df``: :math:`k` its columns) when the effect is absent (:math:`n_{\rm eff}` counts the
independent residuals, :func:`~cvxid.identify.profile.effective_rows`: a model error
colours them).  :math:`J` is one batch of simulations, then one simulation per candidate
(:math:`J_c` by a forward difference); no fit.  The candidate with the
most significant statistic (the largest, among candidates of one :math:`k`), when it
is significant (:data:`LEVEL`), is added and the model polished
again from :math:`\hat\theta` on the training record; it is **kept when the free-run error
on the test record** (every coordinate's), which neither fit saw, **falls beyond chance**:

.. math::

    \mathrm{SSE}_{\rm new} < \mathrm{SSE}_{\rm old}\,\big(1 - \chi^2_{k,0.95}/n_{\rm eff}\big),

the likelihood-ratio bound the delay's profile interval uses, for the :math:`k` coefficients
the candidate adds.  The loop repeats while an
effect is kept (at most ``max_steps``).  One rule for every spec: no hand-set fraction.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, replace
from typing import Sequence

import numpy as np
import pandas as pd
from joblib import Parallel, delayed
from scipy.special import gammaln
from scipy.stats import chi2

from cvxid.data.experiment import Experiment
from cvxid.diagnosis.candidates import Candidate, candidates as candidates_of, default_candidates, missing, \
    with_candidate, with_input_delay
from cvxid.diagnosis.compare import free_run_residual
from cvxid.errors import CvxidError, CvxidWarning
from cvxid.identified import IdentifiedModel, IdentifiedSystem
from cvxid.identify.output_error import (PolishResult, linearisation, output_error, polish, residual, typical_size,
                                         typical_spread, typical_states)
from cvxid.identify.profile import effective_rows
from cvxid.identify.score import block_score_gain
from cvxid.metrics import band_period
from cvxid.parallel import one_blas_thread
from cvxid.progress import progress
from cvxid.simulate import SimulationDiverged

LEVEL = 0.99
"""The score test's level: a candidate is tried when its statistic exceeds
:math:`\\chi^2_k(\\text{LEVEL})`."""
SEED = 1e-30
"""The added candidate's starting coefficient (zero, but kept in the simulated model so
that the polish moves it)."""
STEP = 1e-8
"""The candidate's coefficient in the forward difference of its score, as a share of its
natural size (the equation's force per unit of the term on the measured states,
:func:`~cvxid.identify.output_error.typical_states`), or the input's delay as a share of
the period at the output's band edge: the polish's own step
(:data:`~cvxid.identify.output_error.JACOBIAN_STEP` times its floor).  (A step of 1e-8 in
the data's units scored a hidden cubic stiffness 9.1 in metres and 0 in micrometres.)"""
ITERATIONS = 50
"""Iterations of the polish with a candidate added (from the polished model)."""
PRECISION = 1e-6
"""A test record's free-run error (RMS) below this share of its output's spread (the least
of a coupled record's coordinates) is at the data's numerical precision (a noise-free
record written with nine digits: 4e-9), where any term lowers it by chance: nothing is
tried there."""


@dataclass(frozen=True)
class SimulationStep:
    """One candidate added by simulation error and what the test record said."""

    added: str
    term: str
    score: float
    test_rms_before: float
    test_rms_after: float
    bound_rms: float  # the test RMS the new model had to beat
    kept: bool

    def as_dict(self) -> dict:
        return dict(self.__dict__)


@dataclass
class SimulationRefinement:
    """The loop's score rankings, its steps (kept or not) and the final polish."""

    polish: PolishResult
    steps: list[SimulationStep]
    rankings: list[pd.DataFrame]
    at_precision: bool = False
    """Nothing tried: the model reproduces the test record to its numerical precision
    (:data:`PRECISION`)."""

    def table(self) -> pd.DataFrame:
        return pd.DataFrame([s.as_dict() for s in self.steps]).set_index("added") if self.steps else pd.DataFrame()

    def __repr__(self) -> str:
        head = "Diagnosis by simulation error (score test, then the test record decides)"
        if self.at_precision:
            return head + ": none tried, the model reproduces the test record to its numerical precision"
        if not self.rankings:
            return head + ": no candidate"
        text = head + "\n" + self.rankings[0].to_string(float_format=lambda v: f"{v:.4g}")
        if self.steps:
            text += "\n" + self.table().to_string(float_format=lambda v: f"{v:.4g}")
        return text


@one_blas_thread
def score_candidates(fitted: IdentifiedModel | IdentifiedSystem, train: Experiment, candidates: Sequence[str],
                     initial=None) -> pd.DataFrame:
    """Each candidate's score statistic (see the module docstring) at the polished
    ``fitted`` (one equation or a system) on ``train``, most significant first (by
    :func:`_log_significance`: the largest statistic among candidates of one size):
    ``term``,
    ``meaning``, ``score`` (its :math:`\\chi^2_k` value), ``df`` (:math:`k`, the equations it
    joins), ``share`` (of the simulation error it explains to first order).  A candidate
    whose sign is constrained (a nonnegative effect, an input delay) scores 0 when its
    Gauss–Newton step from zero has the forbidden sign: the constrained fit stays at zero (a
    one-sided score test)."""
    system = IdentifiedSystem.of(fitted)
    return _scores(system, candidates_of(system.specs, [c for c in candidates if c != "delay"]), train, initial)


def _scores(system: IdentifiedSystem, found: dict[str, Candidate], train: Experiment, initial) -> pd.DataFrame:
    """:func:`score_candidates` of the candidates ``found``."""
    rows = []
    _, r, J = linearisation(system, train, initial)
    sigma2 = float(r @ r) / max(r.size - J.shape[1] - 1, 1)
    colour = effective_rows(r) / r.size
    period = band_period(map(train.output, system.coordinates), train.dt)
    states = typical_states(train, 0, system.coordinates, period)
    for name, candidate in progress(found.items(), "diagnosis by simulation: score tests", total=len(found)):
        try:  # a late input reads a spline of the whole record: its own residual at 0 is the base
            base = residual(_with_candidate(system, candidate, train, 0.0), train, initial) \
                if name == "input_delay" else r
            columns = []
            for label in _coefficients(candidate):
                h = _step(system, candidate, train, label, states, period)
                moved = residual(_with_candidate(system, candidate, train, h, label), train, initial)
                columns.append((moved - base) / h)
        except SimulationDiverged:
            continue
        gain, steps = block_score_gain(r, J, np.column_stack(columns))
        statistic, share = float(gain / sigma2 * colour), float(gain / max(r @ r, 1e-300))
        if name == "input_delay" and steps[0] < 0 or any(
                s < 0 and label in candidate.signed for s, label in zip(steps, candidate.equations)):
            statistic = share = 0.0  # its Gauss-Newton step is negative: the sign forbids it
        rows.append({"effect": name, "term": candidate.term.name, "meaning": candidate.term.meaning,
                     "score": statistic, "df": len(columns), "share": share})
    frame = pd.DataFrame(rows, columns=["effect", "term", "meaning", "score", "df", "share"]).set_index("effect")
    order = frame.assign(z=-_log_significance(frame["score"], frame["df"])).sort_values("z", ascending=False).index
    return frame.loc[order]


def _log_significance(statistic, df) -> np.ndarray:
    r"""The natural log of each :math:`\chi^2_k` statistic's p-value, :math:`\log Q(k/2, x/2)`
    (the upper regularised gamma function), which orders candidates of different sizes by
    their significance.  Past :math:`x \approx 1400` the p-value itself underflows to 0: there
    its asymptotic expansion,

    .. math::

        \log Q(a, y) \approx -y + (a - 1)\log y - \log\Gamma(a) + \log\Big(1 + \frac{a-1}{y}\Big).
    """
    x, k = np.asarray(statistic, float), np.asarray(df, float)
    a, y = k / 2, np.maximum(x / 2, 1e-300)
    with np.errstate(divide="ignore", invalid="ignore"):  # (each form where the other is taken)
        exact = chi2.logsf(x, k)
        asymptotic = -y + (a - 1) * np.log(y) - gammaln(a) + np.log1p((a - 1) / y)
    return np.where(np.isfinite(exact) & (exact > -700), exact, asymptotic)


def _coefficients(candidate: Candidate) -> tuple[str | None, ...]:
    """The equations whose own coefficient of ``candidate`` the score perturbs one by one;
    ``(None,)`` for the one parameter an input delay shares between the equations."""
    return (None,) if candidate.reestimated else candidate.equations


def _step(system: IdentifiedSystem, candidate: Candidate, train: Experiment, equation: str | None,
          states: dict[str, np.ndarray], period: float) -> float:
    """The forward-difference step of ``candidate``'s coefficient in ``equation`` (its
    first for an input's delay): :data:`STEP` of its natural size in ``train``'s units
    (``states``: :func:`~cvxid.identify.output_error.typical_states`; ``period``: the
    record's band period, an input delay's size)."""
    if candidate.name == "input_delay":
        return STEP * period
    force = typical_spread(system.specs[equation or candidate.equations[0]].received_input(train))
    return STEP * force / typical_size(candidate.term.evaluate(states))


def _with_candidate(system: IdentifiedSystem, candidate: Candidate, train: Experiment, value: float,
                    equation: str | None = None) -> IdentifiedSystem:
    """``system`` with ``candidate`` at ``value`` (a term's coefficient, in the ``equation``
    given or in every equation it joins, 0 elsewhere; or the input's delay in seconds for
    ``"input_delay"``, every equation's)."""
    if candidate.name == "input_delay":
        late = with_input_delay(system.specs, train)
        return replace(system, models={label: IdentifiedModel(late[label].with_input_tau(value), m.coefficients, m.lam,
                                                              m.info, m.tau) for label, m in system.models.items()})
    specs = with_candidate(system.specs, candidate)
    models = {label: IdentifiedModel(specs[label], dict(m.coefficients, **{candidate.term.name: value if equation in (
        None, label) else 0.0}) if label in candidate.equations else m.coefficients, m.lam, m.info, m.tau)
        for label, m in system.models.items()}
    return replace(system, models=models)


def _holds(system: IdentifiedSystem, candidate: Candidate) -> bool:
    """Whether ``system`` holds an added ``candidate``: its coefficient in an equation it
    joined, or the input's delay, is not 0.  One held at its bound of 0 adds nothing,
    however the test error moved with the other parameters' further polish (an outside
    check: a Coulomb friction "kept", at exactly 0 in the final model)."""
    if candidate.name == "input_delay":
        return any(m.spec.input_tau != 0 for m in system.models.values())
    return any(system.models[label].coefficients.get(candidate.term.name, 0.0) != 0 for label in candidate.equations)


def refine_by_simulation(polished: PolishResult, train: Experiment, test: Experiment,
                         candidates: Sequence[str] | None = None, max_steps: int = 5,
                         schedule: dict | None = None, n_jobs: int = 1) -> SimulationRefinement:
    """Score the candidates missing from the polished system; try the significant ones,
    best first, each added and polished, until the test record's free-run error falls
    beyond chance (then score again from the new system); at most ``max_steps`` tries.
    With ``n_jobs`` other than 1 a round's significant candidates are fitted together, as
    joblib tasks on the engine in use (:mod:`cvxid.parallel`), and read best first as the
    serial tries are (the same result; the fits past the first kept are spent).
    When an effect was kept, the final system is polished again as ``polished`` was
    (``schedule``: :func:`~cvxid.identify.output_error.polish`'s settings): its delay's
    profile, and every interval read from it, are of the system it reports (the first
    polish's were of the system without the additions); should that polish fit the
    training record worse than the kept fit did, the kept fit is reported, its intervals
    the standard errors' alone."""
    current, steps, rankings, added = polished, [], [], {}
    before = free_run_residual(polished.system, test)  # then each kept model's own, from its trial
    spread = min(np.nanstd(test.output(c)) for c in polished.system.coordinates)  # (each coordinate's, at least)
    precise = bool(before is not None and np.sqrt(np.mean(before**2)) < PRECISION * spread)
    while before is not None and not precise and len(steps) < max_steps:
        system = current.system
        pool = [c for c in (candidates if candidates is not None else default_candidates(system.specs))
                if c != "delay" and missing(system.specs, c)]
        if not pool:
            break
        found = candidates_of(system.specs, pool)
        ranking = _scores(system, found, train, current.initial)
        rankings.append(ranking)
        kept = None
        significant = ranking["score"] >= chi2.ppf(LEVEL, ranking["df"])
        names = list(ranking.index[significant.to_numpy()][:max_steps - len(steps)])
        tries = (delayed(_try)(system, found[name], ranking, current, train, test, before) for name in names)
        results = Parallel(n_jobs=n_jobs)(tries) if n_jobs != 1 and len(names) > 1 else \
            (function(*args, **kwargs) for function, args, kwargs in tries)  # (serial: lazily, to the first kept)
        for best, (tried, fitted, after) in zip(names, results):
            steps.append(tried)
            if tried.kept:
                kept, added[best] = fitted, found[best]
                break
        if kept is None:
            break
        before = after
        current = replace(kept, rms_before=current.rms_before, seconds=current.seconds + kept.seconds)
    if current is not polished:
        with warnings.catch_warnings():  # (its start is the kept fit: inside every bound)
            warnings.simplefilter("ignore", CvxidWarning)
            again = polish(current.system, train, initial=current.initial, **(schedule or {}))
        # the model the test record judged, unless the profile found it a better fit of the
        # same terms that the test record does not judge worse (on a real record the profile's
        # other basin fitted the training record better and the test record 50 % worse);
        # without a profile of its own its intervals are the standard errors'
        better = again.rms_after <= current.rms_after * (1 + 1e-3)
        judged = free_run_residual(again.system, test) if better else None
        kept = again if better and _no_worse(judged, before) else replace(current, profile=None)
        if better and kept is not again:
            warnings.warn(
                f"the final delay profile found a model that fits the training record better (simulation RMS "
                f"{again.rms_after:.4g} against {current.rms_after:.4g}) and the test record worse: the model the "
                "test record judged is kept, and its intervals are its standard errors' at its own delay only (no "
                "profile over the delay: a trade between the delay, a free gain and the stiffness is not in them)",
                CvxidWarning, stacklevel=2)
        current = replace(kept, rms_before=polished.rms_before, seconds=current.seconds + again.seconds)
        dropped = [s for s in steps if s.kept and not _holds(current.system, added[s.added])]
        if dropped:
            warnings.warn(
                f"the diagnosis by simulation error kept {', '.join(f'{s.added} ({s.term})' for s in dropped)} on the "
                "test record, and the final polish took its coefficient to 0 (its bound): the final model does not "
                "hold it (its term stays in the model, at 0)", CvxidWarning, stacklevel=2)
            steps = [replace(s, kept=False) if s in dropped else s for s in steps]
    return SimulationRefinement(current, steps, rankings, precise)


TEST_SLACK = 0.01
"""A final re-polish is kept when its free-run RMS on the test record is at most this
share above the model the test record judged (a rounding-level difference is no verdict)."""


def _no_worse(residual: np.ndarray | None, judged: np.ndarray) -> bool:
    """Whether the test residual ``residual`` (None: diverged) is within
    :data:`TEST_SLACK` of the ``judged`` model's."""
    return residual is not None and np.sqrt(np.mean(residual**2)) <= (1 + TEST_SLACK) * np.sqrt(np.mean(judged**2))


def _try(system: IdentifiedSystem, candidate: Candidate, ranking: pd.DataFrame, current: PolishResult,
         train: Experiment, test: Experiment, before: np.ndarray) -> tuple[SimulationStep, PolishResult | None, np.ndarray | None]:
    """The candidate added and polished from the current system, judged on the test record
    (the step, the fit and its test residual)."""
    name = candidate.name
    start = _with_candidate(system, candidate, train, 0.0 if name == "input_delay" else SEED)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", CvxidWarning)  # the new model is judged on the test record
            fitted = output_error(start, train, current.initial, step=train.dt, max_iterations=ITERATIONS)
        after = free_run_residual(fitted.system, test)
    except (SimulationDiverged, CvxidError):
        fitted, after = None, None
    old = float(before @ before)
    bound = old * (1 - chi2.ppf(0.95, len(_coefficients(candidate))) / effective_rows(before))
    new = float(after @ after) if after is not None and after.size == before.size else np.inf
    tried = SimulationStep(name, str(ranking.loc[name, "term"]), float(ranking.loc[name, "score"]),
                           float(np.sqrt(old / before.size)), float(np.sqrt(new / before.size)),
                           float(np.sqrt(bound / before.size)), bool(new < bound and _holds(fitted.system, candidate)))
    return tried, fitted, after
