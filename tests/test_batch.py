"""The batch runner: results in order, progress sees each finished result, --strict stops."""

import pytest

from hortishape._batch import raise_failed, run_jobs
from hortishape.errors import HortishapeError
from hortishape.pipeline import InstanceResult


def _square(x):
    return x * x


def _blas_threads(_):
    from threadpoolctl import threadpool_info

    return max(i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas")


def _result(name):
    return InstanceResult(name=name, source=f"{name}.ply", ok=name != "bad", error="broken" if name == "bad" else None)


@pytest.mark.parametrize("n_jobs", [1, 2])
def test_results_in_order_and_progress_sees_finished_results(n_jobs):
    seen = []

    def progress(iterable):
        for item in iterable:
            seen.append(item)
            yield item

    assert run_jobs(_square, [3, 1, 2], n_jobs=n_jobs, progress=progress) == [9, 1, 4]
    assert sorted(seen) == [1, 4, 9]  # the results, not the jobs or futures


@pytest.mark.parametrize("n_jobs", [1, 2])
def test_strict_stops_at_a_failed_result(n_jobs):
    with pytest.raises(HortishapeError, match="bad.ply|broken"):
        run_jobs(_result, ["a", "bad", "c"], n_jobs=n_jobs, stop=raise_failed)
    assert [r.ok for r in run_jobs(_result, ["a", "bad"], n_jobs=n_jobs)] == [True, False]


@pytest.mark.parametrize("n_jobs", [1, 2])
def test_jobs_run_on_one_blas_thread_wherever_they_run(n_jobs):
    # with more, BLAS may sum in another order: a batch's results would depend on n_jobs (the
    # registrations of a single process on two threads and a worker's on one: 3e-14 mm apart)
    assert run_jobs(_blas_threads, [0, 1], n_jobs=n_jobs) == [1, 1]
