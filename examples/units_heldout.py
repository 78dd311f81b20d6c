# ---
# jupyter:
#   jupytext:
#     text_representation:
#       format_name: percent
# ---

# %% [markdown]
# # Other units on systems cvxid has never seen
#
# `cvxid bench --heldout`'s random delayed oscillators (other masses, stiffnesses, gains,
# delays of 0.05-0.3 s, multisine or chirp forcing, 8 s records starting in mid-motion,
# noise 0.01 on x and f, the gain given; `cvxid.tools.heldout`), each written as the
# benchmark writes it and again with its positions and forces in micrometres, and with its
# positions and forces a billion times larger (nanometres of a metre's motion, an encoder's
# counts), and with its time axis 100 times shorter or longer (the delay's range, the spec's default 0.5 s, scaled
# with it).  A method free of absolute constants returns, in the reference's units, the
# same estimates for every scale: the table gives the largest relative difference of any
# parameter from the reference run, and whether each run's delay interval covers the truth.
#
# `python examples/units_heldout.py` (report seeds 1000-1009, no effect and a Coulomb
# friction: about 5 minutes; `SEEDS=0:10` for tuning seeds).

# %%
import os
import re
import tempfile
import warnings
from pathlib import Path

import numpy as np
import pandas as pd

import cvxid
from cvxid.tools.heldout import draw, write

SCALES = {"reference": (1.0, 1.0), "micrometres": (1.0, 1e-6), "nanometres": (1.0, 1e9),
          "100 times faster": (0.01, 1.0), "100 times slower": (100.0, 1.0)}  # name: (time scale, amplitude)
POWERS = {"m": (2, 0), "x'": (1, 0), "x": (0, 0), "tau": (1, 0), "sign(x')": (0, 1)}
"""Each parameter's powers of the time scale and of the amplitude in the scaled record."""


def scaled(folder: Path, spec: Path, time_scale: float, amplitude: float) -> Path:
    """The benchmark's files with the time axis times ``time_scale`` and the signals times
    ``amplitude``, the delay searched over 0.5 s of the reference's time."""
    folder.mkdir()
    for name in ("train.csv", "test.csv"):
        frame = pd.read_csv(spec.parent / name)
        frame["t"] *= time_scale
        frame[["x", "f"]] *= amplitude
        frame.to_csv(folder / name, index=False)
    text = re.sub(r"(?s)\[truth\].*?(?=\n\[data)", "", spec.read_text())
    text = text.replace('method = "exact"', f'method = "exact"\ntau_max = {0.5 * time_scale:g}')
    (folder / "spec.toml").write_text(text)
    return folder / "spec.toml"


def one(seed: int, effect: str, folder: Path) -> list[dict]:
    oscillator = draw(seed, effect, 0.01, 8.0)
    spec = write(oscillator, folder / f"{seed}_{effect}", "structure", True)
    rows, reference = [], None
    for name, (time_scale, amplitude) in SCALES.items():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            result = cvxid.run(scaled(folder / f"{seed}_{effect}_{name.replace(' ', '_')}", spec, time_scale,
                                      amplitude)).to_dict()
        values = {p: result["physical"][p] / time_scale**t / amplitude**a
                  for p, (t, a) in POWERS.items() if p in result["physical"]}
        reference = reference or values
        low, high = np.array(result["tau"]["interval"]) / time_scale
        rows.append({"seed": seed, "effect": effect, "scale": name,
                     "tau error %": 100 * (values["tau"] - oscillator.tau) / oscillator.tau,
                     "largest difference from the reference %": max(
                         100 * abs(values[p] - reference[p]) / max(abs(reference[p]), 1e-12) for p in values),
                     "tau interval covers": bool(low <= oscillator.tau <= high)})
    return rows


if __name__ == "__main__":
    first, last = map(int, os.environ.get("SEEDS", "1000:1010").split(":"))
    with tempfile.TemporaryDirectory() as scratch:
        rows = [r for seed in range(first, last) for effect in ("none", "coulomb") for r in one(seed, effect,
                                                                                              Path(scratch))]
    frame = pd.DataFrame(rows)
    table = frame.groupby(["effect", "scale"], sort=False).agg(
        systems=("seed", "size"),
        **{"|tau error| % median": ("tau error %", lambda v: float(np.median(np.abs(v)))),
           "largest difference % (median)": ("largest difference from the reference %", "median"),
           "largest difference % (max)": ("largest difference from the reference %", "max"),
           "tau covers %": ("tau interval covers", lambda v: 100 * float(np.mean(v)))})
    with pd.option_context("display.width", 250, "display.max_columns", 10):
        print(table.round(3))
