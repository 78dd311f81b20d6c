"""BLAS on one thread while the output-error fits run (cvxid.parallel.one_blas_thread)."""

from threadpoolctl import threadpool_info, threadpool_limits

from cvxid.parallel import one_blas_thread


def _blas_threads() -> list[int]:
    return [pool["num_threads"] for pool in threadpool_info() if pool["user_api"] == "blas"]


def test_blas_runs_on_one_thread_inside_and_as_before_after():
    @one_blas_thread
    def inside():
        return _blas_threads()

    with threadpool_limits(2, "blas"):  # two threads before, whatever the machine's setting
        before = _blas_threads()
        assert max(before) == 2, "numpy's BLAS is not seen by threadpoolctl"
        assert inside() == [1] * len(before)
        assert _blas_threads() == before
