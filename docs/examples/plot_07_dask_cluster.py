"""
A build on a Dask cluster
=========================

A build's time is its registrations: two per scan. ``--scheduler`` sends them (and the extraction
of volumes) to a `dask.distributed <https://distributed.dask.org>`_ cluster, so a population of
hundreds of scans runs on as many machines as you have. On a real cluster::

    dask scheduler                                         # on one machine (port 8786)
    dask worker tcp://HOST:8786 --nthreads 1 --nworkers 4  # on each machine
    hortishape build scans/ --out model/ --scheduler tcp://HOST:8786 --cache /shared/cache

Here the same commands start a scheduler and two one-thread workers as processes on this machine
(``pip install "hortishape[cluster]"`` gives the ``dask`` command).
"""

# %%
# Scans, and a cluster
# --------------------
import tempfile
from pathlib import Path

import subprocess
import sys

from distributed import Client

from hortishape import synth
from hortishape.cli import main as hortishape

work = Path(tempfile.mkdtemp())
synth.write_population("apple", 6, work / "scans", random_state=700, n_vertices=30000)

dask = [sys.executable, "-m", "dask"]  # the ``dask`` command of this Python
log = open(work / "dask.log", "w")
processes = [subprocess.Popen([*dask, "scheduler", "--host", "127.0.0.1", "--port", "0",
                               "--scheduler-file", str(work / "scheduler.json"), "--dashboard-address", ":0"],
                              stdout=log, stderr=subprocess.STDOUT)]
processes += [subprocess.Popen([*dask, "worker", "--scheduler-file", str(work / "scheduler.json"),
                                "--nthreads", "1", "--dashboard-address", ":0"], stdout=log, stderr=subprocess.STDOUT)
              for _ in range(2)]
with Client(scheduler_file=str(work / "scheduler.json"), timeout="60s") as client:
    client.wait_for_workers(2, timeout=120)
    address = client.scheduler.address
print("scheduler at", address, "with 2 workers")

# %%
# The build, on the cluster
# -------------------------
# Each scan's bytes go to a worker and its registration comes back to be written here, so workers
# need not see the build's files. ``--cache`` keeps every registration under the hash of what
# decides it (the scan's bytes, the reference, every setting, hortishape's version).
hortishape(["build", str(work / "scans"), "--out", str(work / "model"), "--points", "3000",
            "--scheduler", address, "--cache", str(work / "cache")])

# %%
# The same scans built again into another folder come from the cache, not from new registrations:
hortishape(["build", str(work / "scans"), "--out", str(work / "model-again"), "--points", "3000",
            "--scheduler", address, "--cache", str(work / "cache")])

for process in processes:
    process.terminate()
for process in processes:
    process.wait(timeout=30)
log.close()
