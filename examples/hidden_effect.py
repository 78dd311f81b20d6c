# ---
# jupyter:
#   jupytext:
#     text_representation:
#       format_name: percent
# ---

# %% [markdown]
# # A hidden effect: compare, see where it fails, name it, add it, watch the error fall
#
# The data come from a delayed oscillator with **Coulomb friction**,
# `x'' + 0.4 x' + 6 x + 0.8 sign(x') = f + 1.5 x(t - 0.15)`, but our model starts linear
# (`problems/hidden_friction.toml`).  Figures go to `OUT` (default `out/hidden_effect`).

# %%
import os
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

import cvxid  # noqa: E402
from cvxid.diagnosis.refine import refit  # noqa: E402

HERE = Path(__file__).resolve().parent
OUT = Path(os.environ.get("OUT", "out/hidden_effect"))
OUT.mkdir(parents=True, exist_ok=True)
spec = cvxid.load_problem(HERE.parent / "problems" / "hidden_friction.toml")
train, test = spec.experiment("train"), spec.experiment("test")

# %% [markdown]
# ## 1. The linear model, compared with the test data

# %%
linear = refit(spec.model, train, spec.model.column_names, None)
print(linear.equation())
cmp = cvxid.compare(linear, test)
print(cmp)
cmp.plot().savefig(OUT / "1_linear_fit.png", dpi=100)

# %% [markdown]
# ## 2. Where it fails: the residual against the velocity steps at x' = 0

# %%
res = cvxid.residuals(linear, train)
bins = res.binned("velocity", bins=12)
print(bins)
fig, ax = plt.subplots(figsize=(6, 4))
ax.errorbar(bins["center"], bins["mean"], yerr=bins["std"], fmt="ko-")
ax.axvline(0, color="gray", lw=0.8)
ax.set_xlabel("velocity x'")
ax.set_ylabel("equation error (force units)")
ax.set_title("a step at x' = 0: dry friction")
fig.tight_layout()
fig.savefig(OUT / "2_residual_vs_velocity.png", dpi=100)

# %% [markdown]
# ## 3. Which physical effect is missing?

# %%
diagnosis = cvxid.diagnose(linear, train, test)
print(diagnosis)

# %% [markdown]
# ## 4. Add it, refit, and watch the error fall (the loop stops by itself)

# %%
loop = cvxid.refine(linear, train, test)
print(loop)
print(loop.model.equation())
loop.plot().savefig(OUT / "3_error_falls.png", dpi=100)
cvxid.compare(loop.model, test).plot().savefig(OUT / "4_final_fit.png", dpi=100)

# %% [markdown]
# ## 5. The story in one picture (the README's figure: `docs/hidden_friction.png`)

# %%
final = cvxid.compare(loop.model, test)
fig, axes = plt.subplots(2, 1, figsize=(8, 4.6), sharex=True)
for ax, (label, c) in zip(axes, [("the model as written (no friction)", cmp),
                                 (f"with the effect cvxid named and added ({loop.steps[0].added})", final)]):
    ax.plot(c.time, c.measured, "k", lw=0.8, label="measured (test record)")
    ax.plot(c.time, c.free_run, "r", lw=1.0, label="free-run simulation")
    ax.set_title(f"{label}: fit {c.fit_percent:.1f} %", fontsize=10)
    ax.set_ylabel("x")
axes[0].legend(fontsize=8, loc="lower left", ncol=2)
axes[-1].set_xlabel("time [s]")
fig.tight_layout()
fig.savefig(OUT / "story.png", dpi=90)
