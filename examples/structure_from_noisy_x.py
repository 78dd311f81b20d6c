# ---
# jupyter:
#   jupytext:
#     text_representation:
#       format_name: percent
# ---

# %% [markdown]
# # Finding the structure from noisy x alone
#
# The paper's Duffing oscillator (`problems/duffing_delay.toml`, noise 0.01 on x and f)
# has a term `x'^3` that needs the velocity.  From noisy x, every velocity estimate leaves
# an error that the equation-error regression turns into wrong terms.  This script runs,
# for `SEEDS` noise seeds (default 4), the paper's thresholded least squares (`stlsq`,
# Savitzky–Golay velocity), cvxid's default convex selection (`adaptive_lasso`) and its
# selection by simulation error (`stepwise_oe`) on the same data, and prints whether each
# found the true support and its parameter errors.

# %%
import os
from dataclasses import replace

import pandas as pd

import cvxid
from cvxid.spec.load import load_problem

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")
seeds = int(os.environ.get("SEEDS", "4"))
spec = load_problem(os.path.join(ROOT, "problems", "duffing_delay.toml"))
TRUE = {"x''", "x", "x'", "x^3", "x^2 x'", "x'^3", "x'''"}


def variant(seed, estimator):
    train = dict(spec.data["train"], simulate=dict(spec.data["train"]["simulate"], seed=seed))
    return replace(spec, data=dict(spec.data, train=train), fit=replace(spec.fit, estimator=estimator))


# %%
rows = []
for seed in range(1, seeds + 1):
    for estimator in ("stlsq", "adaptive_lasso", "stepwise_oe"):
        result = cvxid.run(variant(seed, estimator))
        support = set(result.model.support)
        row = {"seed": seed, "estimator": estimator, "true support": support == TRUE,
               "extra": " ".join(sorted(support - TRUE)), "missing": " ".join(sorted(TRUE - support))}
        physical = result.model.physical
        for name, truth in spec.truth.physical.items():
            row[f"{name} %"] = 100 * (physical.get(name, 0.0) / truth - 1)
        row["seconds"] = result.seconds
        rows.append(row)
table = pd.DataFrame(rows).set_index(["seed", "estimator"])
pd.set_option("display.width", 200)
print(table.to_string(float_format=lambda v: f"{v:+.2f}"))
if os.environ.get("OUT"):  # the table as CSV too, for scripts and the test suite
    table.to_csv(os.path.join(os.environ["OUT"], "structure_from_noisy_x.csv"))
for estimator, group in table.groupby(level="estimator"):
    worst = group[[c for c in group.columns if c.endswith("%")]].abs().max()
    print(f"{estimator}: true support {int(group['true support'].sum())}/{len(group)}; worst |error| "
          + ", ".join(f"{k[:-2]} {v:.2f} %" for k, v in worst.items()))
