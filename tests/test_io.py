"""Tests for hortishape.io: mesh and volume files.

All test data are generated here (small synthetic meshes and volumes); the
expected answers are known by construction.
"""

from __future__ import annotations

import hashlib
import re
import sys
import warnings
import zlib
from pathlib import Path

import numpy as np
import pytest

import hortishape._files
import hortishape.io as hio
from hortishape.errors import MeshError, VolumeError
from hortishape.io import (
    MeshData,
    Volume,
    is_mesh_file,
    mesh_formats,
    read_mesh,
    read_mesh_data,
    read_volume,
    volume_formats,
    write_mesh,
    write_volume,
)
from hortishape.mesh import Mesh

# (extension, binary) for every format that keeps vertex order; binary=None is the format default.
ORDERED_FORMATS = [
    (".ply", True),
    (".ply", False),
    (".obj", None),
    (".off", None),
    (".vtk", True),
    (".vtk", False),
    (".vtp", True),
    (".vtp", False),
]
ATTRIBUTE_FORMATS = [(e, b) for e, b in ORDERED_FORMATS if e in (".ply", ".vtk", ".vtp")]


def _format_id(case) -> str:
    ext, binary = case
    return ext[1:] + ("" if binary is None else ("-binary" if binary else "-ascii"))


def _needs_vtk_to_read(ext: str) -> None:
    if ext in (".vtk", ".vtp"):
        pytest.importorskip("vtkmodules")


def _file_hash(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _starts_with_path(path: Path, pattern: str) -> str:
    """A ``pytest.raises(match=...)`` pattern: the message starts with the path."""
    return "^" + re.escape(str(path)) + ": .*" + pattern


@pytest.fixture
def shuffled_sphere() -> Mesh:
    """A closed triangle mesh with scrambled vertex order and full float64 coordinates."""
    import trimesh

    base = trimesh.creation.icosphere(subdivisions=2)
    rng = np.random.default_rng(7)
    perm = rng.permutation(len(base.vertices))
    inverse = np.argsort(perm)
    vertices = base.vertices[perm] * 37.3 + rng.normal(scale=1e-3, size=(len(perm), 3))
    return Mesh(vertices, inverse[base.faces])


def _with_unreferenced_vertex(mesh: Mesh, at: int = 5) -> Mesh:
    vertices = np.insert(mesh.vertices, at, [1e3 / 3, -2.0 / 7, np.pi], axis=0)
    faces = np.where(mesh.faces >= at, mesh.faces + 1, mesh.faces)
    return Mesh(vertices, faces)


def _first_use_order(mesh: Mesh) -> tuple[np.ndarray, np.ndarray]:
    """Vertex order of first use in the faces, and the old -> new index map."""
    _, first = np.unique(mesh.faces.ravel(), return_index=True)
    order = mesh.faces.ravel()[np.sort(first)]
    rank = np.empty(len(mesh.vertices), dtype=np.int64)
    rank[order] = np.arange(order.size)
    return order, rank


# --------------------------------------------------------------------------
# Mesh round trips
# --------------------------------------------------------------------------


def test_mesh_formats_lists_every_supported_extension():
    assert mesh_formats() == (".obj", ".off", ".ply", ".stl", ".vtk", ".vtp")


@pytest.mark.parametrize("case", ORDERED_FORMATS, ids=_format_id)
def test_round_trip_keeps_vertex_order_and_values_exactly(tmp_path, shuffled_sphere, case):
    ext, binary = case
    _needs_vtk_to_read(ext)
    path = write_mesh(tmp_path / f"fruit{ext}", shuffled_sphere, binary=binary)
    assert path == tmp_path / f"fruit{ext}"
    back = read_mesh(path)
    np.testing.assert_array_equal(back.vertices, shuffled_sphere.vertices)
    np.testing.assert_array_equal(back.faces, shuffled_sphere.faces)
    assert back.vertices.dtype == np.float64 and back.faces.dtype == np.int64


@pytest.mark.parametrize("case", ORDERED_FORMATS, ids=_format_id)
def test_round_trip_keeps_an_unreferenced_vertex(tmp_path, shuffled_sphere, case):
    ext, binary = case
    _needs_vtk_to_read(ext)
    mesh = _with_unreferenced_vertex(shuffled_sphere)
    back = read_mesh(write_mesh(tmp_path / f"fruit{ext}", mesh, binary=binary))
    np.testing.assert_array_equal(back.vertices, mesh.vertices)
    np.testing.assert_array_equal(back.faces, mesh.faces)


def test_write_accepts_vertices_and_faces_and_uppercase_extension(tmp_path, shuffled_sphere):
    path = write_mesh(
        tmp_path / "FRUIT.PLY", shuffled_sphere.vertices, shuffled_sphere.faces.tolist()
    )
    assert path.read_bytes().startswith(b"ply\nformat binary_little_endian")
    np.testing.assert_array_equal(read_mesh(str(path)).vertices, shuffled_sphere.vertices)


@pytest.mark.parametrize("binary", [True, False], ids=["binary", "ascii"])
def test_stl_keeps_order_of_meshes_numbered_by_first_use(tmp_path, shuffled_sphere, binary):
    order, rank = _first_use_order(shuffled_sphere)
    mesh = Mesh(shuffled_sphere.vertices[order], rank[shuffled_sphere.faces])
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no order warning for such a mesh
        path = write_mesh(tmp_path / "fruit.stl", mesh, binary=binary)
    back = read_mesh(path)
    np.testing.assert_array_equal(back.faces, mesh.faces)
    # Binary STL stores float32; ASCII STL text is written with full float64 precision.
    expected = mesh.vertices.astype(np.float32).astype(np.float64) if binary else mesh.vertices
    np.testing.assert_array_equal(back.vertices, expected)


@pytest.mark.parametrize("binary", [True, False], ids=["binary", "ascii"])
def test_stl_renumbers_vertices_by_first_use_and_warns(tmp_path, shuffled_sphere, binary):
    mesh = _with_unreferenced_vertex(shuffled_sphere)
    with pytest.warns(UserWarning, match="STL cannot store vertex order"):
        path = write_mesh(tmp_path / "fruit.stl", mesh, binary=binary)
    back = read_mesh(path)
    order, rank = _first_use_order(mesh)
    assert back.n_vertices == mesh.n_vertices - 1  # the unreferenced vertex is gone
    np.testing.assert_array_equal(back.faces, rank[mesh.faces])
    np.testing.assert_allclose(back.vertices, mesh.vertices[order], rtol=1e-7 if binary else 0)


def test_binary_stl_whose_header_starts_with_solid_is_read_as_binary(tmp_path):
    corners = np.array(
        [[[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[1, 0, 0], [1, 1, 0], [0, 1, 0]]], np.float32
    )
    records = np.zeros(2, dtype=hio.stl._STL_RECORD)
    records["corners"] = corners
    path = tmp_path / "solid.stl"
    path.write_bytes(b"solid but binary".ljust(80) + np.uint32(2).tobytes() + records.tobytes())
    mesh = read_mesh(path)
    np.testing.assert_array_equal(mesh.vertices, [[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]])
    np.testing.assert_array_equal(mesh.faces, [[0, 1, 2], [1, 3, 2]])


def test_stl_welds_signed_zeros(tmp_path):
    text = (
        "solid z\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nvertex 0 1 0\n"
        "endloop\nendfacet\nfacet normal 0 0 1\nouter loop\nvertex -0.0 0 0\nvertex 0 1 0\n"
        "vertex -1 0 0\nendloop\nendfacet\nendsolid z\n"
    )
    (tmp_path / "z.stl").write_text(text)
    mesh = read_mesh(tmp_path / "z.stl")
    np.testing.assert_array_equal(mesh.faces, [[0, 1, 2], [0, 2, 3]])


@pytest.mark.parametrize("case", ATTRIBUTE_FORMATS, ids=_format_id)
@pytest.mark.parametrize("channels", [3, 4])
def test_colours_and_scalars_round_trip(tmp_path, shuffled_sphere, case, channels):
    ext, binary = case
    _needs_vtk_to_read(ext)
    rng = np.random.default_rng(3)
    n = shuffled_sphere.n_vertices
    colors = rng.integers(0, 256, size=(n, channels)).astype(np.uint8)
    scalars = {"error_mm": rng.normal(size=n), "curvature": rng.uniform(size=n)}
    path = write_mesh(
        tmp_path / f"map{ext}",
        shuffled_sphere,
        vertex_colors=colors,
        vertex_scalars=scalars,
        binary=binary,
    )
    data = read_mesh_data(path)
    assert isinstance(data, MeshData)
    np.testing.assert_array_equal(data.mesh.vertices, shuffled_sphere.vertices)
    np.testing.assert_array_equal(data.vertex_colors, colors)
    assert data.vertex_colors.dtype == np.uint8
    assert set(data.vertex_scalars) == set(scalars)
    for name, values in scalars.items():
        np.testing.assert_array_equal(data.vertex_scalars[name], values)


def test_mesh_data_is_read_only(tmp_path, shuffled_sphere):
    n = shuffled_sphere.n_vertices
    path = write_mesh(tmp_path / "a.ply", shuffled_sphere, vertex_scalars={"e": np.zeros(n)})
    data = read_mesh_data(path)
    assert not data.vertex_scalars["e"].flags.writeable
    with pytest.raises(TypeError):
        data.vertex_scalars["f"] = np.zeros(n)  # type: ignore[index]
    assert read_mesh_data(write_mesh(tmp_path / "b.obj", shuffled_sphere)).vertex_colors is None


@pytest.mark.parametrize("newline", ["\n", "\r\n"], ids=["lf", "crlf"])
def test_ascii_ply_with_texture_coordinates_and_normals(tmp_path, newline):
    # The layout of scanner / MeshLab exports: float x y z s t nx ny nz, a quad among triangles.
    lines = [
        "ply",
        "format ascii 1.0",
        "comment VCGLIB generated",
        "obj_info scanner 1",
        "element vertex 5",
        *(f"property float {name}" for name in ("x", "y", "z", "s", "t", "nx", "ny", "nz")),
        "element face 3",
        "property list uchar int vertex_indices",
        "end_header",
        "0 0 0 0.1 0.2 0 0 1",
        "1 0 0 0.3 0.4 0 0 1",
        "1 1 0 0.5 0.6 0 0 1",
        "0 1 0 0.7 0.8 0 0 1",
        "0.5 0.5 1e-1 0.9 1.0 0 0 -1",
        "4 0 1 2 3",
        "3 2 4 3",
        "3 0 4 1",
    ]
    path = tmp_path / "scan.ply"
    path.write_bytes(newline.join(lines).encode() + newline.encode())
    data = read_mesh_data(path)
    np.testing.assert_array_equal(data.mesh.vertices[4], [0.5, 0.5, 0.1])
    np.testing.assert_array_equal(data.mesh.faces, [[0, 1, 2], [0, 2, 3], [2, 4, 3], [0, 4, 1]])
    assert set(data.vertex_scalars) == {"s", "t", "nx", "ny", "nz"}
    np.testing.assert_array_equal(data.vertex_scalars["t"], [0.2, 0.4, 0.6, 0.8, 1.0])
    assert data.vertex_colors is None


def _ply_with_mixed_polygons(encoding: str) -> bytes:
    """A PLY with an element before the vertices, extra vertex properties, polygons of
    3, 4 and 5 corners followed by a per-face property, and an element after the faces."""
    vertices = [
        (0.0, 0.0, 0.0),
        (1.0, 0.0, 0.0),
        (1.0, 1.0, 0.0),
        (0.0, 1.0, 0.0),
        (0.5, 2.0, 0.25),
        (-1.0, 0.5, 1.5),
    ]
    polygons = [[0, 1, 2], [0, 2, 3, 5], [3, 2, 4, 1, 0]]
    header = (
        f"ply\nformat {encoding} 1.0\n"
        "element material 2\nproperty list uchar float rgb\nproperty int id\n"
        "element vertex 6\nproperty float x\nproperty float y\nproperty float z\n"
        "property float nx\nproperty uchar red\nproperty uchar green\nproperty uchar blue\n"
        "element face 3\nproperty list uchar uint vertex_indices\nproperty short flags\n"
        "element edge 1\nproperty int vertex1\nproperty int vertex2\nend_header\n"
    ).encode()
    if encoding == "ascii":
        body = "2 0.5 0.25 7\n3 1 2 3 8\n"
        body += "".join(f"{x} {y} {z} -1 {10 * i} 20 30\n" for i, (x, y, z) in enumerate(vertices))
        body += "".join(f"{len(p)} {' '.join(map(str, p))} -3\n" for p in polygons)
        body += "0 1\n"
        return header + body.encode()
    o = "<" if encoding == "binary_little_endian" else ">"
    parts = [
        np.uint8(2).tobytes(),
        np.array([0.5, 0.25], o + "f4").tobytes(),
        np.array(7, o + "i4").tobytes(),
        np.uint8(3).tobytes(),
        np.array([1, 2, 3], o + "f4").tobytes(),
        np.array(8, o + "i4").tobytes(),
    ]
    record = np.dtype([("xyz", o + "f4", 3), ("nx", o + "f4"), ("rgb", "u1", 3)])
    rows = np.zeros(len(vertices), record)
    rows["xyz"] = vertices
    rows["nx"] = -1
    rows["rgb"] = [[10 * i, 20, 30] for i in range(len(vertices))]
    parts.append(rows.tobytes())
    for p in polygons:
        parts += [
            np.uint8(len(p)).tobytes(),
            np.array(p, o + "u4").tobytes(),
            np.array(-3, o + "i2").tobytes(),
        ]
    parts.append(np.array([0, 1], o + "i4").tobytes())
    return header + b"".join(parts)


@pytest.mark.parametrize("encoding", ["ascii", "binary_little_endian", "binary_big_endian"])
def test_ply_with_mixed_polygons_extra_properties_and_elements(tmp_path, encoding):
    path = tmp_path / "mixed.ply"
    path.write_bytes(_ply_with_mixed_polygons(encoding))
    data = read_mesh_data(path)
    np.testing.assert_array_equal(data.mesh.vertices[4], [0.5, 2.0, 0.25])
    np.testing.assert_array_equal(
        data.mesh.faces, [[0, 1, 2], [0, 2, 3], [0, 3, 5], [3, 2, 4], [3, 4, 1], [3, 1, 0]]
    )
    np.testing.assert_array_equal(data.vertex_colors[:, 0], [0, 10, 20, 30, 40, 50])
    np.testing.assert_array_equal(data.vertex_scalars["nx"], -np.ones(6))


def test_ply_and_obj_interoperate_with_trimesh(tmp_path, shuffled_sphere):
    import trimesh

    theirs = trimesh.Trimesh(shuffled_sphere.vertices, shuffled_sphere.faces, process=False)
    for ext in ("ply", "obj"):
        path = tmp_path / f"trimesh.{ext}"
        exported = theirs.export(
            file_type=ext, **({"include_normals": True} if ext == "obj" else {})
        )
        path.write_bytes(exported.encode() if isinstance(exported, str) else exported)
        back = read_mesh(path)
        # trimesh writes OBJ with 8 decimals.
        np.testing.assert_allclose(back.vertices, shuffled_sphere.vertices, rtol=1e-7, atol=1e-7)
        np.testing.assert_array_equal(back.faces, shuffled_sphere.faces)
    ours = trimesh.load(write_mesh(tmp_path / "ours.ply", shuffled_sphere), process=False)
    np.testing.assert_array_equal(ours.vertices, shuffled_sphere.vertices)
    np.testing.assert_array_equal(ours.faces, shuffled_sphere.faces)


def test_obj_with_normals_and_texture_coordinates_keeps_vertex_order(tmp_path):
    # Texture and normal indices differ from position indices: they must not re-index vertices.
    text = """# exported
mtllib fruit.mtl
o fruit
v 0 0 0
v 1 0 0
v 1 1 0
vt 0.5 0.5
vt 0 0
v 0 1 0 0.2 0.3 0.4
vn 0 0 1
vt 1 1
g skin
usemtl peel
s off
f 3/1/1 1/2/1 2/3/1
f 1/3/1 3/2/1 4/1/1 2//1
l 1 2
p 3
"""
    (tmp_path / "fruit.obj").write_text(text)
    mesh = read_mesh(tmp_path / "fruit.obj")
    np.testing.assert_array_equal(mesh.vertices, [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]])
    np.testing.assert_array_equal(mesh.faces, [[2, 0, 1], [0, 2, 3], [0, 3, 1]])


def test_obj_negative_indices_count_back_from_the_last_vertex(tmp_path):
    text = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf -3 -2 -1\nv 1 1 0\nf -3 -1 -2\n"
    (tmp_path / "rel.obj").write_text(text)
    np.testing.assert_array_equal(read_mesh(tmp_path / "rel.obj").faces, [[0, 1, 2], [1, 3, 2]])


def test_off_with_comments_colours_and_polygons(tmp_path):
    text = """COFF 5 3 0
# vertices with RGBA colours
0 0 0 255 0 0 255
1 0 0 0 255 0 255

1 1 0 0 0 255 255
0 1 0 10 10 10 255
0.5 0.5 1 1 2 3 4  # apex
4 0 1 2 3 0.5 0.5 0.5
3 0 1 4
3 2 3 4 255 0 0
"""
    (tmp_path / "box.off").write_text(text)
    mesh = read_mesh(tmp_path / "box.off")
    np.testing.assert_array_equal(mesh.vertices[4], [0.5, 0.5, 1])
    np.testing.assert_array_equal(mesh.faces, [[0, 1, 2], [0, 2, 3], [0, 1, 4], [2, 3, 4]])


def test_vtk_files_written_by_vtk_itself(tmp_path):
    pytest.importorskip("vtkmodules")
    from vtkmodules.util.numpy_support import numpy_to_vtk
    from vtkmodules.vtkCommonCore import vtkPoints
    from vtkmodules.vtkCommonDataModel import vtkCellArray, vtkPolyData, vtkUnstructuredGrid
    from vtkmodules.vtkIOLegacy import vtkPolyDataWriter, vtkUnstructuredGridWriter

    vertices = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [2, 0, 0], [2, 1, 0]], float)
    points = vtkPoints()
    points.SetData(numpy_to_vtk(vertices, deep=True))

    def cells(*polygons):
        array = vtkCellArray()
        for polygon in polygons:
            array.InsertNextCell(len(polygon), polygon)
        return array

    polydata = vtkPolyData()
    polydata.SetPoints(points)
    polydata.SetPolys(cells([0, 1, 2, 3]))
    polydata.SetStrips(cells([1, 4, 2, 5]))
    polydata.SetLines(cells([0, 5]))
    writer = vtkPolyDataWriter()  # VTK 9 writes file version 5.1 by default
    writer.SetFileName(str(tmp_path / "poly.vtk"))
    writer.SetInputData(polydata)
    writer.SetFileTypeToBinary()
    assert writer.Write() == 1
    mesh = read_mesh(tmp_path / "poly.vtk")
    np.testing.assert_array_equal(mesh.vertices, vertices)
    np.testing.assert_array_equal(mesh.faces, [[0, 1, 2], [0, 2, 3], [1, 4, 2], [2, 4, 5]])

    grid = vtkUnstructuredGrid()
    grid.SetPoints(points)
    grid.InsertNextCell(5, 3, [0, 1, 2])  # triangle
    grid.InsertNextCell(10, 4, [0, 1, 2, 5])  # tetrahedron: not a surface cell, ignored
    grid.InsertNextCell(9, 4, [1, 4, 5, 2])  # quad
    writer = vtkUnstructuredGridWriter()
    writer.SetFileName(str(tmp_path / "grid.vtk"))
    writer.SetInputData(grid)
    assert writer.Write() == 1
    np.testing.assert_array_equal(
        read_mesh(tmp_path / "grid.vtk").faces, [[0, 1, 2], [1, 4, 5], [1, 5, 2]]
    )


@pytest.mark.parametrize(
    "case", [*ORDERED_FORMATS, (".stl", True), (".stl", False)], ids=_format_id
)
def test_reading_never_changes_the_file(tmp_path, shuffled_sphere, case):
    ext, binary = case
    _needs_vtk_to_read(ext)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        path = write_mesh(tmp_path / f"f{ext}", shuffled_sphere, binary=binary)
    before, mtime = _file_hash(path), path.stat().st_mtime_ns
    read_mesh_data(path)
    assert _file_hash(path) == before and path.stat().st_mtime_ns == mtime


def test_writing_never_changes_the_inputs(tmp_path, shuffled_sphere):
    vertices = shuffled_sphere.vertices.copy()
    faces = shuffled_sphere.faces.copy()
    colors = np.arange(3 * len(vertices)).reshape(-1, 3) % 256
    scalars = {"e": np.linspace(0, 1, len(vertices))}
    keep = [a.copy() for a in (vertices, faces, colors, scalars["e"])]
    for ext in (".ply", ".vtk"):
        write_mesh(
            tmp_path / f"a{ext}", vertices, faces, vertex_colors=colors, vertex_scalars=scalars
        )
    for ext in (".obj", ".off", ".stl"):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            write_mesh(tmp_path / f"a{ext}", vertices, faces)
    for original, kept in zip((vertices, faces, colors, scalars["e"]), keep, strict=True):
        np.testing.assert_array_equal(original, kept)
        assert original.flags.writeable
    assert list(scalars) == ["e"]


def test_is_mesh_file(tmp_path):
    (tmp_path / "a.PLY").write_bytes(b"x")
    (tmp_path / "b.ply").mkdir()
    (tmp_path / ".c.ply").write_bytes(b"x")
    (tmp_path / "d.txt").write_bytes(b"x")
    assert is_mesh_file(tmp_path / "a.PLY")
    assert not is_mesh_file(tmp_path / "b.ply")  # a folder
    assert not is_mesh_file(tmp_path / ".c.ply")  # hidden: temp files, macOS leftovers
    assert not is_mesh_file(tmp_path / "d.txt")
    assert not is_mesh_file(tmp_path / "missing.obj")


# --------------------------------------------------------------------------
# Mesh errors
# --------------------------------------------------------------------------

_TRIANGLE_PLY = (
    b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
    b"property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
    + np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], "<f4").tobytes()
    + b"\x03"
    + np.array([0, 1, 2], "<i4").tobytes()
)

BAD_MESHES = [
    ("empty.ply", b"", "the file is empty"),
    ("not.ply", b"hello world\n", r"not a PLY file"),
    ("header.ply", b"ply\nformat ascii 1.0\nelement vertex 3\n", "end_header"),
    ("format.ply", b"ply\nformat utf8 1.0\nend_header\n", "unknown PLY format"),
    ("truncated.ply", _TRIANGLE_PLY[:-5], "truncated"),
    ("huge.ply", _TRIANGLE_PLY.replace(b"vertex 3", b"vertex 300000000000"), "truncated"),
    (
        "words.ply",
        b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nend_header\nabc\n",
        "not a number",
    ),
    (
        "noxyz.ply",
        b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float q\nend_header\n1\n",
        "no x, y, z",
    ),
    ("nan.obj", b"v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n", "NaN or infinite"),
    ("inf.off", b"OFF\n3 1 0\n0 0 0\n1 inf 0\n0 1 0\n3 0 1 2\n", "NaN or infinite"),
    ("lines.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nl 1 2\nl 2 3\n", "no faces"),
    (
        "points.ply",
        b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
        b"property float z\nend_header\n1 2 3\n",
        "no faces",
    ),
    (
        "range.off",
        b"OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 3\n",
        r"face indices must lie in \[0, 2\]",
    ),
    (
        "range.ply",
        _TRIANGLE_PLY.replace(b"\x03\x00\x00\x00\x00", b"\x03\x07\x00\x00\x00"),
        "face indices",
    ),
    ("zero.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n", "start at 1"),
    ("short.obj", b"v 0 0\nf 1 2 3\n", "fewer than 3 coordinates"),
    ("count.off", b"OFF\nthree 1 0\n", "vertex and face counts"),
    ("truncated.off", b"OFF\n3 1 0\n0 0 0\n1 0 0\n", "truncated"),
    ("notoff.off", b"PLY\n3 1 0\n", "not an OFF file"),
    ("size.stl", b"\x01" * 90, "neither a binary STL"),
    ("tiny.stl", b"abc", "does not start with 'solid'"),
    (
        "facet.stl",
        b"solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nendloop\n"
        b"endfacet\nendsolid x\n",
        "facets need exactly 3",
    ),
]


@pytest.mark.parametrize("name, content, problem", BAD_MESHES, ids=[b[0] for b in BAD_MESHES])
def test_bad_mesh_file_raises_mesh_error_naming_the_file(tmp_path, name, content, problem):
    path = tmp_path / name
    path.write_bytes(content)
    with pytest.raises(MeshError, match=_starts_with_path(path, problem)):
        read_mesh(path)


def test_missing_directory_and_unknown_extension(tmp_path):
    with pytest.raises(MeshError, match=_starts_with_path(tmp_path / "gone.ply", "no such file")):
        read_mesh(tmp_path / "gone.ply")
    (tmp_path / "folder.ply").mkdir()
    with pytest.raises(
        MeshError, match=_starts_with_path(tmp_path / "folder.ply", "is a directory")
    ):
        read_mesh(tmp_path / "folder.ply")
    (tmp_path / "mesh.xyz").write_text("1 2 3\n")
    supported = re.escape("supported: .obj, .off, .ply, .stl, .vtk, .vtp")
    with pytest.raises(
        MeshError, match=_starts_with_path(tmp_path / "mesh.xyz", "'.xyz'; " + supported)
    ):
        read_mesh(tmp_path / "mesh.xyz")


@pytest.mark.parametrize("ext", [".vtk", ".vtp"])
def test_broken_vtk_files_raise_without_printing(tmp_path, capfd, ext):
    pytest.importorskip("vtkmodules")
    path = tmp_path / f"broken{ext}"
    path.write_text(
        '<?xml version="1.0"?>\n<VTKFile type="PolyData"><bad' if ext == ".vtp" else "hello\n"
    )
    with pytest.raises(MeshError, match=_starts_with_path(path, f"not a valid \\{ext} file")):
        read_mesh(path)
    assert capfd.readouterr().err == ""


def test_vtk_image_data_is_not_a_surface(tmp_path):
    pytest.importorskip("vtkmodules")
    path = tmp_path / "image.vtk"
    path.write_text(
        "# vtk DataFile Version 3.0\nimage\nASCII\nDATASET STRUCTURED_POINTS\nDIMENSIONS 2 2 1\n"
        "ORIGIN 0 0 0\nSPACING 1 1 1\n"
    )
    with pytest.raises(MeshError, match=_starts_with_path(path, "not a surface")):
        read_mesh(path)


def test_missing_vtk_package_gives_install_hint(tmp_path, shuffled_sphere, monkeypatch):
    for name in [*hio.vtk_files._VTK_MODULES, "vtkmodules"]:
        monkeypatch.setitem(sys.modules, name, None)
    path = tmp_path / "x.vtp"
    path.write_text("<VTKFile/>")
    hint = re.escape("""needs the optional dependency 'vtk' (pip install "hortishape[vtk]")""")
    with pytest.raises(MeshError, match=_starts_with_path(path, "reading .vtp files " + hint)):
        read_mesh(path)
    with pytest.raises(
        MeshError, match=_starts_with_path(tmp_path / "y.vtp", "writing .vtp files " + hint)
    ):
        write_mesh(tmp_path / "y.vtp", shuffled_sphere)
    write_mesh(tmp_path / "z.vtk", shuffled_sphere)  # legacy VTK is written with numpy alone
    assert (tmp_path / "z.vtk").read_bytes().startswith(b"# vtk DataFile Version 4.2\n")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.vtp", "z.vtk"]


def test_bad_write_arguments(tmp_path, shuffled_sphere):
    m, v, f = shuffled_sphere, shuffled_sphere.vertices, shuffled_sphere.faces
    n = m.n_vertices
    p = tmp_path / "a.ply"
    cases = [
        (lambda: write_mesh(p, m, f), p, "either a Mesh"),
        (lambda: write_mesh(p, v), p, "faces are required"),
        (lambda: write_mesh(p, v, f + n), p, "face indices must lie in"),
        (lambda: write_mesh(tmp_path / "a.obj", m, binary=True), tmp_path / "a.obj", "text only"),
        (lambda: write_mesh(p, m, binary="yes"), p, "binary must be"),
        (
            lambda: write_mesh(tmp_path / "a.stl", m, vertex_scalars={"e": np.zeros(n)}),
            tmp_path / "a.stl",
            "cannot store vertex colours or scalars",
        ),
        (lambda: write_mesh(p, m, vertex_colors=np.zeros((n, 2))), p, r"shape \(\d+, 3\) or"),
        (lambda: write_mesh(p, m, vertex_colors=np.full((n, 3), 0.5)), p, "integers in 0..255"),
        (lambda: write_mesh(p, m, vertex_colors=np.full((n, 3), 256)), p, "integers in 0..255"),
        (lambda: write_mesh(p, m, vertex_scalars={"e": np.zeros(n + 1)}), p, "must have shape"),
        (lambda: write_mesh(p, m, vertex_scalars={"x": np.zeros(n)}), p, "name 'x'"),
        (lambda: write_mesh(p, m, vertex_scalars={"two words": np.zeros(n)}), p, "without spaces"),
        (lambda: write_mesh(tmp_path / "a.3ds", m), tmp_path / "a.3ds", "unknown mesh format"),
        (
            lambda: write_mesh(tmp_path / "no" / "a.ply", m),
            tmp_path / "no" / "a.ply",
            "does not exist",
        ),
    ]
    for write, path, problem in cases:
        with pytest.raises(MeshError, match=_starts_with_path(path, problem)):
            write()
    (tmp_path / "d.ply").mkdir()
    with pytest.raises(MeshError, match=_starts_with_path(tmp_path / "d.ply", "is a directory")):
        write_mesh(tmp_path / "d.ply", m)
    assert sorted(x.name for x in tmp_path.iterdir()) == ["d.ply"]


def test_failed_write_leaves_target_untouched_and_no_temp_file(
    tmp_path, shuffled_sphere, monkeypatch
):
    target = tmp_path / "fruit.obj"
    target.write_text("old content")

    def fail(*args, **kwargs):
        raise RuntimeError("disk on fire")

    def deny(*args, **kwargs):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(hio.obj_off, "_floats_text", fail)  # fails half-way through writing
    with pytest.raises(RuntimeError, match="disk on fire"):
        write_mesh(target, shuffled_sphere)
    with pytest.raises(RuntimeError):
        write_mesh(tmp_path / "new.obj", shuffled_sphere)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fruit.obj"]
    assert target.read_text() == "old content"

    monkeypatch.undo()
    monkeypatch.setattr(hortishape._files.os, "replace", deny)  # fails at the very end
    with pytest.raises(
        MeshError, match=_starts_with_path(target, "cannot write .*Permission denied")
    ):
        write_mesh(target, shuffled_sphere)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fruit.obj"]
    assert target.read_text() == "old content"


# --------------------------------------------------------------------------
# Volume type
# --------------------------------------------------------------------------


def _rotation(seed: int) -> np.ndarray:
    q, r = np.linalg.qr(np.random.default_rng(seed).normal(size=(3, 3)))
    return q * np.sign(np.diag(r))


def _asymmetric_volume(dtype=np.int16, seed: int = 0) -> Volume:
    """Shape (4, 5, 6) with data[x, y, z] = x + 10 y + 100 z: every axis tells itself apart."""
    x, y, z = np.meshgrid(np.arange(4), np.arange(5), np.arange(6), indexing="ij")
    return Volume(
        (x + 10 * y + 100 * z).astype(dtype),
        spacing=(0.31, 0.57, 1.13),
        origin=(-12.5, 3.25, 100.0 / 3),
        direction=_rotation(seed),
    )


def test_volume_geometry_maps_indices_to_world_and_back():
    vol = _asymmetric_volume()
    ijk = np.array([[0, 0, 0], [3, 4, 5], [1.5, 2.25, 0.5]])
    world = vol.index_to_world(ijk)
    expected = vol.origin + (vol.direction @ (vol.spacing * ijk).T).T
    np.testing.assert_allclose(world, expected, atol=1e-12)
    np.testing.assert_allclose(vol.world_to_index(world), ijk, atol=1e-12)
    assert vol.index_to_world([1, 0, 0]).shape == (1, 3)
    # One voxel step along x moves spacing[0] along the first direction column.
    np.testing.assert_allclose(
        vol.index_to_world([1, 0, 0]) - vol.index_to_world([0, 0, 0]), [0.31 * vol.direction[:, 0]]
    )


def test_volume_is_read_only_and_does_not_touch_the_input():
    data = np.zeros((3, 3, 3), np.float32)
    vol = Volume(data, spacing=1.0)
    assert data.flags.writeable and not vol.data.flags.writeable and not vol.spacing.flags.writeable
    np.testing.assert_array_equal(vol.spacing, [1, 1, 1])
    np.testing.assert_array_equal(vol.direction, np.eye(3))
    assert vol.shape == (3, 3, 3)


@pytest.mark.parametrize(
    "kwargs, problem",
    [
        ({"data": np.zeros((3, 3))}, "a 2D image, not a 3D volume"),
        ({"data": np.zeros((3, 3, 3, 3))}, "4-dimensional"),
        ({"data": np.zeros((3, 1, 3))}, "at least 2 voxels"),
        ({"data": np.full((2, 2, 2), np.nan)}, "8 voxels are NaN"),
        ({"data": np.array([[["a"] * 2] * 2] * 2)}, "must be numbers"),
        ({"spacing": (1, 0, 1)}, "spacing must be 3 positive"),
        ({"spacing": (1, -1, 1)}, "spacing must be 3 positive"),
        ({"spacing": (1, 1)}, "spacing must be 3 positive"),
        ({"origin": (0, np.inf, 0)}, "origin must be 3 finite"),
        ({"direction": np.diag([1, 2, 1])}, "orthonormal"),
        ({"direction": np.eye(2)}, "3 x 3"),
    ],
)
def test_invalid_volume_raises(kwargs, problem):
    args = {"data": np.zeros((2, 2, 2)), "spacing": (1, 1, 1), **kwargs}
    with pytest.raises(VolumeError, match="^volume: .*" + problem):
        Volume(**args)


# --------------------------------------------------------------------------
# MetaImage (native)
# --------------------------------------------------------------------------

ALL_DTYPES = [np.uint8, np.int8, np.int16, np.uint16, np.int32, np.uint32, np.float32, np.float64]


@pytest.mark.parametrize("dtype", ALL_DTYPES, ids=lambda d: np.dtype(d).name)
@pytest.mark.parametrize("compress", [True, False], ids=["zlib", "raw"])
@pytest.mark.parametrize("ext", [".mha", ".mhd"])
def test_metaimage_round_trip(tmp_path, dtype, compress, ext):
    vol = _asymmetric_volume(dtype, seed=int(compress))
    path = write_volume(tmp_path / f"ct{ext}", vol, compress=compress)
    back = read_volume(path)
    assert back.data.dtype == np.dtype(dtype)
    np.testing.assert_array_equal(back.data, vol.data)
    for name in ("spacing", "origin", "direction"):
        np.testing.assert_array_equal(getattr(back, name), getattr(vol, name))
    if ext == ".mhd":
        assert sorted(p.name for p in tmp_path.iterdir()) == [
            "ct.mhd",
            "ct.zraw" if compress else "ct.raw",
        ]


def _handwritten_mha(fields: str, payload: bytes) -> bytes:
    return (fields.strip() + "\nElementDataFile = LOCAL\n").encode() + payload


def test_handwritten_big_endian_metaimage_lands_on_the_right_axes(tmp_path):
    # The file stores x fastest; data[x, y, z] must be x + 4 y + 12 z.
    # TransformMatrix lists the world directions of the x, y, z axes: x -> world y, y -> world -x.
    header = """ObjectType = Image
NDims = 3
DimSize = 4 3 2
ElementType = MET_USHORT
BinaryData = True
BinaryDataByteOrderMSB = True
TransformMatrix = 0 1 0 -1 0 0 0 0 1
Offset = 10 20 30
ElementSpacing = 0.5 2 3
"""
    path = tmp_path / "hand.mha"
    path.write_bytes(_handwritten_mha(header, np.arange(24, dtype=">u2").tobytes()))
    vol = read_volume(path)
    x, y, z = np.meshgrid(np.arange(4), np.arange(3), np.arange(2), indexing="ij")
    np.testing.assert_array_equal(vol.data, x + 4 * y + 12 * z)
    assert vol.data.dtype == np.uint16
    np.testing.assert_array_equal(
        vol.index_to_world([[1, 0, 0], [0, 1, 0], [0, 0, 1]]),
        [[10, 20.5, 30], [8, 20, 30], [10, 20, 33]],
    )


def test_mhd_with_separate_data_file_and_header_size(tmp_path):
    (tmp_path / "scan.raw").write_bytes(b"JUNKHEADER" + np.arange(8, dtype="<f4").tobytes())
    (tmp_path / "scan.mhd").write_text(
        "NDims = 3\nDimSize = 2 2 2\nElementType = MET_FLOAT\nHeaderSize = 10\n"
        "ElementSpacing = 1 1 1\nElementDataFile = scan.raw\n"
    )
    np.testing.assert_array_equal(read_volume(tmp_path / "scan.mhd").data[1, 1, 1], 7.0)
    (tmp_path / "ascii.mha").write_text(
        "NDims = 3\nDimSize = 2 2 2\nElementType = MET_SHORT\nBinaryData = False\n"
        "ElementDataFile = LOCAL\n0 1 2 3\n4 5 6 7\n"
    )
    np.testing.assert_array_equal(read_volume(tmp_path / "ascii.mha").data[:, 1, 1], [6, 7])


def test_metaimage_matches_simpleitk_geometry_and_axis_order(tmp_path):
    sitk = pytest.importorskip("SimpleITK")
    vol = _asymmetric_volume(np.float32, seed=3)
    ours = write_volume(tmp_path / "ours.mha", vol)
    image = sitk.ReadImage(str(ours))
    np.testing.assert_array_equal(sitk.GetArrayFromImage(image).transpose(2, 1, 0), vol.data)
    for ijk in [(0, 0, 0), (3, 1, 2), (1, 4, 5)]:
        assert image.GetPixel(*ijk) == vol.data[ijk]
        np.testing.assert_allclose(
            image.TransformIndexToPhysicalPoint(ijk), vol.index_to_world(ijk)[0], atol=1e-12
        )
    # And the other way: SimpleITK writes a compressed .mha, we read it.
    sitk.WriteImage(image, str(tmp_path / "theirs.mha"), True)
    back = read_volume(tmp_path / "theirs.mha")
    np.testing.assert_array_equal(back.data, vol.data)
    np.testing.assert_allclose(back.direction, vol.direction, atol=1e-15)
    np.testing.assert_allclose(
        back.index_to_world([[3, 1, 2]]), vol.index_to_world([[3, 1, 2]]), atol=1e-12
    )


def test_reading_and_writing_volumes_never_changes_inputs(tmp_path):
    vol = _asymmetric_volume()
    data = vol.data.copy()
    path = write_volume(tmp_path / "a.mha", vol)
    np.testing.assert_array_equal(vol.data, data)
    before = _file_hash(path)
    read_volume(path)
    assert _file_hash(path) == before


def test_failed_volume_write_leaves_no_file(tmp_path, monkeypatch):
    def fail(*args, **kwargs):
        raise RuntimeError("disk on fire")

    monkeypatch.setattr(hio.metaimage, "_metaimage_text", fail)
    for name in ("a.mha", "a.mhd"):
        with pytest.raises(RuntimeError):
            write_volume(tmp_path / name, _asymmetric_volume())
    assert [p.name for p in tmp_path.iterdir()] == ["a.zraw"]  # .mhd: data file done, header failed


# --------------------------------------------------------------------------
# Volume errors
# --------------------------------------------------------------------------

_GOOD_FIELDS = "NDims = 3\nDimSize = 2 2 2\nElementType = MET_FLOAT\nElementSpacing = 1 1 1\n"
_EIGHT_FLOATS = np.arange(8, dtype="<f4").tobytes()

BAD_VOLUMES = [
    ("empty.mha", b"", "the file is empty"),
    ("noheader.mha", b"\x00\x01 not a header", "no 'ElementDataFile' line"),
    (
        "flat.mha",
        _handwritten_mha("NDims = 2\nDimSize = 2 2\nElementType = MET_UCHAR", b"\0" * 4),
        "2D image",
    ),
    (
        "4d.mha",
        _handwritten_mha("NDims = 4\nDimSize = 2 2 2 2\nElementType = MET_UCHAR", b"\0" * 16),
        "NDims = 4",
    ),
    (
        "truncated.mha",
        _handwritten_mha(_GOOD_FIELDS, _EIGHT_FLOATS[:-3]),
        "truncated: .*needs 32 bytes",
    ),
    (
        "long.mha",
        _handwritten_mha(_GOOD_FIELDS, _EIGHT_FLOATS + b"xx"),
        "needs 32 bytes of voxel data, found 34",
    ),
    (
        "corrupt.mha",
        _handwritten_mha(_GOOD_FIELDS + "CompressedData = True", b"garbage"),
        "corrupt",
    ),
    (
        "cut.mha",
        _handwritten_mha(_GOOD_FIELDS + "CompressedData = True", zlib.compress(_EIGHT_FLOATS)[:-6]),
        "truncated",
    ),
    (
        "nan.mha",
        _handwritten_mha(_GOOD_FIELDS, np.array([np.nan] + [0] * 7, "<f4").tobytes()),
        "1 voxels are NaN",
    ),
    (
        "zero.mha",
        _handwritten_mha(_GOOD_FIELDS.replace("1 1 1", "1 0 1"), _EIGHT_FLOATS),
        "spacing must be",
    ),
    (
        "negative.mha",
        _handwritten_mha(_GOOD_FIELDS.replace("1 1 1", "1 1 -2"), _EIGHT_FLOATS),
        "spacing must be",
    ),
    (
        "thin.mha",
        _handwritten_mha(_GOOD_FIELDS.replace("2 2 2", "2 2 1"), _EIGHT_FLOATS[:16]),
        "at least 2 voxels",
    ),
    (
        "type.mha",
        _handwritten_mha(_GOOD_FIELDS.replace("MET_FLOAT", "MET_HALF"), b""),
        "unsupported ElementType",
    ),
    (
        "rgb.mha",
        _handwritten_mha(_GOOD_FIELDS + "ElementNumberOfChannels = 3", _EIGHT_FLOATS * 3),
        "channels",
    ),
    (
        "nodata.mhd",
        _GOOD_FIELDS.encode() + b"ElementDataFile = gone.raw\n",
        "gone.raw does not exist",
    ),
    ("list.mhd", _GOOD_FIELDS.encode() + b"ElementDataFile = LIST\n", "not supported"),
    (
        "dims.mha",
        _handwritten_mha("NDims = 3\nDimSize = 2 x 2\nElementType = MET_FLOAT", b""),
        "DimSize",
    ),
    ("volume.xyz", b"data", r"unknown volume format '\.xyz'; supported: \.mha, \.mhd, "),
    ("slice.dcm", b"DICM", "single DICOM file holds one slice"),
]


@pytest.mark.parametrize("name, content, problem", BAD_VOLUMES, ids=[b[0] for b in BAD_VOLUMES])
def test_bad_volume_file_raises_volume_error_naming_the_file(tmp_path, name, content, problem):
    path = tmp_path / name
    path.write_bytes(content)
    with pytest.raises(VolumeError, match=_starts_with_path(path, problem)):
        read_volume(path)


def test_missing_volume_and_bad_write_arguments(tmp_path):
    with pytest.raises(VolumeError, match=_starts_with_path(tmp_path / "gone.mha", "no such file")):
        read_volume(tmp_path / "gone.mha")
    vol = _asymmetric_volume()
    with pytest.raises(
        VolumeError, match=_starts_with_path(tmp_path / "a.png", "cannot write volume format")
    ):
        write_volume(tmp_path / "a.png", vol)
    with pytest.raises(
        VolumeError, match=_starts_with_path(tmp_path / "a.mha", "expected a Volume")
    ):
        write_volume(tmp_path / "a.mha", vol.data)  # type: ignore[arg-type]
    with pytest.raises(
        VolumeError, match=_starts_with_path(tmp_path / "no" / "a.mha", "does not exist")
    ):
        write_volume(tmp_path / "no" / "a.mha", vol)
    with pytest.raises(VolumeError, match="cannot store float16"):
        write_volume(tmp_path / "h.mha", Volume(np.zeros((2, 2, 2), np.float16), spacing=1))
    path = write_volume(tmp_path / "ok.mha", vol)
    with pytest.raises(VolumeError, match=_starts_with_path(path, "spacing must be")):
        read_volume(path, spacing=(1, 1, 0))
    assert not list(tmp_path.glob(".*"))


# --------------------------------------------------------------------------
# Other volume formats through SimpleITK
# --------------------------------------------------------------------------


def _sitk_image(sitk, vol: Volume):
    image = sitk.GetImageFromArray(np.ascontiguousarray(vol.data.transpose(2, 1, 0)))
    image.SetSpacing(vol.spacing.tolist())
    image.SetOrigin(vol.origin.tolist())
    image.SetDirection(vol.direction.ravel().tolist())
    return image


@pytest.mark.parametrize("ext", [".nrrd", ".nii", ".nii.gz"])
def test_nrrd_and_nifti_round_trips(tmp_path, ext):
    sitk = pytest.importorskip("SimpleITK")
    vol = _asymmetric_volume(np.int16, seed=5)
    sitk.WriteImage(_sitk_image(sitk, vol), str(tmp_path / f"theirs{ext}"))
    write_volume(tmp_path / f"ours{ext}", vol)
    for name in ("theirs", "ours"):
        back = read_volume(tmp_path / f"{name}{ext}")
        np.testing.assert_array_equal(back.data, vol.data)
        # NIfTI stores geometry in float32.
        tol = 1e-6 if ext.startswith(".nii") else 1e-12
        np.testing.assert_allclose(back.spacing, vol.spacing, rtol=tol)
        np.testing.assert_allclose(back.origin, vol.origin, rtol=tol)
        np.testing.assert_allclose(back.direction, vol.direction, atol=tol)
    assert sorted(p.name for p in tmp_path.iterdir()) == [f"ours{ext}", f"theirs{ext}"]


def test_multipage_tiff_without_a_voxel_size_is_refused(tmp_path):
    sitk = pytest.importorskip("SimpleITK")
    vol = _asymmetric_volume(np.uint16)
    sitk.WriteImage(_sitk_image(sitk, vol), str(tmp_path / "stack.tif"))  # no OME or ImageJ metadata
    with pytest.raises(VolumeError, match=_starts_with_path(tmp_path / "stack.tif", "no voxel size: ")) as err:
        read_volume(tmp_path / "stack.tif")
    assert "--spacing SX SY SZ" in str(err.value) and "\n" not in str(err.value)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        back = read_volume(tmp_path / "stack.tif", spacing=(0.1, 0.1, 0.2))
    np.testing.assert_array_equal(back.data, vol.data)
    np.testing.assert_array_equal(back.spacing, [0.1, 0.1, 0.2])
    np.testing.assert_array_equal(back.direction, np.eye(3))
    assert back.spacing_source.startswith("given")
    # hortishape writes OME-TIFF, which keeps the voxel size (not the origin or direction)
    write_volume(tmp_path / "ours.tiff", vol)
    ours = read_volume(tmp_path / "ours.tiff")
    np.testing.assert_array_equal(ours.data, vol.data)
    np.testing.assert_allclose(ours.spacing, vol.spacing, rtol=1e-12)
    assert ours.spacing_source == "OME-TIFF PhysicalSizeX/Y/Z"


def test_folder_of_tiff_slices_in_natural_order(tmp_path):
    sitk = pytest.importorskip("SimpleITK")
    x, y, z = np.meshgrid(np.arange(5), np.arange(4), np.arange(11), indexing="ij")
    data = (x + 10 * y + 100 * z).astype(np.uint16)
    folder = tmp_path / "slices"
    folder.mkdir()
    for k in range(11):  # slice_2 must come before slice_10
        sitk.WriteImage(
            sitk.GetImageFromArray(np.ascontiguousarray(data[:, :, k].T)),
            str(folder / f"slice_{k}.tif"),
        )
    (folder / "notes.txt").write_text("ignored")
    vol = read_volume(folder, spacing=(0.05, 0.05, 0.1))
    np.testing.assert_array_equal(vol.data, data)


def _write_dicom_series(sitk, folder: Path, vol: Volume, series_uid: str) -> None:
    writer = sitk.ImageFileWriter()
    writer.KeepOriginalImageUIDOn()
    writer.SetImageIO("GDCMImageIO")
    data = np.ascontiguousarray(vol.data.transpose(2, 1, 0))
    for k in range(data.shape[0]):
        image = sitk.GetImageFromArray(data[k])
        image.SetSpacing(vol.spacing[:2].tolist())
        position = vol.index_to_world([0, 0, k])[0]
        tags = {
            "0008|0060": "CT",
            "0008|0018": f"{series_uid}.{k + 1}",
            "0020|000d": "1.2.826.0.1.3680043.8.498.1",
            "0020|000e": series_uid,
            "0020|0032": "\\".join(f"{c:.6f}" for c in position),
            "0020|0037": "1\\0\\0\\0\\1\\0",
            "0020|0013": str(k + 1),
            "0018|0050": f"{vol.spacing[2]}",
        }
        for tag, value in tags.items():
            image.SetMetaData(tag, value)
        writer.SetFileName(str(folder / f"IM{k:04d}"))  # extensionless, as scanners write them
        writer.Execute(image)


def test_dicom_series_folder(tmp_path):
    sitk = pytest.importorskip("SimpleITK")
    x, y, z = np.meshgrid(np.arange(6), np.arange(5), np.arange(4), indexing="ij")
    vol = Volume(
        (x + 10 * y + 100 * z).astype(np.int16), spacing=(0.5, 0.6, 1.5), origin=(-3, 4, 10)
    )
    folder = tmp_path / "series"
    folder.mkdir()
    _write_dicom_series(sitk, folder, vol, "1.2.826.0.1.3680043.8.498.2")
    back = read_volume(folder)
    np.testing.assert_array_equal(back.data, vol.data)
    np.testing.assert_allclose(back.spacing, vol.spacing, rtol=1e-6)
    np.testing.assert_allclose(back.origin, vol.origin, atol=1e-5)
    # Two series in one folder are ambiguous.
    _write_dicom_series(
        sitk, folder, Volume(vol.data[:, :, :2] + 1, spacing=1), "1.2.826.0.1.3680043.8.498.3"
    )
    with pytest.raises(VolumeError, match=_starts_with_path(folder, "holds 2 DICOM series")):
        read_volume(folder)


def test_sitk_volume_errors(tmp_path, monkeypatch):
    sitk = pytest.importorskip("SimpleITK")
    flat = tmp_path / "flat.tif"
    sitk.WriteImage(sitk.GetImageFromArray(np.zeros((4, 5), np.uint8)), str(flat))
    with pytest.raises(VolumeError, match=_starts_with_path(flat, "2D image, not a 3D volume")):
        read_volume(flat, spacing=1)
    garbage = tmp_path / "garbage.nrrd"
    garbage.write_bytes(b"NRRD0004\nthis is not\n")
    with pytest.raises(VolumeError, match=_starts_with_path(garbage, "cannot read it")):
        read_volume(garbage)
    rgb = tmp_path / "rgb.nrrd"
    sitk.WriteImage(
        sitk.GetImageFromArray(np.zeros((3, 4, 5, 3), np.uint8), isVector=True), str(rgb)
    )
    with pytest.raises(VolumeError, match=_starts_with_path(rgb, "3 values per voxel")):
        read_volume(rgb)
    empty = tmp_path / "empty"
    empty.mkdir()
    (empty / "readme.txt").write_text("no images here")
    with pytest.raises(
        VolumeError, match=_starts_with_path(empty, "no DICOM series and no .tif slices")
    ):
        read_volume(empty)
    monkeypatch.setitem(sys.modules, "SimpleITK", None)
    hint = re.escape("""needs the optional dependency 'SimpleITK' (pip install "hortishape[ct]")""")
    with pytest.raises(
        VolumeError, match=_starts_with_path(garbage, "reading .nrrd files " + hint)
    ):
        read_volume(garbage)
    with pytest.raises(
        VolumeError, match=_starts_with_path(tmp_path / "o.nii", "writing .nii files " + hint)
    ):
        write_volume(tmp_path / "o.nii", _asymmetric_volume())


def test_volume_formats():
    assert volume_formats() == (
        ".mha",
        ".mhd",
        ".nhdr",
        ".nii",
        ".nii.gz",
        ".nrrd",
        ".tif",
        ".tiff",
    )


def test_reads_a_real_scan_in_metres():
    """A real YCB scan (ASCII PLY with s, t and normals, in metres) reads with its order."""
    from pathlib import Path

    import trimesh

    path = Path(__file__).parent / "data" / "ycb" / "013_apple_google16k.ply"
    mesh = read_mesh(path)
    assert mesh.n_vertices == 8194 and mesh.n_faces == 16384
    extent = np.ptp(mesh.vertices, axis=0)
    assert np.all((extent > 0.06) & (extent < 0.09))  # metres: about 75 mm across
    assert trimesh.Trimesh(mesh.vertices, mesh.faces, process=False).is_watertight
    first = path.read_text().split("end_header\n", 1)[1].splitlines()[0].split()
    np.testing.assert_allclose(mesh.vertices[0], [float(x) for x in first[:3]])


def test_point_clouds_round_trip_and_mesh_files_give_their_vertices(tmp_path, shuffled_sphere):
    from hortishape.io import read_points, write_points

    rng = np.random.default_rng(0)
    points, normals = rng.normal(size=(50, 3)), rng.normal(size=(50, 3))
    path = write_points(tmp_path / "seen.ply", points, normals=normals)
    cloud = read_points(path)
    np.testing.assert_array_equal(cloud.points, points)
    np.testing.assert_array_equal(cloud.normals, normals)
    assert cloud.faces.shape == (0, 3)
    assert read_points(write_points(tmp_path / "bare.ply", points)).normals is None
    # a mesh file: its vertices, in order, and its faces; no normals from the file
    mesh_path = write_mesh(tmp_path / "scan.obj", shuffled_sphere)
    cloud = read_points(mesh_path)
    np.testing.assert_array_equal(cloud.points, shuffled_sphere.vertices)
    assert len(cloud.faces) == shuffled_sphere.n_faces and cloud.normals is None
    # errors name the file
    with pytest.raises(MeshError, match="point clouds are written as .ply"):
        write_points(tmp_path / "seen.stl", points)
    with pytest.raises(MeshError, match=_starts_with_path(tmp_path / "missing.ply", "no such file")):
        read_points(tmp_path / "missing.ply")
    (tmp_path / "empty.ply").write_bytes(b"")
    with pytest.raises(MeshError, match="empty"):
        read_points(tmp_path / "empty.ply")
    with pytest.raises(MeshError, match="finite"):
        write_points(tmp_path / "nan.ply", np.full((3, 3), np.nan))


def test_binary_ply_written_in_blocks_reads_back_whole(tmp_path, monkeypatch):
    from hortishape.io import ply

    monkeypatch.setattr(ply, "_WRITE_BLOCK", 1000)  # blocks of 1,000: 3 or 4 per element here
    rng = np.random.default_rng(5)
    vertices, faces = rng.normal(size=(2500, 3)), rng.integers(0, 2500, size=(3100, 3))
    colors, error = rng.integers(0, 256, size=(2500, 3)).astype(np.uint8), rng.normal(size=2500)
    path = write_mesh(tmp_path / "blocks.ply", vertices, faces, vertex_colors=colors, vertex_scalars={"e": error})
    data = read_mesh_data(path)
    np.testing.assert_array_equal(data.mesh.vertices, vertices)
    np.testing.assert_array_equal(data.mesh.faces, faces)
    np.testing.assert_array_equal(data.vertex_colors, colors)
    np.testing.assert_array_equal(data.vertex_scalars["e"], error)


@pytest.mark.parametrize("binary", [True, False])
def test_a_legacy_vtk_file_with_a_damaged_cell_count_is_refused_not_crashed_on(tmp_path, binary):
    # VTK's legacy reader trusts the counts and reads past its buffer (a crash, VTK 9.4 and 9.7): the cells are
    # checked first, in a child process here so that a crash fails this test instead of the run
    import subprocess
    import sys

    pytest.importorskip("vtk")
    mesh = Mesh([[0, 0, 0], [0, 10, 0], [10, 0, 0], [0, 0, 10]], [[0, 1, 2], [0, 2, 3], [0, 3, 1], [2, 1, 3]])
    path = write_mesh(tmp_path / "m.vtk", mesh, binary=binary)
    data = bytearray(path.read_bytes())
    at = data.index(b"POLYGONS 4 16\n") + len(b"POLYGONS 4 16\n")
    if binary:
        data[at + 2] = 0xFF  # the first cell's point count, big-endian int32: 3 -> 65283
    else:
        data[at] = ord("9")  # "3 0 1 2" -> "9 0 1 2"
    path.write_bytes(bytes(data))
    code = ("from hortishape.io import read_mesh\nfrom hortishape.errors import MeshError\n"
            f"try:\n    read_mesh({str(path)!r})\nexcept MeshError as e:\n    print(e)\n")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    assert run.stdout.startswith(f"{path}: not a valid .vtk file (POLYGONS: ")
