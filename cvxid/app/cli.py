"""The ``cvxid`` command.

``cvxid run SPEC --out DIR`` identifies the model of a problem spec and writes the report.
A user error (bad spec, bad data, failed solve) prints one line and exits with status 2;
there is never a Python traceback for it.
"""

from __future__ import annotations

import argparse
import gc
import math
import signal
import sys
import threading
import warnings

from cvxid import __version__
from cvxid.data.experiment import TIME_UNITS
from cvxid.errors import CvxidError, CvxidWarning
from cvxid.parallel import BACKENDS
from cvxid.progress import set_quiet
from cvxid.tools.speed import JOBS as SPEED_JOBS


def _run(args) -> int:
    from cvxid.app.report import prepare_folder
    from cvxid.spec.load import load_problem
    from cvxid.spec.problem import ProblemSpec

    if args.out:
        prepare_folder(args.out)  # an unusable --out fails before any work
    spec = _with_engine(args.spec, args.backend, args.scheduler)
    if not isinstance(spec, ProblemSpec):  # (parsed before any work: a bad spec fails at once; its notes, a
        #                                      retired key, are said with the run's warnings)
        spec = load_problem(spec)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", CvxidWarning)  # (run() issues result.warnings: the summary prints them)
        result, path, replaced, table = _identify_and_report(spec, args)
    print(result.summary())                                                            # closed pipe loses nothing
    if path:
        print(f"  wrote {path} and figures" + (f", replacing the files of an earlier run of {replaced}" if replaced else ""))
    if args.profile:
        print("\nwhere the seconds went (cumulative; nested stages count in each; starting Python is before the run; "
              "measured under Python's profiler, which slows the Python-heavy stages, the figures and the diagnosis's "
              "loops, up to about twice and the compiled simulations and solvers not: read the shares, and time the "
              "run itself without --profile):")
        print(table.to_string(float_format=lambda v: f"{v:.3f}", na_rep="–"))
    return 0


def _identify_and_report(spec, args):
    """``run(spec)`` and its report in ``args.out`` (the report before printing: a closed
    pipe loses nothing): the result, the result.json path, the earlier run it replaced,
    and with ``--profile`` where the seconds went."""
    from cvxid.app.report import write_report
    from cvxid.app.run import run

    if args.profile:
        from cvxid.app.profile import profiled, since_start

        imported = since_start()
        (result, (path, replaced)), table = profiled(
            lambda: (r := run(spec), write_report(r, args.out) if args.out else (None, None)), imported)
        return result, path, replaced, table
    result = run(spec)
    path, replaced = write_report(result, args.out) if args.out else (None, None)
    return result, path, replaced, None


def _with_engine(spec: str, backend: str | None, scheduler: str | None):
    """The spec (its path or name), or the parsed spec with ``--backend``/``--scheduler``
    in place of its ``[fit]`` ones."""
    if backend is None and scheduler is None:
        return spec
    from dataclasses import replace

    from cvxid.parallel import check_backend
    from cvxid.spec.load import load_problem

    parsed = load_problem(spec)
    backend = backend or parsed.fit.backend
    scheduler = scheduler or parsed.fit.scheduler
    check_backend(backend, scheduler, where="--backend")
    return replace(parsed, fit=replace(parsed.fit, backend=backend, scheduler=scheduler))


def _init(args) -> int:
    from cvxid.app.starting_spec import init

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", CvxidWarning)
        path = init(args.data, args.out, args.test, args.time, args.output, args.input, args.dt, args.force,
                    args.time_unit)
    for said in caught:  # (what the starting spec's comments say, and the run would not: the time's units)
        if issubclass(said.category, CvxidWarning):
            print(f"warning: {said.message}", file=sys.stderr)
        else:  # (a reader's or numpy's own, as without the record)
            warnings.showwarning(said.message, said.category, said.filename, said.lineno)
    print(f"wrote {path}: run it with `cvxid run {path} --out out/`")
    return 0


def _problems(args) -> int:
    from cvxid.spec.shipped import problems_table, shipped_folder

    table = problems_table()
    width, data = max(map(len, table.index)), max(map(len, table["data"]))
    print(f"{'problem':<{width}}  {'data':<{data}}  what it shows")
    for name, row in table.iterrows():
        print(f"{name:<{width}}  {row['data']:<{data}}  {row['what it shows']}")
    print(f"  in {shipped_folder()}; run one with `cvxid run NAME`")
    return 0


HELDOUT_FLAGS = ("effects", "duration", "keep", "estimator", "selection", "stability", "prune", "known_gain",
                 "systems", "feedback")
"""``cvxid bench`` flags that only the held-out benchmark reads (``--mode`` too, when not its default)."""


def _check_bench_flags(args) -> None:
    """One benchmark per call, and no flag it would ignore: a clear error instead."""
    modes = [f"--{name}" for name in ("heldout", "long", "accuracy", "speed") if getattr(args, name)]
    if len(modes) > 1:
        raise CvxidError(f"{' and '.join(modes)} are separate benchmarks: give one of them")
    given = [f"--{name.replace('_', '-')}" for name in HELDOUT_FLAGS if getattr(args, name)]
    given += ["--mode"] if args.mode != "structure" else []
    if given and not args.heldout:
        raise CvxidError(f"{', '.join(given)} {'is' if len(given) == 1 else 'are'} for cvxid bench --heldout")
    if (args.seeds or args.noises) and not (args.heldout or args.accuracy):
        raise CvxidError("--seeds and --noises are for cvxid bench --heldout and --accuracy")
    if (args.repeat is not None or args.against) and not args.speed:
        raise CvxidError("--repeat and --against are for cvxid bench --speed")


def _bench(args) -> int:
    from cvxid.parallel import engine

    _check_bench_flags(args)
    if (args.long or args.speed) and (args.backend or args.scheduler):
        raise CvxidError(f"--{'long' if args.long else 'speed'} runs each record in a fresh process on this machine: "
                         "drop --backend/--scheduler")
    with engine(args.backend or "loky", args.scheduler):
        if args.heldout:
            return _heldout(args)
        if args.long:
            return _long(args)
        if args.speed:
            return _speed(args)
        if args.accuracy:
            return _accuracy(args)
        from cvxid.tools.bench import run_bench

        run_bench(args.spec, args.order, args.naive_lambdas, args.json, args.jobs)
        return 0


def _accuracy(args) -> int:
    import json

    from cvxid.spec.load import load_problem
    from cvxid.tools.accuracy import accuracy, summary

    noises = tuple(float(v) for v in (args.noises or "0,0.001,0.01,0.05").split(","))
    if args.seeds and not args.seeds.isdigit():
        raise CvxidError(f"--seeds with --accuracy is a number of seeds per noise level, got '{args.seeds}'")
    seeds = int(args.seeds or 5)
    frame = accuracy(load_problem(args.spec), noises, seeds)
    table = summary(frame)
    print(f"cvxid bench --accuracy: {args.spec}, {seeds} seeds per noise level, true structure, noisy x only")
    print(table.to_string(float_format=lambda v: f"{v:.3f}"))
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({"runs": frame.to_dict(orient="records"),
                       "summary": table.reset_index().to_dict(orient="records")}, fh, indent=2)
    return 0


def _long(args) -> int:
    import json

    from cvxid.app.report import plain
    from cvxid.tools.long_record import growth

    if args.spec:
        raise CvxidError("--long writes its own records: give no SPEC")
    try:
        sizes = [int(float(v)) for v in args.long.split(",")]
    except (ValueError, OverflowError):
        raise CvxidError(f"--long takes record lengths in samples, like 1e5,1e6,2e6, got '{args.long}'") from None
    if any(not 100 <= n <= 10**8 for n in sizes):
        raise CvxidError(f"--long: each record length must lie in 100 … 1e8 samples, got {args.long}")
    frame = growth(sizes)
    print("cvxid bench --long: x'' + 0.5 x' + 6 x = f at 1 kHz (CSV), noise 0.001, order-3 library, documented "
          "defaults; one fresh process per row (wall seconds include the import and reading the CSV)")
    print(frame.to_string(index=False, float_format=lambda v: f"{v:.4g}"))
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(plain({"rows": frame.to_dict(orient="records")}), fh, indent=2)
    return 0


def _speed(args) -> int:
    import json

    from cvxid.app.report import plain
    from cvxid.tools.speed import speed

    if args.spec:
        raise CvxidError("--speed takes its jobs after it (--speed duffing_delay,my.toml): give no SPEC")
    repeat = 5 if args.repeat is None else args.repeat
    frame = speed([job for job in args.speed.split(",") if job], repeat, args.against)
    print(f"cvxid bench --speed: wall seconds of `cvxid run JOB --quiet --out DIR`, each in a fresh process (starting "
          f"Python, importing, the run, the report); cold: numba's cache empty; warm: {repeat} runs after it"
          + (f"; interleaved run by run with the cvxid of {args.against} (parameters differ: the largest relative "
             "difference of its reported parameters from this one's, inf where they report other parameters)"
             if args.against else ""))
    shown = frame if frame["error"].astype(bool).any() else frame.drop(columns="error")
    print(shown.to_string(index=False, float_format=lambda v: f"{v:.3g}"))
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(plain({"rows": frame.to_dict(orient="records")}), fh, indent=2)
    return 0


def _numbers(text: str, flag: str, what: str, least: float) -> list[float]:
    """A comma-separated list of finite numbers of at least ``least``, or a clear error."""
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        raise CvxidError(f"{flag} takes {what}, got '{text}'") from None
    if not all(math.isfinite(v) and v >= least for v in values):
        raise CvxidError(f"{flag} takes {what}, each at least {least:g}, got '{text}'")
    return values


def _seeds(text: str) -> list[int]:
    """``"1000:1010"`` (a range, end excluded), ``"3,7,8"`` or one seed."""
    try:
        if ":" in text:
            start, stop = text.split(":")
            return list(range(int(start), int(stop)))
        return [int(v) for v in text.split(",")]
    except ValueError:
        raise CvxidError(f"--seeds must be a range like 1000:1010 or a list like 3,7,8, got '{text}'") from None


def _heldout(args) -> int:
    import json
    import time

    import pandas as pd

    from cvxid.app.report import plain
    from cvxid.identify.path import SELECTION_RULES
    from cvxid.spec.problem import SELECTORS
    from cvxid.tools.heldout import EFFECTS, OUTSIDE, SELECTION_EFFECTS, by_duration, confusion, heldout, summary

    if args.spec:
        raise CvxidError("--heldout draws its own systems: give no SPEC")
    seeds = _seeds(args.seeds or "1000:1010")
    effects = tuple(args.effects.split(",")) if args.effects else \
        SELECTION_EFFECTS if args.mode.startswith("selection") else EFFECTS
    unknown = [e for e in effects if e not in EFFECTS + OUTSIDE]
    if unknown:
        raise CvxidError(f"--effects: unknown hidden effect '{unknown[0]}'; one of: {', '.join(EFFECTS + OUTSIDE)}")
    noises = tuple(_numbers(args.noises, "--noises", "noise levels like 0.01,0.001", 0.0)) if args.noises else (None,)
    lengths = _numbers(args.duration, "--duration", "record seconds like 8 or 20,200", 1.0) if args.duration \
        else [None]
    if not seeds:
        raise CvxidError(f"--seeds {args.seeds} holds no seed: a range like 1000:1010 ends after its start")
    fit = {k: v for k, v in (("estimator", args.estimator), ("selection", args.selection)) if v}
    if args.stability:
        fit["stability"] = args.stability == "on"
    if args.prune:
        fit["prune"] = args.prune == "on"
    for key, choices in (("estimator", SELECTORS), ("selection", SELECTION_RULES)):
        if key in fit and fit[key] not in choices:
            raise CvxidError(f"--{key} must be one of {', '.join(choices)}, got '{fit[key]}'")
    if fit.get("estimator") == "stepwise_oe" and args.mode != "selection":
        raise CvxidError("--estimator stepwise_oe selects terms from a library without a diagnosis: use it with "
                         "--mode selection")
    start = time.perf_counter()
    frame = pd.concat([heldout(seeds, effects, noises, length, args.mode, args.jobs, args.keep, args.known_gain, fit,
                               args.feedback or "position") for length in lengths], ignore_index=True)
    wall = time.perf_counter() - start
    by = ("duration", "effect", "noise") if len(lengths) > 1 else ("effect", "noise")
    table = summary(frame, by)
    print(f"cvxid bench --heldout: seeds {args.seeds or '1000:1010'}, {args.mode} mode, "
          f"{'the paper feedback b x(t - tau) + b1 x' + chr(39) + '(t - tau), ' if args.feedback == 'paper' else ''}"
          f"{', '.join(f'{k} {v}' for k, v in fit.items()) + ', ' if fit else ''}"
          f"{len(frame)} systems in {wall:.0f} s ({args.jobs} jobs)")
    print(table.to_string(float_format=lambda v: f"{v:.3g}"))
    if args.mode in ("diagnosis", "selection_diagnosis"):
        print()
        print(confusion(frame, ("effect",) + tuple(k for k in by if k != "effect"))
              .to_string(float_format=lambda v: f"{v:.3g}"))
    if args.systems:
        print()
        print(frame.drop(columns=["error"]).to_string(float_format=lambda v: f"{v:.4g}"))
    failed = frame[frame["status"] != "ok"]
    for _, row in failed.iterrows():
        print(f"  failed: seed {row['seed']} {row['effect']} noise {row['noise']}: {row['error']}")
    if len(lengths) > 1:
        pairs = by_duration(frame)
        print()
        print(pairs.to_string(float_format=lambda v: f"{v:.3g}"))
        better = pairs["longest at least as accurate"]
        print(f"  {max(lengths):g} s at least as accurate on tau as {min(lengths):g} s: {int(better.sum())}/{len(better)}")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(plain({"seconds": wall, "systems": frame.to_dict(orient="records"),
                             "summary": table.reset_index().to_dict(orient="records")}), fh, indent=2)
    return 0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        prog="cvxid",
        description="Identify nonlinear systems with time delay from data, as convex problems (cvxpy).",
    )
    parser.add_argument("--version", action="version", version=f"cvxid {__version__}")
    quiet = argparse.ArgumentParser(add_help=False)
    quiet.add_argument("--quiet", "-q", action="store_true", help="no progress bars")
    sub = parser.add_subparsers(dest="command", required=True)
    engines = argparse.ArgumentParser(add_help=False)
    engines.add_argument("--backend", default=None, choices=BACKENDS,
                         help="where parallel work runs (joblib): loky (this machine), threading, dask, ray")
    engines.add_argument("--scheduler", default=None, help="the dask (or ray) cluster's address, e.g. tcp://host:8786")
    p_run = sub.add_parser("run", help="identify the model of a problem spec", parents=[quiet, engines])
    p_run.add_argument("spec", help="a TOML problem spec (see docs/spec.md) or a shipped problem's name")
    p_run.add_argument("--out", default=None, help="folder for result.json, report.md and figures")
    p_run.add_argument("--profile", action="store_true", help="also print where the seconds went, stage by stage")
    sub.add_parser("problems", help="list the shipped problems (run one with `cvxid run NAME`)", parents=[quiet])
    p_init = sub.add_parser("init", help="write a commented starting spec for your own record", parents=[quiet])
    p_init.add_argument("data", help="the record: .csv (header row), .mat or .npz")
    p_init.add_argument("--out", "-o", default="spec.toml", help="the spec to write (default: spec.toml)")
    p_init.add_argument("--test", default=None, help="a test record (default: the last 20 %% of DATA)")
    p_init.add_argument("--time", default=None, help="the time column (default: found by name or by its steps)")
    p_init.add_argument("--output", default=None, help="the measured coordinate's column (default: found)")
    p_init.add_argument("--input", default=None, help="the input's column (default: found)")
    p_init.add_argument("--dt", type=float, default=None, help="the sample step in seconds, for a file without a "
                        "time column")
    p_init.add_argument("--time-unit", default=None, choices=list(TIME_UNITS), help="the unit the time column counts "
                        "(default: read off its name, e.g. time_ms, else seconds); cvxid reads it as seconds")
    p_init.add_argument("--force", action="store_true", help="replace an existing spec file")
    p_bench = sub.add_parser("bench", help="time the lambda path against the baselines", parents=[quiet, engines])
    p_bench.add_argument("spec", nargs="?", help="a TOML problem spec (none with --heldout)")
    p_bench.add_argument("--order", type=int, default=None, help="library order (default: the spec's)")
    p_bench.add_argument("--naive-lambdas", type=int, default=5, help="lambdas timed for the naive cvxpy baseline")
    p_bench.add_argument("--jobs", type=int, default=2, help="joblib workers for Algorithm 1")
    p_bench.add_argument("--json", default=None, help="also write the figures to this JSON file")
    p_bench.add_argument("--accuracy", action="store_true", help="delay and parameter errors of four methods")
    p_bench.add_argument("--seeds", default=None,
                         help="seeds per noise level (--accuracy, default 5); seeds as 1000:1010 or 3,7,8 "
                              "(--heldout, default 1000:1010; 0-99 tune, 1000+ report)")
    p_bench.add_argument("--noises", default=None,
                         help="noise levels (--accuracy, default 0,0.001,0.01,0.05; --heldout, default drawn)")
    p_bench.add_argument("--heldout", action="store_true", help="random delayed oscillators cvxid's examples lack")
    p_bench.add_argument("--effects", default=None, help="hidden effects, e.g. none,coulomb (--heldout, default all "
                              "of the catalogue's; the selection modes: those whose terms the library holds; "
                              "abs_stiffness and smooth_friction, outside the catalogue, only by name)")
    p_bench.add_argument("--duration", default=None,
                         help="record seconds, or several (20,200) to compare the same systems (--heldout, default drawn)")
    p_bench.add_argument("--mode", default="structure",
                         choices=("structure", "diagnosis", "selection", "selection_diagnosis"),
                         help="true terms given, a base library diagnosed, the terms selected from an "
                              "18-term library, or selected from the order-3 polynomial then diagnosed (--heldout)")
    p_bench.add_argument("--estimator", default=None,
                         help="the specs' [fit] estimator (--heldout; default: the documented default)")
    p_bench.add_argument("--selection", default=None,
                         help="the specs' [fit] selection rule (--heldout; default: the documented default)")
    p_bench.add_argument("--stability", default=None, choices=("on", "off"),
                         help="the specs' [fit] stability selection (--heldout; default: the documented default)")
    p_bench.add_argument("--prune", default=None, choices=("on", "off"),
                         help="the specs' [fit] prune: selected terms pruned, and exchanged while the model misses "
                              "the record, by simulation error (--heldout; default: the documented default)")
    p_bench.add_argument("--known-gain", action="store_true", help="give the spec the true feedback gain (--heldout)")
    p_bench.add_argument("--feedback", choices=("position", "paper"), default=None,
                         help="the drawn loop feeds back the position (default), or the paper's position and velocity, "
                              "b x(t - tau) + b1 x'(t - tau), identified with signal = [\"x\", \"x'\"] (--heldout)")
    p_bench.add_argument("--keep", default=None, help="keep each system's data, spec and result.json here (--heldout)")
    p_bench.add_argument("--systems", action="store_true", help="also print one row per system (--heldout)")
    p_bench.add_argument("--long", default=None,
                         help="record lengths in samples, e.g. 1e5,1e6,2e6,1e7: seconds, peak memory and accuracy")
    p_bench.add_argument("--speed", nargs="?", const=",".join(SPEED_JOBS), default=None, metavar="NAMES",
                         help="wall seconds of `cvxid run`, cold and warm, each in a fresh process: shipped problems "
                              f"or spec files (default {','.join(SPEED_JOBS)})")
    p_bench.add_argument("--repeat", type=int, default=None, help="warm runs per job (--speed, default 5)")
    p_bench.add_argument("--against", default=None,
                         help="another copy of cvxid to time beside this one, interleaved: the folder holding its "
                              "cvxid/ (--speed)")
    args = parser.parse_args(argv)
    if args.command == "bench" and not (args.heldout or args.long or args.speed or args.repeat is not None
                                        or args.against) and not args.spec:
        parser.error("bench needs a SPEC (or --heldout, --long or --speed)")
    set_quiet(args.quiet)
    warnings.simplefilter("ignore", UserWarning)  # cvxid's own warnings are reported in the result
    previous = _stop_on_sigterm()
    try:
        return {"run": _run, "bench": _bench, "problems": _problems, "init": _init}[args.command](args)
    except CvxidError as exc:
        print(f"cvxid: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("cvxid: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # output piped into head, less, …
        return 0
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


def command() -> int:
    """The console script ``cvxid``: :func:`main` between two :func:`gc.freeze` calls.
    The first takes what importing cvxid made (numba, cvxpy, scipy, pandas: about 190,000
    objects that last as long as the process) out of the collector's walks during the
    run; the second, as the process ends, spares the interpreter's last collections
    through everything the run made (about 0.4 s of a 4 s run).  Objects are still
    freed as their references go; only cycles made before a freeze are left to the exit.
    (Not in :func:`main`, which tests and scripts call in a process that goes on.)"""
    gc.freeze()
    status = main()
    gc.freeze()
    return status


def _stop_on_sigterm():
    """A SIGTERM (``kill``, a scheduler's timeout) stops the command as Ctrl-C does: joblib
    then ends its worker processes, which a plain termination left running.  Returns the
    handler it replaced (None off the main thread, where signals cannot be set)."""
    if threading.current_thread() is not threading.main_thread():
        return None

    def interrupted(signum, frame):
        raise KeyboardInterrupt

    return signal.signal(signal.SIGTERM, interrupted)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(command())
