"""One reference registered onto many targets, in worker processes."""

from __future__ import annotations

import warnings
from concurrent.futures import ProcessPoolExecutor
from typing import Callable, Sequence

from ..errors import ConvergenceWarning
from ..mesh import Mesh
from .config import RegistrationConfig
from .core import register
from .result import Registration
from .template import Template, prepare_reference


def _register_one(args):
    template, target, config, kwargs = args
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", ConvergenceWarning)
        reg = register(template, target, config, **kwargs)
    return reg, [str(w.message) for w in caught if issubclass(w.category, ConvergenceWarning)]


def register_many(
    reference: Mesh | Template,
    targets: Sequence[Mesh],
    config: RegistrationConfig | None = None,
    *,
    n_jobs: int = 1,
    callback: Callable[[int, Registration], None] | None = None,
) -> list[Registration]:
    """Register one reference to many targets, optionally in parallel processes.

    Parameters
    ----------
    reference : Mesh or Template
        Prepared once (see :func:`prepare_reference`) and shared by all.
    targets : sequence of Mesh
    config : RegistrationConfig, optional
    n_jobs : int, default: 1
        Worker processes (1: run in this process).
    callback : callable, optional
        Called as ``callback(index, registration)`` when one finishes.

    Returns
    -------
    list of Registration
        In the order of ``targets``.

    Examples
    --------
    >>> import trimesh
    >>> s = trimesh.creation.icosphere(3, radius=40.0)
    >>> ref = prepare_reference(Mesh(s.vertices, s.faces), coarse_vertices=300)
    >>> regs = register_many(ref, [Mesh(s.vertices * 1.05, s.faces)], RegistrationConfig(orientation="pca"))
    >>> len(regs)
    1
    """
    template = reference if isinstance(reference, Template) else prepare_reference(reference)
    cfg = config if config is not None else RegistrationConfig()
    out: list[Registration | None] = [None] * len(targets)
    if n_jobs <= 1:
        for i, t in enumerate(targets):
            out[i] = register(template, t, cfg)
            if callback is not None:
                callback(i, out[i])
        return out  # type: ignore[return-value]
    with ProcessPoolExecutor(max_workers=n_jobs) as pool:
        futures = [pool.submit(_register_one, (template, t, cfg, {})) for t in targets]
        for i, fut in enumerate(futures):
            reg, msgs = fut.result()
            for m in msgs:  # re-raise worker warnings here, where users see them
                warnings.warn(m, ConvergenceWarning, stacklevel=2)
            out[i] = reg
            if callback is not None:
                callback(i, reg)
    return out  # type: ignore[return-value]
