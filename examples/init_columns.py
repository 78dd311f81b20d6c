# ---
# jupyter:
#   jupytext:
#     text_representation:
#       format_name: percent
# ---

# %% [markdown]
# # Which column is the output? `cvxid init`'s guess on random oscillators
#
# Given two signal columns with names that say nothing, `cvxid init` takes for the output
# the one whose spectrum above its noise floor sits lower (a mechanical system filters its
# input: `cvxid.app.starting_spec.spectral_centroid`).  This draws the held-out
# benchmark's oscillators (`SEEDS`, default `0:40`, tuning seeds; 20 s records), adds
# noise to the position and to the force in five ways, and counts how often that rule, and
# the noise level's ratio to the spread it replaced, name the position (`init picks` is the rule `cvxid init` runs).  `OUT` also writes
# the table as CSV.

# %%
import os

import numpy as np
import pandas as pd

from cvxid.app.starting_spec import detect_columns
from cvxid.metrics import noise_level
from cvxid.tools.heldout import draw

first, last = map(int, os.environ.get("SEEDS", "0:40").split(":"))
NOISES = {"x 0.01, f clean": (0.01, 0.0), "both 0.01": (0.01, 0.01), "both 0.001": (0.001, 0.001),
          "x 0.001, f clean": (0.001, 0.0), "x 0.01, f 0.001": (0.01, 0.001)}

# %%
rows = []
for seed in range(first, last):
    t, x, _, f = draw(seed, noise=0.0, duration=20.0).simulate("train")
    rng = np.random.default_rng(seed)
    for case, (on_x, on_f) in NOISES.items():
        position = x + on_x * rng.standard_normal(x.size)
        force = f + on_f * rng.standard_normal(f.size)
        rough = {n: noise_level(v) / np.std(v) for n, v in (("position", position), ("force", force))}
        rows.append({"seed": seed, "noise": case,
                     "init picks the position": detect_columns({"t": t, "a": force, "b": position}).output == "b",
                     "smoother by noise level": rough["position"] < rough["force"]})
table = pd.DataFrame(rows)
summary = 100 * table.groupby("noise", sort=False)[["init picks the position", "smoother by noise level"]].mean()
print(f"seeds {first}:{last}, % of oscillators whose position is taken for the output")
print(summary.to_string(float_format=lambda v: f"{v:.0f}"))
if os.environ.get("OUT"):
    table.to_csv(os.path.join(os.environ["OUT"], "init_columns.csv"), index=False)
