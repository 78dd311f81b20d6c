# ---
# jupyter:
#   jupytext:
#     text_representation:
#       format_name: percent
# ---

# %% [markdown]
# # The rotary flexible joint: two coupled equations, one shared delay
#
# The paper's section 5 rig, simulated by cvxid (`cvxid.coupled.flexible_joint`): motor
# angle theta and link deflection alpha under proportional control of theta delayed by
# 0.2 s, a sine reference for training, Coulomb friction on the motor side.  Both equations
# are identified in one cvxpy problem: the theta' coefficient appears in both with opposite
# signs and is tied; the delay is profiled on the joint objective.
#
# `NOISE` (rad, default 0.001), `DURATION` (s, default 60) and `WINDOWS` (restart windows in
# seconds, default "1,2") set the runs.

# %%
import os

from cvxid.coupled import flexible_joint, flexible_joint_experiment, flexible_joint_specs, identify_coupled, with_terms

noise = float(os.environ.get("NOISE", "0.001"))
duration = float(os.environ.get("DURATION", "60"))
windows = [float(w) for w in os.environ.get("WINDOWS", "1,2").split(",")]

# %%
for friction in (0.0, 0.05):
    system, truth = flexible_joint(coulomb=friction)
    data = flexible_joint_experiment(system, truth, "sine", duration=duration, noise=noise, seed=1)
    specs = flexible_joint_specs(truth["gain"], tau_max=0.3)
    ties = [("alpha:theta'", "theta:theta'", -1.0)]
    if friction:
        specs = with_terms(specs, ["sign(theta')"])
        ties.append(("alpha:sign(theta')", "theta:sign(theta')", -1.0))
    for window in windows:
        result = identify_coupled(specs, data, ties=ties, window=window)
        theta = result.models["theta"].coefficients
        k_s = -theta["alpha"]
        line = (f"friction {friction:.2f}, window {window:g} s: tau {result.tau:.4f} "
                f"({100 * (result.tau / truth['tau'] - 1):+.1f} %), k_s {k_s:.3f} "
                f"({100 * (k_s / truth['k_s'] - 1):+.1f} %)")
        if friction:
            coulomb = theta["sign(theta')"]
            line += f", Coulomb {coulomb:.4f} (truth {friction})"
        print(line)
