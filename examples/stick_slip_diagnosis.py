# ---
# jupyter:
#   jupytext:
#     text_representation:
#       format_name: percent
# ---

# %% [markdown]
# # A hidden dry friction that holds the motion: the diagnosis on stick-slip records
#
# The held-out benchmark's Coulomb friction is 10-30 % of the spring's force at the motion's
# amplitude (`cvxid.tools.heldout.EFFECT_SHARE`): the mass slides most of the time.  A
# ninth outside check found that a friction of the same size as the forcing, which holds
# the mass still for a fifth to a third of the record, was refused by the diagnosis on 8 s
# records: the refit with the friction, its delay and damping from the equation error,
# simulated the test record worse than the linear start.  Here the benchmark's systems are
# drawn again with a friction of 100-150 % of that force (everything else as drawn: mass,
# stiffness, damping, delayed feedback, forcing scaled to the same motion, records from
# mid-motion), 8 s at noise 0.01 on x and f, the gain given, diagnosed from the base
# library `x, x', x^3` with the documented defaults (`cvxid bench --heldout --mode
# diagnosis` does the same at the benchmark's friction).  The table gives, per friction
# share: the share of samples at rest in the training record (median), the friction added
# (%), the final model's delay error and how many 95 % intervals cover it.
#
# `python examples/stick_slip_diagnosis.py` (report seeds 1000-1019; `SEEDS=0:20` for tuning
# seeds; the rows in `OUT/stick_slip_diagnosis.csv`).  Run it with the code before the
# diagnosis judged such a refit polished (2026-11-27) for the baseline.

# %%
import os

import numpy as np

import cvxid.tools.heldout as heldout

os.environ.setdefault("SEEDS", "1000:1020")
SHARES = {"benchmark (10-30 %)": (0.1, 0.3), "stick-slip (100-150 %)": (1.0, 1.5)}


def diagnosed(seed: int, share: str) -> dict:
    """One Coulomb system of the friction ``share``, diagnosed (``heldout.run_one``), with
    the share of its training record's samples at rest."""
    heldout.EFFECT_SHARE = SHARES[share]  # (each worker process draws with its own)
    row = heldout.run_one(seed, "coulomb", 0.01, 8.0, mode="diagnosis", known_gain=True)
    _, _, v, _ = heldout.draw(seed, "coulomb", 0.01, 8.0).simulate("train")
    return {**row, "share": share, "at rest": float(np.mean(np.abs(v) < 1e-9))}


rows = heldout.example_runs(diagnosed, [(share,) for share in SHARES], "stick_slip_diagnosis")
ok = rows[rows["status"] == "ok"].assign(
    equation=lambda f: f["added"].fillna("").str.contains("coulomb"),
    simulation=lambda f: f["added by simulation"].fillna("").str.contains("coulomb"))
groups = ok.groupby("share", sort=False)
table = groups.agg(systems=("seed", "count"), **{"at rest (median)": ("at rest", "median")})
table["friction added %"] = groups.apply(lambda f: 100 * (f["equation"] | f["simulation"]).mean())
table["of it by simulation %"] = groups.apply(lambda f: 100 * (f["simulation"] & ~f["equation"]).mean())
table["median |tau err| %"] = groups["tau error %"].apply(lambda e: e.abs().median())
table["covers"] = groups["covers"].sum()
print(table.to_string(float_format=lambda v: f"{v:.3g}"))
