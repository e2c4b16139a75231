"""The former home of :mod:`hortishape.registration`, kept so that existing imports work.

New code imports from :mod:`hortishape.registration`.
"""

from .registration import (  # noqa: F401
    IterationRecord,
    Registration,
    RegistrationConfig,
    Template,
    prepare_reference,
    register,
    register_many,
)

__all__ = ["IterationRecord", "Registration", "RegistrationConfig", "Template", "prepare_reference", "register", "register_many"]
