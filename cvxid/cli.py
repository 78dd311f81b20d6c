"""The ``cvxid`` command.

``cvxid run SPEC --out DIR`` identifies the model of a problem spec and writes the report.
A user error (bad spec, bad data, failed solve) prints one line and exits with status 2;
there is never a Python traceback for it.
"""

from __future__ import annotations

import argparse
import sys
import warnings

from .errors import CvxidError


def _run(args) -> int:
    from .pipeline import run
    from .report import write_report

    result = run(args.spec)
    print(result.summary())
    if args.out:
        path = write_report(result, args.out)
        print(f"  wrote {path} and figures")
    return 0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="cvxid", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    p_run = sub.add_parser("run", help="identify the model of a problem spec")
    p_run.add_argument("spec", help="a TOML problem spec (see problems/README.md)")
    p_run.add_argument("--out", default=None, help="folder for result.json, report.md and figures")
    args = parser.parse_args(argv)
    warnings.simplefilter("ignore", UserWarning)  # cvxid's own warnings are reported in the result
    try:
        return {"run": _run}[args.command](args)
    except CvxidError as exc:
        print(f"cvxid: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("cvxid: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
