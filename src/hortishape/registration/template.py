"""The reference surface prepared once for many registrations: its fine, coarse and search levels."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from ..align import FruitAxis, fruit_axis
from ..errors import MeshError
from ..mesh import Mesh
from ..surface import FilledSurface, check_closed_surface, checked_surface, closest_points, fill_holes, remesh
from .config import MAX_HOLE_SHARE


def _face_pairs(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The two faces on each edge of a closed manifold surface, ``(a, b)``."""
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    owner = np.tile(np.arange(len(faces)), 3)
    order = np.lexsort((edges[:, 1], edges[:, 0]))
    edges, owner = edges[order], owner[order]
    pair = (edges[1:] == edges[:-1]).all(axis=1)  # each edge twice, adjacent after sorting
    return owner[:-1][pair], owner[1:][pair]


class _Factor:
    """LDL^T of ``beta^2 L + W`` for one graph Laplacian ``L``, refactorised per call.

    The sparsity pattern never changes (``L`` has a full diagonal), so the
    fill-reducing ordering and the symbolic analysis are done once and each
    solve only refactorises the values (QDLDL), faster than a fresh
    CHOLMOD factorisation (``docs/design-notes.md``).
    """

    def __init__(self, lap: sp.csr_matrix) -> None:
        upper = sp.triu(lap, format="csc")
        upper.sort_indices()
        self._upper = upper
        col = np.repeat(np.arange(upper.shape[1]), np.diff(upper.indptr))
        self._diag = np.flatnonzero(upper.indices == col)
        if len(self._diag) != upper.shape[0]:  # pragma: no cover - a Laplacian of a closed mesh
            raise ValueError("the Laplacian lacks diagonal entries")
        self._solver = None

    def solve(self, beta: float, w: np.ndarray, rhs: np.ndarray) -> np.ndarray:
        import qdldl

        data = (beta * beta) * self._upper.data
        data[self._diag] += w
        a = sp.csc_matrix((data, self._upper.indices, self._upper.indptr), shape=self._upper.shape)
        if self._solver is None:
            self._solver = qdldl.Solver(a, upper=True)
        else:
            self._solver.update(a, upper=True)
        return np.column_stack([self._solver.solve(np.ascontiguousarray(rhs[:, j])) for j in range(rhs.shape[1])])


@dataclass(frozen=True, eq=False)
class _Level:
    """One resolution of the reference: mesh, Laplacian and edge length."""

    vertices: np.ndarray
    faces: np.ndarray
    laplacian: sp.csr_matrix  # M^T M, the graph Laplacian of eq. 8
    edge_length: float
    _cache: dict = field(default_factory=dict, repr=False)

    def factor(self) -> _Factor:
        """The level's reusable factorisation of eq. 8's system (built on first use)."""
        if "ldl" not in self._cache:
            self._cache["ldl"] = _Factor(self.laplacian)
        return self._cache["ldl"]

    def face_pairs(self) -> tuple[np.ndarray, np.ndarray]:
        """:func:`_face_pairs` of the level's faces (built on first use)."""
        if "pairs" not in self._cache:
            self._cache["pairs"] = _face_pairs(self.faces)
        return self._cache["pairs"]

    @staticmethod
    def build(mesh: Mesh) -> "_Level":
        e = mesh.edges()
        n = mesh.n_vertices
        m = len(e)
        inc = sp.csr_matrix(
            (np.r_[np.ones(m), -np.ones(m)], (np.r_[np.arange(m), np.arange(m)], np.r_[e[:, 0], e[:, 1]])),
            shape=(m, n),
        )
        lap = (inc.T @ inc).tocsr()
        lap.sort_indices()
        h = float(np.linalg.norm(inc @ mesh.vertices, axis=1).mean())  # the mean edge length
        return _Level(mesh.vertices, mesh.faces, lap, h)


@dataclass(frozen=True, eq=False)
class Template:
    """A reference surface prepared for registration (see :func:`prepare_reference`).

    Attributes
    ----------
    mesh : Mesh
        The full-resolution reference (the registered meshes have its vertices).
    coarse : Mesh
        A coarse remesh of it (the stiff iterations).
    coarse_face_index, coarse_barycentric : (n,) int64, (n, 3) float64 ndarray
        Where each full-resolution vertex lies on ``coarse`` (carries the coarse
        displacement to the full mesh).
    search : Mesh
        A very coarse remesh (the orientation search).
    source_face_index, source_barycentric : (n,) int64, (n, 3) float64 ndarray or None
        Where each vertex of ``mesh`` lies on the surface ``prepare_reference``
        was given (None if that surface was used as it is).
    """

    mesh: Mesh
    coarse: Mesh
    coarse_face_index: np.ndarray
    coarse_barycentric: np.ndarray
    search: Mesh
    source_face_index: np.ndarray | None = None
    source_barycentric: np.ndarray | None = None
    _levels: dict = field(default_factory=dict, repr=False)

    def level(self, name: str) -> _Level:
        # built lazily and cached (the Laplacians are cheap but not free)
        if name not in self._levels:
            mesh = {"fine": self.mesh, "coarse": self.coarse, "search": self.search}[name]
            self._levels[name] = _Level.build(mesh)
        return self._levels[name]

    def axis(self) -> FruitAxis:
        """The reference's axis of near revolution and cavity end (:func:`hortishape.align.fruit_axis`), cached."""
        if "axis" not in self._levels:
            self._levels["axis"] = fruit_axis(self.mesh.vertices, self.mesh.faces)
        return self._levels["axis"]

    def prolongation(self) -> sp.csr_matrix:
        """``(n, n_coarse)`` barycentric interpolation from the coarse to the full mesh."""
        if "P" not in self._levels:
            n, nc = self.mesh.n_vertices, self.coarse.n_vertices
            tri = self.coarse.faces[self.coarse_face_index]
            self._levels["P"] = sp.csr_matrix(
                (self.coarse_barycentric.ravel(), (np.repeat(np.arange(n), 3), tri.ravel())), shape=(n, nc)
            )
        return self._levels["P"]

    def __getstate__(self):  # do not ship the cache to worker processes
        d = dict(self.__dict__)
        d["_levels"] = {}
        return d

    def __setstate__(self, d):
        for k, v in d.items():
            object.__setattr__(self, k, v)


def prepare_reference(
    mesh: Mesh,
    n_vertices: int | None = None,
    *,
    coarse_vertices: int = 2500,
    search_vertices: int = 800,
) -> Template:
    """Prepare a reference surface once for many registrations.

    Parameters
    ----------
    mesh : Mesh
        Closed single-component reference surface (mm).
    n_vertices : int or None, default: None
        Resample uniformly to this many vertices first (:func:`hortishape.surface.remesh`;
        the paper: 30,000 apple, 40,000 pepper, 13,000 zucchini). ``None``
        uses ``mesh`` as it is (it should then already be uniform).
    coarse_vertices : int, default: 2500
        Size of the coarse level (stiff iterations).
    search_vertices : int, default: 800
        Size of the level used to choose the initial orientation.

    Returns
    -------
    Template

    Raises
    ------
    MeshError
        If the surface has several components, degenerate triangles or holes
        over ``MAX_HOLE_SHARE`` of it (smaller holes are closed by smooth
        patches first, :func:`hortishape.surface.fill_holes`).

    Examples
    --------
    >>> import trimesh
    >>> s = trimesh.creation.icosphere(4, radius=40.0)
    >>> t = prepare_reference(Mesh(s.vertices, s.faces), coarse_vertices=500, search_vertices=200)
    >>> t.mesh.n_vertices, t.coarse.n_vertices, t.search.n_vertices
    (2562, 500, 200)
    """
    src_fi = src_bc = None
    _, closed = close_scan(mesh, name="reference")
    if closed is not None:  # the patches become reference surface; the input's faces come first
        mesh = closed.mesh
    if n_vertices is not None:
        r = remesh(mesh, n_vertices)
        fine, src_fi, src_bc = r.mesh, r.face_index, r.barycentric
    else:
        fine = mesh
    sign = check_closed_surface(fine, name="reference")
    if sign < 0:
        raise MeshError("reference: faces wind inward (negative enclosed volume); flip them")
    n_coarse = int(min(coarse_vertices, fine.n_vertices))
    coarse = remesh(fine, n_coarse).mesh if n_coarse < fine.n_vertices else fine
    n_search = int(min(search_vertices, coarse.n_vertices))
    search = remesh(coarse, n_search).mesh if n_search < coarse.n_vertices else coarse
    cp = closest_points(coarse, fine.vertices)
    return Template(fine, coarse, cp.face_index, cp.barycentric, search, src_fi, src_bc)


def close_scan(mesh: Mesh, *, name: str = "scan") -> tuple[float, FilledSurface | None]:
    """Check a scan as a registration takes it, and close its holes if it has any.

    Parameters
    ----------
    mesh : Mesh
        One consistently oriented manifold surface; holes are allowed (a
        structured-light scan has them where the scanner did not see).
    name : str, default: "scan"
        Name in error messages.

    Returns
    -------
    sign : float
        +1.0 if the faces wind outward, -1.0 if inward.
    closed : FilledSurface or None
        The surface with its holes closed (:func:`hortishape.surface.fill_holes`),
        None if it had none.

    Raises
    ------
    MeshError
        If the surface is non-manifold or has several components, or its holes
        hold more than ``MAX_HOLE_SHARE`` of it once closed.

    Examples
    --------
    >>> import trimesh
    >>> s = trimesh.creation.icosphere(3, radius=40.0)
    >>> cut = trimesh.Trimesh(s.vertices, s.faces[s.triangles_center[:, 2] < 38.0])
    >>> cut.remove_unreferenced_vertices()
    >>> sign, closed = close_scan(Mesh(cut.vertices, cut.faces))
    >>> sign, closed.n_holes, round(closed.hole_share, 3)
    (1.0, 1, 0.022)
    """
    sign, loops = checked_surface(mesh, name=name, allow_degenerate=True, allow_holes=True)
    if not loops:
        return sign, None
    closed = fill_holes(mesh, name=name, loops=loops)
    if closed.hole_share > MAX_HOLE_SHARE:
        raise MeshError(
            f"{name}: the surface has {closed.n_holes} hole(s) covering {100 * closed.hole_share:.0f} % of it (at "
            f"most {100 * MAX_HOLE_SHARE:.0f} % can be bridged); fit a partial scan with `hortishape fit --partial`"
        )
    return sign, closed
