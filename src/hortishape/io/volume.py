"""The :class:`Volume` type: voxels indexed ``[x, y, z]``, spacing, origin and direction in mm."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from ..errors import VolumeError


def _check_volume(data, spacing, origin, direction, *, name: str):
    """Validate and convert the parts of a volume; see :class:`Volume`."""
    arr = np.asarray(data)
    if arr.dtype.kind not in "biuf":
        raise VolumeError(f"{name}: voxel values must be numbers, got dtype {arr.dtype}")
    if arr.ndim != 3:
        what = "a 2D image" if arr.ndim == 2 else f"{arr.ndim}-dimensional"
        raise VolumeError(f"{name}: is {what}, not a 3D volume (shape {arr.shape})")
    if min(arr.shape) < 2:
        raise VolumeError(f"{name}: needs at least 2 voxels along each axis, got shape {arr.shape}")
    if arr.dtype.kind == "f" and not np.isfinite(arr).all():
        bad = int((~np.isfinite(arr)).sum())
        raise VolumeError(f"{name}: {bad} voxels are NaN or infinite")
    try:
        s = np.array(spacing, dtype=np.float64).reshape(-1)
        o = np.array(origin, dtype=np.float64).reshape(-1)
        d = np.array(direction, dtype=np.float64)
    except (TypeError, ValueError):
        raise VolumeError(f"{name}: spacing, origin and direction must be numeric") from None
    if s.size == 1:
        s = np.repeat(s, 3)
    if s.shape != (3,) or not np.all(np.isfinite(s)) or np.any(s <= 0):
        raise VolumeError(
            f"{name}: spacing must be 3 positive finite numbers (mm), got {s.tolist()}"
        )
    if o.shape != (3,) or not np.all(np.isfinite(o)):
        raise VolumeError(f"{name}: origin must be 3 finite numbers (mm), got {o.tolist()}")
    if d.shape != (3, 3) or not np.all(np.isfinite(d)):
        raise VolumeError(f"{name}: direction must be a finite 3 x 3 matrix, got shape {d.shape}")
    # Headers store directions with a few digits only, hence the tolerance.
    if np.abs(d.T @ d - np.eye(3)).max() > 1e-3:
        raise VolumeError(f"{name}: direction must be orthonormal (a rotation or reflection)")
    return arr, s, o, d


@dataclass(frozen=True, eq=False)
class Volume:
    """A 3D image: voxel values indexed ``[x, y, z]`` with its geometry in millimetres.

    Parameters
    ----------
    data : (nx, ny, nz) array_like of numbers
        Voxel values, at least 2 voxels along each axis, no NaN or infinity.
        Indexed ``data[x, y, z]`` (the transpose of ITK/SimpleITK's
        ``(z, y, x)`` arrays). Stored as a read-only view, not copied
        (volumes are large): do not modify the array you passed.
    spacing : (3,) array_like of float or float
        Voxel size along x, y, z in mm, positive.
    origin : (3,) array_like of float, default: (0, 0, 0)
        World position of voxel ``[0, 0, 0]`` in mm.
    direction : (3, 3) array_like of float, default: identity
        Orthonormal; column ``j`` is the world direction of index axis ``j``.
    spacing_source : str, default: ""
        Where the voxel size came from (a file's header, a scanner log, given).

    Examples
    --------
    >>> v = Volume(np.zeros((4, 5, 6)), spacing=(0.5, 0.5, 2.0), origin=(10, 0, 0))
    >>> v.shape
    (4, 5, 6)
    >>> v.index_to_world([1, 2, 3]).tolist()
    [[10.5, 1.0, 6.0]]
    """

    data: np.ndarray
    spacing: np.ndarray
    origin: np.ndarray = None  # type: ignore[assignment]
    direction: np.ndarray = None  # type: ignore[assignment]
    spacing_source: str = ""

    def __post_init__(self) -> None:
        origin = np.zeros(3) if self.origin is None else self.origin
        direction = np.eye(3) if self.direction is None else self.direction
        arr, s, o, d = _check_volume(self.data, self.spacing, origin, direction, name="volume")
        view = arr.view()
        for a in (view, s, o, d):
            a.flags.writeable = False
        object.__setattr__(self, "data", view)
        object.__setattr__(self, "spacing", s)
        object.__setattr__(self, "origin", o)
        object.__setattr__(self, "direction", d)

    @property
    def shape(self) -> tuple[int, int, int]:
        """Number of voxels along x, y, z."""
        return tuple(int(k) for k in self.data.shape)  # type: ignore[return-value]

    def index_to_world(self, ijk: npt.ArrayLike) -> np.ndarray:
        """World coordinates (mm) of voxel indices.

        Parameters
        ----------
        ijk : (k, 3) or (3,) array_like of float
            Indices along x, y, z (may be fractional).

        Returns
        -------
        (k, 3) float64 ndarray
            ``origin + direction @ (spacing * ijk)`` for each row.

        Examples
        --------
        >>> Volume(np.zeros((2, 2, 2)), spacing=2.0).index_to_world([[1, 0, 0]]).tolist()
        [[2.0, 0.0, 0.0]]
        """
        p = np.atleast_2d(np.asarray(ijk, dtype=np.float64))
        if p.ndim != 2 or p.shape[1] != 3:
            raise VolumeError(f"indices must have shape (k, 3), got {np.shape(ijk)}")
        return self.origin + (p * self.spacing) @ self.direction.T

    def world_to_index(self, xyz: npt.ArrayLike) -> np.ndarray:
        """Continuous voxel indices of world points (mm); the inverse of :meth:`index_to_world`.

        Parameters
        ----------
        xyz : (k, 3) or (3,) array_like of float

        Returns
        -------
        (k, 3) float64 ndarray
            Fractional indices along x, y, z; round them to get a voxel.

        Examples
        --------
        >>> Volume(np.zeros((2, 2, 2)), spacing=2.0).world_to_index([[2, 0, 0]]).tolist()
        [[1.0, 0.0, 0.0]]
        """
        p = np.atleast_2d(np.asarray(xyz, dtype=np.float64))
        if p.ndim != 2 or p.shape[1] != 3:
            raise VolumeError(f"points must have shape (k, 3), got {np.shape(xyz)}")
        return np.linalg.solve(self.direction, (p - self.origin).T).T / self.spacing
