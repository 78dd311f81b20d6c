# ---
# jupyter:
#   jupytext:
#     text_representation:
#       format_name: percent
# ---

# %% [markdown]
# # Physical sign constraints change the answer
#
# Three seconds of a delayed oscillator with viscous and Coulomb friction (truth: `c = 0.4`,
# Coulomb `0.8`), noise 0.003, and a library that also offers drag `x'|x'|` and cubic
# damping `x'^3`.  These damping terms are nearly collinear on a short record: least
# squares trades them against each other and returns a *negative* drag.  Dissipative
# effects cannot be negative; saying so (`c >= 0`) is a convex constraint, and the answer
# becomes physical and closer to the truth.

# %%
from dataclasses import replace
from pathlib import Path

import numpy as np

import cvxid
from cvxid.model.library import Library
from cvxid.model.terms import parse_term
from cvxid.regression.builder import RegressionBuilder

HERE = Path(__file__).resolve().parent
spec = cvxid.load_problem(HERE.parent / "problems" / "hidden_friction.toml")
full = spec.experiment("train")
keep = full.time <= 3.0
rng = np.random.default_rng(1)
data = cvxid.Experiment(full.time[keep], {"x": full.output("x")[keep] + 0.003 * rng.standard_normal(keep.sum())},
                        {"f": full.input("f")[keep]}, "3 s")
damping = ["x'", "sign(x')", "x'|x'|", "x'^3"]
model = replace(spec.model, library=Library([parse_term(n) for n in ["x", *damping]]))
regression = RegressionBuilder(model, data, "savgol").at(0.15)  # the delay as known, to isolate the point

# %%
free = cvxid.Problem.from_regression(regression, nonnegative=["x''"])
signed = cvxid.Problem.from_regression(regression, nonnegative=["x''", *damping])
print(signed)  # the cvxpy formulation, with its named constraints
every = np.ones(len(regression.names), bool)
table = {
    "truth": {"x''": 1.0, "x": 6.0, "x'": 0.4, "sign(x')": 0.8, "x'|x'|": 0.0, "x'^3": 0.0},
    "least squares": dict(zip(regression.names, free.refit(every).coefficients)),
    "with signs": dict(zip(regression.names, signed.refit(every).coefficients)),
}
import pandas as pd  # noqa: E402

print(pd.DataFrame(table).round(3))
