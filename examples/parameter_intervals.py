# ---
# jupyter:
#   jupytext:
#     text_representation:
#       format_name: percent
# ---

# %% [markdown]
# # Parameter intervals: the local standard error against the delay's profile
#
# The output-error polish reports each parameter's 95 % interval.  From the standard error
# alone (the Wald interval, estimate ± 1.96 se) it describes one point of the simulation
# error; where the delay trades with other parameters (a free feedback gain against the
# stiffness, a delay against a damping) the record holds a long valley, and the profile
# over the delay walks it.  cvxid's interval is the hull of the Wald interval and of the
# parameter's refitted values at the delays the profile keeps.
#
# This draws the held-out benchmark's oscillators (`cvxid bench --heldout`: random masses,
# stiffnesses, gains, delays, forcing, 8 s records starting mid-motion, noise 0.01, the
# true terms listed), runs each with the documented defaults and counts, for every
# parameter but the delay (`m`, the coefficients, the gain when estimated), whether each
# kind of interval covers its truth: both from the same fit.  `SEEDS` (default
# `1000:1010`, report seeds), `EFFECTS` (default: the five of the benchmark), `GAIN`
# (`estimated`, the default, or `known`); `OUT` also writes the table as CSV.

# %%
import os

import numpy as np
import pandas as pd

import cvxid.tools.heldout as heldout

first, last = map(int, os.environ.get("SEEDS", "1000:1010").split(":"))
effects = os.environ.get("EFFECTS", "none,coulomb,quadratic_damping,quadratic_stiffness,offset").split(",")
known = os.environ.get("GAIN", "estimated") == "known"

# %%
rows = []
for effect in effects:
    for seed in range(first, last):
        oscillator = heldout.draw(seed, effect, 0.01, 8.0)
        result = heldout.identify_drawn(oscillator, known_gain=known)
        polish = result.polish
        truth = {k: v for k, v in oscillator.truth.items() if k in polish.parameters and k != "tau"}
        wald = [abs(polish.parameters[k] - v) <= 1.96 * polish.standard_errors[k] for k, v in truth.items()]
        profile = [polish.interval(k)[0] <= v <= polish.interval(k)[1] for k, v in truth.items()]
        widths = [np.diff(polish.interval(k))[0] / (2 * 1.96 * polish.standard_errors[k]) for k in truth]
        rows.append({"seed": seed, "effect": effect, "parameters": len(truth),
                     "Wald covers %": 100 * np.mean(wald), "profile covers %": 100 * np.mean(profile),
                     "Wald all": all(wald), "profile all": all(profile), "width ratio": np.median(widths),
                     "gain said": any("gain" in w and ("not identified" in w or "not determined" in w)
                                      for w in result.warnings)})
table = pd.DataFrame(rows).set_index(["effect", "seed"])
pd.set_option("display.width", 200)
summary = table.groupby(level="effect", sort=False).agg(
    systems=("parameters", "size"), **{"Wald covers %": ("Wald covers %", "mean"),
                                       "profile covers %": ("profile covers %", "mean"),
                                       "Wald: all cover %": ("Wald all", lambda s: 100 * s.mean()),
                                       "profile: all cover %": ("profile all", lambda s: 100 * s.mean()),
                                       "width ratio median": ("width ratio", "median"),
                                       "gain warning %": ("gain said", lambda s: 100 * s.mean())})
print(f"gain {'known' if known else 'estimated'}, seeds {first}:{last}, noise 0.01, 8 s")
print(summary.to_string(float_format=lambda v: f"{v:.3g}"))
print(f"all systems: Wald covers {table['Wald covers %'].mean():.1f} % of parameters, the profile hull "
      f"{table['profile covers %'].mean():.1f} %; every parameter covered on {100 * table['Wald all'].mean():.0f} % "
      f"and {100 * table['profile all'].mean():.0f} % of systems")
if os.environ.get("OUT"):
    table.to_csv(os.path.join(os.environ["OUT"], "parameter_intervals.csv"))
