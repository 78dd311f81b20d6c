"""``cvxid bench --speed``: the jobs' wall seconds in fresh processes, beside another copy
of cvxid (docs/benchmarks.md, the README's speed table)."""

from pathlib import Path

import pytest

from cvxid import CvxidError
from cvxid.tools.speed import speed

SPEC = """name = "speed_check"
[truth]
mass = 1.0
coefficients = { "x'" = 0.5, "x" = 6.0 }
[data.train.simulate]
duration = 4.0
dt = 1e-3
x0 = 0.3
seed = 1
noise = { output = 0.001, input = 0.0 }
input = [ { kind = "sine", amplitude = 3.0, omega = 1.9 }, { kind = "sine", amplitude = 2.0, omega = 4.7 } ]
[model.library]
terms = ["x", "x'"]
"""


STUB = """import json, sys
from pathlib import Path


def command():
    spec = sys.argv[sys.argv.index("run") + 1]
    if "missing" in spec:
        print("cvxid: error: the stub fails", file=sys.stderr)
        return 2
    out = Path(sys.argv[sys.argv.index("--out") + 1])
    out.mkdir(parents=True, exist_ok=True)
    (out / "result.json").write_text(json.dumps({"physical": {"m": 2.0, "x": 6.0, "x'": 0.5}}))
    return 0
"""


def _copy(folder: Path, cli: str) -> Path:
    """A stand-in copy of cvxid in ``folder``: its ``cvxid.app.cli`` is ``cli``."""
    (folder / "cvxid" / "app").mkdir(parents=True)
    (folder / "cvxid" / "__init__.py").write_text("")
    (folder / "cvxid" / "app" / "__init__.py").write_text("")
    (folder / "cvxid" / "app" / "cli.py").write_text(cli)
    return folder


def test_another_copy_is_timed_beside_this_one_its_parameters_compared_and_a_failing_job_is_its_row(
        tmp_path, monkeypatch):
    """A stand-in copy (given by a relative path, as a user types it) that reports the
    mass 2 for this copy's 1.0001: its row says the parameters differ by a half; a job
    whose spec names a missing file fails in both copies, its rows say why, and the
    benchmark goes on to the next job."""
    (tmp_path / "speed_check.toml").write_text(SPEC)
    (tmp_path / "missing.toml").write_text('[data.train]\nfile = "missing.csv"\n[model.library]\nterms = ["x"]\n')
    _copy(tmp_path / "other", STUB)
    monkeypatch.chdir(tmp_path)
    frame = speed(["missing.toml", "speed_check.toml"], repeat=1, against="other", cold=False)
    assert list(zip(frame["job"], frame["version"])) == [("missing.toml", "this"), ("missing.toml", "against"),
                                                          ("speed_check.toml", "this"), ("speed_check.toml", "against")]
    failed, ran = frame.iloc[:2], frame.iloc[2:]
    assert "data file not found" in failed["error"].iloc[0] and "the stub fails" in failed["error"].iloc[1]
    assert failed["warm s median"].isna().all() and (failed["warm runs"] == 0).all()
    assert (ran["error"] == "").all() and (ran["warm runs"] == 1).all()
    assert ran["parameters differ"].iloc[1] == pytest.approx(0.5, abs=1e-3)
    assert ran["warm s min"].iloc[0] > 0.3  # (a fresh Python importing cvxid takes about a second)


def test_speed_says_what_is_wrong_with_its_jobs_and_copies(tmp_path, capsys):
    with pytest.raises(CvxidError, match=r"--against .*imports cvxid from .*give the folder that holds another copy"):
        speed(["hidden_friction"], repeat=1, against=tmp_path, cold=False)
    older = _copy(tmp_path / "older", "def main():\n    return 0\n")
    with pytest.raises(CvxidError, match=r"has no console entry cvxid.app.cli.command .*time it against a newer copy"):
        speed(["hidden_friction"], repeat=1, against=older, cold=False)
    with pytest.raises(CvxidError, match="--speed names hidden_friction.toml twice"):
        speed(["hidden_friction", "hidden_friction.toml"], repeat=1, cold=False)
    from cvxid.app.cli import main

    for argv, said in ((["--speed", "hidden_friction", "--repeat", "0"], "--repeat must be at least 1"),
                       (["--speed", ","], "--speed needs at least one job"),
                       (["--heldout", "--repeat", "3"], "--repeat and --against are for cvxid bench --speed"),
                       (["--repeat", "3"], "--repeat and --against are for cvxid bench --speed"),
                       (["--speed", "no_such_problem"], "not a shipped problem")):
        assert main(["bench", *argv]) == 2
        assert said in capsys.readouterr().err, argv
