"""Builds on a Dask cluster: a scheduler and workers started as users start them, one killed mid-build.

Also the cache of registrations by content, shared between builds.
"""

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("distributed")

from hortishape import synth  # noqa: E402
from hortishape._batch import run_jobs  # noqa: E402
from hortishape.cli import main  # noqa: E402
from hortishape.errors import HortishapeError  # noqa: E402
from hortishape.model import ShapeModel  # noqa: E402
from hortishape.pipeline import build_model  # noqa: E402
from hortishape.registration import RegistrationConfig  # noqa: E402

CONFIG = RegistrationConfig(n_iterations=12)
N_POINTS = 1500


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _dask(*args, log):
    """A ``dask`` command in its own process group (so killing it takes its nanny and worker together)."""
    exe = shutil.which("dask", path=str(Path(sys.executable).parent)) or shutil.which("dask")
    cmd = [exe, *args] if exe else [sys.executable, "-m", "dask", *args]
    env = dict(os.environ, OMP_NUM_THREADS="1", PYTHONPATH=os.pathsep.join(sys.path))
    return subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, env=env, start_new_session=True)


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    """``(address, [worker processes])``: a scheduler and two one-thread workers, separate processes."""
    from distributed import Client

    log = open(tmp_path_factory.mktemp("dask") / "dask.log", "w")
    port = _free_port()
    address = f"tcp://127.0.0.1:{port}"
    procs = [_dask("scheduler", "--host", "127.0.0.1", "--port", str(port), "--dashboard-address", ":0", log=log)]
    for name in ("w1", "w2"):
        procs.append(_dask("worker", address, "--nthreads", "1", "--name", name, "--dashboard-address", ":0",
                           log=log))
    try:
        with Client(address, timeout="60s") as client:
            client.wait_for_workers(2, timeout=120)
        yield address, procs[1:]
    finally:
        for p in procs:
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGTERM)
        for p in procs:
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
        log.close()


@pytest.fixture(scope="module")
def scans(tmp_path_factory):
    folder = tmp_path_factory.mktemp("scans")
    synth.write_population("apple", 10, folder, random_state=21, pose="random", n_vertices=4000, n_jobs=2)
    return folder


@pytest.fixture(scope="module")
def local(scans, tmp_path_factory):
    return build_model(scans, tmp_path_factory.mktemp("local"), n_points=N_POINTS, config=CONFIG, n_jobs=2)


def _square_plus(x):
    from hortishape import _batch

    return x * x + _batch._INITIALIZED.get("offset", 0)


def _set_offset(offset):
    from hortishape import _batch

    _batch._INITIALIZED["offset"] = offset


def _kill_own_group_if_busy(dask_worker):
    if dask_worker.state.executing:
        os.killpg(os.getpgid(0), signal.SIGKILL)
    return False


@pytest.mark.slow
def test_run_jobs_on_the_cluster(cluster):
    address, _ = cluster
    seen = []
    got = run_jobs(_square_plus, list(range(12)), scheduler=address, initializer=_set_offset, initargs=(100,),
                   collect=lambda i, r, attempts: seen.append((i, attempts)) or r)
    assert got == [x * x + 100 for x in range(12)]  # in order, every worker prepared
    assert sorted(seen) == [(i, 1) for i in range(12)]


@pytest.mark.slow
def test_a_worker_killed_mid_build_costs_only_its_task(cluster, scans, local, tmp_path):
    address, workers = cluster
    out = tmp_path / "cluster"
    result = {}

    def build():
        result["build"] = build_model(scans, out, n_points=N_POINTS, config=CONFIG, scheduler=address)

    thread = threading.Thread(target=build)
    thread.start()
    # once the first pass is under way, the second worker kills itself (and its nanny) while it runs a task:
    # deciding and killing in the worker's event loop means the scheduler cannot have its result yet
    deadline = time.time() + 300
    # (one result in: the registrations take a fraction of a second each, and after two the first
    # pass could be over before the client below is connected)
    while not any((out / "work" / "first-pass").glob("*.json")) and time.time() < deadline:
        time.sleep(0.05)
    from distributed import Client

    with Client(address, timeout="60s") as client:
        second = next(a for a, w in client.scheduler_info()["workers"].items() if w["name"] == "w2")
        while workers[1].poll() is None and time.time() < deadline:
            try:
                client.run(_kill_own_group_if_busy, workers=[second], on_error="return")
            except Exception:  # the worker died under the call
                pass
            time.sleep(0.02)
    assert workers[1].wait(timeout=60) is not None
    thread.join(timeout=600)
    assert not thread.is_alive() and "build" in result
    built = result["build"]
    assert built.names == local.names and built.skipped == ()
    # (in either pass or the orientation check: the kill lands where the worker is)
    retried = {(name, k) for name, k, _ in built.retried}
    assert retried, "the killed worker was running a registration: it must have been run again"
    assert retried >= {(r.name, k + 1) for k, rs in enumerate((built.first_pass, built.second_pass))
                       for r in rs if r.attempts > 1}
    summary = json.loads((out / "summary.json").read_text())
    assert {(r["name"], r["pass"]) for r in summary["retried"]} == retried
    # the same model as the local build's
    a, b = ShapeModel.load(local.model_path), ShapeModel.load(built.model_path)
    np.testing.assert_allclose(b.mean_, a.mean_, atol=1e-9)
    np.testing.assert_allclose(b.explained_variance_, a.explained_variance_, rtol=1e-9)


@pytest.mark.slow
def test_the_cache_serves_a_second_build_and_only_the_same_settings(scans, local, tmp_path):
    cache = tmp_path / "cache"
    first = build_model(scans, tmp_path / "a", n_points=N_POINTS, config=CONFIG, n_jobs=2, cache=cache)
    assert all(r.attempts == 1 for r in first.second_pass)
    # another output folder, and the scans renamed: every registration comes from the cache
    renamed = tmp_path / "renamed"
    renamed.mkdir()
    for p in scans.glob("*.ply"):
        shutil.copy(p, renamed / f"x_{p.name}")
    again = build_model(renamed, tmp_path / "b", n_points=N_POINTS, config=CONFIG, n_jobs=2, cache=cache)
    assert all(r.resumed and r.attempts == 0 for r in (*again.first_pass, *again.second_pass))
    np.testing.assert_array_equal(ShapeModel.load(again.model_path).mean_, ShapeModel.load(first.model_path).mean_)
    np.testing.assert_allclose(ShapeModel.load(first.model_path).mean_, ShapeModel.load(local.model_path).mean_,
                               atol=1e-9)
    # a changed setting is not served from the cache
    other = build_model(renamed, tmp_path / "c", n_points=N_POINTS, config=RegistrationConfig(n_iterations=11),
                        n_jobs=2, cache=cache)
    assert not any(r.resumed for r in other.first_pass)


@pytest.mark.slow
def test_an_unreachable_scheduler_is_one_line(scans, tmp_path, capsys, monkeypatch):
    from hortishape import _batch

    monkeypatch.setattr(_batch, "CONNECT_TIMEOUT_S", 2)
    port = _free_port()
    assert main(["build", str(scans), "--out", str(tmp_path / "m"), "--points", "500",
                 "--scheduler", f"tcp://127.0.0.1:{port}"]) == 1
    err = capsys.readouterr().err
    assert f"cannot reach the Dask scheduler at tcp://127.0.0.1:{port}" in err and err.count("\n") == 1
    with pytest.raises(HortishapeError, match="cannot reach"):
        run_jobs(_square_plus, [1], scheduler=f"tcp://127.0.0.1:{port}")
