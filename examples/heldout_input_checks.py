# ---
# jupyter:
#   jupytext:
#     text_representation:
#       format_name: percent
# ---

# %% [markdown]
# # Two input checks of the fourth outside check, on systems cvxid has never seen
#
# The outside check found them on one record each: an output clipped to a third of its
# peak read a noise ceiling of 100 %, and a force sensor mounted the other way round gave
# a mass at its bound with no hint.  Here the held-out benchmark's delayed oscillators
# (`cvxid.tools.heldout.draw`: noise 0.01 on x and f, 8 s starting mid-motion; report
# seeds 1000-1019) measure both:
#
# 1. the noise level `cvxid.metrics.noise_level` reads off the training output clipped
#    at its 15 % / 85 % and 30 % / 70 % quantiles, against the same record unclipped (the
#    true noise is 0.01);
# 2. the warnings of `cvxid run` (the spec `cvxid bench --heldout` writes, the gain
#    estimated as `cvxid init` writes it) on each record as measured and with its input's
#    sign reversed: how often "at its lower bound" (the input's sign) and the negative
#    damping warning fire on each.
#
# `python examples/heldout_input_checks.py` (`SEEDS=0:20` for tuning seeds).

# %%
import os
import tempfile
import warnings

import numpy as np
import pandas as pd
from joblib import Parallel, delayed

from cvxid.app.run import run
from cvxid.metrics import noise_ceiling_percent, noise_level
from cvxid.tools.heldout import draw, write

first, last = map(int, os.environ.get("SEEDS", "1000:1020").split(":"))
seeds = range(first, last)

rows = []
for seed in seeds:
    x = draw(seed, "none", 0.01, 8.0).experiment("train").output("x")
    for share in (0.0, 0.15, 0.3):
        y = np.clip(x, *np.quantile(x, [share, 1 - share])) if share else x
        rows.append({"clipped at the quantiles": f"{share:g} / {1 - share:g}" if share else "none (baseline)",
                     "noise read / true": noise_level(y) / 0.01, "ceiling %": noise_ceiling_percent(y)})
noise = pd.DataFrame(rows).groupby("clipped at the quantiles", sort=False).agg(
    median=("noise read / true", "median"), least=("noise read / true", "min"),
    most=("noise read / true", "max"), ceiling_max=("ceiling %", "max"))
print(f"1. noise level read off the clipped training output, {len(seeds)} systems (true noise 0.01)")
print(noise.to_string(float_format=lambda v: f"{v:.3g}"))


def one(seed: int, effect: str, reversed_input: bool) -> dict:
    oscillator = draw(seed, effect, 0.01, 8.0)
    def reversed_(which, rows):
        if reversed_input:
            rows[:, 2] *= -1

    with tempfile.TemporaryDirectory() as folder, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        said = run(write(oscillator, folder, change=reversed_)).warnings
    return {"seed": seed, "effect": effect, "input": "reversed" if reversed_input else "as measured",
            "inertia at its bound": any("at its lower bound" in w for w in said),
            "negative damping": any("feeds energy in" in w for w in said)}


jobs = [(seed, effect, flip) for seed in seeds for effect in ("none", "coulomb") for flip in (False, True)]
frame = pd.DataFrame(Parallel(n_jobs=2)(delayed(one)(*job) for job in jobs))
by = frame.groupby(["input", "effect"])
print(f"\n2. warnings of cvxid run, {len(seeds)} systems per row (counts)")
print(pd.DataFrame({"systems": by.size(), "inertia at its bound": by["inertia at its bound"].sum(),
                    "negative damping": by["negative damping"].sum()}).to_string())
