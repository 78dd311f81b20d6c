# ---
# jupyter:
#   jupytext:
#     text_representation:
#       format_name: percent
# ---

# %% [markdown]
# # Values the spec gives, checked against the record, on systems cvxid has never seen
#
# A spec may give a value instead of estimating it: the mass (`inertia = false`, `mass =
# …`), the feedback gain (`[model.delay] gain`), a tie between two coefficients
# (`[[model.tie]]`).  The fit takes it as exact; a wrong one moves everything else.  Delayed
# oscillators drawn at random (`cvxid.tools.heldout.draw`, no hidden effect, noise 0.01 on
# x and f, 8 s records starting mid-motion), identified with the true terms listed and the
# output-error polish, with: the mass given right, 10 % high or 10 % low (the gain given
# right too); the gain given right or 20 % high (the mass estimated); a tie of the damping
# to the stiffness (`x' = factor x`) given right or 1.5 times too large.  The table gives per
# case: the runs with any warning; those whose given-value warning (`polish.given` in
# `result.json`) named the wrong value, and those where it named a right one (alone, a
# false alarm; beside a wrong one, an alternative the record cannot rule out: freeing the
# right gain can fit as well as freeing a wrong mass, the gain trading with the stiffness);
# those where the wrong value fitted best of the values named; those where its freed
# estimate's 95 % interval holds the truth; and the delay's median error and coverage with
# the values as given.
#
# `python examples/given_values.py` (report seeds 1000-1009; `SEEDS=0:10` tuning seeds;
# rows in `OUT/given_values.csv`).  `BASELINE=/path/to/an/older/cvxid` runs the same
# systems with that copy of the package too (its folder holding `cvxid/`), in the same run.
# `CONTROLS=1` adds the false alarms on `cvxid bench --heldout`'s systems, every hidden
# effect of its catalogue, the gain given right: with the true terms listed (structure) and
# from the base terms with the diagnosis (rows in `OUT/given_values_controls.csv`).

# %%
import os
import sys
import tempfile
import tomllib
import warnings

import pandas as pd

from cvxid.app.run import run
from cvxid.spec.load import parse_problem
from cvxid.tools.heldout import EFFECTS, draw, example_runs, identify_drawn, write

CASES = {  # name: (the value given, its factor on the truth)
    "mass right": ("mass", 1.0), "mass +10 %": ("mass", 1.1), "mass -10 %": ("mass", 0.9),
    "gain right": ("gain", 1.0), "gain +20 %": ("gain", 1.2),
    "tie right": ("tie", 1.0), "tie x1.5": ("tie", 1.5),
}


def given_spec(raw: dict, oscillator, value: str, factor: float) -> dict:
    """The held-out spec ``raw`` with ``value`` given, ``factor`` times the truth."""
    model, truth = raw["model"], dict(oscillator.coefficients)
    if value == "mass":
        model.update(inertia=False, mass=factor * oscillator.mass)
        model["constraints"]["nonnegative"] = []
        model["delay"]["gain"] = oscillator.gain
    elif value == "gain":
        model["delay"]["gain"] = factor * oscillator.gain
    else:
        model["tie"] = [{"left": "x'", "right": "x", "factor": factor * truth["x'"] / truth["x"]}]
    return raw


def one(seed: int, case: str) -> dict:
    value, factor = CASES[case]
    oscillator = draw(seed, "none", 0.01, 8.0)
    with warnings.catch_warnings(), tempfile.TemporaryDirectory() as scratch:
        warnings.simplefilter("ignore")
        path = write(oscillator, scratch)
        raw = given_spec(tomllib.loads(path.read_text()), oscillator, value, factor)
        out = run(parse_problem(raw, path.parent))
    result = out.to_dict()
    checks = getattr(out, "given", ())  # (an older cvxid has none)
    said = [c for c in checks if c.disagrees]
    name = {"mass": "m", "gain": "gain", "tie": "x'"}[value] if factor != 1 else None  # the wrong value's
    wrong = next((c for c in checks if c.name == name), None)
    truth = {"mass": oscillator.mass, "gain": oscillator.gain,
             "tie": dict(oscillator.coefficients)["x'"] / dict(oscillator.coefficients)["x"]}[value]
    low, high = result["tau"]["interval"]
    return {"seed": seed, "case": case, "any warning": bool(result["warnings"]),
            "wrong value said": wrong is not None and wrong.disagrees,
            "right value said": any(c.name != name for c in said),
            "wrong fits best": bool(said) and min(said, key=lambda c: c.rms).name == name,
            "freed covers": wrong is not None and wrong.disagrees and wrong.interval is not None
            and wrong.interval[0] <= truth <= wrong.interval[1],
            "tau error %": 100 * (result["tau"]["estimate"] / oscillator.tau - 1),
            "tau covers": bool(low <= oscillator.tau <= high), "seconds": out.seconds}


def control(seed: int, effect: str, mode: str) -> dict:
    """A held-out system with ``effect`` hidden, the gain given right, in ``mode``: its
    given-value checks (a warning is a false alarm)."""
    out = identify_drawn(draw(seed, effect, 0.01, 8.0), mode=mode, known_gain=True)
    checks = out.given
    return {"seed": seed, "effect": effect, "mode": mode, "checked": sum(not c.reason for c in checks),
            "significant": sum(c.p < 0.01 for c in checks), "refitted": sum(c.rms is not None for c in checks),
            "said": any(c.disagrees for c in checks)}


def table(frame: pd.DataFrame) -> pd.DataFrame:
    groups = frame.groupby(["version", "case"], sort=False)
    return pd.DataFrame({"systems": groups.size(), "any warning": groups["any warning"].sum(),
                         "wrong value said": groups["wrong value said"].sum(),
                         "right value said": groups["right value said"].sum(),
                         "wrong fits best": groups["wrong fits best"].sum(),
                         "its interval holds the truth": groups["freed covers"].sum(),
                         "median |tau error| %": groups["tau error %"].apply(lambda e: e.abs().median()),
                         "tau covers": groups["tau covers"].sum(), "seconds (median)": groups["seconds"].median()})


# %%
if os.environ.get("ROWS_ONLY"):  # (a baseline's own process: its rows, nothing else)
    example_runs(one, [(c,) for c in CASES], os.environ["ROWS_ONLY"])
    sys.exit(0)
from cvxid.tools.heldout import with_baseline  # noqa: E402  (after the baseline's exit: an older cvxid lacks it)

frame = with_baseline(example_runs(one, [(c,) for c in CASES], "given_values"), __file__, "given_values")
pd.set_option("display.width", 200)
print(table(frame).to_string(float_format=lambda v: f"{v:.3g}"))
if os.environ.get("CONTROLS"):
    controls = example_runs(control, [(e, m) for e in EFFECTS for m in ("structure", "diagnosis")],
                            "given_values_controls")
    groups = controls.groupby(["mode", "effect"])
    print(groups[["checked", "significant", "refitted", "said"]].sum().assign(systems=groups.size()).to_string())
