"""Reading and writing triangle meshes and CT volumes.

Meshes
------
:func:`read_mesh` / :func:`write_mesh` handle ``.ply``, ``.stl``, ``.obj``,
``.off``, ``.vtk`` (legacy POLYDATA) and ``.vtp`` (VTK XML PolyData), chosen
by the file extension (case-insensitive) through a registry keyed by extension.

Vertex order is the correspondence in hortishape, so no reader merges, drops or
reorders vertices, with one documented exception: STL is a triangle soup that
cannot store vertex order. STL corners with identical coordinates are welded,
numbered in order of first appearance. An STL round trip therefore keeps the
order only for meshes whose vertices are numbered in order of first use in
``faces`` (no unreferenced vertices, no two vertices at the same position);
:func:`write_mesh` warns when a mesh does not meet that.

Polygons with more than three corners are fan-triangulated on read; lines and
points are ignored; a file without any triangle is an error.

Precision: binary STL stores float32 coordinates. Every other format stores
float64 (binary PLY/VTK/VTP) or the shortest decimal text that reads back to
the same float64 (ASCII PLY/STL/VTK, OBJ, OFF), so coordinates round-trip
exactly. (VTK's own legacy ASCII writer keeps only 11 digits, which is why
``.vtk`` is written here with numpy.)

Backends: PLY, STL, OBJ, OFF and writing legacy VTK are implemented with numpy
(vectorised; no Python loops over vertices or faces). Reading ``.vtk`` and
reading or writing ``.vtp`` use the optional ``vtk`` package
(``pip install "hortishape[vtk]"``), imported only when needed.

Point clouds
------------
:func:`read_points` reads what a depth camera or a partial scan gives: a
PLY file without faces (its ``nx``, ``ny``, ``nz`` properties as normals),
or the vertices of any mesh file; :func:`write_points` writes one.

Volumes
-------
:class:`Volume` holds ``data`` indexed ``[x, y, z]``: ITK and SimpleITK
arrays are indexed ``(z, y, x)`` and are transposed once, here, at the
boundary. Lengths are millimetres. World coordinates follow ITK's convention
(the one MetaImage, NRRD and DICOM headers and SimpleITK use)::

    world = origin + direction @ (spacing * [i, j, k])

MetaImage (``.mha`` / ``.mhd``) is read and written natively with numpy;
NRRD and NIfTI go through the optional ``SimpleITK`` package, DICOM series
through ``pydicom`` and TIFF stacks through ``tifffile``
(``pip install "hortishape[ct]"``). :func:`find_sources` finds the scans
in folders by content (DICOM series whatever their files are called, in
nested study folders) and says what it passed over, and why.

All writers are atomic: data go to a temporary file next to the target,
which replaces the target only once complete.
"""

from .dicom import write_dicom_series
from .mesh_files import MeshData, is_mesh_file, mesh_formats, read_mesh, read_mesh_data, write_mesh
from .point_files import PointCloud, read_points, write_points
from .sources import Sources, VolumeSource, find_sources
from .volume import Volume
from .volume_files import read_volume, volume_formats, write_volume

__all__ = [
    "MeshData",
    "PointCloud",
    "Sources",
    "Volume",
    "VolumeSource",
    "find_sources",
    "is_mesh_file",
    "mesh_formats",
    "read_mesh",
    "read_mesh_data",
    "read_points",
    "read_volume",
    "volume_formats",
    "write_dicom_series",
    "write_mesh",
    "write_points",
    "write_volume",
]
