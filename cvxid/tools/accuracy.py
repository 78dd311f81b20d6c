"""``cvxid bench --accuracy SPEC``: delay and parameter errors of four methods, side by side.

For each noise level and seed, the spec's training experiment is simulated again (noise on
x and on the input at that level, new seed) and the *true structure* (the terms of
``[truth]``) is fitted from noisy x only (Savitzky–Golay velocity where a term needs one):

* ``paper as published`` — the paper's own algebra (n = 2, m = 3, which keeps one
  initial-condition term of the third-order Taylor column) with the simulator's true
  velocity, as the paper ran it;
* ``paper (true v)`` — the same with cvxid's initial-condition-exact orders (n = 3, m = 4);
* ``paper`` — Taylor order 3, thresholded least squares (the paper's method);
* ``taylor5`` — Taylor order 5 with one more integration (n = 5, m = 6);
* ``exact`` — the delayed signal through the algebraic operation, tau by profile search;
* ``exact+oe`` — the exact estimate polished by output error (no velocity at all).

The table gives, per method and noise level, the mean and standard deviation over seeds
of the delay's relative error and of the largest relative error of the other physical
parameters, and how often the tau interval covered the truth.  A spec whose training data
is a file (e.g. the paper's own dataset, with a ``[truth]`` section) gives one row per
method on that record.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pandas as pd

from cvxid.errors import CvxidError
from cvxid.identified import IdentifiedModel
from cvxid.identify.output_error import polish
from cvxid.identify.problem import Problem
from cvxid.identify.profile import profile_delay
from cvxid.identify.stlsq import stlsq
from cvxid.model.delay import DelayedFeedback
from cvxid.model.library import Library
from cvxid.progress import progress
from cvxid.regression.builder import RegressionBuilder
from cvxid.spec.problem import ProblemSpec

METHODS = ("paper as published", "paper (true v)", "paper", "taylor5", "exact", "exact+oe")
NOISES = (0.0, 0.001, 0.01, 0.05)


def _experiment(spec: ProblemSpec, noise: float | None, seed: int):
    """The training experiment: simulated anew at ``noise`` and ``seed``, or the spec's own
    file (``noise`` None: the data are what they are)."""
    table = dict(spec.data["train"])
    if "simulate" not in table:
        return spec.experiment("train")
    sim = dict(table["simulate"], seed=seed, noise={"output": noise, "input": noise})
    return replace(spec, data={"train": dict(table, simulate=sim)}).experiment("train")


def _fit(spec: ProblemSpec, method: str, experiment) -> tuple[dict, tuple | None]:
    truth, (equation,) = spec.truth.system, spec.truth.system.equations
    base = spec.model
    library = Library(equation.terms)
    gain = (equation.delay_gain, equation.delay_rate_gain) if equation.delay_rate_gain else equation.delay_gain
    rate = bool(equation.delay_rate_gain)  # (the paper's b0 x(t - tau) + b1 x'(t - tau))
    if method in ("paper as published", "paper (true v)", "paper", "taylor5"):
        paper = method.startswith("paper")
        delay = DelayedFeedback(base.coordinate, truth.derivative, gain, 3 if paper else 5, rate=rate)
        orders = {"paper as published": (2, 3), "taylor5": (5, 6)}.get(method, (None, None))
        model = replace(base, library=library, delay=delay, orders=orders,
                        keep_initial_conditions=method == "paper as published")
        true_v = method in ("paper as published", "paper (true v)")
        reg = RegressionBuilder(model, experiment, "measured" if true_v else "savgol").at(None)
        problem = Problem.from_regression(reg, model.nonnegative)
        fit = stlsq(problem, 0.0) if paper else problem.refit(np.ones(problem.k, bool))
        return model.physical(dict(zip(reg.names, fit.coefficients))), None
    tau_max = max(0.5, 2.5 * float(truth.tau))
    delay = DelayedFeedback(base.coordinate, truth.derivative, gain, method="exact", tau_max=tau_max,
                            history=truth.history, rate=rate)
    model = replace(base, library=library, delay=delay)
    family = RegressionBuilder(model, experiment, "savgol")
    profile = profile_delay(family, nonnegative=model.nonnegative)
    reg = family.at(profile.estimate)
    fit = Problem.from_regression(reg, model.nonnegative).refit(np.ones(reg.shape[1], bool))
    identified = IdentifiedModel(model, dict(zip(reg.names, fit.coefficients)), tau=profile.estimate)
    if method == "exact":
        return identified.physical, profile.interval
    polished = polish(identified, experiment)
    return polished.model.physical, polished.interval("tau")


def accuracy(spec: ProblemSpec, noises=NOISES, seeds: int = 5, methods=METHODS) -> pd.DataFrame:
    """One row per (method, noise): tau error and worst other-parameter error (%)."""
    if spec.truth is None or not spec.truth.system.equations[0].delay_gain:
        raise CvxidError("the accuracy benchmark needs a [truth] with a delayed feedback")
    truth = spec.truth.physical
    rows = []
    if "simulate" not in spec.data["train"]:  # measured data: one record, its own noise
        noises, seeds = ("data",), 1
    cases = [(noise, seed) for noise in noises for seed in range(seeds)]
    for noise, seed in progress(cases, desc="accuracy"):
        experiment = _experiment(spec, None if noise == "data" else noise, 1000 + seed)
        for method in methods:
            if method in ("paper as published", "paper (true v)") and spec.model.coordinate not in experiment.velocities:
                continue
            phys, interval = _fit(spec, method, experiment)
            others = [abs(phys[k] / truth[k] - 1) for k in truth if k != "tau" and truth[k] != 0]
            rows.append({
                "method": method, "noise": noise, "seed": seed,
                "tau": phys["tau"],
                "tau_error_%": 100 * (phys["tau"] / truth["tau"] - 1),
                "worst_other_error_%": 100 * max(others),
                "covered": None if interval is None else bool(interval[0] <= truth["tau"] <= interval[1]),
            })
    return pd.DataFrame(rows)


def summary(frame: pd.DataFrame) -> pd.DataFrame:
    grouped = frame.groupby(["method", "noise"], sort=False)
    out = pd.DataFrame({
        "tau mean": grouped["tau"].mean(),
        "tau error % mean": grouped["tau_error_%"].mean(),
        "tau error % std": grouped["tau_error_%"].std(),
        "worst other % mean": grouped["worst_other_error_%"].mean(),
        "worst other % std": grouped["worst_other_error_%"].std(),
        "interval covers": grouped["covered"].apply(lambda c: f"{int(c.sum())}/{len(c)}" if c.notna().all() else "-"),
    })
    return out
