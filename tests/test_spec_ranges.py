"""Every numeric key of a spec has a checked range; huge jobs are refused before any work;
the spec reader never ends in anything but a spec or a CvxidError (hypothesis)."""

import copy
import os

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cvxid.errors import CvxidError
from cvxid.spec.load import parse_problem
from cvxid.spec.toml import tomllib

from .conftest import ROOT

SPEC = ROOT / "problems" / "hidden_friction.toml"
EXAMPLES = int(os.environ.get("CVXID_FUZZ_EXAMPLES", "150"))  # the long version: CVXID_FUZZ_EXAMPLES=5000


def raw():
    return tomllib.loads(SPEC.read_text())


def mutated(path, value):
    spec = copy.deepcopy(raw())
    table = spec
    for key in path[:-1]:
        table = table.setdefault(key, {})
    table[path[-1]] = value
    return spec


@pytest.mark.parametrize("path, value, message", [
    (("model", "library"), {"order": 40}, r"\[model.library\] order = 40 is out of range \(allowed: 1 to 8\); a polynomial"),
    (("model", "delay", "tau_min"), -0.1, r"tau_min = -0.1 is out of range \(allowed: at least 0\); a delay cannot"),
    (("fit", "lambdas"), {"min": 1e-6, "max": 1.0, "count": 10**6}, r"count = 1000000 is out of range \(allowed: 1 to 1000\)"),
    (("fit", "bootstrap"), {"samples": 10**7}, r"samples = 10000000 is out of range \(allowed: 2 to 10000\)"),
    (("fit", "bootstrap"), {"fraction": 1.5}, r"fraction = 1.5 is out of range \(allowed: at most 1\)"),
    (("fit", "n_jobs"), 0, r"n_jobs = 0 is no worker"),
    (("fit", "n_jobs"), 10**6, r"n_jobs = 1000000 is out of range \(allowed: -1 to 256\); -1 uses every core"),
    (("diagnose", "max_steps"), 10**9, r"max_steps = 1000000000 is out of range \(allowed: 1 to 20\)"),
    (("data", "train", "simulate", "seed"), -3, r"seed = -3 is out of range"),
    (("data", "train", "simulate", "noise"), {"output": -0.01}, r"output = -0.01 is out of range \(allowed: at least 0\)"),
    (("fit", "window"), 1e300, r"window = 1e\+300 is out of range"),
])
def test_an_out_of_range_key_names_itself_its_value_and_the_range(path, value, message):
    with pytest.raises(CvxidError, match=message):
        parse_problem(mutated(path, value), SPEC.parent).experiment("train")  # (simulated data: read when made)


def test_a_job_of_hours_is_refused_unless_asked_for():
    big = mutated(("fit", "lambdas"), {"min": 1e-6, "max": 1.0, "count": 1000})
    big["fit"]["bootstrap"] = {"samples": 1000}
    with pytest.raises(CvxidError, match=r"asks for 1,000,000 convex solves .* set allow_large = true"):
        parse_problem(big, SPEC.parent)
    big["fit"]["allow_large"] = True
    assert parse_problem(big, SPEC.parent).fit.bootstrap.samples == 1000


def leaves(table, prefix=()):
    for key, value in table.items():
        if isinstance(value, dict):
            yield from leaves(value, prefix + (key,))
        else:
            yield prefix + (key,)


LEAVES = sorted(leaves(raw()))
VALUES = st.one_of(
    st.none(), st.booleans(), st.integers(-10**12, 10**12),
    st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=12),
    st.lists(st.one_of(st.integers(-5, 5), st.text(max_size=6)), max_size=3),
    st.dictionaries(st.text(max_size=6), st.integers(-5, 5), max_size=2),
)


@settings(max_examples=EXAMPLES, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(path=st.sampled_from(LEAVES), value=VALUES)
def test_any_single_key_mutation_of_a_shipped_spec_reads_or_is_a_clear_error(path, value):
    spec = mutated(path, value)
    if value is None:  # TOML has no null: a missing key
        table = spec
        for key in path[:-1]:
            table = table[key]
        del table[path[-1]]
    try:
        parse_problem(spec, SPEC.parent).experiment("train")  # the spec, and the data it simulates
    except CvxidError as exc:
        assert str(exc) and "Traceback" not in str(exc)


TOML_VALUES = st.recursive(
    st.one_of(st.booleans(), st.integers(-10**6, 10**6), st.floats(), st.text(max_size=8)),
    lambda inner: st.one_of(st.lists(inner, max_size=3),
                            st.dictionaries(st.sampled_from(["model", "fit", "data", "train", "test", "simulate",
                                                             "library", "delay", "order", "terms", "x", "truth"]),
                                            inner, max_size=3)),
    max_leaves=12,
)


@settings(max_examples=EXAMPLES, deadline=None)
@given(document=st.dictionaries(st.sampled_from(["name", "model", "fit", "data", "truth", "diagnose", "other"]),
                                TOML_VALUES, max_size=5))
def test_any_document_reads_or_is_a_clear_error(document):
    try:
        parse_problem(document, SPEC.parent)
    except CvxidError as exc:
        assert str(exc)
