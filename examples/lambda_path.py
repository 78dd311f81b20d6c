# ---
# jupyter:
#   jupytext:
#     text_representation:
#       format_name: percent
# ---

# %% [markdown]
# # Exploring the λ path
#
# The paper's Duffing oscillator (simulated by cvxid; here with the simulator's velocity,
# as the paper used it).  One cvxpy problem is solved over 50 values of λ, each solution
# refitted on its support; the test experiment scores each one.  Figures go to `OUT`.

# %%
import os
from pathlib import Path

import numpy as np

import cvxid
from cvxid.regression.builder import RegressionBuilder

HERE = Path(__file__).resolve().parent
OUT = Path(os.environ.get("OUT", "out/lambda_path"))
OUT.mkdir(parents=True, exist_ok=True)
spec = cvxid.load_problem(HERE.parent / "problems" / "duffing_delay.toml")
train = RegressionBuilder(spec.model, spec.experiment("train"), "measured").at(None)
test = RegressionBuilder(spec.model, spec.experiment("test"), "measured").at(None)
problem = cvxid.Problem.from_regression(train, spec.model.nonnegative)
print(problem)

# %% [markdown]
# ## Lasso, adaptive lasso (weights from least squares) and the paper's thresholding, side by side

# %%
lambdas = np.logspace(-6, 2, 50)
for estimator in ("lasso", "adaptive_lasso", "stlsq"):
    path = cvxid.Path.compute(problem, lambdas, validate=test.residual, estimator=estimator)
    print(f"\n{estimator}: Pareto front (least training error per number of terms)")
    print(path.pareto)
    for rule in ("min", "1se"):
        best = path.best(rule)
        chosen = [n for n, s in zip(path.names, best.support) if s]
        print(f"  {rule}: lambda = {best.lam:.3g}, {len(chosen)} terms: {', '.join(chosen)}")
    path.plot(path.best("min").lam).savefig(OUT / f"path_{estimator}.png", dpi=100)

# %% [markdown]
# ## How sure is the selection?  The bootstrap's inclusion probabilities

# %%
boot = cvxid.Bootstrap.of(problem, samples=10, fraction=0.5, seed=0, lambdas=lambdas, validate=test.residual,
                          estimator="stlsq", show_progress=False)
print(boot.summary().round(4))
