"""hortishape: 3D statistical shape models of fruit and vegetables.

The method follows Danckaers et al. (2017), "Building 3D statistical shape
models of horticultural products", Food and Bioprocess Technology 10:2100-2112.
All lengths are in millimetres.

Submodules are imported on use, so ``import hortishape`` stays light:
``hortishape.io``, ``hortishape.synth`` and so on. ``hortishape.fit_partial``
(a model fitted to a partial scan, :mod:`hortishape.partial`) is imported
when first used.
"""

from ._version import __version__
from .errors import (
    ConvergenceWarning,
    ExtractionWarning,
    FitWarning,
    HortishapeError,
    MeshError,
    NotFittedError,
    VolumeError,
)

__all__ = [
    "ConvergenceWarning",
    "ExtractionWarning",
    "FitWarning",
    "PartialFitter",
    "fit_partial",
    "HortishapeError",
    "MeshError",
    "NotFittedError",
    "VolumeError",
    "__version__",
]


def __getattr__(name: str):
    # the partial fit is a top-level name without making every import of hortishape load it
    if name in ("fit_partial", "PartialFitter"):
        from . import partial

        return getattr(partial, name)
    raise AttributeError(f"module 'hortishape' has no attribute {name!r}")
