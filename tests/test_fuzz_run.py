"""`cvxid run` fuzzed (docs/bad-input.md): any single-key mutation of a shipped spec, run on
small data, ends in a written report or in one CvxidError (the command's `cvxid: error: …`,
exit status 2) within a time limit: never another exception, a hang or a report that
cannot be written.  A short version runs in the suite; `CVXID_FUZZ_RUNS=300 pytest
tests/test_fuzz_run.py` is the long one."""

import copy
import os
import signal

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cvxid.app.report import write_report
from cvxid.app.run import run
from cvxid.errors import CvxidError
from cvxid.progress import set_quiet
from cvxid.spec.load import parse_problem
from cvxid.spec.shipped import resolve_spec
from cvxid.spec.toml import tomllib

from .test_spec_ranges import VALUES, leaves

RUNS = int(os.environ.get("CVXID_FUZZ_RUNS", "5"))
LIMIT = 120
"""Seconds a fuzzed run of small data may take (measured: 3-5 s unmutated)."""
SHIPPED = ("hidden_friction", "duffing_delay_exact", "flexible_joint")
RAW = {name: tomllib.loads(resolve_spec(name).read_text()) for name in SHIPPED}
MUTATIONS = [(name, path) for name in SHIPPED for path in sorted(leaves(RAW[name]))]


def _number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def small(raw: dict, seconds: float = 2.0) -> dict:
    """The spec on small data and short sweeps (a numeric value is lowered, any other is
    left for the reader to judge)."""
    raw = copy.deepcopy(raw)
    for part in raw.get("data", {}).values() if isinstance(raw.get("data"), dict) else ():
        simulate = part.get("simulate") if isinstance(part, dict) else None
        if isinstance(simulate, dict) and _number(simulate.get("duration")):
            simulate["duration"] = min(simulate["duration"], seconds)
    fit = raw.get("fit") if isinstance(raw.get("fit"), dict) else {}
    for key, field, most in (("lambdas", "count", 8), ("bootstrap", "samples", 3)):
        table = fit.get(key)
        if isinstance(table, dict) and _number(table.get(field)):
            table[field] = min(table[field], most)
    return raw


class Hang(Exception):
    pass


def _alarm(signum, frame):
    raise Hang(f"no answer within {LIMIT} s")


@settings(max_examples=RUNS, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(mutation=st.sampled_from(MUTATIONS), value=VALUES)
def test_any_single_key_mutation_of_a_shipped_spec_runs_or_is_one_clear_error(tmp_path_factory, mutation, value):
    name, path = mutation
    raw = copy.deepcopy(RAW[name])
    table = raw
    for key in path[:-1]:
        table = table[key]
    if value is None:  # TOML has no null: a missing key
        del table[path[-1]]
    else:
        table[path[-1]] = value
    set_quiet(True)
    previous = signal.signal(signal.SIGALRM, _alarm)
    signal.alarm(LIMIT)
    try:
        result = run(parse_problem(small(raw), resolve_spec(name).parent))
        written, _ = write_report(result, tmp_path_factory.mktemp("out"))
        assert written.is_file() and result.summary()
    except CvxidError as exc:
        assert str(exc) and "Traceback" not in str(exc)
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)
