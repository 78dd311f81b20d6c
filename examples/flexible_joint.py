# ---
# jupyter:
#   jupytext:
#     text_representation:
#       format_name: percent
# ---

# %% [markdown]
# # The rotary flexible joint: two coupled equations, one shared delay
#
# The paper's section 5 rig, simulated by cvxid from `problems/flexible_joint.toml`: motor
# angle theta and link deflection alpha under proportional control of theta delayed by
# 0.2 s, a sine reference for training and a square wave for testing, and a Coulomb
# friction on the motor side that the starting library lacks.
#
# `cvxid run` identifies both equations in one cvxpy problem (the motor damping and the
# inertia are tied across them, the delay is profiled on the joint objective), ranks the
# missing effects, adds Coulomb friction, and polishes everything by the simulation error
# of both angles.
#
# `SEEDS` (default 5) noise seeds are then run to measure the accuracy of tau and k_s;
# `DURATION` (s, default 60) shortens the training record.

# %%
import os
from dataclasses import replace

import pandas as pd

import cvxid
from cvxid.spec.load import load_problem

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")
seeds = int(os.environ.get("SEEDS", "5"))
duration = float(os.environ.get("DURATION", "60"))
spec = load_problem(os.path.join(ROOT, "problems", "flexible_joint.toml"))


def with_seed(spec, seed):
    train = dict(spec.data["train"], simulate=dict(spec.data["train"]["simulate"], seed=seed, duration=duration))
    return replace(spec, data=dict(spec.data, train=train))


# %% [markdown]
# ## One run, as `cvxid run problems/flexible_joint.toml` does it

# %%
result = cvxid.run(with_seed(spec, 1))
print(result.summary())

# %% [markdown]
# ## Accuracy over noise seeds (noise 0.001 rad on both angles)
#
# The equation-error estimate (the joint least squares after the diagnosis added the
# friction) and the final output-error estimate, against the truth tau = 0.2 s, k_s = 1.3.

# %%
rows = []
for seed in range(1, seeds + 1):
    run = cvxid.run(with_seed(spec, seed))
    equation_error = run.refinement.system if run.refinement else None
    row = {"seed": seed, "added": ", ".join(s.added for s in run.refinement.steps) if run.refinement else ""}
    if equation_error is not None:
        row["tau EE %"] = 100 * (equation_error.tau / 0.2 - 1)
        row["k_s EE %"] = 100 * (-equation_error.models["theta"].coefficients["alpha"] / 1.3 - 1)
    row["tau %"] = 100 * (run.physical["tau"] / 0.2 - 1)
    row["k_s %"] = 100 * (run.physical["k_s"] / 1.3 - 1)
    row["seconds"] = run.seconds
    rows.append(row)
table = pd.DataFrame(rows).set_index("seed")
print(table.to_string(float_format=lambda v: f"{v:+.3f}"))
print(f"worst |tau error| {table['tau %'].abs().max():.3f} %, worst |k_s error| {table['k_s %'].abs().max():.3f} %")
