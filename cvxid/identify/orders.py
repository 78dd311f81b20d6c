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

from dataclasses import dataclass, field
from typing import Callable

import warnings

import numpy as np
import pandas as pd

from cvxid.errors import CvxidError
from cvxid.identify.bootstrap import Bootstrap, BootstrapSettings, bootstrap
from cvxid.identify.path import select
from cvxid.identify.problem import Problem
from cvxid.model.system import SystemSpec
from cvxid.progress import progress
from cvxid.regression.regression import Regression


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
        from cvxid.plots import order_figure

        return order_figure(self.table, self.best_order)

    def __repr__(self) -> str:
        return f"OrderSearch (best order {self.best_order})\n" + self.table.to_string(
            float_format=lambda v: f"{v:.4g}"
        )


def search_orders(
    system: Callable[[int], SystemSpec],
    train: Regression,
    test: Regression,
    orders,
    lambdas,
    estimator: str = "lasso",
    debias: bool = True,
    selection: str = "min",
    solver: str = "CLARABEL",
    boot: BootstrapSettings | None = None,
    show_progress: bool = True,
) -> OrderSearch:
    r"""Score every library order: ``system(N)`` is the system (of :math:`N \ge 1`
    equations) at order ``N``, ``train``/``test`` the regressions at the highest order
    (each order takes its columns by name, its ties those between columns it has);
    ``boot`` bootstraps each order, else one path each.  What an order's fit warns of is
    said with its order (the paper's dataset, orders 1–6: "25 of 30 bootstrap samples: the
    regression is rank-deficient: column(s) x^6 x'^4 …" beside a model of order 3 read as
    if it were about that model)."""
    orders = sorted({int(o) for o in orders})
    if not orders or orders[0] < 1:
        raise CvxidError(f"orders must be whole numbers >= 1, got {orders}")
    rows, coefficients, ensembles = [], {}, {}
    for order in progress(orders, desc="orders", disable=not show_progress):
        model = system(order)
        names = model.column_names
        tr, te = train.subset(names), test.subset(names)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            if boot is not None:
                ens = bootstrap(
                    tr, lambdas, te.residual, boot, model.nonnegative, solver, estimator, debias, selection,
                    show_progress=False, ties=model.ties,
                )
                coef = ens.mean.to_numpy()
                ensembles[order] = ens
            else:
                problem = Problem.from_regression(tr, model.nonnegative, solver, ties=model.ties)
                _, best = select(problem, lambdas, te.residual, estimator, debias, rule=selection)
                coef = np.where(best.support | (problem.penalties == 0), best.coefficients, 0.0)
        for said in caught:
            warnings.warn(f"the order search, order {order}: {said.message}", said.category, stacklevel=2)
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
