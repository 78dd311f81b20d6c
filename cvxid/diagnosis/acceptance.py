r"""The one rule by which a diagnosis adds an effect to a model (one equation or coupled).

A candidate effect is added when three things hold, all on data the fit did not use or on
many halves of the data it did:

1. **it lowers the test record's equation error** when the model is refitted with it
   (validation ratio above 1);
2. **the training record keeps choosing it**: on each of :math:`K = 20` halves of the
   training rows (5 of 10 contiguous blocks each, because neighbouring windowed rows share
   their noise) the model is fitted by least squares with and without the candidate, and the
   half keeps the candidate when dropping it raises the test record's equation-error MSE by
   more than that error's standard error (block standard error,
   :func:`~cvxid.identify.path.validation_score`):

   .. math::

       \text{MSE}_\text{test}(\hat c^{(k)}_{-j}) > \text{MSE}_\text{test}(\hat c^{(k)})
       + \text{se}\big(\text{MSE}_\text{test}(\hat c^{(k)})\big).

   This is the one-standard-error :math:`\lambda` rule of the debiased (adaptive) lasso
   with the candidate its only penalised column: along its path the debiased fit is one of
   these two, so the rule's choice is this comparison.  The share of halves that keep it,
   the candidate's inclusion probability

   .. math::

       \hat\pi = \frac1K \sum_{k=1}^{K} \mathbf 1\{\text{half } k \text{ keeps it}\},

   must reach :math:`\pi_{\text{thr}} = 0.7` (:data:`ACCEPTANCE`: the halves and threshold of
   the stability selection of :mod:`cvxid.identify.selection`);
3. **the refitted model is better, and a simulation agrees beyond chance**: the model
   refitted with it (a delay profiled again, a library selected again) has a lower test
   equation error, and its free run (or k-step-ahead prediction; a coupled system: its free
   run) of the test record an error lower than the model's before by more than one added
   parameter lowers it by chance (:func:`chance_fall`, read off the refitted model's
   error as an F test reads the larger model's).  When conditions 1 and 2 hold for a term
   (not a delay or an input delay, which an unprofiled polish trades with each other) and
   the refit's simulation does not fall, the free runs of the two models polished by output
   error decide (:func:`cvxid.diagnosis.refine._polished`: an equation-error model of a
   dry friction can simulate far from the data its equation error fits).

No share is set per spec: the rule is the same for every spec, and its constants (20
halves, 10 blocks, 0.7) are the stability selection's defaults, not tuned for it.  Two
tests of the test record's equation errors were measured and rejected: a paired t-test
over 10 blocks, and a Diebold–Mariano test (Newey–West variance, lag one window).  Windowed rows overlap by
a whole window, so an 8 s test record holds only about six independent stretches: the
Diebold–Mariano statistic of an offset that lowered the test equation error 1.3·10⁷-fold
was 1.6 (tuning seed 0), below any usual critical value.
"""

from __future__ import annotations

import warnings
from typing import Sequence

import numpy as np

from cvxid.errors import CvxidError, CvxidWarning
from cvxid.identify.path import validation_score
from cvxid.identify.profile import chance_factor, effective_rows
from cvxid.identify.problem import constrained_least_squares
from cvxid.identify.selection import StabilitySettings
from cvxid.regression.regression import Reduced, Regression

ACCEPTANCE = StabilitySettings()
"""The halves, blocks, threshold (0.7) and seed of the inclusion test: the stability
selection's defaults, not tuned for the test."""


def inclusion(fitted: Regression, scored: Regression, kept: Sequence[str], added: Sequence[str],
              nonnegative: Sequence[str] = (), ties: Sequence[tuple[str, str, float]] = ()) -> float:
    """The candidate's inclusion probability :math:`\\hat\\pi`: the share of halves of the
    training rows ``fitted`` on which dropping the columns ``added`` from the least squares
    of ``kept`` + ``added`` (a name in both is a candidate) raises the equation error on the
    test rows ``scored`` by more than its standard error.  Rows stacked from several
    equations (:attr:`~cvxid.regression.regression.Regression.parts`) are halved on the same
    stretches of time of each.  Halves on which a column is zero are skipped; with fewer than half of
    them left, or too few rows to cut, the candidate is refused (0) with a warning."""

    names = list(kept) + [n for n in added if n not in kept]
    regression, validate = fitted.subset(names), scored.subset(names).residual
    signs = [n for n in nonnegative if n in names]
    ties = [(a, b, f) for a, b, f in ties if a in names and b in names and (a in added) == (b in added)]
    both, without = np.ones(len(names), bool), np.array([n not in added for n in names])

    def error(reduced: Reduced, mask: np.ndarray) -> tuple[float, float]:
        scaled = constrained_least_squares(reduced, names, mask, signs, ties)
        return validation_score(validate(reduced.to_physical(scaled)))

    parts = regression.parts or (regression.shape[0],)
    try:
        halves = list(ACCEPTANCE.halves(regression.shape[0], parts))
    except CvxidError:
        fewest = min(parts)
        warnings.warn(f"the diagnosis cannot test {', '.join(added)}: {fewest} regression rows are too few to "
                      f"cut into {ACCEPTANCE.blocks} blocks; it is not added (give a longer record)", CvxidWarning,
                      stacklevel=3)
        return 0.0
    keeps = []
    for rows in halves:
        with warnings.catch_warnings():  # a candidate may repeat a model column: its ratio said so already
            warnings.simplefilter("ignore", CvxidWarning)
            try:  # (the half as 0/1 row weights, as the bootstrap's samples are)
                reduced = regression.reduce(rows.astype(float))
            except CvxidError:  # a column zero on this half (a record whose forcing starts late)
                continue
        with_it, se = error(reduced, both)
        keeps.append(error(reduced, without)[0] > with_it + se)
    if len(keeps) < ACCEPTANCE.samples / 2:
        warnings.warn(f"the diagnosis cannot test {', '.join(added)}: a column is zero on {ACCEPTANCE.samples - len(keeps)} "
                      f"of {ACCEPTANCE.samples} halves of the record; it is not added", CvxidWarning, stacklevel=3)
        return 0.0
    return float(np.mean(keeps))


def chance_fall(residuals: Sequence[np.ndarray | None], parameters: int = 1) -> float:
    r"""The factor by which ``parameters`` added parameters lower a test record's
    simulation error by chance alone (:func:`~cvxid.identify.profile.chance_factor`), read
    off the error of the model *with* them (``residuals``, one per coordinate), as an F
    test reads the larger model's residual variance:

    .. math:: \left(1 + \chi^2_{p,\,0.95} / n_\text{eff}\right)^{1/2},

    :math:`n_\text{eff}` the effective samples of that error
    (:func:`~cvxid.identify.profile.effective_rows` of its finite samples, the fewest over
    the coordinates); 1 when a simulation diverged (None) or left no finite sample.  Read
    off the model before, a poor model's error (few effective samples: a free run far off
    the record) would forbid the very additions that repair it (an outside check's Coulomb
    friction, 85.7 → 94.7 % on 3 effective samples); the diagnosis by simulation error
    reads its bound off the model before (:mod:`cvxid.diagnosis.simulation`), where both
    are polished and their errors alike.  A sixth outside check, at noise 0.1: a quadratic
    damping added on a fall of 1.0001 times, the model before already at the noise's
    ceiling (here about 1.0008 is needed)."""
    finite = [None if r is None else r[np.isfinite(r)] for r in residuals]
    if not finite or any(r is None or r.size == 0 for r in finite):
        return 1.0
    return chance_factor(min(effective_rows(r) for r in finite), parameters)


def accepted(probability: float) -> bool:
    """Whether an inclusion probability passes the rule's threshold."""
    return probability >= ACCEPTANCE.threshold - 1e-12


def stopped_at(effect: str, validation_ratio: float, errors_fall: bool | None = None,
               inclusion: float | None = None, polished: bool = False) -> dict:
    """Where a diagnosis loop stopped: the refused ``effect``, its ``validation_ratio`` (the
    test equation error before over after, above 1 when it helps), whether the refitted
    model's test errors fell and its inclusion (None where an earlier condition failed
    first), and whether the simulations compared were of the polished models; JSON-ready."""
    inclusion = None if inclusion is None or np.isnan(inclusion) else float(inclusion)
    return {"effect": effect, "validation_ratio": float(validation_ratio),
            "errors_fall": None if errors_fall is None else bool(errors_fall), "inclusion": inclusion,
            "polished": bool(polished)}


def stop_reason(stopped: dict) -> str:
    """The condition of the rule the refused candidate failed, in one line."""
    s = stopped
    reason = ("it does not lower the test equation error" if not s["validation_ratio"] > 1 else
              "the refitted model's test errors do not both fall (the simulation's beyond chance"
              + (", the two models polished by output error, the halves keeping it on "
                 f"{100 * s['inclusion']:.0f} %)" if s.get("polished") else ")")
              if not s["errors_fall"] else
              f"halves of the training record keep it on {100 * s['inclusion']:.0f} % of them "
              f"({100 * ACCEPTANCE.threshold:.0f} % needed)")
    return f"stopped at {s['effect']} (validation ratio {s['validation_ratio']:.4g}): {reason}"

