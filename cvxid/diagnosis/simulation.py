r"""The diagnosis by simulation error, after the output-error polish.

The equation-error diagnosis (:mod:`cvxid.diagnosis.ranking`) sees what its regression
sees; an effect whose force is small beside the noise of an estimated velocity (an
amplitude-dependent damping, say) can be plain in the free-run simulation and invisible
there.  This stage starts from the polished model :math:`\hat\theta` and asks, for each
candidate effect :math:`g_c` it lacks, the **score (Lagrange-multiplier) test** of adding
it: with :math:`r` the simulation residual on the training record, :math:`J` its Jacobian
in the model's parameters and :math:`j_c = \partial r/\partial c` at :math:`c = 0`,

.. math::

    j_\perp = (I - J J^+)\, j_c, \qquad
    \mathrm{LM}_c = \frac{(j_\perp^T r)^2}{j_\perp^T j_\perp\;\hat\sigma^2}\,
        \frac{n_{\rm eff}}{n}, \qquad \hat\sigma^2 = \frac{r^T r}{n - p},

which is :math:`\chi^2_1` when the effect is absent (:math:`n_{\rm eff}` counts the
independent residuals, :func:`~cvxid.identify.profile.effective_rows`: a model error
colours them).  :math:`J` is one batch of simulations, then one simulation per candidate
(:math:`j_c` by a forward difference); no fit.  The candidate with the
largest statistic, when it is significant (:data:`LEVEL`), is added and the model polished
again from :math:`\hat\theta` on the training record; it is **kept when the free-run error
on the test record**, which neither fit saw, **falls beyond chance**:

.. math::

    \mathrm{SSE}_{\rm new} < \mathrm{SSE}_{\rm old}\,\big(1 - \chi^2_{1,0.95}/n_{\rm eff}\big),

the likelihood-ratio bound the delay's profile interval uses.  The loop repeats while an
effect is kept (at most ``max_steps``).  One rule for every spec: no hand-set fraction.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, replace
from typing import Sequence

import numpy as np
import pandas as pd
from scipy.stats import chi2

from cvxid.data.experiment import Experiment
from cvxid.diagnosis.candidates import default_candidates, missing, with_effect, with_input_delay
from cvxid.diagnosis.compare import compare
from cvxid.errors import CvxidError, CvxidWarning
from cvxid.identified import IdentifiedModel, IdentifiedSystem
from cvxid.identify.output_error import PolishResult, linearisation, output_error, residual
from cvxid.identify.profile import effective_rows
from cvxid.identify.score import score_gains
from cvxid.model.library import resolve_term
from cvxid.model.terms import InputRate
from cvxid.parallel import one_blas_thread
from cvxid.progress import progress
from cvxid.simulate import SimulationDiverged

LEVEL = 0.99
"""The score test's level: a candidate is tried when its statistic exceeds
:math:`\\chi^2_1(\\text{LEVEL})`."""
SEED = 1e-30
"""The added candidate's starting coefficient (zero, but kept in the simulated model so
that the polish moves it)."""
STEP = 1e-8
"""The candidate's coefficient (or input delay, seconds) in the forward difference of its
score (the polish's own step, :data:`~cvxid.identify.output_error.JACOBIAN_STEP` times its
floor 1e-3)."""
ITERATIONS = 50
"""Iterations of the polish with a candidate added (from the polished model)."""


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

    def table(self) -> pd.DataFrame:
        return pd.DataFrame([s.as_dict() for s in self.steps]).set_index("added") if self.steps else pd.DataFrame()

    def __repr__(self) -> str:
        head = "Diagnosis by simulation error (score test, then the test record decides)"
        if not self.rankings:
            return head + ": no candidate"
        text = head + "\n" + self.rankings[0].to_string(float_format=lambda v: f"{v:.4g}")
        if self.steps:
            text += "\n" + self.table().to_string(float_format=lambda v: f"{v:.4g}")
        return text


@one_blas_thread
def score_candidates(model: IdentifiedModel, train: Experiment, candidates: Sequence[str],
                     initial=None) -> pd.DataFrame:
    """Each candidate's score statistic (see the module docstring) at the polished
    ``model`` on ``train``, largest first: ``term``, ``meaning``, ``score`` (its
    :math:`\\chi^2_1` value), ``share`` (of the simulation error it explains to first order).
    A candidate whose sign is constrained (a nonnegative effect, an input delay) scores 0
    when its Gauss–Newton step from zero has the forbidden sign: the constrained fit stays
    at zero (a one-sided score test)."""
    rows = []
    _, r, J = linearisation(model, train, initial)
    sigma2 = float(r @ r) / max(r.size - J.shape[1] - 1, 1)
    colour = effective_rows(r) / r.size
    for name in progress(candidates, "diagnosis by simulation: score tests", total=len(candidates)):
        trial, term = _with_candidate(model, name, train, STEP)
        try:  # a late input reads a spline of the whole record: its own residual at 0 is the base
            base = residual(_with_candidate(model, name, train, 0.0)[0], train, initial) if name == "input_delay" else r
            j = (residual(trial, train, initial) - base) / STEP
        except SimulationDiverged:
            continue
        (gain,), (step,) = score_gains(r, J, j)
        statistic, share = float(gain / sigma2 * colour), float(gain / max(r @ r, 1e-300))
        if step < 0 and (name == "input_delay" or term.name in trial.spec.nonnegative):
            statistic = share = 0.0  # its Gauss-Newton step is negative: the sign forbids it
        rows.append({"effect": name, "term": term.name, "meaning": term.meaning, "score": statistic, "share": share})
    frame = pd.DataFrame(rows, columns=["effect", "term", "meaning", "score", "share"]).set_index("effect")
    return frame.sort_values("score", ascending=False)


def _with_candidate(model: IdentifiedModel, name: str, train: Experiment, value: float):
    """``model`` with the candidate ``name`` at ``value`` (a term's coefficient, or the
    input's delay in seconds for ``"input_delay"``), and the candidate's term."""
    if name == "input_delay":
        spec = with_input_delay(model.spec, train).with_input_tau(value)
        return IdentifiedModel(spec, model.coefficients, model.lam, model.info, model.tau), InputRate(spec.input)
    spec = with_effect(model.spec, name)
    term = resolve_term(name, (spec.coordinate,), spec.effects)
    return IdentifiedModel(spec, dict(model.coefficients, **{term.name: value}), model.lam, model.info, model.tau), term


def _missing(model: IdentifiedModel, name: str) -> bool:
    return name != "delay" and missing(model.spec, name)


def _test_residual(model: IdentifiedModel, test: Experiment) -> np.ndarray | None:
    cmp = compare(model, test)
    if cmp.free_run is None:
        return None
    covered = np.isfinite(cmp.free_run)
    return cmp.free_run[covered] - cmp.measured[covered]


def refine_by_simulation(polished: PolishResult, train: Experiment, test: Experiment,
                         candidates: Sequence[str] | None = None, max_steps: int = 5) -> SimulationRefinement:
    """Score the candidates missing from the polished model; try the significant ones,
    best first, each added and polished, until the test record's free-run error falls
    beyond chance (then score again from the new model); at most ``max_steps`` tries."""
    if polished.system.single is None:
        raise CvxidError("the diagnosis by simulation error is for one equation")
    current, steps, rankings = polished, [], []
    before = _test_residual(polished.model, test)  # then each kept model's own, from its trial
    while before is not None and len(steps) < max_steps:
        model = current.model
        pool = [c for c in (candidates if candidates is not None else default_candidates(model.spec))
                if _missing(model, c)]
        if not pool:
            break
        ranking = score_candidates(model, train, pool, current.initial)
        rankings.append(ranking)
        kept = None
        for best in ranking.index[ranking["score"] >= chi2.ppf(LEVEL, 1)][:max_steps - len(steps)]:
            step, fitted, after = _try(model, best, ranking, current, train, test, before)
            steps.append(step)
            if step.kept:
                kept = fitted
                break
        if kept is None:
            break
        before = after
        current = replace(kept, rms_before=current.rms_before, profile=current.profile,
                          seconds=current.seconds + kept.seconds)
    return SimulationRefinement(current, steps, rankings)


def _try(model: IdentifiedModel, name: str, ranking: pd.DataFrame, current: PolishResult, train: Experiment,
         test: Experiment, before: np.ndarray) -> tuple[SimulationStep, PolishResult | None, np.ndarray | None]:
    """The candidate added and polished from the current model, judged on the test record
    (the step, the fit and its test residual)."""
    start, _ = _with_candidate(model, name, train, 0.0 if name == "input_delay" else SEED)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", CvxidWarning)  # the new model is judged on the test record
            fitted = output_error(IdentifiedSystem.of(start), train, current.initial, step=train.dt,
                                  max_iterations=ITERATIONS)
        after = _test_residual(fitted.model, test)
    except (SimulationDiverged, CvxidError):
        fitted, after = None, None
    old = float(before @ before)
    bound = old * (1 - chi2.ppf(0.95, 1) / effective_rows(before))
    new = float(after @ after) if after is not None and after.size == before.size else np.inf
    step = SimulationStep(name, str(ranking.loc[name, "term"]), float(ranking.loc[name, "score"]),
                          float(np.sqrt(old / before.size)), float(np.sqrt(new / before.size)),
                          float(np.sqrt(bound / before.size)), bool(new < bound))
    return step, fitted, after
