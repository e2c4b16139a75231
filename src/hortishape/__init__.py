"""hortishape: 3D statistical shape models of fruit and vegetables.

The method follows Danckaers et al. (2017), "Building 3D statistical shape
models of horticultural products", Food and Bioprocess Technology 10:2100-2112.
All lengths are in millimetres.

Submodules are imported on use, so ``import hortishape`` stays light:
``hortishape.io``, ``hortishape.synth`` and so on.
"""

from importlib.metadata import PackageNotFoundError, version

from .errors import (
    ConvergenceWarning,
    HortishapeError,
    MeshError,
    NotFittedError,
    VolumeError,
)

try:
    __version__ = version("hortishape")
except PackageNotFoundError:  # running from a source tree without install
    __version__ = "0.0.0+unknown"

__all__ = [
    "ConvergenceWarning",
    "HortishapeError",
    "MeshError",
    "NotFittedError",
    "VolumeError",
    "__version__",
]
