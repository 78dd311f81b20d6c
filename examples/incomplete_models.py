# ---
# jupyter:
#   jupytext:
#     text_representation:
#       format_name: percent
# ---

# %% [markdown]
# # Does a run say when its model misses part of the dynamics?
#
# A system whose missing effect is outside the diagnosis's catalogue comes back as a model
# of the catalogue's terms: the run cannot name the effect, and it must not present the
# model as complete either.  Delayed oscillators drawn at random
# (`cvxid.tools.heldout.draw`, 8 s records starting mid-motion, noise 0.01 and 0.001 on x
# and f), identified from the base terms `x, x', x^3` with the diagnosis and the
# output-error polish (`cvxid bench --heldout --mode diagnosis`'s specs, the documented
# defaults), with one hidden effect: none (a control), two of the catalogue (Coulomb
# friction, a quadratic stiffness: the diagnosis adds them, and the final model is
# complete) and two outside it (a stiffness `x|x|` and a smooth friction `tanh(x'/v)`,
# `cvxid.tools.heldout.OUTSIDE`).  The table gives per hidden effect and noise: the systems,
# those whose run said the final model misses part of the dynamics (the gap or drift
# warning), and how far the final model's free runs miss the training and test records, in
# multiples of what each record's noise allows (`(100 - fit) / (100 - ceiling)` from
# `result.json`'s `train_fit_percent`, `test_fit_percent` and their noise ceilings).
#
# `python examples/incomplete_models.py` (report seeds 1000-1009; `SEEDS=0:10` tuning
# seeds; rows in `OUT/incomplete_models.csv`).  `BASELINE=/path/to/an/older/cvxid` runs the
# same files (data and spec, kept in a temporary folder) with that copy of the package too
# (its folder holding `cvxid/`), in the same run.

# %%
import os
import sys
import tempfile
from pathlib import Path

import pandas as pd

EFFECTS = ("none", "coulomb", "quadratic_stiffness", "abs_stiffness", "smooth_friction")
NOISES = (0.01, 0.001)
WORDS = ("part of the dynamics is not in the model", "the model lacks part of the dynamics")  # gap, drift


def gap(result: dict, record: str) -> float:
    """How far the final model's free run misses ``record`` ("train" or "test") in
    multiples of what its noise allows (NaN where ``result.json`` lacks the figures)."""
    fit, ceiling = result.get(f"{record}_fit_percent"), result.get(f"{record}_fit_percent_noise_ceiling")
    return float("nan") if fit is None or ceiling is None else (100.0 - fit) / max(100.0 - ceiling, 1e-12)


def row(folder: Path, result: dict) -> dict:
    """One system's row: its identity from the folder's name (``seed_effect_noise_durations``)."""
    seed, *effect, noise, _ = folder.name.split("_")
    return {"seed": int(seed), "effect": "_".join(effect), "noise": float(noise),
            "said": any(w in message for message in result["warnings"] for w in WORDS),
            "train gap": gap(result, "train"), "test gap": gap(result, "test"), "seconds": result["seconds"]}


def rerun(folder: Path) -> dict:
    """A kept system identified again by the cvxid on the path (a baseline's)."""
    import warnings

    from cvxid.app.run import run

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return row(folder, run(folder / "spec.toml").to_dict())


def table(frame: pd.DataFrame) -> pd.DataFrame:
    groups = frame.groupby(["effect", "noise", "version"], sort=False)
    return pd.DataFrame({"systems": groups.size(), "said": groups["said"].sum(),
                         "train gap median": groups["train gap"].median(), "train gap max": groups["train gap"].max(),
                         "test gap median": groups["test gap"].median(), "test gap max": groups["test gap"].max(),
                         "seconds (median)": groups["seconds"].median()}).unstack("version")


# %%
if os.environ.get("ROWS_ONLY"):  # (a baseline's own process: the kept systems' rows, nothing else)
    from joblib import Parallel, delayed

    rows = Parallel(n_jobs=2)(delayed(rerun)(f) for f in sorted(Path(os.environ["SYSTEMS"]).iterdir()))
    pd.DataFrame(rows).to_csv(os.path.join(os.environ.get("OUT", "."), f"{os.environ['ROWS_ONLY']}.csv"), index=False)
    sys.exit(0)
import json  # noqa: E402

from cvxid.tools.heldout import example_runs, run_one, with_baseline  # noqa: E402

with tempfile.TemporaryDirectory() as systems:
    os.environ["SYSTEMS"] = systems

    def one(seed: int, effect: str, noise: float) -> dict:
        run_one(seed, effect, noise, 8.0, "diagnosis", keep=systems)
        folder = next(Path(systems).glob(f"{seed}_{effect}_{noise:g}_*"))
        return row(folder, json.loads((folder / "result.json").read_text()))

    frame = with_baseline(example_runs(one, [(e, n) for e in EFFECTS for n in NOISES], "incomplete_models"),
                          __file__, "incomplete_models")
pd.set_option("display.width", 250)
print(table(frame).to_string(float_format=lambda v: f"{v:.3g}"))
