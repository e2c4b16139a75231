"""The former home of :mod:`hortishape.registration.correspondences`, kept so that existing imports work."""

from .registration.correspondences import *  # noqa: F401,F403
from .registration.correspondences import __all__  # noqa: F401
