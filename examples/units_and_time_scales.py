# ---
# jupyter:
#   jupytext:
#     text_representation:
#       format_name: percent
# ---

# %% [markdown]
# # The same system in other units, time scales and sample rates
#
# One delayed oscillator, `2 x'' + 0.8 x' + 10 x = f + 3 x(t - 0.12)` (12 s starting in
# mid-motion, a three-sine force, noise 1 % of each signal's spread, one noise draw), written
# as a CSV in other units: positions and forces in micrometres, the plant 100 times slower
# or faster (its time axis stretched), and the reference sampled at 50 Hz or 20 kHz.  Each
# goes through `cvxid init` (the documented starting spec, the feedback gain given, the
# delay searched over the reference's range, 0.5 s, in the record's own time) and
# `cvxid run`.  A method free of absolute constants gives every row the reference row's
# relative errors (the reference row is the baseline, in the same run).  Two more rows keep
# the range `cvxid init` writes, whose floor of 0.5 time units is the one absolute constant
# left (docs/limitations.md).
#
# `python examples/units_and_time_scales.py` (about 3 minutes; `OUT=folder` keeps the files).

# %%
import os
import re
import subprocess
import tempfile
import warnings
from pathlib import Path

import numpy as np
import pandas as pd

import cvxid
from cvxid.model.terms import parse_term
from cvxid.simulate import System, simulate

TRUTH = {"m": 2.0, "x'": 0.8, "x": 10.0, "gain": 3.0, "tau": 0.12}
CASES = {  # name: (time scale, amplitude, sample step in the reference's time)
    "reference (1 kHz, m)": (1.0, 1.0, 1e-3),
    "micrometres": (1.0, 1e-6, 1e-3),
    "100 times slower": (100.0, 1.0, 1e-3),
    "100 times faster": (0.01, 1.0, 1e-3),
    "sampled at 50 Hz": (1.0, 1.0, 0.02),
    "sampled at 20 kHz": (1.0, 1.0, 5e-5),
}
RANGE = 0.5
"""The delay range of every row's spec, in the reference's seconds (``cvxid init``'s own
range for an ordinary plant; the rows with init's own range show what its rule does)."""
UNITS = {"m": 2, "x'": 1, "x": 0, "gain": 0, "tau": 1}  # powers of the time scale that divide each parameter


def record(time_scale: float, amplitude: float, dt: float) -> pd.DataFrame:
    force = lambda s: 4 * np.sin(1.7 * s) + 3 * np.sin(4.3 * s + 1) + 2 * np.sin(9.1 * s + 2)  # noqa: E731
    system = System((parse_term("x'"), parse_term("x")), np.array([TRUTH["x'"], TRUTH["x"]]), TRUTH["m"], "x",
                    TRUTH["gain"], TRUTH["tau"], 0, "zero")
    t = np.arange(int(round(20.0 / dt)) + 1) * dt
    x, _ = simulate(system, t, force, 0.3, 0.0, substeps=max(1, int(round(dt / 1e-4))))
    keep = t >= 8.0 - 1e-12  # the last 12 s: a record that starts in mid-motion
    x, f, t = x[keep], force(t[keep]), t[keep] - t[keep][0]
    rng = np.random.default_rng(0)
    x = x + 0.01 * x.std() * rng.standard_normal(x.size)
    f = f + 0.01 * f.std() * rng.standard_normal(f.size)
    return pd.DataFrame({"t": t * time_scale, "x": amplitude * x, "f": amplitude * f})


def one(folder: Path, name: str, time_scale: float, amplitude: float, dt: float, scaled_range: bool = True) -> dict:
    here = folder / (re.sub(r"\W+", "_", name) + ("" if scaled_range else "_init_range"))
    here.mkdir()
    record(time_scale, amplitude, dt).to_csv(here / "data.csv", index=False)
    subprocess.run(["cvxid", "init", "data.csv", "-o", "spec.toml"], cwd=here, check=True, capture_output=True)
    spec = (here / "spec.toml").read_text()
    written = float(re.search(r"(?m)^tau_max = ([0-9.e+-]+)", spec).group(1))
    spec = re.sub(r"(?m)^# gain = .*$", f"gain = {TRUTH['gain']}", spec)
    if scaled_range:  # the reference's range in this record's time: the method alone, not init's rule
        spec = re.sub(r"(?m)^tau_max = [0-9.e+-]+", f"tau_max = {RANGE * time_scale:g}", spec)
    (here / "spec.toml").write_text(spec)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = cvxid.run(here / "spec.toml").to_dict()
    row = {"case": name, "tau_max": "the reference's" if scaled_range else "init's",
           "init's tau_max (reference s)": written / time_scale}
    intervals = (result.get("polish") or {}).get("intervals") or {}
    for key, power in UNITS.items():
        if key == "gain":
            continue
        value = result["physical"][key if key != "tau" else "tau"]
        row[f"{key} error %"] = 100 * (value / time_scale**power - TRUTH[key]) / TRUTH[key]
        low, high = (result["tau"]["interval"] if key == "tau" else intervals.get(key, (np.nan, np.nan)))
        row[f"{key} covers"] = bool(low <= TRUTH[key] * time_scale**power <= high)
    row["test fit %"] = result["test_fit_percent"]
    row["window (reference s)"] = (result["window"] or {}).get("seconds", np.nan) / time_scale
    row["added"] = ", ".join(s["added"] for s in result["refinement"] or []) or "–"
    return row


if __name__ == "__main__":
    keep = os.environ.get("OUT")
    with tempfile.TemporaryDirectory() as scratch:
        folder = Path(keep or scratch)
        folder.mkdir(parents=True, exist_ok=True)
        rows = [one(folder, name, *case) for name, case in CASES.items()]
        rows += [one(folder, name, *CASES[name], scaled_range=False) for name in ("100 times slower", "100 times faster")]
        table = pd.DataFrame(rows).set_index(["case", "tau_max"])
    with pd.option_context("display.width", 200, "display.max_columns", 20):
        print(table.round(3))
