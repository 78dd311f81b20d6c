# ---
# jupyter:
#   jupytext:
#     text_representation:
#       format_name: percent
# ---

# %% [markdown]
# # Sensor faults on systems cvxid has never seen
#
# Delayed oscillators drawn at random (`cvxid.tools.heldout.draw`: mass, stiffness,
# damping, cubic stiffness, a delayed feedback, multisine or chirp forcing, records that
# start mid-motion, noise 0.01 on x and f).  Each training record is spoiled one way — a
# clipped sensor (the top and bottom 10 % held), a frozen stretch (5 % of the record holds
# one value), one outlier of 50 standard deviations — and identified with the true terms
# listed, an exact delay of known gain, `estimator = "lstsq"`: with the documented default
# `faults = "warn"` and with `faults = "gap"`.  The table gives, per fault, how often the
# warning came, and the median free-run test fit (the clean record's beside it); the clean
# records count the false alarms.
#
# `python examples/sensor_faults.py` (report seeds 1000-1009; `SEEDS=0:10` for tuning seeds).

# %%
import os
import tempfile
import warnings
from pathlib import Path

import numpy as np
import pandas as pd

import cvxid
from cvxid.progress import set_quiet
from cvxid.tools.heldout import draw

set_quiet(True)
first, stop = (int(v) for v in os.environ.get("SEEDS", "1000:1010").split(":"))
FAULTS = ("clean", "clipped", "frozen", "outlier")


def spoiled(kind: str, x: np.ndarray) -> np.ndarray:
    y = x.copy()
    if kind == "clipped":
        return np.clip(x, *np.quantile(x, [0.1, 0.9]))
    if kind == "frozen":
        a = y.size // 3
        y[a:a + y.size // 20] = y[a]
    if kind == "outlier":
        y[y.size // 2] += 50 * np.std(x)
    return y


def spec_text(oscillator, faults: str) -> str:
    terms = ", ".join(f'"{t}"' for t in oscillator.terms)
    return f"""name = "seed{oscillator.seed}"
[data.train]
file = "train.csv"
faults = "{faults}"
[data.test]
file = "test.csv"
[model.library]
terms = [{terms}]
[model.delay]
signal = "x"
gain = {oscillator.gain!r}
method = "exact"
tau_max = 0.4
[fit]
estimator = "lstsq"
"""


def write(path: Path, record: cvxid.Experiment, x: np.ndarray) -> None:
    np.savetxt(path, np.column_stack([record.time, x, record.input("f")]), delimiter=",", header="t,x,f",
               comments="")


rows = []
with tempfile.TemporaryDirectory() as tmp:
    folder = Path(tmp)
    for seed in range(first, stop):
        oscillator = draw(seed, "none", noise=0.01, duration=8.0)
        train, test = oscillator.experiment("train"), oscillator.experiment("test")
        write(folder / "test.csv", test, test.output("x"))
        for kind in FAULTS:
            write(folder / "train.csv", train, spoiled(kind, train.output("x")))
            for faults in ("warn", "gap"):
                (folder / "spec.toml").write_text(spec_text(oscillator, faults))
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    result = cvxid.run(folder / "spec.toml")
                said = [w for w in result.warnings if "experiment 'train': output 'x'" in w]
                rows.append({"seed": seed, "fault": kind, "faults": faults, "warned": bool(said),
                             "fit %": result.test_fit.fit_percent})

frame = pd.DataFrame(rows)
table = frame.pivot_table(index="fault", columns="faults", values=["warned", "fit %"],
                          aggfunc={"warned": "mean", "fit %": "median"}).reindex(list(FAULTS))
print(f"sensor faults on seeds {first}-{stop - 1}: share warned, median free-run test fit %")
print(table.to_string(float_format=lambda v: f"{v:.3g}"))
if os.environ.get("OUT"):  # the rows as CSV too, for scripts and the test suite
    frame.to_csv(os.path.join(os.environ["OUT"], "sensor_faults.csv"), index=False)
