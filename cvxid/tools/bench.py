"""``cvxid bench SPEC``: speed of the lambda path against the baselines, in one run.

Times (seconds, wall clock, this machine):

* ``path_seconds`` — our :class:`~cvxid.identify.path.Path`: QR reduction, one cvxpy problem with
  ``lambda`` a parameter, one Clarabel solve per lambda;
* ``naive_cvxpy_seconds`` — a cvxpy problem rebuilt on the raw (scaled) rows for each
  lambda, measured on ``naive_lambdas`` of the grid and scaled to the whole grid
  (it takes minutes otherwise; ``--naive-lambdas 50`` measures all);
* ``sklearn_seconds`` — scikit-learn's ``lasso_path`` on the same scaled data with the
  unpenalised columns projected out (no sign constraints: compared with our path on the
  same problem without them);
* ``stlsq_seconds`` — the paper's thresholded least squares over the same grid;
* ``algorithm1_seconds`` — the whole Algorithm 1: orders 1–6, 30 bootstraps, 50 lambdas.

Our path and scikit-learn's are timed as the best of :data:`REPEATS` runs each (a single
run of tens of milliseconds varies by a third on a busy machine); the rest once.

``max_coefficient_difference`` is the largest relative difference (scaled units) of our
path's coefficients from the naive cvxpy solutions, and ``sklearn_max_difference`` from
scikit-learn's, over the lambdas where both are optimal.
"""

from __future__ import annotations

import json
import time
import warnings
from dataclasses import replace

import cvxpy as cp
import numpy as np
import pandas as pd

from cvxid.app.run import order_search
from cvxid.errors import CvxidError, CvxidWarning
from cvxid.identify.path import Path
from cvxid.identify.problem import SOLVER_SETTINGS, Problem
from cvxid.identify.profile import profiled_tau
from cvxid.regression.builder import RegressionBuilder
from cvxid.regression.regression import Regression
from cvxid.spec.load import load_problem
from cvxid.spec.problem import ProblemSpec


def _relative(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.max(np.abs(a - b)) / max(np.max(np.abs(b)), 1e-12))


def _naive(regression: Regression, nonnegative, lambdas) -> tuple[float, list[np.ndarray]]:
    """A cvxpy problem on the raw scaled rows, rebuilt per lambda (the straightforward way)."""
    scale = np.sqrt(np.mean(regression.P**2, axis=0))
    tscale = np.sqrt(np.mean(regression.p**2))
    P, p = regression.P / scale, regression.p / tscale
    n = len(p)
    start = time.perf_counter()
    out = []
    for lam in lambdas:
        c = cp.Variable(P.shape[1])
        cons = [c[regression.names.index(m)] >= 0 for m in nonnegative]
        obj = cp.sum_squares(P @ c - p) / n + lam * cp.norm1(cp.multiply(regression.penalties, c))
        prob = cp.Problem(cp.Minimize(obj), cons)
        try:
            prob.solve(solver="CLARABEL", **SOLVER_SETTINGS["CLARABEL"])
        except cp.error.SolverError:  # the baseline's own failure: counted, not compared
            out.append(None)
            continue
        out.append(c.value if prob.status == cp.OPTIMAL else None)
    return time.perf_counter() - start, out


REPEATS = 5
"""Runs of our path and of scikit-learn's; the fastest of each is reported."""


def _fastest(job):
    """``job()`` run :data:`REPEATS` times: the fewest seconds and the last result."""
    seconds = np.inf
    for _ in range(REPEATS):
        start = time.perf_counter()
        result = job()
        seconds = min(seconds, time.perf_counter() - start)
    return seconds, result


def _sklearn(problem: Problem, lambdas) -> tuple[float | None, np.ndarray | None]:
    """scikit-learn's lasso_path on the projected, scaled factor (None if not installed)."""
    try:
        from sklearn.linear_model import lasso_path
    except ImportError:
        return None, None
    u = problem._free.size

    def path():
        Q, Rp = np.linalg.qr(problem.reduced.R[:, np.r_[problem._free, problem._rest]])
        rp = Q.T @ problem.reduced.r
        X, y = Rp[u:, u:], rp[u:]
        # ours: (1/N)||Xc - y||^2 + lam |c|_1;  sklearn: (1/(2 n))||Xc - y||^2 + alpha |c|_1
        alphas = np.asarray(lambdas) * problem.reduced.rows / (2 * X.shape[0])
        return lasso_path(X, y, alphas=alphas, tol=1e-10, max_iter=100_000)[1]

    seconds, coefs = _fastest(path)
    return seconds, coefs.T  # one row per alpha (same order as lambdas)


def benchmark(spec: ProblemSpec, order: int | None = None, naive_lambdas: int = 5, n_jobs: int = 2) -> dict:
    """Measure everything the module docstring lists; returns the figures."""
    fit = spec.fit
    lambdas = np.sort(fit.lambdas)[::-1]
    velocity = fit.velocity if fit.velocity in ("observer", "savgol", "spline") else "measured"
    if spec.system.single is None or not spec.polynomials:
        raise CvxidError(f"cvxid bench SPEC times the lambda path and the paper's Algorithm 1 (orders 1-6) of one "
                         f"equation's polynomial library; '{spec.name}' "
                         + ("is coupled" if spec.system.single is None else "lists its terms")
                         + ": bench a spec with [model.library] order = ... (duffing_delay, paper_duffing_data)")
    model = spec.model if order is None else spec.at_order(spec.system, order).single
    builder = RegressionBuilder(model, spec.experiment("train"), velocity)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", CvxidWarning)
        train = builder.at(profiled_tau(builder))  # an exact delay: the path at the profiled delay

        def ours_path():
            problem = Problem.from_regression(train, model.nonnegative, "CLARABEL")
            return problem, Path.compute(problem, lambdas, debias=False)

        path_seconds, (problem, ours) = _fastest(ours_path)

        pick = np.unique(np.linspace(0, len(lambdas) - 1, min(naive_lambdas, len(lambdas))).astype(int))
        naive_seconds, naive = _naive(train, model.nonnegative, lambdas[pick])
        naive_total = naive_seconds * len(lambdas) / len(pick)
        diffs = [
            _relative(ours.fits[i].scaled, sol)
            for i, sol in zip(pick, naive)
            if sol is not None
        ]

        free = Problem.from_regression(train, (), "CLARABEL")  # no sign constraints: sklearn's problem
        free_path = Path.compute(free, lambdas, debias=False)
        sk_seconds, sk = _sklearn(free, lambdas)
        sk_diff = sk_gap = None
        if sk is not None:
            sk_diff = max(_relative(f.scaled[free._rest], s) for f, s in zip(free_path.fits, sk))
            # objectives tell which solution is better where coefficients are ill-determined
            sk_gap = max(
                f.objective / free._finish(f.lam, free._full(s), "", 0.0).objective - 1
                for f, s in zip(free_path.fits, sk)
            )

        start = time.perf_counter()
        Path.compute(problem, lambdas, estimator="stlsq")
        stlsq_seconds = time.perf_counter() - start

        start = time.perf_counter()
        lasso = spec if fit.estimator in ("lasso", "stlsq") else replace(spec, fit=replace(fit, estimator="lasso"))
        search = order_search(lasso, range(1, 7), samples=30, n_jobs=n_jobs, show_progress=False)
        algorithm1_seconds = time.perf_counter() - start
    return {
        "terms": len(train.names),
        "rows": train.shape[0],
        "lambdas": len(lambdas),
        "path_seconds": path_seconds,
        "naive_cvxpy_seconds": naive_total,
        "naive_lambdas_measured": int(len(pick)),
        "naive_failures": int(sum(sol is None for sol in naive)),
        "sklearn_seconds": sk_seconds,
        "stlsq_seconds": stlsq_seconds,
        "algorithm1_seconds": algorithm1_seconds,
        "algorithm1_order": search.best_order,
        "max_coefficient_difference": max(diffs) if diffs else None,
        "sklearn_max_difference": sk_diff,
        "sklearn_max_objective_gap": sk_gap,
    }


def table(figures: dict) -> pd.DataFrame:
    """The figures as a printable table, with speed-ups against our path."""
    ours = figures["path_seconds"]
    rows = [
        ("(a) cvxid Path (reduce + 1 canonicalisation + Clarabel per lambda)", ours),
        (f"(b) cvxpy rebuilt on raw rows per lambda (from {figures['naive_lambdas_measured']} lambdas)",
         figures["naive_cvxpy_seconds"]),
        ("(c) scikit-learn lasso_path (no signs)", figures["sklearn_seconds"]),
        ("(d) thresholded least squares (the paper)", figures["stlsq_seconds"]),
        ("(e) Algorithm 1: orders 1-6 x 30 bootstraps x 50 lambdas", figures["algorithm1_seconds"]),
    ]
    frame = pd.DataFrame(rows, columns=["approach", "seconds"]).set_index("approach")
    frame["x our path"] = frame["seconds"] / ours
    return frame


def run_bench(spec_path, order=None, naive_lambdas=5, json_path=None, n_jobs=2) -> dict:
    spec = load_problem(spec_path)
    figures = benchmark(spec, order, naive_lambdas, n_jobs)
    print(f"cvxid bench: {spec.name}, {figures['terms']} columns x {figures['rows']} rows, {figures['lambdas']} lambdas")
    print(table(figures).to_string(float_format=lambda v: f"{v:.4g}"))
    print(f"max relative coefficient difference, (a) vs (b): {figures['max_coefficient_difference']} "
          f"({figures['naive_failures']} of {figures['naive_lambdas_measured']} naive solves failed)")
    if figures["sklearn_seconds"] is None:
        print("(c) not measured: scikit-learn is not installed (pip install \"cvxid[bench]\" brings it)")
    else:
        print(f"max relative coefficient difference, (a) vs (c): {figures['sklearn_max_difference']}; "
              f"largest relative excess of our objective over scikit-learn's: {figures['sklearn_max_objective_gap']}")
        print(f"our path (weights and signs) / scikit-learn's lasso_path (neither): "
              f"{figures['path_seconds'] / figures['sklearn_seconds']:.2f}x")
    print(f"Algorithm 1 chose order {figures['algorithm1_order']}")
    if json_path:
        with open(json_path, "w") as fh:
            json.dump(figures, fh, indent=2)
    return figures
