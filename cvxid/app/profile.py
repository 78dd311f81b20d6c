"""``cvxid run SPEC --profile``: where the seconds of a run go.

The run executes under :mod:`cProfile`; the table gives the cumulative seconds of the
functions that enter each stage (a stage nested in another is counted in both: the
diagnosis refits, and its refits solve).  Compiling the simulation kernels (numba, the
first run on a machine) and importing cvxid are measured beside them.
"""

from __future__ import annotations

import cProfile
import os
import pstats
import time

import pandas as pd

def _stages() -> dict[str, list]:
    """Each stage's entry functions (imported here: the profile names them by their code)."""
    from numba.core.dispatcher import Dispatcher

    from cvxid.app import report, run
    from cvxid.identify import bootstrap, path, system
    from cvxid.regression.builder import RegressionBuilder
    from cvxid.spec.problem import ProblemSpec

    return {
        "data (load or simulate the records)": [ProblemSpec.experiment],
        "regression (the algebraic operation)": [RegressionBuilder.__init__, RegressionBuilder.at],
        "delay profile (convex)": [system.fit_support],
        "lambda path (solves)": [path.Path.compute.__func__],
        "stepwise search by simulation error": [run._stepwise],
        "bootstrap": [bootstrap.bootstrap],
        "diagnosis and refinement": [run._diagnose],
        "output-error polish (simulations)": [run._polish],
        "comparison on the test record": [run._compare, run._score],
        "report and figures": [report.write_report],
        "compiling the simulation kernels (numba)": [Dispatcher._compile_for_args],
    }


def _key(function) -> tuple[str, int, str]:
    code = function.__code__
    return code.co_filename, code.co_firstlineno, code.co_name


def since_start() -> float:
    """Seconds since this process started (Linux: its /proc entry; NaN elsewhere): before a
    run, the time spent starting Python and importing cvxid."""
    try:
        with open("/proc/self/stat") as fh:
            ticks = int(fh.read().rsplit(")", 1)[1].split()[19])
        with open("/proc/uptime") as fh:
            uptime = float(fh.read().split()[0])
        return uptime - ticks / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return float("nan")


def profiled(job, imported: float) -> tuple[object, pd.DataFrame]:
    """Run ``job()`` under the profiler; its result and the table of stages (seconds and
    share of the run), with ``imported`` (seconds spent importing cvxid) as the first row."""
    profiler = cProfile.Profile()
    start = time.perf_counter()
    result = profiler.runcall(job)
    total = time.perf_counter() - start
    stats = pstats.Stats(profiler).stats
    rows = {"starting Python, importing cvxid": imported}
    for stage, entries in _stages().items():
        keys = {_key(f) for f in entries}
        rows[stage] = sum(values[3] for key, values in stats.items() if key in keys)
    rows["the whole run"] = total
    frame = pd.DataFrame({"seconds": pd.Series(rows)})
    frame["% of the run"] = 100 * frame["seconds"] / total
    frame.loc["starting Python, importing cvxid", "% of the run"] = float("nan")
    frame.index.name = "stage"
    return result, frame
