"""Parallel work on an engine the user picks, through joblib.

cvxid runs no pool of its own: bootstrap samples, the order search and the held-out
benchmark are joblib ``Parallel`` calls (the stepwise search's candidate fits too, when it
is called with ``n_jobs`` > 1), and :func:`engine`
chooses where they run for the duration of a ``with`` block:

* ``"loky"`` (joblib's default): worker processes on this machine, ``n_jobs`` of them;
* ``"threading"``: threads of this process;
* ``"dask"``: a `dask.distributed <https://distributed.dask.org>`_ cluster, at the
  scheduler ``address`` (``"tcp://host:8786"``), or a local cluster started for the block
  when no address is given (a worker a core, one thread each); every core of the cluster
  is used (``pip install
  "cvxid[distributed]"`` brings dask);
* ``"ray"``: a `Ray <https://www.ray.io>`_ cluster (``ray.init(address)``, joblib backend
  ``ray.util.joblib``; Ray is installed by the user).

The numbers do not depend on the engine: each task carries its own data and seed.

In a spec, ``[fit] backend = "dask"`` and ``[fit] scheduler = "tcp://host:8786"``; on the
command line ``cvxid run SPEC --backend dask --scheduler tcp://host:8786`` (also
``cvxid bench --heldout``).
"""

from __future__ import annotations

import functools
import os
from contextlib import contextmanager
from typing import Callable, Iterator, TypeVar

from joblib import parallel_config
from threadpoolctl import ThreadpoolController

from cvxid.errors import CvxidError

BACKENDS = ("loky", "threading", "dask", "ray")
ONE_THREAD = {name: "1" for name in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS",
                                     "MKL_NUM_THREADS")}
"""The environment of a local dask cluster's workers: one worker a core, one thread each
(the compiled simulations and BLAS would otherwise start a thread a core in every worker
and contend; joblib's own processes limit them the same way)."""


def check_backend(backend: str, scheduler: str | None = None, where: str = "backend") -> None:
    """A clear error for an engine cvxid does not know, or a scheduler it cannot use."""
    if backend not in BACKENDS:
        raise CvxidError(f"{where} must be one of {', '.join(BACKENDS)}, got '{backend}'")
    if scheduler is not None and backend not in ("dask", "ray"):
        raise CvxidError(f"a scheduler address ('{scheduler}') needs backend = \"dask\" or \"ray\", "
                         f"not '{backend}'")


@contextmanager
def engine(backend: str = "loky", scheduler: str | None = None) -> Iterator[None]:
    """Run every joblib ``Parallel`` call inside the block on ``backend`` (see the module
    docstring); ``scheduler``: the cluster's address (dask, ray)."""
    check_backend(backend, scheduler)
    if backend == "loky":
        yield
    elif backend == "threading":
        with parallel_config(backend="threading"):
            yield
    elif backend == "dask":
        try:
            from dask.distributed import Client
        except ImportError as exc:
            raise CvxidError('backend = "dask" needs dask.distributed: pip install "cvxid[distributed]"') from exc
        try:
            client = Client(scheduler) if scheduler else Client(
                n_workers=os.cpu_count() or 1, threads_per_worker=1, env=ONE_THREAD, dashboard_address=None)
        except (OSError, TimeoutError) as exc:
            raise CvxidError(f"cannot reach the dask scheduler at '{scheduler}' ({exc}); start one "
                             "(`dask scheduler`) or leave scheduler out for a local cluster") from exc
        try:
            with parallel_config(backend="dask"):
                yield
        finally:
            client.close()
    else:
        try:
            import ray
            from ray.util.joblib import register_ray
        except ImportError as exc:
            raise CvxidError('backend = "ray" needs Ray: pip install "ray[default]"') from exc
        started = not ray.is_initialized()
        ray.init(address=scheduler, ignore_reinit_error=True)
        register_ray()
        try:
            with parallel_config(backend="ray"):
                yield
        finally:
            if started:
                ray.shutdown()


F = TypeVar("F", bound=Callable)


@functools.cache
def _threadpools() -> ThreadpoolController:
    return ThreadpoolController()


def one_blas_thread(function: F) -> F:
    """Run ``function`` with the BLAS library (OpenBLAS, MKL) on one thread.

    The output-error fits alternate small linear algebra (a singular value decomposition
    of a samples × parameters Jacobian each iteration) with the compiled simulations, whose
    batch runs on a thread a core.  After each call BLAS's own threads keep spinning for a
    while and take the cores from the simulation: on the 2-core machine the
    ``hidden_friction`` polish took 2.7 times as long with two BLAS threads as with one.
    Small matrices gain nothing from BLAS threads, so they are limited to one for the call
    (:mod:`threadpoolctl`; nested calls within a thread are free).  The limit is the
    process's: calls that overlap in several threads (joblib's ``"threading"`` engine) may
    leave BLAS on one thread after them, which changes speed, never results."""

    @functools.wraps(function)
    def limited(*args, **kwargs):
        with _threadpools().limit(limits=1, user_api="blas"):
            return function(*args, **kwargs)

    return limited
