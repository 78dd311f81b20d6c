# ---
# jupyter:
#   jupytext:
#     text_representation:
#       format_name: percent
# ---

# %% [markdown]
# # Coupled systems cvxid has never seen: the diagnosis for N = 2
#
# A single equation is the system with N = 1, and every stage runs the same code for any N;
# the held-out benchmark (`cvxid bench --heldout`) draws one equation only.  This draws
# pairs of coupled, delayed oscillators
#
#     m1 x'' + c1 x' + (k1 + kc) x - kc y = u + g1 x(t - tau)
#     m2 y'' + c2 y' + (k2 + kc) y - kc x = ±u + g2 x(t - tau)
#
# (masses 0.5-2, stiffnesses 2-10, damping ratios 0.05-0.3, coupling 0.5-3, known gains of
# 10-50 % of each stiffness, either sign, tau 0.05-0.3 s, a random three-sine input scaled
# to an x of RMS 1; 20 s to train and 10 s to test at 2 ms, noise 0.01 on both outputs),
# hides one effect in one coordinate's equation (a Coulomb friction, a quadratic damping, a
# cubic stiffness or an offset, its force 10-30 % of that coordinate's spring force), and
# runs the linear model with the documented defaults plus `[diagnose] refine = true` and
# `[fit] refine = "output_error"`.  Per effect it prints the share of systems whose
# diagnosis names the hidden effect (in its coordinate) first, adds it first, and adds
# nothing else; for the systems without one (`none`), the share with nothing added; the
# median errors of the effect's coefficient, the delay and the worst other parameter, and
# the test record's free-run fit (the worse coordinate) at the start and at the end, and
# what the noise allows that coordinate.
#
# `SEEDS` (default `100:110`), `EFFECTS` (default: all five), `N_JOBS` (default 2).
# Nothing here was tuned on these seeds: the diagnosis's rules are one equation's.

# %%
import os
import time
import tomllib

import numpy as np
import pandas as pd
from joblib import Parallel, delayed

import cvxid
from cvxid.errors import CvxidError
from cvxid.spec.load import parse_problem

first, last = map(int, os.environ.get("SEEDS", "100:110").split(":"))
effects = os.environ.get("EFFECTS", "none,coulomb,quadratic_damping,cubic_stiffness,offset").split(",")
TERMS = {"coulomb": "sign({c}')", "quadratic_damping": "{c}'|{c}'|", "cubic_stiffness": "{c}^3", "offset": "1"}


def spec_text(p: dict, amplitude: float, effect: str | None = None, size: float = 0.0) -> str:
    """The spec of the drawn system ``p`` (its hidden ``effect`` of coefficient ``size`` in
    the equation of ``p["where"]``), the model linear, the input scaled by ``amplitude``."""
    coefficients = {
        "x": {"x'": p["c"][0], "x": p["k"][0] + p["kc"], "y": -p["kc"]},
        "y": {"y'": p["c"][1], "y": p["k"][1] + p["kc"], "x": -p["kc"]},
    }
    if effect is not None:
        coefficients[p["where"]][TERMS[effect].format(c=p["where"])] = size
    inputs = {"x": "u", "y": p["input_y"]}

    def sines(seed):
        return "[" + ", ".join(f'{{ kind = "sine", amplitude = {amplitude * a}, omega = {w}, phase = {f} }}'
                               for a, w, f in zip(*p["forcing"][seed])) + "]"

    truth = "".join(
        f'[[truth.equation]]\ncoordinate = "{q}"\nmass = {p["m"][i]}\ninput = "{inputs[q]}"\n'
        f'delay_gain = {p["g"][i]}\ncoefficients = {{ {", ".join(f"{chr(34)}{t}{chr(34)} = {v}" for t, v in coefficients[q].items())} }}\n'
        for i, q in enumerate("xy"))
    model = "".join(
        f'[[model.equation]]\ncoordinate = "{q}"\ninput = "{inputs[q]}"\ndelay_gain = {p["g"][i]}\n'
        f'library = {{ terms = ["{q}\'", "{q}", "{o}"] }}\n'
        for i, (q, o) in enumerate(("xy", "yx")))
    return f"""
[truth]
history = "zero"
delay = {{ signal = "x", tau = {p["tau"]} }}
{truth}
[data.train.simulate]
duration = 20.0
dt = 2e-3
seed = {p["seed"]}
noise = {{ output = 0.01 }}
input = {sines(0)}
[data.test.simulate]
duration = 10.0
dt = 2e-3
seed = {p["seed"] + 1}
noise = {{ output = 0.01 }}
input = {sines(1)}
[model.delay]
signal = "x"
method = "exact"
tau_min = 0.0
tau_max = 0.5
{model}
[fit]
refine = "output_error"
[diagnose]
refine = true
"""


def draw(seed: int, effect: str) -> tuple[str, dict]:
    """A stable drawn system (retried until its simulation stays finite) and its spec."""
    rng = np.random.default_rng(seed)
    for attempt in range(50):
        m, k, zeta = rng.uniform(0.5, 2, 2), rng.uniform(2, 10, 2), rng.uniform(0.05, 0.3, 2)
        p = {"seed": seed, "m": m, "k": k, "c": 2 * zeta * np.sqrt(k * m), "kc": rng.uniform(0.5, 3),
             "tau": rng.uniform(0.05, 0.3), "g": rng.choice([-1, 1], 2) * rng.uniform(0.1, 0.5, 2) * k,
             "input_y": str(rng.choice(["u", "-u"])), "where": str(rng.choice(["x", "y"]))}
        omega = np.sqrt(k / m).mean()
        p["forcing"] = [(rng.uniform(0.5, 1.5, 3), rng.uniform(0.3, 2.5, 3) * omega, rng.uniform(0, 2 * np.pi, 3))
                        for _ in range(2)]
        try:
            train = parse_problem(tomllib.loads(spec_text(p, 1.0)), ".").experiment("train")
        except CvxidError:
            continue  # an unstable loop: draw again
        amplitude = 1.0 / np.std(train.output("x"))
        if effect == "none":
            return spec_text(p, amplitude), p
        scaled = parse_problem(tomllib.loads(spec_text(p, amplitude)), ".").experiment("train")
        q = p["where"]
        x, v = scaled.output(q), scaled.velocities[q]
        spring = np.std((p["k"]["xy".index(q)] + p["kc"]) * x)
        signal = {"coulomb": np.ones_like(v), "quadratic_damping": v * np.abs(v), "cubic_stiffness": x**3,
                  "offset": np.ones_like(x)}[effect]
        size = rng.uniform(0.1, 0.3) * spring / np.sqrt(np.mean(signal**2))
        text = spec_text(p, amplitude, effect, size)
        try:
            parse_problem(tomllib.loads(text), ".").experiment("train")
        except CvxidError:
            continue
        p["size"] = size
        return text, p
    raise RuntimeError(f"seed {seed}: no stable system in 50 draws")


def one(seed: int, effect: str) -> dict:
    text, p = draw(seed, effect)
    start = time.perf_counter()
    try:
        result = cvxid.run(parse_problem(tomllib.loads(text), "."))
    except CvxidError as exc:
        return {"effect": effect, "seed": seed, "error": str(exc)[:80]}
    data = result.to_dict()
    label = "offset" if effect == "offset" else f"{effect}({p['where']})"
    added = [s["added"] for s in data["refinement"] or []]
    added += [s["added"] for s in (data["simulation_diagnosis"] or {}).get("steps", []) if s["kept"]]
    truth, physical = data["truth"], data["physical"]
    key = None if effect == "none" else f"{p['where']}:{TERMS[effect].format(c=p['where'])}"
    others = [abs(physical[n] / v - 1) for n, v in truth.items() if n in physical and n not in (key, "tau") and v]
    steps = result.refinement.steps
    fits, ceilings = data["test_fit_percent"], data["test_fit_percent_noise_ceiling"]
    worse = min(fits, key=fits.get)
    return {"effect": effect, "seed": seed, "where": p["where"],
            "named first": bool(data["diagnosis"]["ranking"]) and data["diagnosis"]["ranking"][0]["effect"] == label,
            "added first": bool(added) and added[0] == label, "added only it": added == ([] if effect == "none"
                                                                                          else [label]),
            "effect error %": None if key is None else 100 * abs(physical.get(key, 0.0) / truth[key] - 1),
            "tau error %": 100 * abs(physical["tau"] / truth["tau"] - 1),
            "worst other %": 100 * max(others),
            "fit before %": steps[0].fit_before if steps else min(fits.values()),
            "fit after %": fits[worse], "noise allows %": ceilings[worse], "added": ", ".join(added),
            "seconds": time.perf_counter() - start, "error": ""}


# %%
jobs = [(seed, effect) for effect in effects for seed in range(first, last)]
rows = Parallel(n_jobs=int(os.environ.get("N_JOBS", "2")))(delayed(one)(s, e) for s, e in jobs)
table = pd.DataFrame(rows).set_index(["effect", "seed"])
pd.set_option("display.width", 200)
ok = table[table["error"] == ""]
summary = ok.groupby(level="effect", sort=False).agg(**{
    "systems": ("tau error %", "size"),
    "named first %": ("named first", lambda s: 100 * s.mean()),
    "added first %": ("added first", lambda s: 100 * s.mean()),
    "added only it (controls: nothing) %": ("added only it", lambda s: 100 * s.mean()),
    "effect error % (median)": ("effect error %", "median"),
    "tau error % (median)": ("tau error %", "median"),
    "worst other % (median)": ("worst other %", "median"),
    "fit before % (median)": ("fit before %", "median"),
    "fit after % (median)": ("fit after %", "median"),
    "noise allows % (median)": ("noise allows %", "median"),
})
summary.loc["none", ["named first %", "added first %"]] = np.nan  # (nothing to name)
print(summary.to_string(float_format=lambda v: f"{v:.1f}"))
print(f"\n{len(table) - len(ok)} runs failed" + "".join(f"\n  {i}: {e}" for i, e in table["error"][table["error"] != ""].items()))
print(f"{table['seconds'].sum():.0f} s of runs (seeds {first}:{last})")
if os.environ.get("SYSTEMS"):
    print(table.to_string(float_format=lambda v: f"{v:.3g}"))
