"""The perturbation check's ``no-embree`` in the processes the tests start (Dask workers, the CLI).

``tests/conftest.py`` puts this folder on ``PYTHONPATH`` when ``HORTISHAPE_PERTURB``
asks for ``no-embree``; Python imports this module as each process starts.
"""

import os
import sys

if "no-embree" in os.environ.get("HORTISHAPE_PERTURB", "").split(","):
    sys.modules["embreex"] = None  # importing embreex now raises ImportError
