r"""The outer loop of the paper's Algorithm 1: which library order?

For each polynomial order :math:`N = 1, 2, \dots` the library is built, a bootstrap ensemble
of sparse fits is computed (or a single path when no bootstrap is asked for), and the mean
model is scored on the test experiment.  The order with the least test error wins (the
smallest one among ties, as the paper chooses).  AIC and BIC of the mean model on the
training rows are reported beside it,

.. math::

    \mathrm{AIC} = n \log(\mathrm{RSS}/n) + 2k, \qquad \mathrm{BIC} = n\log(\mathrm{RSS}/n) + k \log n,

with :math:`k` the number of selected terms; the rows of an algebraic regression are
strongly correlated, so these are indicative only.

Nested libraries share columns: the regression is built once at the highest order and each
order takes its columns by name.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
import pandas as pd

from .bootstrap import Bootstrap, BootstrapSettings, bootstrap
from .errors import CvxidError
from .path import Path
from .problem import Problem
from .problems import ProblemSpec
from .progress import progress
from .regression import Regression


@dataclass
class OrderSearch:
    """Test error (and information criteria) per library order."""

    table: pd.DataFrame
    coefficients: dict[int, pd.Series]
    ensembles: dict[int, Bootstrap] = field(default_factory=dict)

    @property
    def best_order(self) -> int:
        errors = self.table["test_mse"]
        return int(errors.index[np.flatnonzero(errors <= errors.min() * (1 + 1e-9))[0]])

    def plot(self):
        """Test error against order (the paper's Fig. 1)."""
        from .plots import order_figure

        return order_figure(self.table, self.best_order)

    def __repr__(self) -> str:
        return f"OrderSearch (best order {self.best_order})\n" + self.table.to_string(
            float_format=lambda v: f"{v:.4g}"
        )


def order_search(
    spec: ProblemSpec,
    orders=range(1, 7),
    samples: int | None = None,
    fraction: float = 0.5,
    seed: int = 0,
    n_jobs: int = 1,
    train: Regression | None = None,
    test: Regression | None = None,
    show_progress: bool = True,
) -> OrderSearch:
    """Run the order search of ``spec`` (its fit settings; ``samples`` bootstraps per order,
    none for a single path).  ``train``/``test`` regressions at the highest order may be
    passed to skip building them."""
    orders = sorted({int(o) for o in orders})
    if not orders or orders[0] < 1:
        raise CvxidError(f"orders must be whole numbers >= 1, got {orders}")
    if "test" not in spec.data and test is None:
        raise CvxidError("the order search scores orders on the test experiment: add [data.test]")
    fit = spec.fit
    top = replace(spec.model, library=spec.library(orders[-1]))
    velocity = fit.velocity if fit.velocity in ("observer", "savgol", "spline") else "measured"
    train = train if train is not None else Regression.build(top, spec.experiment("train"), velocity)
    test = test if test is not None else Regression.build(top, spec.experiment("test"), velocity)
    rows, coefficients, ensembles = [], {}, {}
    for order in progress(orders, desc="orders", disable=not show_progress):
        model = top.with_library(spec.library(order))
        names = model.column_names
        tr, te = train.subset(names), test.subset(names)
        if samples:
            ens = bootstrap(
                tr, fit.lambdas, te.residual, BootstrapSettings(samples, fraction, seed, n_jobs),
                model.nonnegative, fit.solver, fit.estimator, fit.debias, fit.selection,
                show_progress=False,
            )
            coef = ens.mean.to_numpy()
            ensembles[order] = ens
        else:
            problem = Problem.from_regression(tr, model.nonnegative, fit.solver)
            best = Path.compute(problem, fit.lambdas, te.residual, fit.estimator, fit.debias).best(fit.selection)
            coef = np.where(best.support | (problem.penalties == 0), best.coefficients, 0.0)
        n = tr.shape[0]
        k = int(np.count_nonzero(coef))
        rss = float(np.sum(tr.residual(coef) ** 2))
        rows.append(
            {
                "order": order,
                "terms": k,
                "test_mse": te.mse(coef),
                "train_mse": rss / n,
                "aic": n * np.log(rss / n) + 2 * k,
                "bic": n * np.log(rss / n) + k * np.log(n),
            }
        )
        coefficients[order] = pd.Series(coef, index=names)
    table = pd.DataFrame(rows).set_index("order")
    return OrderSearch(table, coefficients, ensembles)
