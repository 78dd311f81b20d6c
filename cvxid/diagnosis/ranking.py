r"""Name the missing effect: candidates ranked by the share of the residual they explain.

Each candidate's columns (one per equation it joins, :mod:`cvxid.diagnosis.candidates`)
go through the same algebraic operation as the model's, are orthogonalised against the
model's columns :math:`Q` and scored two ways:

* the **error-reduction ratio**, the share of the model's equation-error residual
  :math:`r` the candidate explains,

  .. math::

      \mathrm{ERR} = \frac{r^T G_\perp (G_\perp^T G_\perp)^{+} G_\perp^T r}{r^T r},
      \qquad G_\perp = (I - QQ^T)\,G,

  for one column :math:`g` the familiar :math:`(g_\perp^T r)^2 / (g_\perp^T g_\perp\; r^T r)`;
* the **validation ratio**, the test record's equation-error MSE of the model refitted
  without the candidate over that with it (above 1: it helps on data the fit did not see).

Candidates whose orthogonalised contributions :math:`G_\perp\beta` (a single column: the
column itself) correlate above :data:`COLLINEAR` form one group: the equation error cannot
tell them apart, and the refinement lets a simulation decide
(:mod:`cvxid.diagnosis.refine`).  The same code ranks for one equation and for a system of
several, whose regressions are stacked.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field, replace
from typing import Sequence

import numpy as np
import pandas as pd

from cvxid.data.experiment import Experiment
from cvxid.diagnosis.candidates import (Candidate, candidates as candidates_of, default_candidates, lacks_delay,
                                        with_feedback_delay)
from cvxid.errors import CvxidError, CvxidWarning
from cvxid.identified import IdentifiedModel, IdentifiedSystem
from cvxid.identify.problem import Problem
from cvxid.identify.profile import profile_delay
from cvxid.model.equation import ModelSpec
from cvxid.model.system import SystemSpec
from cvxid.progress import progress
from cvxid.regression.builder import SystemBuilder
from cvxid.regression.windows import Windows, fitting_every, resolve_window, usable_seconds, windows_for_test

COLLINEAR = 0.9
"""Candidates whose orthogonalised contributions correlate above this form one group."""


def by_fit(fits: dict[str, float | None]) -> list[str]:
    """The candidates of ``fits`` (candidate -> free-run fit %, None when its run diverged),
    the best fit first and the diverged last."""
    return sorted(fits, key=lambda g: fits[g] if fits[g] is not None and np.isfinite(fits[g]) else -np.inf,
                  reverse=True)


@dataclass
class Diagnosis:
    """Candidate effects ranked by how much of the residual they explain."""

    ranking: pd.DataFrame
    groups: list[list[str]] = field(default_factory=list)
    residual: np.ndarray | None = None  # the model's (scaled) equation-error residual
    columns: dict[str, np.ndarray] = field(default_factory=dict)  # orthogonalised candidates
    candidates: dict[str, Candidate] = field(default_factory=dict)  # what each ranked name adds

    def plot(self, top: int = 3):
        """Partial-residual (added-variable) plots of the top candidates."""
        from cvxid.plots import partial_residual_figure

        return partial_residual_figure(self, top)

    @property
    def top(self) -> str:
        """The best-scoring candidate (by validation drop when known, else by ERR; among
        collinear rivals, by the free run when :meth:`decided` was called)."""
        return str(self.ranking.index[0])

    def decided(self, fits: dict[str, float | None]) -> Diagnosis:
        """This diagnosis with collinear rivals decided by their test free-run fits
        (``fits``: rival -> fit %, the mean over coordinates; None when its free run
        diverged): a ``free_run_fit`` column, and the best rival first."""
        best = by_fit(fits)[0]
        ranking = self.ranking.assign(free_run_fit=pd.Series({g: np.nan if f is None else f for g, f in fits.items()},
                                                             dtype=float))
        ranking = pd.concat([ranking.loc[[best]], ranking.drop(index=best)])
        return replace(self, ranking=ranking)

    def records(self) -> list[dict]:
        out = []
        for name, row in self.ranking.iterrows():
            rec = {"effect": str(name)}
            rec.update({k: (None if pd.isna(v) else (float(v) if not isinstance(v, str) else v)) for k, v in row.items()})
            out.append(rec)
        return out

    def __repr__(self) -> str:
        text = "Diagnosis: missing effects, best first\n" + self.ranking.to_string(float_format=lambda v: f"{v:.4g}")
        shared = [g for g in self.groups if len(g) > 1]
        if shared:
            text += "\n  nearly collinear (the data cannot tell them apart by ERR alone): "
            text += "; ".join(" ~ ".join(g) for g in shared)
        if "free_run_fit" in self.ranking:
            text += ("\n  free_run_fit: the test record's free-run fit (%) of each collinear rival refitted; "
                     "the best is ranked first")
        return text


def builders_for(specs: dict[str, ModelSpec], train: Experiment, test: Experiment | None, velocity: str,
                 window: float | str | None, given=None) -> tuple[SystemBuilder, SystemBuilder | None]:
    """The train and test builders passed in (a system's, or one equation's
    :class:`~cvxid.regression.builder.RegressionBuilder`), or new ones for the equations
    ``specs`` (the test data on the training data's windows)."""
    train_rows, test_rows = (None if b is None else SystemBuilder.of(b) for b in (given or (None, None)))
    if train_rows is None:
        train_rows = SystemBuilder(specs, train, velocity, window)
    if test_rows is None and test is not None:  # (a test record too short for automatic windows: its own)
        test_rows = SystemBuilder(specs, test, velocity, windows_for_test(window, train_rows.window, specs.values(), test))
    return train_rows, test_rows


def feedback_builders(specs: dict[str, ModelSpec], train: Experiment, test: Experiment | None, velocity: str,
                      window: float | str | None) -> tuple[SystemBuilder, SystemBuilder | None]:
    """The train and test builders of ``specs`` with a fed-back delay added
    (:func:`~cvxid.diagnosis.candidates.with_feedback_delay`): their rows start where the
    delay's measured history does, and their windows may differ, so a model without a delay
    is scored against the candidate on these rows, never across the two."""
    records = [e for e in (train, test) if e is not None]
    fed = with_feedback_delay(specs, *records)
    model = next(iter(fed.values()))
    seconds = window.seconds if isinstance(window, Windows) else window
    if window == "auto" or isinstance(seconds, (int, float)) and seconds > usable_seconds(model, records):
        window = fitting_every(resolve_window("auto", model, train.segments()), model, records)  # (every record's)
    return builders_for(fed, train, test, velocity, window)


def diagnose(
    model: IdentifiedModel | IdentifiedSystem,
    train: Experiment,
    test: Experiment | None = None,
    candidates: Sequence[str] | None = None,
    velocity: str = "savgol",
    window: float | str | None = "auto",
    builders: tuple[SystemBuilder, SystemBuilder | None] | None = None,
    fed_builders: tuple[SystemBuilder, SystemBuilder | None] | None = None,
) -> Diagnosis:
    """Rank ``candidates`` (catalogue names or term names; by default the catalogue and the
    spec's own effects) missing from ``model``, one equation or a system of several
    (``velocity`` and restart ``window`` as in
    :class:`~cvxid.regression.builder.RegressionBuilder`; ``builders`` of the train and test
    data may be passed to reuse their columns).

    A model without a delay offered the ``delay`` candidate (a fed-back delay to add) is
    scored with every candidate on the rows of the model with that delay
    (:func:`feedback_builders`, or ``fed_builders``), at the delay whose column, beside
    the model's terms, fits the training rows best (the delay profile).  That choice
    flatters its ERR (a column picked from many); its validation ratio is on the test
    rows, which the choice did not see, and ranks it when there is a test record (left
    out, with a word, where no delay fits the records: :func:`~cvxid.diagnosis.candidates.feedback_bound`)."""
    system = IdentifiedSystem.of(model)
    spec = system.spec
    found = candidates_of(system.specs, candidates if candidates is not None else default_candidates(system.specs))
    if not found:
        raise CvxidError("no candidate effect is missing from the model: each one named is in it already "
                         "([diagnose] candidates in a spec); name others, or leave them out for the whole catalogue")
    fed = "delay" in found and lacks_delay(system.specs)
    if fed and fed_builders is None:
        given = SystemBuilder.of(builders[0]).window if builders is not None and builders[0] is not None else window
        try:
            fed_builders = feedback_builders(system.specs, train, test, velocity, given)
        except CvxidError as exc:
            warnings.warn(f"the diagnosis leaves out the fed-back delay: {exc}", CvxidWarning, stacklevel=2)
            found.pop("delay")
            fed = False
            if not found:
                raise CvxidError("no candidate effect is left to rank (the fed-back delay was left out)") from None
    if fed:
        train_rows, test_rows = fed_builders
        specs = {label: replace(s, delay=train_rows.delay) for label, s in system.specs.items()}
    else:
        specs = system.specs
        train_rows, test_rows = builders_for(system.specs, train, test, velocity, window, builders)
    # the candidates are scored as candidates, a linear one too (kept, it would be in every refit)
    extended = {label: replace(s, library=s.library + _new_terms(s, found.values(), label), keep_linear=False)
                for label, s in specs.items()}
    names = list(SystemSpec(extended, system.ties).column_names)
    coefficients = system.coefficients
    used = [names.index(n) for n in spec.column_names if coefficients.get(n, 0.0) != 0.0]
    own = {name: [names.index(spec.column(label, c.term.name)) for label in c.equations] for name, c in found.items()}
    tau = system.tau
    if fed:  # the delay whose column explains the most beside the model's terms (those alone: a cheaper profile)
        alone = {label: replace(s, library=[t for t in s.library if coefficients.get(spec.column(label, t.name), 0.0)],
                                keep_linear=False) for label, s in specs.items()}  # (and its delayed column)
        tau = profile_delay(train_rows, nonnegative=spec.nonnegative, model=alone, ties=system.ties,
                            interval=False).estimate
    reg = train_rows.at(tau, extended)
    if fed:  # (the delayed column of an estimated gain is never penalised in a model; here it is a candidate)
        reg = replace(reg, penalties=np.where(np.isin(np.arange(len(names)), own["delay"]), 1.0, reg.penalties))
    scale = np.sqrt(np.mean(reg.P**2, axis=0))
    P, p = reg.P / scale, reg.p / np.sqrt(np.mean(reg.p**2))
    Q, _ = np.linalg.qr(P[:, used])
    r = p - Q @ (Q.T @ p)
    ortho, err = {}, {}
    for name, columns in own.items():
        ortho[name], err[name] = _explained(P[:, columns], Q, r)
    drops = {}
    if test_rows is not None:
        treg = test_rows.at(tau, extended)
        with warnings.catch_warnings():
            # a candidate may repeat a model column (the delay's derivative at tau = 0 is x'):
            # its ERR and its group say so, the rank warning would only alarm
            warnings.filterwarnings("ignore", message="the regression is rank-deficient", category=CvxidWarning)
            base = Problem.from_regression(reg, spec.nonnegative, ties=system.ties)
        mask = np.zeros(len(names), bool)
        mask[used] = True
        val_before = treg.mse(base.refit(mask).coefficients)
        for name, columns in progress(own.items(), "diagnosis: candidates", total=len(own)):
            m2 = mask.copy()
            m2[columns] = True
            drops[name] = val_before / max(treg.mse(base.refit(m2).coefficients), 1e-300)
    ranking = pd.DataFrame(
        {
            "term": [found[n].term.name for n in found],
            "meaning": [found[n].term.meaning for n in found],
            "err": [err[n] for n in found],
            "validation_ratio": [drops.get(n, np.nan) for n in found],
        },
        index=pd.Index(list(found), name="effect"),
    )
    key = "validation_ratio" if test_rows is not None else "err"
    ranking = ranking.sort_values([key, "err"], ascending=False)
    return Diagnosis(ranking, _groups(ortho, list(ranking.index)), r, ortho, found)



def _new_terms(spec, found, label) -> list:
    """The candidates' terms that join equation ``label``, each once."""
    terms = {}
    for c in found:
        if label in c.equations and c.term.name not in spec.column_names:
            terms.setdefault(c.term.name, c.term)
    return list(terms.values())


def _explained(columns: np.ndarray, Q: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, float]:
    """The candidate's ``columns`` orthogonalised against the model's (orthonormal ``Q``):
    the part of the residual ``r`` they explain (one column: the column itself) and its share
    of :math:`r^T r` (the ERR).  A column the model spans already (its orthogonal part below
    :math:`10^{-12}` of its norm: rounding) explains nothing."""
    G = columns - Q @ (Q.T @ columns)
    spanned = np.einsum("ij,ij->j", G, G) <= 1e-24 * np.einsum("ij,ij->j", columns, columns)
    if spanned.all():
        return np.zeros(r.size), 0.0
    if G.shape[1] == 1:
        g = G[:, 0]
        return g, float((g @ r) ** 2 / max((g @ g) * (r @ r), 1e-300))
    G = G[:, ~spanned]
    fitted = G @ np.linalg.lstsq(G, r, rcond=None)[0]
    return fitted, float((fitted @ r) / max(r @ r, 1e-300))


def _groups(ortho: dict[str, np.ndarray], order: list[str]) -> list[list[str]]:
    groups: list[list[str]] = []
    for name in order:
        g = ortho[name]
        for group in groups:
            h = ortho[group[0]]
            corr = abs(g @ h) / max(np.linalg.norm(g) * np.linalg.norm(h), 1e-300)
            if corr > COLLINEAR:
                group.append(name)
                break
        else:
            groups.append([name])
    return groups
