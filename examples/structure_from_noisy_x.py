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
# for `SEEDS` noise seeds (default 4), on the same data: with the spec's Taylor delay the
# paper's thresholded least squares (`stlsq`, Savitzky–Golay velocity), cvxid's default
# convex selection (`adaptive_lasso`) and its selection by simulation error
# (`stepwise_oe`), and the lasso and the adaptive lasso with the output-error polish and the
# pruning of the selected terms by simulation error (`[fit] prune`, the default); with an exact delay
# (`method = "exact"`, `tau_max = 0.5`) the lasso with the polish, without and with the
# pruning, and `stepwise_oe`.  It prints whether
# each found the true support and its parameter errors.

# %%
import os
import tomllib

import pandas as pd

import cvxid
from cvxid.spec.load import load_problem, parse_problem

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")
SPEC = os.path.join(ROOT, "problems", "duffing_delay.toml")
seeds = int(os.environ.get("SEEDS", "4"))
truth = load_problem(SPEC).truth.physical
TRUE = {"x''", "x", "x'", "x^3", "x^2 x'", "x'^3"}  # and the delay (the column x''' of a Taylor delay)
EXACT = {"signal": "x", "gain": 2.0, "method": "exact", "tau_max": 0.5}
VARIANTS = {  # name: (the delay, [fit] settings)
    "stlsq": (None, {"estimator": "stlsq"}),
    "adaptive_lasso": (None, {"estimator": "adaptive_lasso"}),
    "stepwise_oe": (None, {"estimator": "stepwise_oe"}),
    "lasso + polish + pruning": (None, {"estimator": "lasso", "refine": "output_error"}),
    "adaptive_lasso + polish + pruning": (None, {"estimator": "adaptive_lasso", "refine": "output_error"}),
    "exact delay, lasso + polish, no pruning": (EXACT, {"estimator": "lasso", "refine": "output_error",
                                                        "prune": False}),
    "exact delay, lasso + polish + pruning": (EXACT, {"estimator": "lasso", "refine": "output_error"}),
    "exact delay, stepwise_oe": (EXACT, {"estimator": "stepwise_oe"}),
}


def variant(seed, name):
    """duffing_delay.toml with the training record's noise seed, the delay and [fit] of ``name``."""
    with open(SPEC, "rb") as f:
        raw = tomllib.load(f)
    delay, fit = VARIANTS[name]
    raw["data"]["train"]["simulate"]["seed"] = seed
    if delay is not None:
        raw["model"]["delay"] = delay
    raw["fit"] = {"lambdas": raw["fit"]["lambdas"], "velocity": "savgol", **fit}
    return parse_problem(raw, os.path.join(ROOT, "problems"))


# %%
rows = []
for seed in range(1, seeds + 1):
    for name in VARIANTS:
        result = cvxid.run(variant(seed, name))
        support = set(result.model.support) - {"x'''"}
        row = {"seed": seed, "estimator": name, "true support": support == TRUE,
               "extra": " ".join(sorted(support - TRUE)), "missing": " ".join(sorted(TRUE - support))}
        physical = result.model.physical
        for parameter, value in truth.items():
            row[f"{parameter} %"] = 100 * (physical.get(parameter, 0.0) / value - 1)
        row["seconds"] = result.seconds
        rows.append(row)
table = pd.DataFrame(rows).set_index(["seed", "estimator"])
pd.set_option("display.width", 220)
print(table.to_string(float_format=lambda v: f"{v:+.2f}"))
if os.environ.get("OUT"):  # the table as CSV too, for scripts and the test suite
    table.to_csv(os.path.join(os.environ["OUT"], "structure_from_noisy_x.csv"))
for estimator, group in table.groupby(level="estimator", sort=False):
    worst = group[[c for c in group.columns if c.endswith("%")]].abs().max()
    print(f"{estimator}: true support {int(group['true support'].sum())}/{len(group)}; worst |error| "
          + ", ".join(f"{k[:-2]} {v:.2f} %" for k, v in worst.items())
          + f"; {group['seconds'].median():.1f} s a run (median)")
