"""Benchmark of builds that grow: a local Dask cluster of worker processes, 50 to 400 scans and beyond.

For each population size N (synthetic apples, CT-like surfaces of about 8,000
vertices, random poses, seed 1), it builds the model with ``hortishape build
--scheduler`` on a cluster of separate processes started here as a user starts
them (``dask scheduler``, ``dask worker --nthreads 1``; restarted before each
size so their peak memory is that size's), and prints:

- seconds per instance (wall time of the build over N) and the build's stages;
- the peak memory (RSS) of each worker and of the process that ran the build
  (the workers run without Dask's statistical profiler unless
  ``--dask-profile``: its history grows them for their first 1,000 seconds);
- with ``--compare-upto M``: for N <= M, the same build on local processes,
  and how far apart the two models are (mean: largest vertex distance, mm;
  variances: largest relative difference);
- with ``--kill N``: N scans are built a second time with one worker killed
  when half the first pass is done; the build must finish, say what was
  retried, and give the same model.

Then it fits time and memory against N (least squares) and prints the
figures for 1,000 scans extrapolated from the slope, with the command that
measures them on a machine that has the time.

With ``--pca N``, it only times the model's PCA (:meth:`ShapeModel.fit`) on
N random shapes of ``--points`` points, with every mode and with 20, and
prints its peak memory beyond the shapes (tracemalloc).

Run::

    python benchmarks/scale.py                                  # 50 100 200 400, 2 workers
    python benchmarks/scale.py --sizes 50 100 --compare-upto 100 --kill 100
    python benchmarks/scale.py --sizes 1000 --workers 16        # a larger machine
    python benchmarks/scale.py --pca 1000                       # the PCA alone
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _dask(*args, log, profile: bool = True):
    exe = shutil.which("dask", path=str(Path(sys.executable).parent)) or shutil.which("dask")
    env = dict(os.environ, OMP_NUM_THREADS="1", PYTHONPATH=os.pathsep.join(sys.path))
    if not profile:
        env["DASK_DISTRIBUTED__WORKER__PROFILE__ENABLED"] = "False"
    return subprocess.Popen([exe, *args], stdout=log, stderr=subprocess.STDOUT, env=env, start_new_session=True)


class Cluster:
    """A scheduler and ``n`` one-thread workers, each its own process group.

    ``profile=False`` starts the workers without Dask's statistical profiler
    (``DASK_DISTRIBUTED__WORKER__PROFILE__ENABLED=False``): it keeps a
    snapshot of the running tasks' stacks for each second of the last
    ``distributed.admin.low-level-log-length`` (1,000), which with tasks a
    second long grew each worker by about 0.3 MB per task until the history
    was full.
    """

    def __init__(self, n_workers: int, log_path: Path, *, profile: bool = True):
        from distributed import Client

        self.log = open(log_path, "a")
        port = _free_port()
        self.address = f"tcp://127.0.0.1:{port}"
        self.scheduler = _dask("scheduler", "--host", "127.0.0.1", "--port", str(port), "--dashboard-address", ":0",
                               log=self.log)
        self.workers = [_dask("worker", self.address, "--nthreads", "1", "--name", f"w{i}",
                              "--dashboard-address", ":0", log=self.log, profile=profile) for i in range(n_workers)]
        self.client = Client(self.address, timeout="60s")
        self.client.wait_for_workers(n_workers, timeout=120)

    def restart(self) -> None:
        self.client.restart(wait_for_workers=True)

    def peak_rss_mb(self) -> list[float]:
        """Each worker process's peak RSS since it started, MB."""
        def peak():
            import resource

            return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0

        return sorted(self.client.run(peak).values())

    def close(self) -> None:
        self.client.close()
        for p in [*self.workers, self.scheduler]:
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGTERM)
        for p in [*self.workers, self.scheduler]:
            try:
                p.wait(timeout=30)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
        self.log.close()


def one_build(scans: Path, out: Path, points: int, scheduler: str | None, kill_pid: int | None) -> dict:
    """Build in this process; with ``kill_pid``, kill that process group when half the first pass is done."""
    from hortishape.pipeline import build_model

    n = len(list(scans.glob("*.ply")))
    if kill_pid:
        def killer():
            folder = out / "work" / "first-pass"
            while len(list(folder.glob("*.json"))) < n // 2:
                time.sleep(0.05)
            os.killpg(kill_pid, signal.SIGKILL)

        threading.Thread(target=killer, daemon=True).start()
    t = time.perf_counter()
    result = build_model(scans, out, n_points=points, scheduler=scheduler, n_jobs=None)
    seconds = time.perf_counter() - t
    retried = [(r.name, r.attempts) for r in (*result.first_pass, *result.second_pass) if r.attempts > 1]
    return {"seconds": seconds, "n": len(result.names), "skipped": len(result.skipped), "retried": retried,
            "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
            "model": str(result.model_path)}


def in_child(scans: Path, out: Path, points: int, scheduler: str | None, kill_pid: int | None = None) -> dict:
    """:func:`one_build` in a fresh process, so its peak memory is its own; ``out`` is emptied first."""
    shutil.rmtree(out, ignore_errors=True)
    cmd = [sys.executable, __file__, "--one", str(scans), str(out), str(points), scheduler or "-", str(kill_pid or 0)]
    done = subprocess.run(cmd, capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f"build failed:\n{done.stderr[-3000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def compare(a_path: str, b_path: str) -> tuple[float, float]:
    from hortishape.model import ShapeModel

    a, b = ShapeModel.load(a_path), ShapeModel.load(b_path)
    mean = float(np.linalg.norm(a.mean_ - b.mean_, axis=1).max())
    k = min(a.n_components_, b.n_components_)
    var = float(np.max(np.abs(a.explained_variance_[:k] / b.explained_variance_[:k] - 1.0)))
    return mean, var


def pca_cost(n_shapes: int, n_points: int) -> None:
    """Seconds and peak memory beyond the shapes of :meth:`ShapeModel.fit`, every mode and 20."""
    import tracemalloc

    from hortishape.model import ShapeModel

    rng = np.random.default_rng(0)
    base = rng.normal(size=(n_points, 3)) * 40.0
    modes = rng.normal(size=(30, 3 * n_points)) * np.linspace(3.0, 0.1, 30)[:, None] / np.sqrt(n_points)
    shapes = base + (rng.normal(size=(n_shapes, 30)) @ modes).reshape(n_shapes, n_points, 3)
    shapes += 0.01 * rng.normal(size=shapes.shape)
    print(f"PCA of {n_shapes} shapes of {n_points} points ({shapes.nbytes / 1e6:.0f} MB):")
    for k in (None, 20):
        tracemalloc.start()
        t = time.perf_counter()
        model = ShapeModel(n_components=k).fit(shapes)
        seconds = time.perf_counter() - t
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        print(f"  {'every mode' if k is None else f'{k} modes':>10}: {seconds:6.2f} s, peak {peak / 1e6:5.0f} MB "
              f"beyond the shapes (the modes kept: {model.components_.nbytes / 1e6:.0f} MB)")


def main(argv=None) -> int:
    if argv is None and len(sys.argv) > 1 and sys.argv[1] == "--one":
        _, _, scans, out, points, scheduler, kill = sys.argv
        print(json.dumps(one_build(Path(scans), Path(out), int(points), None if scheduler == "-" else scheduler,
                                   int(kill) or None)))
        return 0
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", type=int, nargs="+", default=[50, 100, 200, 400])
    ap.add_argument("--points", type=int, default=5000, help="vertices of the reference")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--compare-upto", type=int, default=100, metavar="M",
                    help="also build on local processes for N <= M and compare the models")
    ap.add_argument("--kill", type=int, default=None, metavar="N",
                    help="build N scans (one of --sizes) again with a worker killed half-way through the first pass")
    ap.add_argument("--work", type=Path, default=None, help="scratch folder (default: a temporary one)")
    ap.add_argument("--dask-profile", action="store_true",
                    help="keep Dask's statistical profiler on in the workers (as `dask worker` starts them)")
    ap.add_argument("--pca", type=int, default=None, metavar="N",
                    help="only time the PCA of N random shapes of --points points")
    args = ap.parse_args(argv)
    if args.pca:
        pca_cost(args.pca, args.points)
        return 0

    from hortishape import synth

    work = args.work or Path(tempfile.mkdtemp(prefix="hortishape-scale-"))
    work.mkdir(parents=True, exist_ok=True)
    scans_all = work / "scans"
    n_max = max(args.sizes)
    if len(list(scans_all.glob("*.ply"))) < n_max:
        t = time.perf_counter()
        synth.write_population("apple", n_max, scans_all, random_state=1, pose="random", n_vertices=8000)
        print(f"made {n_max} synthetic apples in {time.perf_counter() - t:.0f} s ({scans_all})")
    cluster = Cluster(args.workers, work / "dask.log", profile=args.dask_profile)
    rows = []
    try:
        print(f"{'N':>5} {'s/instance':>10} {'build s':>8} {'worker peak MB':>16} {'build process MB':>17}"
              f" {'vs local: mean mm':>18} {'variances':>10}")
        for n in sorted(args.sizes):
            scans = work / f"scans-{n}"
            if not scans.is_dir():
                scans.mkdir()
                for p in sorted(scans_all.glob("*.ply"))[:n]:
                    os.link(p, scans / p.name)
            cluster.restart()
            got = in_child(scans, work / f"cluster-{n}", args.points, cluster.address)
            workers = cluster.peak_rss_mb()
            cmp = "", ""
            if n <= args.compare_upto:
                local = in_child(scans, work / f"local-{n}", args.points, None)
                mean, var = compare(got["model"], local["model"])
                cmp = f"{mean:.2e}", f"{100 * var:.2e} %"
            rows.append((n, got["seconds"], max(workers), got["peak_rss_mb"]))
            print(f"{n:>5} {got['seconds'] / n:>10.2f} {got['seconds']:>8.0f} "
                  f"{' / '.join(f'{w:.0f}' for w in workers):>16} {got['peak_rss_mb']:>17.0f} {cmp[0]:>18} {cmp[1]:>10}")
        if args.kill:
            n = args.kill
            cluster.restart()
            victim = cluster.workers[-1]
            killed = in_child(work / f"scans-{n}", work / f"killed-{n}", args.points, cluster.address,
                              kill_pid=victim.pid)
            mean, var = compare(killed["model"], str(work / f"cluster-{n}" / "model.h5"))
            print(f"N = {n} with a worker killed when half the first pass was done: finished in "
                  f"{killed['seconds']:.0f} s with {killed['n']} instances; run again: {killed['retried'] or 'none'}; "
                  f"against the build without the kill: mean {mean:.2e} mm, variances {100 * var:.2e} %")
    finally:
        cluster.close()
    if len(rows) >= 2:
        n = np.array([r[0] for r in rows], float)
        for label, col in (("build seconds", 1), ("worker peak MB", 2), ("build process peak MB", 3)):
            y = np.array([r[col] for r in rows])
            slope, icpt = np.polyfit(n, y, 1)
            print(f"{label}: {icpt:.1f} + {slope:.3f} N  ->  N = 1000: {icpt + 1000 * slope:.0f} (extrapolated)")
        print("measure N = 1000 on a larger machine: python benchmarks/scale.py --sizes 1000 --workers W "
              "--compare-upto 0")
    print(f"scratch: {work}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
