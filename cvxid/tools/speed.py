r"""The shipped jobs' wall seconds, cold and warm (``cvxid bench --speed``).

Each run is ``cvxid run SPEC --quiet --out DIR`` in a fresh Python process, timed from
its start to its exit (starting Python, importing, the run and its report): what a user
waits for.  *Cold* is a first run on a machine: the simulation kernels compiled by numba
into an empty cache (``NUMBA_CACHE_DIR``, a temporary folder of the benchmark's own, so the
machine's cache is left alone); *warm* are the runs after it, which read that cache.

``against``: another copy of cvxid (a folder holding its ``cvxid/`` package, e.g. from
``git worktree add /tmp/base REV``), run the same way on the same spec files and
interleaved with this one run by run, so both see the same machine (its speed drifts by
10–15 % from hour to hour here).  Each job's last ``result.json`` of the two is compared:
the largest relative difference of the reported physical parameters, 0 where both print
the same model.
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

import cvxid
from cvxid.errors import CvxidError
from cvxid.progress import progress
from cvxid.spec.shipped import resolve_spec

JOBS = ("duffing_delay", "hidden_friction", "flexible_joint")
"""The shipped jobs timed by default."""

TARGETS = {"duffing_delay": 6.0, "hidden_friction": 4.0, "flexible_joint": 10.0}
"""The warm wall seconds each shipped job is held to on a 2-core machine (issue 15)."""

CHILD = "import sys\nfrom cvxid.app.cli import command\nsys.exit(command())\n"
"""The console script's own entry (:func:`~cvxid.app.cli.command`, its collector frozen after the imports)."""
WHERE = "import cvxid\nprint(cvxid.__file__)\nfrom cvxid.app.cli import command\n"


def _environment(root: Path, cache: Path | None) -> dict[str, str]:
    """The child's environment: ``root``'s cvxid first on the path, numba's cache in
    ``cache`` (None: the machine's own)."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, (str(root), os.environ.get("PYTHONPATH"))))}
    if cache is not None:
        env["NUMBA_CACHE_DIR"] = str(cache)
    return env


def _last_line(text: str) -> str:
    return text.strip().splitlines()[-1] if text.strip() else "no message"


def _check_copy(root: Path, folder: Path) -> None:
    """A clear error unless a child started with ``root`` first on its path imports cvxid
    from it, with the console script's entry (older copies lack it)."""
    found = subprocess.run([sys.executable, "-c", WHERE], capture_output=True, text=True, cwd=folder,
                           env=_environment(root, None))
    lines = found.stdout.strip().splitlines()
    where = Path(lines[0]).resolve() if lines else None
    if where is None or root not in where.parents:
        raise CvxidError(f"--against {root}: a Python started with it first on its path imports cvxid from "
                         f"{where or 'nowhere (' + _last_line(found.stderr) + ')'}; give the folder that holds "
                         "another copy's cvxid/ package (e.g. from `git worktree add /tmp/base REV`)")
    if found.returncode != 0:
        raise CvxidError(f"--against {root}: its cvxid has no console entry cvxid.app.cli.command "
                         f"({_last_line(found.stderr)}): it is older than the script entry this benchmark times; "
                         "time it against a newer copy")


def _run_once(spec: Path, root: Path, cache: Path | None, out: Path, folder: Path) -> tuple[float, str]:
    """Wall seconds of one ``cvxid run`` of ``spec`` in a fresh process, and its error's
    last line ("" when it succeeded)."""
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-c", CHILD, "run", str(spec), "--quiet", "--out", str(out)],
                          stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, cwd=folder,
                          env=_environment(root, cache))
    seconds = time.perf_counter() - start
    return seconds, "" if done.returncode == 0 else f"exit {done.returncode}: {_last_line(done.stderr)}"


def _physical(out: Path) -> dict[str, float]:
    """The physical parameters a run's ``result.json`` reports (coupled: by coordinate)."""
    physical = json.loads((out / "result.json").read_text()).get("physical", {})
    flat = {}
    for name, value in physical.items():
        for key, number in (value.items() if isinstance(value, dict) else [(None, value)]):
            if isinstance(number, (int, float)):
                flat[name if key is None else f"{name}:{key}"] = float(number)
    return flat


def _difference(a: dict[str, float], b: dict[str, float]) -> float:
    """The largest relative difference between two runs' parameters (inf where they
    report different ones)."""
    if set(a) != set(b):
        return float("inf")
    return max((abs(a[k] - b[k]) / max(abs(a[k]), abs(b[k]), 1e-300) for k in a if a[k] != b[k]), default=0.0)


def speed(jobs=JOBS, repeat: int = 5, against: str | Path | None = None, cold: bool = True) -> pd.DataFrame:
    """One row per job and copy of cvxid (``"this"``, and ``"against"`` when given): the
    cold run's seconds (NaN without ``cold``: the warm runs then read the machine's own
    cache), the warm runs' least, median and most, the target (:data:`TARGETS`), whether
    the median is within it, for ``against`` the largest relative difference of its
    parameters from this copy's (inf where the two report different parameters), and the
    first failed run's error ("" when none failed; its seconds are left out).  ``jobs``:
    shipped problem names or spec files.  The copies take turns, the first of each round
    alternating; a progress bar counts the runs."""
    if repeat < 1:
        raise CvxidError(f"--repeat must be at least 1 warm run, got {repeat}")
    if not jobs:
        raise CvxidError("--speed needs at least one job: shipped problem names or spec files, comma-separated")
    specs = [resolve_spec(str(job)).resolve() for job in jobs]
    twice = next((str(job) for i, job in enumerate(jobs) if specs[i] in specs[:i]), None)
    if twice is not None:
        raise CvxidError(f"--speed names {twice} twice: give each job once (--repeat sets the runs)")
    copies = {"this": Path(cvxid.__file__).resolve().parents[1]}
    if against is not None:
        copies["against"] = Path(against).resolve()
    rows = []
    with tempfile.TemporaryDirectory() as tmp, progress(desc="cvxid bench --speed",
                                                         total=len(specs) * (repeat + cold) * len(copies)) as bar:
        folder = Path(tmp)
        if against is not None:
            _check_copy(copies["against"], folder)
        for index, (job, spec) in enumerate(zip(jobs, specs)):
            seconds, errors, first = {name: [] for name in copies}, {name: "" for name in copies}, {}
            caches = {name: folder / f"numba_{index}_{name}" if cold else None for name in copies}
            for run in range(repeat + cold):
                for name in list(copies)[::1 if run % 2 == 0 else -1]:
                    bar.set_postfix_str(f"{job}, {'cold' if cold and run == 0 else 'warm'} ({name})")
                    took, error = _run_once(spec, copies[name], caches[name], folder / f"out_{index}_{name}", folder)
                    bar.update()
                    errors[name] = errors[name] or error
                    if error:
                        continue
                    if cold and run == 0:
                        first[name] = took
                    else:
                        seconds[name].append(took)
            reported = {name: _physical(folder / f"out_{index}_{name}") if not errors[name] else None
                        for name in copies}
            for name in copies:
                warm = np.array(seconds[name]) if seconds[name] else np.array([np.nan])
                median = float(np.median(warm))
                rows.append({"job": str(job), "version": name, "cold s": first.get(name, np.nan),
                             "warm s min": warm.min(), "warm s median": median, "warm s max": warm.max(),
                             "warm runs": len(seconds[name]), "target s": TARGETS.get(str(job), np.nan),
                             "median within target": bool(median <= TARGETS[str(job)]) if str(job) in TARGETS
                             and np.isfinite(median) else None,
                             "parameters differ": _difference(reported["this"], reported[name])
                             if name != "this" and reported["this"] is not None and reported[name] is not None
                             else np.nan,
                             "error": errors[name]})
    return pd.DataFrame(rows)
