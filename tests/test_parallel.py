"""Parallel work on the engine a user picks (cvxid.parallel): the numbers do not depend on it."""

import sys

import numpy as np
import pytest

from cvxid.app.run import run
from cvxid.errors import CvxidError
from cvxid.parallel import engine
from cvxid.spec.load import parse_problem
from .conftest import cli_error
from .test_sensor import SIMULATED, spec_text


def _spec(tmp_path, **fit):
    """The sensor tests' delayed oscillator with a cubic stiffness, an order-3 library
    and a small bootstrap (2 jobs), ``fit`` keys added."""
    import tomllib

    raw = tomllib.loads(spec_text(SIMULATED))
    raw["truth"]["coefficients"]["x^3"] = 2.0
    raw["model"]["library"] = {"order": 3}
    raw["fit"] = {"lambdas": {"min": 1e-5, "max": 1e1, "count": 12},
                  "bootstrap": {"samples": 6, "fraction": 0.5, "seed": 3}, "n_jobs": 2, **fit}
    return parse_problem(raw, tmp_path)


@pytest.mark.slow
def test_a_bootstrap_on_a_dask_cluster_gives_the_serial_numbers(tmp_path):
    distributed = pytest.importorskip("dask.distributed")  # the [test] extra installs it
    serial = run(_spec(tmp_path, n_jobs=1))
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        spread = run(_spec(tmp_path, backend="dask", scheduler=cluster.scheduler_address))
        assert any("_one_sample" in prefix for prefix in cluster.scheduler.task_prefixes)  # ran there
    a, b = serial.bootstrap.coefficients, spread.bootstrap.coefficients
    assert a.shape == (6, len(serial.problem.names)) and a.notna().all().all()
    np.testing.assert_allclose(b.to_numpy(), a.to_numpy(), rtol=1e-9, atol=1e-12)
    # and the ensemble is a real one: the stiffness of the truth within 2 %, samples that differ
    assert abs(serial.physical["x"] - 6.0) < 0.12
    assert a["x"].std() > 0


def test_an_unknown_engine_is_named_with_the_choices(tmp_path, capsys):
    err = cli_error(tmp_path, capsys, spec_text(SIMULATED).replace('estimator = "lstsq"', 'backend = "spark"'))
    assert "[fit] backend must be one of loky, threading, dask, ray" in err and "spark" in err
    with pytest.raises(CvxidError, match="needs backend"):
        with engine("loky", "tcp://127.0.0.1:8786"):
            pass


def test_a_missing_dask_says_how_to_install_it(monkeypatch):
    monkeypatch.setitem(sys.modules, "dask.distributed", None)  # as if not installed
    with pytest.raises(CvxidError, match=r'pip install "cvxid\[distributed\]"'):
        with engine("dask"):
            pass


def test_an_unreachable_scheduler_is_a_clear_error():
    pytest.importorskip("dask.distributed")
    import dask

    with dask.config.set({"distributed.comm.timeouts.connect": "1s"}):
        with pytest.raises(CvxidError, match="cannot reach the dask scheduler at 'tcp://127.0.0.1:9'"):
            with engine("dask", "tcp://127.0.0.1:9"):
                pass


def test_a_sigterm_stops_the_command_and_its_worker_processes():
    """``kill`` (SIGTERM) of a held-out benchmark running two joblib workers: the command
    stops as on Ctrl-C (exit 130) and its workers end; before, the command did not exit
    within a minute and its workers ran on at full CPU."""
    import signal
    import subprocess
    import sys
    import time

    import psutil  # (with the test extra: dask.distributed needs it)
    command = [sys.executable, "-m", "cvxid.app.cli", "bench", "--heldout", "--seeds", "0:6", "--effects", "none",
               "--noises", "0.01", "--duration", "8", "--quiet"]
    process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        parent, workers, start = psutil.Process(process.pid), [], time.time()
        while len(workers) < 2 and time.time() - start < 60:
            time.sleep(0.5)
            workers = parent.children(recursive=True)
        time.sleep(2)  # the workers at work
        workers = parent.children(recursive=True)
        assert workers, "no worker process started"
        process.send_signal(signal.SIGTERM)
        _, err = process.communicate(timeout=60)
    finally:
        process.kill()
    assert process.returncode == 130 and "cvxid: interrupted" in err
    gone, alive = psutil.wait_procs(workers, timeout=20)
    assert not [p for p in alive if p.status() != psutil.STATUS_ZOMBIE], alive
