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
# complete), two outside it (a stiffness `x|x|` and a smooth friction `tanh(x'/v)`,
# `cvxid.tools.heldout.OUTSIDE`), and none under a noise that is not white (a 50 Hz hum as
# large as the white noise, or a low-passed noise of half its size added to x: complete
# models whose residual is not white).  The table gives per case and noise: the systems,
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
import json
import os
import sys
import tempfile
import warnings
from pathlib import Path

import numpy as np
import pandas as pd

CASES = {  # case: (the hidden effect, what is added to the measured x)
    "none": ("none", None), "coulomb": ("coulomb", None), "quadratic_stiffness": ("quadratic_stiffness", None),
    "abs_stiffness": ("abs_stiffness", None), "smooth_friction": ("smooth_friction", None),
    "none, hum": ("none", "hum"), "none, low-passed noise": ("none", "lowpass"),
}
NOISES = (0.01, 0.001)
WORDS = ("part of the dynamics is not in the model", "part of the dynamics may be missing",  # the gap warnings,
         "the model lacks part of the dynamics")  # the drift's (cvxid.tools.heldout.GAP_WORDS: an older cvxid lacks it)


def coloured(kind: str, noise: float, seed: int):
    """The change to each record's rows that adds a noise that is not white to x: a 50 Hz
    hum of amplitude ``noise``, or white noise low-passed by an AR(1) filter (pole 0.8)
    scaled to half of ``noise``."""
    from scipy.signal import lfilter

    rng = np.random.default_rng([seed, 7])

    def change(which, rows):
        if kind == "hum":
            rows[:, 1] += noise * np.sin(2 * np.pi * 50 * rows[:, 0] + 0.3)
        else:
            low = lfilter([1.0], [1.0, -0.8], rng.standard_normal(len(rows)))
            rows[:, 1] += 0.5 * noise * low / low.std()
    return change


def kept(systems: str, seed: int, case: str, noise: float) -> Path:
    """The folder that keeps a system's files."""
    return Path(systems) / f"{seed}_{case}_{noise:g}".replace(", ", "_").replace(" ", "_")


def gap(result: dict, record: str) -> float:
    """How far the final model's free run misses ``record`` ("train" or "test") in
    multiples of what its noise allows (NaN where ``result.json`` lacks the figures)."""
    fit, ceiling = result.get(f"{record}_fit_percent"), result.get(f"{record}_fit_percent_noise_ceiling")
    return float("nan") if fit is None or ceiling is None else (100.0 - fit) / max(100.0 - ceiling, 1e-12)


def identified(folder: Path, seed: int, case: str, noise: float) -> dict:
    """The row of the system kept in ``folder``, identified by the cvxid on the path (a
    failure is a row with its error: one system does not end the benchmark)."""
    from cvxid.app.run import run

    row = {"seed": seed, "case": case, "noise": noise}
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            result = run(folder / "spec.toml").to_dict()
    except Exception as exc:  # noqa: BLE001
        return row | {"error": f"{type(exc).__name__}: {exc}"}
    return row | {"said": any(w in message for message in result["warnings"] for w in WORDS),
                  "train gap": gap(result, "train"), "test gap": gap(result, "test"), "seconds": result["seconds"]}


def table(frame: pd.DataFrame) -> pd.DataFrame:
    groups = frame.groupby(["case", "noise", "version"], sort=False)
    return pd.DataFrame({"systems": groups.size(), "failed": groups["error"].count(), "said": groups["said"].sum(),
                         "train gap median": groups["train gap"].median(), "train gap max": groups["train gap"].max(),
                         "test gap median": groups["test gap"].median(), "test gap max": groups["test gap"].max(),
                         "seconds (median)": groups["seconds"].median()}).unstack("version")


# %%
if os.environ.get("ROWS_ONLY"):  # (a baseline's own process: the kept systems' rows, nothing else)
    from joblib import Parallel, delayed

    keys = json.loads(Path(os.environ["SYSTEMS"], "systems.json").read_text())
    rows = Parallel(n_jobs=2)(delayed(identified)(kept(os.environ["SYSTEMS"], *key), *key) for key in keys)
    pd.DataFrame(rows).to_csv(os.path.join(os.environ.get("OUT", "."), f"{os.environ['ROWS_ONLY']}.csv"), index=False)
    sys.exit(0)
from cvxid.tools.heldout import draw, example_runs, with_baseline, write  # noqa: E402

with tempfile.TemporaryDirectory() as systems:
    os.environ["SYSTEMS"] = systems

    def one(seed: int, case: str, noise: float) -> dict:
        effect, kind = CASES[case]
        folder = kept(systems, seed, case, noise)
        try:
            write(draw(seed, effect, noise, 8.0), folder, "diagnosis",
                  change=None if kind is None else coloured(kind, noise, seed))
        except Exception as exc:  # noqa: BLE001  (a draw that fails is a row too)
            return {"seed": seed, "case": case, "noise": noise, "error": f"{type(exc).__name__}: {exc}"}
        return identified(folder, seed, case, noise)

    cases = [(c, n) for c in CASES for n in NOISES]
    frame = example_runs(one, cases, "incomplete_models")
    Path(systems, "systems.json").write_text(json.dumps([[seed, c, n] for seed in frame["seed"].unique().tolist()
                                                         for c, n in cases]))
    frame = with_baseline(frame.assign(error=frame.get("error")), __file__, "incomplete_models")
pd.set_option("display.width", 250)
print(table(frame).to_string(float_format=lambda v: f"{v:.3g}"))
