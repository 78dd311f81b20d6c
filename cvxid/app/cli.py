"""The ``cvxid`` command.

``cvxid run SPEC --out DIR`` identifies the model of a problem spec and writes the report.
A user error (bad spec, bad data, failed solve) prints one line and exits with status 2;
there is never a Python traceback for it.
"""

from __future__ import annotations

import argparse
import sys
import warnings

from cvxid import __version__
from cvxid.errors import CvxidError


def _run(args) -> int:
    from cvxid.app.report import write_report
    from cvxid.app.run import run

    result = run(args.spec)
    path = write_report(result, args.out) if args.out else None  # before printing: a closed pipe loses nothing
    print(result.summary())
    if path:
        print(f"  wrote {path} and figures")
    return 0


def _bench(args) -> int:
    if args.accuracy:
        return _accuracy(args)
    from cvxid.tools.bench import run_bench

    run_bench(args.spec, args.order, args.naive_lambdas, args.json, args.jobs)
    return 0


def _accuracy(args) -> int:
    import json

    from cvxid.spec.load import load_problem
    from cvxid.tools.accuracy import accuracy, summary

    noises = tuple(float(v) for v in args.noises.split(","))
    frame = accuracy(load_problem(args.spec), noises, args.seeds)
    table = summary(frame)
    print(f"cvxid bench --accuracy: {args.spec}, {args.seeds} seeds per noise level, true structure, noisy x only")
    print(table.to_string(float_format=lambda v: f"{v:.3f}"))
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({"runs": frame.to_dict(orient="records"),
                       "summary": table.reset_index().to_dict(orient="records")}, fh, indent=2)
    return 0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        prog="cvxid",
        description="Identify nonlinear systems with time delay from data, as convex problems (cvxpy).",
    )
    parser.add_argument("--version", action="version", version=f"cvxid {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    p_run = sub.add_parser("run", help="identify the model of a problem spec")
    p_run.add_argument("spec", help="a TOML problem spec (see problems/README.md)")
    p_run.add_argument("--out", default=None, help="folder for result.json, report.md and figures")
    p_bench = sub.add_parser("bench", help="time the lambda path against the baselines")
    p_bench.add_argument("spec")
    p_bench.add_argument("--order", type=int, default=None, help="library order (default: the spec's)")
    p_bench.add_argument("--naive-lambdas", type=int, default=5, help="lambdas timed for the naive cvxpy baseline")
    p_bench.add_argument("--jobs", type=int, default=2, help="joblib workers for Algorithm 1")
    p_bench.add_argument("--json", default=None, help="also write the figures to this JSON file")
    p_bench.add_argument("--accuracy", action="store_true", help="delay and parameter errors of four methods")
    p_bench.add_argument("--seeds", type=int, default=5, help="seeds per noise level (--accuracy)")
    p_bench.add_argument("--noises", default="0,0.001,0.01,0.05", help="noise levels (--accuracy)")
    args = parser.parse_args(argv)
    warnings.simplefilter("ignore", UserWarning)  # cvxid's own warnings are reported in the result
    try:
        return {"run": _run, "bench": _bench}[args.command](args)
    except CvxidError as exc:
        print(f"cvxid: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("cvxid: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # output piped into head, less, …
        return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
