"""The batch runner: results in order, progress sees each finished result, --strict stops."""

import pytest

from hortishape._batch import raise_failed, run_jobs
from hortishape.errors import HortishapeError
from hortishape.pipeline import InstanceResult


def _square(x):
    return x * x


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
