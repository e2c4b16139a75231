"""Run one function over a batch of jobs: in this process, in worker processes, or on a Dask cluster.

Shared by the batch commands (synthetic populations, CT extraction,
registration) so that they order results, report progress and stop on a
failure the same way.

On a cluster (``scheduler``: the address of a ``dask scheduler``), Dask does
the scheduling, the data movement and the retries: a task whose worker dies
is run again on another worker. hortishape counts how often each task was
started (an event each task logs on its worker), so a batch can say what was
retried.
"""

from __future__ import annotations

import os
import uuid
from concurrent.futures import ProcessPoolExecutor, as_completed
from typing import Callable, Iterable, Iterator, Sequence

from .errors import HortishapeError

#: Tasks in flight on a cluster per worker thread: enough to keep every
#: worker busy, few enough that the jobs' data (a scan's bytes) are not all
#: held at once.
CLUSTER_TASKS_PER_THREAD = 2
#: How long to try to reach a scheduler before giving up, seconds.
CONNECT_TIMEOUT_S = 20


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
    collect: Callable[[int, object, int], object] | None = None,
    scheduler=None,
    ship: Callable[[object], object] | None = None,
    done: Sequence = (),
) -> list:
    """``[fn(job) for job in jobs]``, over ``n_jobs`` processes (default: all cores) or a Dask cluster.

    ``progress`` wraps the iterator of finished jobs' results, in the order
    they finish (e.g. tqdm, or a reporter that describes each); ``stop`` is
    called with each result as it arrives and may raise to end the batch (jobs
    not started are cancelled); ``initializer(*initargs)`` prepares each worker
    process, or this process when the jobs run here (one job or ``n_jobs=1``).
    ``collect(index, result, attempts)`` is called here with each result as
    it arrives (to write it, say) and returns what to keep; ``attempts`` is how
    often the job was started (more than 1 when a cluster lost a worker).

    With ``scheduler`` (an address such as ``tcp://host:8786``, or a
    ``distributed.Client``), the jobs run as tasks on that cluster:
    ``initargs`` are sent once to every worker, and ``ship(job)``, if given,
    turns a job into what is sent (e.g. adds a file's bytes) just before it is
    submitted. ``done`` are results of the batch found before (resumed): they
    pass through ``progress`` first, so it counts the whole batch. Results
    come in the order of ``jobs``.
    """
    results: list = [None] * len(jobs)
    wrap = progress or (lambda it: it)
    keep = collect or (lambda i, result, attempts: result)

    def finished(triples: Iterable) -> Iterator:
        """Each result as it arrives, stored in order and checked by ``stop``."""
        yield from done
        for i, result, attempts in triples:
            results[i] = result = keep(i, result, attempts)
            if stop is not None:
                stop(result)
            yield result

    if scheduler is not None:
        for _ in wrap(finished(_on_cluster(scheduler, fn, jobs, initializer, initargs, ship))):
            pass
        return results
    n_jobs = max(1, min(n_jobs or os.cpu_count() or 1, len(jobs) or 1))
    if n_jobs == 1 or not jobs:
        from threadpoolctl import threadpool_limits

        # on one BLAS thread, as a worker (``_start_worker``): the results do not depend on n_jobs
        with threadpool_limits(limits=1):
            if initializer is not None and jobs:
                initializer(*initargs)
            for _ in wrap(finished((i, fn(job), 1) for i, job in enumerate(jobs))):
                pass
        return results
    with ProcessPoolExecutor(max_workers=n_jobs, initializer=_start_worker, initargs=(initializer, initargs)) as pool:
        futures = {pool.submit(fn, job): i for i, job in enumerate(jobs)}
        try:
            for _ in wrap(finished((futures[f], f.result(), 1) for f in as_completed(futures))):
                pass
        except BaseException:
            for f in futures:
                f.cancel()
            raise
    return results


def _start_worker(initializer: Callable | None, initargs: tuple) -> None:
    """Prepare a local worker process: one BLAS thread and one ray thread, then the batch's own initializer.

    Each worker has a core; BLAS threads would fight the other workers for
    them. It also makes a local worker compute as a Dask worker does (Dask's
    nanny starts its workers with one BLAS thread): with several, BLAS may
    sum in another order, and the registrations differ in the last digits,
    which their iterations can grow to hundredths of a millimetre (seen with
    numpy 1.26's OpenBLAS).
    """
    from threadpoolctl import threadpool_limits

    from .registration import correspondences

    threadpool_limits(limits=1)
    correspondences.RAY_THREADS = 1  # the ray queries' threads too (``RAY_THREAD_MIN``)
    if initializer is not None:
        initializer(*initargs)


# --------------------------------------------------------------------------
# a Dask cluster
# --------------------------------------------------------------------------

# The initializer token each worker process last ran (workers are long-lived and run many batches).
_INITIALIZED: dict = {}


def _cluster_task(fn, initializer, initargs, token: str, topic: str, index: int, job):
    """What runs on a worker: note the attempt, prepare the worker once per batch, run the job."""
    from distributed import get_worker

    try:
        get_worker().log_event(topic, index)
    except ValueError:  # not on a worker (a synchronous test scheduler): nothing to count
        pass
    else:
        from .registration import correspondences

        correspondences.RAY_THREADS = 1  # a worker runs one task per core, as a local one (_start_worker)
    if initializer is not None and _INITIALIZED.get("token") != token:
        initializer(*initargs)
        _INITIALIZED["token"] = token
    return fn(job)


def connect(scheduler):
    """A ``distributed.Client`` for ``scheduler`` (an address), or ``scheduler`` itself if it is one.

    Raises
    ------
    HortishapeError
        If dask.distributed is not installed or the scheduler cannot be reached.
    """
    try:
        from distributed import Client
    except ImportError:
        raise HortishapeError("--scheduler needs dask.distributed: pip install 'hortishape[cluster]'") from None
    if isinstance(scheduler, Client):
        return scheduler
    try:
        return Client(scheduler, timeout=f"{CONNECT_TIMEOUT_S}s")
    except (OSError, TimeoutError) as exc:
        raise HortishapeError(f"cannot reach the Dask scheduler at {scheduler} ({exc})") from None


def _on_cluster(scheduler, fn, jobs, initializer, initargs, ship) -> Iterator:
    from distributed import as_completed as cluster_completed

    client = connect(scheduler)
    own = client is not scheduler
    token = uuid.uuid4().hex
    topic = f"hortishape-attempt-{token}"
    try:
        state = client.scatter(initargs, broadcast=True) if initializer is not None else None
        threads = sum(client.nthreads().values()) or 1
        window = max(4, CLUSTER_TASKS_PER_THREAD * threads)
        pending = iter(enumerate(jobs))
        index_of = {}

        def submit_next(queue) -> None:
            for i, job in pending:
                future = client.submit(_cluster_task, fn, initializer, state, token, topic, i,
                                       ship(job) if ship else job, key=f"hortishape-{token}-{i}", pure=False)
                index_of[future.key] = i
                queue.add(future)
                return

        queue = cluster_completed([])
        for _ in range(min(window, len(jobs))):
            submit_next(queue)
        try:
            for future in queue:
                i = index_of.pop(future.key)
                try:
                    result = future.result()
                except Exception as exc:  # the cluster gave up on the task (its workers kept dying)
                    raise HortishapeError(f"the cluster lost job {i + 1} of {len(jobs)}: "
                                          f"{type(exc).__name__}: {exc}") from None
                future.release()
                submit_next(queue)
                attempts = sum(1 for _, msg in client.get_events(topic) if msg == i) or 1
                yield i, result, attempts
        except BaseException:
            client.cancel(list(queue.futures))
            raise
    finally:
        if own:
            client.close()
