r"""Long records: seconds, peak memory and accuracy as the record grows (``cvxid bench --long``).

Each row writes a linear oscillator

.. math:: \ddot x + 0.5\,\dot x + 6\,x = f

sampled at 1 kHz (a six-sine multisine force, white noise 0.001 on :math:`x` and
:math:`f`, a start in mid-motion) as a CSV of ``samples`` rows, runs ``cvxid run`` on it in
a fresh process with the documented defaults (a polynomial library of order 3, the adaptive lasso
with λ by blocked cross-validation, windows ``"auto"``) and reads the process's wall time
and peak resident memory (the child's own ``VmHWM``) and the identified parameters from ``result.json``.
The baseline in the same run is the paper's whole-record integrals (``window = "record"``),
which weigh the last rows by powers of :math:`t` (up to ``BASELINE_MAX`` samples: beyond, it
needs more memory than it is worth, about 100 bytes per sample and column).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.signal import lsim

TRUTH = {"m": 1.0, "x": 6.0, "x'": 0.5}
DT = 1e-3
NOISE = 0.001
SPEC = """name = "long_record"
description = "x'' + 0.5 x' + 6 x = f at 1 kHz: cvxid bench --long"
[data.train]
file = "record.csv"
[model.library]
order = 3
[fit]
window = {window}
"""
WINDOWS = {"windows": '"auto"', "whole record": '"record"'}
BASELINE_MAX = 2_000_000


def write_record(path: Path, samples: int, seed: int = 0) -> None:
    """The oscillator's record as a CSV (columns t, x, f) of ``samples`` rows."""
    t = np.arange(samples) * DT
    rng = np.random.default_rng(seed)
    f = sum(np.sin(w * t + rng.uniform(0, 2 * np.pi)) for w in (0.7, 1.3, 2.1, 2.9, 3.7, 5.3))
    _, x, _ = lsim(([1.0], [TRUTH["m"], TRUTH["x'"], TRUTH["x"]]), f, t, X0=[0.3, -0.2])
    frame = pd.DataFrame({"t": t, "x": x + NOISE * rng.standard_normal(samples),
                          "f": f + NOISE * rng.standard_normal(samples)})
    frame.to_csv(path, index=False, float_format="%.9g")


RUN_AND_REPORT_PEAK = (
    "import sys\n"
    "from cvxid.app.cli import main\n"
    "code = main(sys.argv[2:])\n"
    "with open('/proc/self/status') as status, open(sys.argv[1], 'w') as out:\n"
    "    out.write(next((line.split()[1] for line in status if line.startswith('VmHWM:')), ''))\n"
    "sys.exit(code)\n")
"""``cvxid`` in a child that writes its own peak resident memory (``VmHWM``, kB) at the
end.  The kernel's ``ru_maxrss`` of a child counts the memory of the process it was
spawned from (the pages it held before ``exec``): a child of a test process of 0.7 GB, or
of the process that had just simulated 10^7 samples, reported that, not its own peak."""


def run_once(folder: Path, window: str = "windows") -> dict:
    """``cvxid run`` on ``folder``'s record in a fresh process: wall seconds, peak resident
    memory, the largest relative parameter error and the terms found beyond the truth."""
    spec = folder / f"spec_{window.replace(' ', '_')}.toml"
    spec.write_text(SPEC.format(window=WINDOWS[window]))
    out = folder / f"out_{window.replace(' ', '_')}"
    peak = folder / "peak.txt"
    peak.unlink(missing_ok=True)
    start = time.perf_counter()
    with open(folder / "stderr.txt", "w") as stderr:  # a file, never a pipe: wait4 cannot block on it
        process = subprocess.Popen([sys.executable, "-c", RUN_AND_REPORT_PEAK, str(peak), "run", str(spec), "--quiet",
                                    "--out", str(out)], stdout=subprocess.DEVNULL, stderr=stderr)
        _, status, usage = os.wait4(process.pid, 0)
    seconds = time.perf_counter() - start
    own = peak.read_text().strip() if peak.exists() else ""
    row = {"window": window, "seconds": seconds, "peak GB": int(own) / 2**20 if own else usage.ru_maxrss / 2**20}
    error = (folder / "stderr.txt").read_text().strip()
    if os.waitstatus_to_exitcode(status) != 0:
        return {**row, "error": error or f"exit status {os.waitstatus_to_exitcode(status)}"}
    result = json.loads((out / "result.json").read_text())
    physical = result["physical"]
    errors = {f"err % {k}": 100 * (physical.get(k, 0.0) - v) / v for k, v in TRUTH.items()}
    extra = [k for k in result["support"] if k not in ("x''", *TRUTH)]
    return {**row, **errors, "max |err| %": max(abs(e) for e in errors.values()), "extra terms": len(extra)}


def growth(sizes, windows=tuple(WINDOWS), keep: str | None = None) -> pd.DataFrame:
    """One row per record length and window rule (see the module docstring)."""
    rows = []
    for samples in sizes:
        with tempfile.TemporaryDirectory(dir=keep) as tmp:
            folder = Path(tmp)
            write_record(folder / "record.csv", int(samples))
            for window in windows:
                if window == "whole record" and samples > BASELINE_MAX:
                    continue
                rows.append({"samples": int(samples), **run_once(folder, window)})
    return pd.DataFrame(rows)
