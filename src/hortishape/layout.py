"""The layout of a model directory: where ``hortishape build`` puts each file.

``build`` writes the directory, ``evaluate`` reads it and adds ``evaluation/``;
every module that reads or writes one goes through :class:`ModelDir`, so the
names live here only.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

__all__ = ["ModelDir"]


@dataclass(frozen=True)
class ModelDir:
    """The files of a built model directory.

    Parameters
    ----------
    root : str or os.PathLike
        The directory (``hortishape build INPUT --out ROOT``).

    Attributes
    ----------
    model : Path
        ``model.h5``: the shape model (:meth:`hortishape.model.ShapeModel.load`).
    summary : Path
        ``summary.json``: instances, skipped scans, per-scan registration figures.
    registered : Path
        ``registered/``: the second pass's registered surfaces ``<stem>.ply``
        (in each scan's coordinates) and their logs ``<stem>.json``.
    aligned : Path
        ``aligned/``: the Procrustes-aligned surfaces ``<stem>.ply``.
    surfaces : Path
        ``surfaces/``: the surfaces extracted from volumes, when the input held volumes.
    work : Path
        ``work/``: what an interrupted build resumes from.
    first_pass : Path
        ``work/first-pass/``: the first pass's registrations.
    first_pass_runner_up, first_pass_flipped : Path
        ``work/first-pass-rank1/``, ``work/first-pass-flipped/``: the
        orientation check's second tries of suspect scans.
    evaluation : Path
        ``evaluation/``: what ``hortishape evaluate`` writes.
    error_map, metrics, viewer : Path
        ``evaluation/error_map.ply`` (the geometric error per vertex of the
        mean), ``evaluation/metrics.json`` (every figure, the landmarks on
        the mean among them) and ``evaluation/viewer.html`` (the model in a
        browser, :mod:`hortishape.view`).

    Examples
    --------
    >>> d = ModelDir("apples")
    >>> d.registered_mesh("apple_003").as_posix()
    'apples/registered/apple_003.ply'
    >>> d.is_built()
    False
    """

    root: Path

    def __init__(self, root: str | os.PathLike) -> None:
        object.__setattr__(self, "root", Path(root))

    @property
    def model(self) -> Path:
        return self.root / "model.h5"

    @property
    def summary(self) -> Path:
        return self.root / "summary.json"

    @property
    def registered(self) -> Path:
        return self.root / "registered"

    @property
    def aligned(self) -> Path:
        return self.root / "aligned"

    @property
    def surfaces(self) -> Path:
        return self.root / "surfaces"

    @property
    def work(self) -> Path:
        return self.root / "work"

    @property
    def first_pass(self) -> Path:
        return self.work / "first-pass"

    @property
    def first_pass_runner_up(self) -> Path:
        return self.work / "first-pass-rank1"

    @property
    def first_pass_flipped(self) -> Path:
        return self.work / "first-pass-flipped"

    @property
    def evaluation(self) -> Path:
        return self.root / "evaluation"

    @property
    def error_map(self) -> Path:
        return self.evaluation / "error_map.ply"

    @property
    def metrics(self) -> Path:
        return self.evaluation / "metrics.json"

    @property
    def viewer(self) -> Path:
        return self.evaluation / "viewer.html"

    def registered_mesh(self, name: str) -> Path:
        """The registered surface of instance ``name`` (a scan's file stem)."""
        return self.registered / f"{name}.ply"

    def aligned_mesh(self, name: str) -> Path:
        """The Procrustes-aligned surface of instance ``name``."""
        return self.aligned / f"{name}.ply"

    def is_built(self) -> bool:
        """Whether the directory holds a finished build (its summary and model)."""
        return self.summary.is_file() and self.model.is_file()
