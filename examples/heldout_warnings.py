# ---
# jupyter:
#   jupytext:
#     text_representation:
#       format_name: percent
# ---

# %% [markdown]
# # The delay's warnings on systems cvxid has never seen
#
# Delayed oscillators drawn at random (`cvxid.tools.heldout.draw`: mass, stiffness,
# damping, a delayed feedback `+ b x(t - tau)`, multisine or chirp forcing, records that
# start mid-motion, noise 0.01 on x and f, 8 s) with no hidden effect, a Coulomb friction or
# a quadratic stiffness, identified as `cvxid bench --heldout` does (the true terms listed,
# the output-error polish), the feedback gain given and estimated.  The table counts, per
# case, how often each warning about the delay and its gain fired; every system has a
# feedback, so "no feedback" is a false alarm, and a delay called "not determined" should be
# one whose error is large.  The second table lists the systems warned "not determined" or
# "cancelling gain".
#
# `python examples/heldout_warnings.py` (report seeds 1000-1009; `SEEDS=0:10` for tuning seeds;
# the rows in `OUT/heldout_warnings.csv`).

# %%
import os

import pandas as pd
from joblib import Parallel, delayed

from cvxid.tools.heldout import draw, identify_drawn

SAID = {"cancelling gain": "nearly cancel", "gain trades": "is not determined apart from",
        "interval reaches 0": "interval reaches 0", "not determined": "the delay is not determined",
        "no feedback": "the data show no fed-back signal", "raise tau_max": "raise [model.delay] tau_max",
        "polish worse": "ended with a larger simulation error", "drifts": "drifts away from the test record",
        "quiet test": "barely moves above its noise"}


def one(seed: int, effect: str, known_gain: bool) -> dict:
    oscillator = draw(seed, effect, 0.01, 8.0)
    result = identify_drawn(oscillator, mode="structure", known_gain=known_gain).to_dict()
    said = " ".join(result["warnings"])
    low, high = result["tau"]["interval"]
    return {"seed": seed, "effect": effect, "gain": "given" if known_gain else "estimated",
            "tau error %": 100 * (result["tau"]["estimate"] - oscillator.tau) / oscillator.tau,
            "covers": low <= oscillator.tau <= high, **{name: text in said for name, text in SAID.items()}}


first, last = map(int, os.environ.get("SEEDS", "1000:1010").split(":"))
OUT = os.environ.get("OUT", ".")
rows = Parallel(n_jobs=2)(delayed(one)(seed, effect, known) for seed in range(first, last)
                          for effect in ("none", "coulomb", "quadratic_stiffness") for known in (True, False))
frame = pd.DataFrame(rows)
frame.to_csv(os.path.join(OUT, "heldout_warnings.csv"), index=False)
by = frame.groupby("gain")
print(by[list(SAID)].sum().assign(systems=by.size(), covers=by["covers"].sum(),
                                  **{"median |tau error| %": by["tau error %"].apply(lambda e: e.abs().median())})
      .to_string())
print(frame[frame["not determined"] | frame["cancelling gain"]][["seed", "effect", "gain", "tau error %", "covers",
                                                                 "not determined", "cancelling gain"]].to_string())
