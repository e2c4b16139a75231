"""Exceptions and warnings raised by hortishape.

Every error a user can cause with bad input derives from
:class:`HortishapeError`, so the command line can turn it into one clear line
and a non-zero exit status. Messages name the file (where there is one) and
the problem.
"""

from __future__ import annotations


class HortishapeError(Exception):
    """Base class of all errors hortishape raises on bad input."""


class MeshError(HortishapeError, ValueError):
    """A mesh file or mesh array is unusable (missing, empty, broken, wrong units)."""


class VolumeError(HortishapeError, ValueError):
    """A volume file or volume array is unusable."""


class NotFittedError(HortishapeError, AttributeError):
    """A model was used before ``fit`` (or ``load``)."""


class ConvergenceWarning(UserWarning):
    """An iterative step (registration) stopped before meeting its convergence test."""


class FitWarning(UserWarning):
    """A partial fit needs a look: the model explains the points far worse than their own noise."""


class ExtractionWarning(UserWarning):
    """An extracted surface needs a look: gaps were closed, the product is cut off, or of no fruit's size."""
