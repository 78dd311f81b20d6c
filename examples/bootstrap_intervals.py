# ---
# jupyter:
#   jupytext:
#     text_representation:
#       format_name: percent
# ---

# %% [markdown]
# # Bootstrap intervals: single rows against blocks of rows
#
# `[fit] bootstrap` resamples the regression's rows and reports each parameter's spread and
# 95 % percentile interval.  The paper drew single rows; but a sliding window's row shares
# most of its data with the next, so single rows count the same data many times and the
# spreads come out too narrow (a tenth outside check: a linear oscillator whose every
# interval missed the truth by 6-10 standard deviations).  cvxid now draws blocks of
# consecutive rows, as long as the residual's correlation (`resample = "blocks"`, the
# default).
#
# This draws the held-out benchmark's oscillators (`cvxid bench --heldout`: random masses,
# stiffnesses, gains, delays, forcing, 8 s records starting mid-motion, noise 0.01 and
# 0.001 on x and f, the true terms listed, the gain given), runs each with `bootstrap = {
# samples = 20 }` and each way of resampling, and counts whether each parameter's bootstrap
# interval covers its truth (the delay's too: each sample's exact delay is profiled again
# on its rows, so the delay's error spreads into the coefficients it trades with).  Neither
# counts the bias that noise on x leaves in the equation error's columns.  Run it on the
# code before 2026-11-27 for the baseline: single rows and the delay held at the estimate.
# `SEEDS` (default `1000:1010`, report seeds; `0:10` tuning), `OUT` for the rows as CSV.

# %%
import numpy as np
import pandas as pd

import cvxid.tools.heldout as heldout

EFFECTS = ("none", "coulomb", "quadratic_damping", "quadratic_stiffness", "offset")
NOISES = (0.01, 0.001)


def covered(seed: int, effect: str, noise: float, resample: str) -> dict:
    """One system's bootstrap: the share of its parameters whose 95 % interval covers the
    truth, and the median spread (std) relative to the estimate."""
    oscillator = heldout.draw(seed, effect, noise, 8.0)
    fit = {"refine": "none", "bootstrap": {"samples": 20, "seed": 0, "resample": resample}}
    spread = heldout.identify_drawn(oscillator, known_gain=True, fit=fit).bootstrap.physical_summary()
    truth = {k: v for k, v in oscillator.truth.items() if k in spread.index}
    covers = [spread.loc[k, "q2.5"] <= v <= spread.loc[k, "q97.5"] for k, v in truth.items()]
    return {"seed": seed, "effect": effect, "noise": noise, "resample": resample, "parameters": len(truth),
            "covers %": 100 * np.mean(covers), "all cover": all(covers),
            "relative std": float(np.median([spread.loc[k, "std"] / abs(v) for k, v in truth.items()]))}


cases = [(e, n, r) for e in EFFECTS for n in NOISES for r in ("rows", "blocks")]
rows = heldout.example_runs(covered, cases, "bootstrap_intervals")
table = rows.groupby(["effect", "noise", "resample"], sort=False).agg(
    systems=("seed", "count"), **{"parameters covered %": ("covers %", "mean"),
                                  "systems all covered %": ("all cover", lambda s: 100 * s.mean()),
                                  "median relative std": ("relative std", "median")})
print(table.to_string(float_format=lambda v: f"{v:.3g}"))
overall = rows.groupby(["noise", "resample"], sort=False)[["covers %"]].mean()
print(overall.rename(columns={"covers %": "parameters covered % (all systems)"}).to_string(float_format=lambda v: f"{v:.3g}"))

# %% [markdown]
# ## The support an exact delay's bootstrap keeps
#
# With an exact delay the run refits the terms the bootstrap chose.  It took every term whose
# ensemble mean is nonzero, i.e. any term a single sample picked; blocks of rows vary more
# from sample to sample than single rows, and such models kept a dozen spurious terms.  It
# now keeps the terms at least half the samples chose.  Here the selection mode's 18-term
# library (`cvxid bench --heldout --mode selection`), gain given, noise 0.01, 8 s, `bootstrap
# = { samples = 20 }`: how many systems end with exactly the true terms.  (Run on the code
# before 2026-11-27, 3ad2277, for the "any sample" baseline.)


# %%
def support(seed: int, effect: str) -> dict:
    """One system selected with a bootstrap: its spurious and missed terms."""
    row = heldout.run_one(seed, effect, 0.01, 8.0, mode="selection", known_gain=True,
                          fit={"bootstrap": {"samples": 20, "seed": 0}, "refine": "none"})
    count = lambda terms: len([t for t in str(terms or "").split(",") if t and t != "nan"])  # noqa: E731
    return {"seed": seed, "effect": effect, "spurious": count(row.get("spurious")), "missed": count(row.get("missed"))}


chosen = heldout.example_runs(support, [("none",), ("quadratic_damping",)], "bootstrap_support")
print(pd.DataFrame({"systems": [len(chosen)],
                    "exactly the true terms": [int(((chosen["spurious"] == 0) & (chosen["missed"] == 0)).sum())],
                    "spurious terms (median)": [chosen["spurious"].median()],
                    "missed terms (all)": [chosen["missed"].sum()]}).to_string(index=False))
