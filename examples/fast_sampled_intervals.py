# ---
# jupyter:
#   jupytext:
#     text_representation:
#       format_name: percent
# ---

# %% [markdown]
# # Delay intervals of records sampled faster than the delay profile's step
#
# The output-error profile over the delay simulates on a 1 ms step; a record sampled
# faster is fitted at its own step last.  This draws the held-out benchmark's oscillators
# (`cvxid bench --heldout`: random masses, stiffnesses, gains, delays, forcing, 8 s records
# starting mid-motion, noise 0.01, the feedback gain known) but samples them at 5 kHz, runs
# each with the documented defaults, and prints each delay's 95 % interval: does it cover
# the truth, and how wide is it beside the standard error?  `SEEDS` (default `1000:1010`,
# report seeds), `EFFECTS` (default `none,coulomb`); `OUT` also writes the table as CSV.
# Run it with `PYTHONPATH=<a checkout of another commit>` to compare.

# %%
import os

import pandas as pd

import cvxid.tools.heldout as heldout

heldout.DT = 2e-4  # 5 kHz instead of the benchmark's 1 kHz
first, last = map(int, os.environ.get("SEEDS", "1000:1010").split(":"))
effects = os.environ.get("EFFECTS", "none,coulomb").split(",")

# %%
rows = []
for effect in effects:
    for seed in range(first, last):
        oscillator = heldout.draw(seed, effect, 0.01, 8.0)
        result = heldout.identify_drawn(oscillator, known_gain=True)
        low, high = result.tau["interval"]
        truth = oscillator.tau
        rows.append({"seed": seed, "effect": effect, "true tau": truth, "tau": result.tau["estimate"],
                     "low": low, "high": high, "covers": low <= truth <= high,
                     "half-width %": 100 * (high - low) / 2 / truth,
                     "1.96 se %": 100 * 1.96 * result.polish.standard_errors["tau"] / truth})
table = pd.DataFrame(rows).set_index(["effect", "seed"])
pd.set_option("display.width", 200)
print(table.to_string(float_format=lambda v: f"{v:.4g}"))
for effect, group in table.groupby(level="effect"):
    print(f"{effect}: intervals cover {int(group['covers'].sum())}/{len(group)}; half-width median "
          f"{group['half-width %'].median():.2f} %, 1.96 se median {group['1.96 se %'].median():.2f} %")
if os.environ.get("OUT"):
    table.to_csv(os.path.join(os.environ["OUT"], "fast_sampled_intervals.csv"))
