# ---
# jupyter:
#   jupytext:
#     text_representation:
#       format_name: percent
# ---

# %% [markdown]
# # The integrator's dry friction, on systems cvxid has never seen
#
# Delayed oscillators drawn at random (`cvxid.tools.heldout.draw`: mass, stiffness, damping,
# a delayed feedback, forcing, and a hidden Coulomb or Stribeck friction), their training
# record of 8 s at 1 kHz simulated from its pre-roll (it starts mid-motion) at the sample
# step and at 1/64 of it.  The table gives, per friction, the largest difference over the
# record in units of the benchmark's noise (0.01): what a fit at the sample step would read
# as signal.  Run it with the code before 404a51a (a clip at every RK4 stage) for the
# baseline: on report seeds 1000-1019 its median was 0.12 (Coulomb) and 0.10 (Stribeck),
# its largest 8.6 and 12.8 noise units; the integrator that splits a step where sliding
# stops gives 3e-7 and 1e-5, at most 4.4e-5 and 7.9e-4.
#
# `python examples/friction_integrator.py` (report seeds 1000-1019; `SEEDS=0:20` for tuning seeds;
# the rows in `OUT/friction_integrator.csv`).

# %%
import os

import numpy as np

from cvxid.simulate import simulate
from cvxid.tools.heldout import DT, draw, example_runs

os.environ.setdefault("SEEDS", "1000:1020")
DURATION, NOISE, FINE = 8.0, 0.01, 64


def error_in_noise_units(seed: int, effect: str) -> dict:
    """The largest |x at the sample step - x at 1/FINE of it| over the record, / NOISE."""
    oscillator = draw(seed, effect, NOISE, DURATION)
    skip = round(oscillator.train.pre / DT)
    t = (np.arange(skip + round(DURATION / DT) + 1) - skip) * DT
    coarse, _ = simulate(oscillator.system, t, oscillator.train, 0.0, 0.0)
    fine, _ = simulate(oscillator.system, t, oscillator.train, 0.0, 0.0, substeps=FINE)
    return {"effect": effect, "seed": seed, "error / noise": float(np.max(np.abs(coarse - fine)[skip:]) / NOISE)}


rows = example_runs(error_in_noise_units, [("coulomb",), ("stribeck",)], "friction_integrator")
table = rows.groupby("effect")["error / noise"].agg(systems="count", median="median", largest="max")
print(table.to_string(float_format=lambda v: f"{v:.2g}"))
