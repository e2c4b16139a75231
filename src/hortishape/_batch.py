"""Run one function over a batch of jobs, in this process or in worker processes.

Shared by the batch commands (synthetic populations, CT extraction,
registration) so that they order results, report progress and stop on a
failure the same way.
"""

from __future__ import annotations

import os
from concurrent.futures import ProcessPoolExecutor, as_completed
from typing import Callable, Iterable, Iterator, Sequence

from .errors import HortishapeError


def raise_failed(result) -> None:
    """``stop`` for :func:`run_jobs` with ``--strict``: raise on a result whose ``ok`` is false."""
    if not result.ok:
        raise HortishapeError(result.error or f"{result.source}: failed")


def run_jobs(
    fn: Callable,
    jobs: Sequence,
    *,
    n_jobs: int | None = None,
    progress: Callable[[Iterable], Iterable] | None = None,
    stop: Callable[[object], None] | None = None,
    initializer: Callable | None = None,
    initargs: tuple = (),
) -> list:
    """``[fn(job) for job in jobs]``, over ``n_jobs`` processes (default: all cores).

    ``progress`` wraps the iterator of finished jobs' results, in the order
    they finish (e.g. tqdm, or a reporter that describes each); ``stop`` is
    called with each result as it arrives and may raise to end the batch (jobs
    not started are cancelled); ``initializer(*initargs)`` prepares each worker
    process, or this process when the jobs run here (one job or ``n_jobs=1``).
    Results come in the order of ``jobs``.
    """
    results: list = [None] * len(jobs)
    wrap = progress or (lambda it: it)
    n_jobs = max(1, min(n_jobs or os.cpu_count() or 1, len(jobs) or 1))

    def finished(pairs: Iterable) -> Iterator:
        """Each result as it arrives, stored in order and checked by ``stop``."""
        for i, result in pairs:
            results[i] = result
            if stop is not None:
                stop(result)
            yield result

    if n_jobs == 1:
        if initializer is not None:
            initializer(*initargs)
        for _ in wrap(finished((i, fn(job)) for i, job in enumerate(jobs))):
            pass
        return results
    with ProcessPoolExecutor(max_workers=n_jobs, initializer=initializer, initargs=initargs) as pool:
        futures = {pool.submit(fn, job): i for i, job in enumerate(jobs)}
        try:
            for _ in wrap(finished((futures[f], f.result()) for f in as_completed(futures))):
                pass
        except BaseException:
            for f in futures:
                f.cancel()
            raise
    return results
