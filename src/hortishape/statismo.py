"""Model files that Statismo and Scalismo read and write: HDF5 (Statismo v0.9) and HDF5-JSON.

:meth:`hortishape.model.ShapeModel.save` and :meth:`~hortishape.model.ShapeModel.load`
call this module. A model file is read into an in-memory :class:`H5Tree` (its
groups, datasets and attributes by path), whatever its form, and a model is
written from one:

* **HDF5**, the Statismo v0.9 layout (see :meth:`ShapeModel.save
  <hortishape.model.ShapeModel.save>`), which Statismo and Scalismo up to 0.91
  read and write;
* **HDF5-JSON**, the HDF Group's JSON form of an HDF5 file, which Scalismo 0.92
  and later write for every model, whatever the file's name.

A file's form is told by its content (the HDF5 signature, or a JSON object),
never by its name. Reading accepts what the writers in the field produce:
string attributes stored as scalars or as one-element arrays (Scalismo),
fixed or variable length; triangle meshes and point sets; with or without
``/modelinfo/scores``; cells as any integer type (Statismo writes uint32,
Scalismo int32). Writing follows Statismo (fixed-length null-terminated
strings in HDF5) and Scalismo (variable-length scalar strings, float32 and
int32 arrays in HDF5-JSON); hortishape's own float64 copy of the model goes
in ``/hortishape`` in both forms.
"""

from __future__ import annotations

import json
import os
import uuid
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from .errors import HortishapeError, MeshError
from .mesh import check_mesh

__all__ = ["FORMATS", "H5Tree", "ModelData", "model_format", "model_provenance", "read_model", "read_tree", "write_model", "write_tree"]

#: The forms a model file can be written in: ``"hdf5"`` (Statismo v0.9) and ``"json"`` (HDF5-JSON).
FORMATS = ("hdf5", "json")

_HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"

_FORMAT = "hortishape-shape-model"
_FORMAT_VERSION = 1
# Statismo 0.9 standard mesh representer (modules/VTK/src/vtkStandardMeshRepresenter.cxx):
# the names "vtkPolyDataRepresenter" and "itkMeshRepresenter" are the legacy
# (<= 0.8) representers that embed a VTK file instead of points and cells.
_REPRESENTER_NAME = "vtkStandardMeshRepresenter"
_REPRESENTER_VERSION = "1.0"
_LEGACY_REPRESENTERS = ("vtkPolyDataRepresenter", "itkMeshRepresenter")

# numpy dtype <-> HDF5-JSON base type (little-endian, as HDF5 writes on every
# platform hortishape runs on)
_JSON_TYPES = {
    np.dtype(np.float32): ("H5T_FLOAT", "H5T_IEEE_F32LE"),
    np.dtype(np.float64): ("H5T_FLOAT", "H5T_IEEE_F64LE"),
    np.dtype(np.int8): ("H5T_INTEGER", "H5T_STD_I8LE"),
    np.dtype(np.int16): ("H5T_INTEGER", "H5T_STD_I16LE"),
    np.dtype(np.int32): ("H5T_INTEGER", "H5T_STD_I32LE"),
    np.dtype(np.int64): ("H5T_INTEGER", "H5T_STD_I64LE"),
    np.dtype(np.uint8): ("H5T_INTEGER", "H5T_STD_U8LE"),
    np.dtype(np.uint16): ("H5T_INTEGER", "H5T_STD_U16LE"),
    np.dtype(np.uint32): ("H5T_INTEGER", "H5T_STD_U32LE"),
    np.dtype(np.uint64): ("H5T_INTEGER", "H5T_STD_U64LE"),
}
_JSON_BASES = {base: dtype for dtype, (_, base) in _JSON_TYPES.items()}
_JSON_BASES.update({b.replace("LE", "BE"): d.newbyteorder(">") for b, d in list(_JSON_BASES.items())})


@dataclass
class H5Tree:
    """The content of an HDF5 file by path: groups, datasets and attributes.

    Dataset and attribute values are numpy arrays (numbers) or ``str`` (a
    string, scalar or one-element) or lists of ``str``. Paths are absolute
    (``"/model/mean"``).

    Examples
    --------
    >>> t = H5Tree()
    >>> t.add("/model/mean", np.zeros(3, np.float32))
    >>> t.attrs["/representer"] = {"datasetType": "POINT_SET"}
    >>> "/model" in t.groups, t.string("/representer", "datasetType")
    (True, 'POINT_SET')
    """

    groups: set = field(default_factory=lambda: {"/"})
    datasets: dict = field(default_factory=dict)
    attrs: dict = field(default_factory=dict)

    def add(self, path: str, value) -> None:
        """Add a dataset (and the groups above it)."""
        self.datasets[path] = value
        self.group(path.rsplit("/", 1)[0] or "/")

    def group(self, path: str) -> None:
        """Add an (empty) group and the groups above it."""
        parts = path.strip("/").split("/")
        for i in range(1, len(parts) + 1):
            self.groups.add("/" + "/".join(parts[:i]))

    def __contains__(self, path: str) -> bool:
        return path in self.datasets or path in self.groups

    def array(self, path: str, dtype=np.float64) -> np.ndarray:
        """A numeric dataset as an array of ``dtype``."""
        value = self.datasets[path]
        if isinstance(value, (str, list)):
            raise TypeError(f"{path} holds text, not numbers")
        return np.asarray(value, dtype=dtype)

    def text(self, path: str) -> str:
        """A string dataset (scalar or one element)."""
        return _one_string(self.datasets[path], path)

    def string(self, path: str, name: str, default: str | None = None) -> str | None:
        """A string attribute (scalar or one element), or ``default`` if absent."""
        a = self.attrs.get(path, {})
        return _one_string(a[name], f"{path}@{name}") if name in a else default

    def children(self, path: str) -> list[str]:
        """Names of the groups and datasets directly in group ``path``."""
        prefix = path.rstrip("/") + "/"
        names = {p[len(prefix):].split("/")[0] for p in (*self.groups, *self.datasets) if p.startswith(prefix)}
        return sorted(n for n in names if n)


def _one_string(value, where: str) -> str:
    if isinstance(value, np.ndarray):
        if value.dtype.kind in "SUO":
            value = value.reshape(-1).tolist()
        else:
            raise TypeError(f"{where} holds numbers, not text")
    if isinstance(value, list):
        if len(value) != 1:
            raise TypeError(f"{where} holds {len(value)} strings, not one")
        value = value[0]
    if isinstance(value, (bytes, np.bytes_)):
        value = value.decode("utf-8", "replace")
    return str(value).rstrip("\x00")


# --------------------------------------------------------------------------
# reading
# --------------------------------------------------------------------------


def model_format(path: str | os.PathLike) -> str:
    """The form of a model file by its content: ``"hdf5"`` or ``"json"``.

    Raises
    ------
    HortishapeError
        If the file is missing, a folder, or neither.

    Examples
    --------
    >>> import tempfile
    >>> p = Path(tempfile.mkdtemp()) / "model.h5"
    >>> _ = p.write_text('{"apiVersion": "1.1.1", "root": "r", "groups": {}, "datasets": {}}')
    >>> model_format(p)
    'json'
    """
    p = Path(path)
    if not p.exists():
        raise HortishapeError(f"{p}: no such file")
    if p.is_dir():
        raise HortishapeError(f"{p}: is a directory, not a model file")
    with open(p, "rb") as f:
        head = f.read(512)
    # HDF5 allows a user block before the signature, at 512, 1024, ... bytes
    if head.startswith(_HDF5_SIGNATURE) or _has_late_signature(p):
        return "hdf5"
    if head.lstrip(b"\xef\xbb\xbf \t\r\n").startswith(b"{"):
        return "json"
    raise HortishapeError(f"{p}: neither an HDF5 nor an HDF5-JSON model file")


def _has_late_signature(p: Path) -> bool:
    size = p.stat().st_size
    offset = 512
    with open(p, "rb") as f:
        while offset + 8 <= size and offset <= 1 << 20:
            f.seek(offset)
            if f.read(8) == _HDF5_SIGNATURE:
                return True
            offset *= 2
    return False


def read_tree(path: str | os.PathLike) -> H5Tree:
    """Read a model file, HDF5 or HDF5-JSON (told by its content), into an :class:`H5Tree`.

    Raises
    ------
    HortishapeError
        If the file is missing, unreadable, or in neither form.

    Examples
    --------
    >>> import tempfile, trimesh
    >>> from hortishape.model import ShapeModel
    >>> s = trimesh.creation.icosphere(subdivisions=2, radius=30.0)
    >>> shapes = s.vertices * np.random.default_rng(0).uniform(0.8, 1.2, (6, 1, 3))
    >>> path = ShapeModel().fit(shapes, s.faces).save(tempfile.mkdtemp() + "/model.json")
    >>> "/model" in read_tree(path).groups
    True
    """
    p = Path(path)
    form = model_format(p)
    try:
        return _read_hdf5(p) if form == "hdf5" else _read_json(p)
    except HortishapeError:
        raise
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise HortishapeError(f"{p}: unreadable {'HDF5' if form == 'hdf5' else 'HDF5-JSON'} file ({exc})") from None


def _read_hdf5(p: Path) -> H5Tree:
    import h5py

    tree = H5Tree()

    def value(raw):
        if isinstance(raw, (bytes, np.bytes_, str)):
            return _one_string(raw, "")
        a = np.asarray(raw)
        if a.dtype.kind in "SO" or a.dtype.kind == "U":
            return [_one_string(x, "") for x in a.reshape(-1)]
        return a

    def visit(name: str, obj) -> None:
        path = "/" + name
        if isinstance(obj, h5py.Dataset):
            tree.add(path, value(obj[()]))
        else:
            tree.group(path)
        if obj.attrs:
            tree.attrs[path] = {k: value(v) for k, v in obj.attrs.items()}

    with h5py.File(p, "r") as f:
        if f.attrs:
            tree.attrs["/"] = {k: value(v) for k, v in f.attrs.items()}
        f.visititems(visit)
    return tree


def _read_json(p: Path) -> H5Tree:
    try:
        doc = json.loads(p.read_text(encoding="utf-8-sig"))  # a byte-order mark is allowed
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise HortishapeError(f"{p}: not valid JSON ({exc})") from None
    if not isinstance(doc, dict) or "root" not in doc or "groups" not in doc:
        raise HortishapeError(f"{p}: JSON, but not an HDF5-JSON file (no root group)")
    groups, datasets = doc["groups"], doc.get("datasets", {})
    tree = H5Tree()
    # walk the links from the root: the paths are where the links say, whatever
    # the (optional) aliases claim
    stack, seen = [("/", doc["root"])], set()
    while stack:
        path, gid = stack.pop()
        if gid in seen:
            continue
        seen.add(gid)
        if gid not in groups:
            raise HortishapeError(f"{p}: the group {path} ({gid}) is missing")
        g = groups[gid]
        tree.group(path)
        if g.get("attributes"):
            tree.attrs[path] = {a["name"]: _json_value(a, p) for a in g["attributes"]}
        for link in g.get("links", []):
            child = path.rstrip("/") + "/" + link["title"]
            if link.get("collection") == "groups":
                stack.append((child, link["id"]))
            elif link.get("collection") == "datasets":
                d = datasets.get(link["id"])
                if d is None:
                    raise HortishapeError(f"{p}: the dataset {child} ({link['id']}) is missing")
                tree.add(child, _json_value(d, p))
                if d.get("attributes"):
                    tree.attrs[child] = {a["name"]: _json_value(a, p) for a in d["attributes"]}
    return tree


def _json_value(item: dict, p: Path):
    t, shape, v = item.get("type", {}), item.get("shape", {}), item.get("value")
    cls = t.get("class") if isinstance(t, dict) else None
    if cls == "H5T_STRING":
        if isinstance(v, list):
            flat = np.asarray(v, dtype=object).reshape(-1).tolist()
            return [str(s).rstrip("\x00") for s in flat]
        return str(v).rstrip("\x00")
    if cls not in ("H5T_FLOAT", "H5T_INTEGER"):
        raise HortishapeError(f"{p}: HDF5-JSON type {t!r} of {item.get('name', item.get('alias'))} is not supported")
    dtype = _JSON_BASES.get(t.get("base"))
    if dtype is None:
        raise HortishapeError(f"{p}: HDF5-JSON base type {t.get('base')!r} is not supported")
    a = np.asarray(v, dtype=dtype.newbyteorder("="))
    dims = shape.get("dims") if shape.get("class") == "H5S_SIMPLE" else []
    if dims is not None and a.size == int(np.prod(dims, dtype=np.int64)):
        a = a.reshape(dims)
    return a


# --------------------------------------------------------------------------
# writing
# --------------------------------------------------------------------------


def write_tree(tree: H5Tree, path: str | os.PathLike, form: str = "hdf5") -> Path:
    """Write ``tree`` to ``path`` as ``form`` (``"hdf5"`` or ``"json"``), atomically.

    In HDF5, strings are fixed-length null-terminated ASCII (as Statismo's
    ``HDF5Utils`` writes them); in HDF5-JSON, variable-length scalar UTF-8
    strings (as Scalismo writes them).

    Examples
    --------
    >>> import tempfile
    >>> t = H5Tree()
    >>> t.add("/model/mean", np.arange(3, dtype=np.float32))
    >>> t.attrs["/representer"] = {"datasetType": "POINT_SET"}
    >>> t.group("/representer")
    >>> d = Path(tempfile.mkdtemp())
    >>> [read_tree(write_tree(t, d / f"m.{f}", f)).array("/model/mean").tolist() for f in FORMATS]
    [[0.0, 1.0, 2.0], [0.0, 1.0, 2.0]]
    """
    from ._files import atomic_path

    if form not in FORMATS:
        raise ValueError(f"form must be one of {FORMATS}, got {form!r}")
    target = Path(path)
    with atomic_path(target, HortishapeError) as tmp:
        if form == "hdf5":
            _write_hdf5(tree, tmp)
        else:
            Path(tmp).write_text(json.dumps(_json_document(tree), separators=(",", ":")), encoding="utf-8")
    return target


def _write_hdf5(tree: H5Tree, tmp) -> None:
    import h5py

    def put_attrs(obj, attrs: dict, fixed: bool) -> None:
        for k, v in attrs.items():
            if isinstance(v, str) and fixed:
                value, dtype = _fixed_string(v)
                obj.attrs.create(k, value, dtype=dtype)
            else:
                obj.attrs[k] = v

    with h5py.File(tmp, "w") as f:
        for g in sorted(tree.groups, key=lambda s: s.count("/")):
            if g != "/":
                f.require_group(g)
        for path, v in tree.datasets.items():
            if isinstance(v, str):
                value, dtype = _fixed_string(v)
                f.create_dataset(path, data=value, dtype=dtype)
            elif isinstance(v, list):
                f.create_dataset(path, data=v, dtype=h5py.string_dtype())
            else:
                f.create_dataset(path, data=v)
        for path, attrs in tree.attrs.items():
            # Statismo's strings are fixed-length; hortishape's own group keeps
            # h5py's variable-length ones, as its files always had
            put_attrs(f[path] if path != "/" else f, attrs, fixed=not path.startswith("/hortishape"))


def _fixed_string(text: str):
    """A null-terminated fixed-length ASCII string type and value, as Statismo's HDF5Utils writes."""
    import h5py

    raw = text.encode("utf-8")
    tid = h5py.h5t.C_S1.copy()
    tid.set_size(len(raw) + 1)
    tid.set_strpad(h5py.h5t.STR_NULLTERM)
    return np.array(raw, dtype=f"S{len(raw) + 1}"), h5py.Datatype(tid)


def _json_item(v) -> dict:
    """HDF5-JSON ``type``, ``shape`` and ``value`` of a dataset or attribute value."""
    string = {"class": "H5T_STRING", "charSet": "H5T_CSET_UTF8", "strPad": "H5T_STR_NULLPAD",
              "length": "H5T_VARIABLE"}
    if isinstance(v, str):
        return {"type": string, "shape": {"class": "H5S_SCALAR"}, "value": v}
    if isinstance(v, list):
        return {"type": string, "shape": {"class": "H5S_SIMPLE", "dims": [len(v)]}, "value": list(v)}
    a = np.asarray(v)
    if a.dtype == np.bool_:  # HDF5-JSON readers (Scalismo's) know no booleans
        a = a.astype(np.int8)
    if a.dtype.newbyteorder("=") not in _JSON_TYPES:
        raise TypeError(f"no HDF5-JSON type for {a.dtype}")
    cls, base = _JSON_TYPES[a.dtype.newbyteorder("=")]
    shape = {"class": "H5S_SCALAR"} if a.ndim == 0 else {"class": "H5S_SIMPLE", "dims": list(a.shape)}
    return {"type": {"class": cls, "base": base}, "shape": shape, "value": a.tolist()}


def _json_document(tree: H5Tree) -> dict:
    ids = {g: str(uuid.uuid4()) for g in sorted(tree.groups)}
    dids = {d: str(uuid.uuid4()) for d in sorted(tree.datasets)}
    groups = {ids[g]: {"alias": [g], "links": []} for g in ids}

    def parent(p: str) -> str:
        return p.rsplit("/", 1)[0] or "/"

    for g in sorted(tree.groups):
        if g != "/":
            groups[ids[parent(g)]]["links"].append(
                {"class": "H5L_TYPE_HARD", "collection": "groups", "id": ids[g], "title": g.rsplit("/", 1)[1]})
    datasets = {}
    for d in sorted(tree.datasets):
        groups[ids[parent(d)]]["links"].append(
            {"class": "H5L_TYPE_HARD", "collection": "datasets", "id": dids[d], "title": d.rsplit("/", 1)[1]})
        datasets[dids[d]] = {"alias": [d], **_json_item(tree.datasets[d])}
    for path, attrs in tree.attrs.items():
        items = [{"name": k, **_json_item(v)} for k, v in attrs.items()]
        if path in ids:
            groups[ids[path]]["attributes"] = items
        else:
            datasets[dids[path]]["attributes"] = items
    return {"apiVersion": "1.1.1", "root": ids["/"], "groups": groups, "datasets": datasets}


# --------------------------------------------------------------------------
# models
# --------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class ModelData:
    """What a model file holds: the fitted attributes of a :class:`~hortishape.model.ShapeModel`.

    ``mean`` ``(n, 3)``, ``components`` ``(k, 3n)`` (orthonormal rows),
    ``variances`` ``(k,)``; ``scores`` ``(N, k)`` in standard deviations;
    ``n_components`` and ``procrustes`` are the model's parameters;
    ``provenance`` what a file read says of who wrote it and when
    (``{"written by": ..., "build time": ...}``, as far as it says).
    """

    mean: np.ndarray
    components: np.ndarray
    variances: np.ndarray
    total_variance: float
    noise_variance: float | None = None
    n_samples: int | None = None
    faces: np.ndarray | None = None
    names: tuple | None = None
    scores: np.ndarray | None = None
    procrustes_transforms: np.ndarray | None = None
    n_components: object = None
    procrustes: bool = False
    provenance: dict = field(default_factory=dict)


def _version() -> str:
    from ._version import __version__

    return __version__


def write_model(data: ModelData, path: str | os.PathLike, form: str | None = None) -> Path:
    """Write a model file, atomically: HDF5 (Statismo v0.9) or HDF5-JSON (Scalismo 0.92+).

    Parameters
    ----------
    data : ModelData
    path : str or os.PathLike
    form : {"hdf5", "json"}, optional
        Default: ``"json"`` for a name ending in ``.json``, else ``"hdf5"``.

    Returns
    -------
    pathlib.Path

    Examples
    --------
    >>> import tempfile, trimesh
    >>> from hortishape.model import ShapeModel
    >>> s = trimesh.creation.icosphere(subdivisions=2, radius=30.0)
    >>> shapes = s.vertices * np.random.default_rng(0).uniform(0.8, 1.2, (6, 1, 3))
    >>> data = read_model(ShapeModel().fit(shapes, s.faces).save(tempfile.mkdtemp() + "/model.h5"))
    >>> path = write_model(data, tempfile.mkdtemp() + "/for-scalismo.json")   # HDF5-JSON, by its name
    >>> bool(np.allclose(read_model(path).mean, data.mean))
    True
    """
    p = Path(path)
    form = form or ("json" if p.suffix.lower() == ".json" else "hdf5")
    if form not in FORMATS:
        raise HortishapeError(f"{p}: unknown model file format {form!r} (one of {', '.join(FORMATS)})")
    return write_tree(model_tree(data), p, form)


def model_tree(data: ModelData, *, build_time: str | None = None) -> H5Tree:
    """The Statismo v0.9 layout of a model plus hortishape's ``/hortishape`` group (see ``ShapeModel.save``)."""
    import time

    build_time = build_time or time.asctime()
    k, d = data.components.shape
    names = data.names or tuple(f"shape_{i:03d}" for i in range(data.n_samples or 0))
    t = H5Tree()
    t.add("/version/majorVersion", np.int32(0))
    t.add("/version/minorVersion", np.int32(9))

    t.group("/representer/pointData")
    t.group("/representer/cellData")
    t.attrs["/representer"] = {
        "name": _REPRESENTER_NAME,
        "version": _REPRESENTER_VERSION,
        "datasetType": "POINT_SET" if data.faces is None else "POLYGON_MESH",
    }
    t.add("/representer/points", np.ascontiguousarray(data.mean.T, dtype=np.float32))
    if data.faces is not None:
        # int32, not Statismo's own uint32: Statismo converts any integer type on
        # reading (H5::PredType::NATIVE_UINT), while scalismo's jhdf reader returns
        # uint32 as Java long[][] and fails to cast it to the Int arrays it expects.
        t.add("/representer/cells", np.ascontiguousarray(data.faces.T, dtype=np.int32))

    t.add("/model/mean", data.mean.reshape(-1).astype(np.float32))
    t.add("/model/pcaBasis", np.ascontiguousarray(data.components.T, dtype=np.float32))
    t.add("/model/pcaVariance", np.asarray(data.variances, dtype=np.float32))
    noise = float(data.noise_variance or 0.0)
    t.add("/model/noiseVariance", np.float32(noise))

    t.add("/modelinfo/build-time", build_time)
    if data.scores is not None:
        t.add("/modelinfo/scores", np.ascontiguousarray(data.scores.T, dtype=np.float32))
    else:  # Statismo's marker for "no scores"
        t.add("/modelinfo/scores", np.zeros((1, 1), dtype=np.float32))
    b = "/modelinfo/modelBuilder-0"
    t.add(f"{b}/builderName", "hortishape.ShapeModel")
    t.add(f"{b}/buildTime", build_time)
    t.group(f"{b}/dataInfo")
    for i, name in enumerate(names):
        t.add(f"{b}/dataInfo/URI_{i}", str(name))
    t.add(f"{b}/parameters/NoiseVariance", repr(noise))
    t.add(f"{b}/parameters/NumberOfComponents", str(k))
    t.add(f"{b}/parameters/Procrustes", "true" if data.procrustes else "false")
    t.add(f"{b}/parameters/Units", "mm")

    h = "/hortishape"
    t.add(f"{h}/mean", np.asarray(data.mean, dtype=np.float64))
    t.add(f"{h}/components", np.asarray(data.components, dtype=np.float64))
    t.add(f"{h}/explained_variance", np.asarray(data.variances, dtype=np.float64))
    t.add(f"{h}/total_variance", np.float64(data.total_variance))
    t.add(f"{h}/noise_variance", np.float64(noise))
    if data.scores is not None:
        t.add(f"{h}/scores", np.asarray(data.scores, dtype=np.float64))
    if data.faces is not None:
        t.add(f"{h}/faces", np.asarray(data.faces, dtype=np.int64))
    if data.names is not None:
        t.add(f"{h}/names", [str(n) for n in data.names])
    if data.procrustes_transforms is not None:
        t.add(f"{h}/procrustes_transforms", np.asarray(data.procrustes_transforms, dtype=np.float64))
    t.attrs[h] = {
        "format": _FORMAT,
        "format_version": np.int32(_FORMAT_VERSION),
        "hortishape_version": _version(),
        "units": "mm",
        "procrustes": np.bool_(data.procrustes),
        "n_components": json.dumps(data.n_components),
        "build_time": build_time,
    }
    if data.n_samples is not None:
        t.attrs[h]["n_samples"] = np.int64(data.n_samples)
    return t


def model_provenance(path: str | os.PathLike) -> dict:
    """Who wrote a model file and when, as far as the file says: ``{"written by": ..., "build time": ...}``.

    The same as ``read_model(path).provenance``.

    Examples
    --------
    >>> import tempfile
    >>> from hortishape.model import ShapeModel
    >>> path = ShapeModel().fit(np.random.default_rng(0).normal(size=(4, 6, 3))).save(tempfile.mkdtemp() + "/m.h5")
    >>> model_provenance(path)["written by"].startswith("hortishape")
    True
    """
    return read_model(path).provenance


def _provenance(tree: H5Tree) -> dict:
    def text(key):
        value = tree.datasets.get(key)
        if isinstance(value, list) and len(value) == 1:
            value = value[0]
        return value if isinstance(value, str) else None

    out = {}
    if "/hortishape" in tree.groups:
        out["written by"] = f"hortishape {tree.string('/hortishape', 'hortishape_version', '?')}"
    elif text("/modelinfo/modelBuilder-0/builderName"):
        out["written by"] = text("/modelinfo/modelBuilder-0/builderName")
    if text("/modelinfo/build-time"):
        out["build time"] = text("/modelinfo/build-time")
    return out


def read_model(path: str | os.PathLike) -> ModelData:
    """Read a model file: hortishape's, Statismo's or Scalismo's, HDF5 or HDF5-JSON.

    Files with a ``/hortishape`` group are read from its float64 copies;
    plain Statismo files (0.9 or 0.8 layout, standard mesh or point-set
    representer) from the float32 datasets: ``/model/mean``, ``pcaBasis``,
    ``pcaVariance``, ``noiseVariance``, the representer's ``cells`` as
    faces and ``/modelinfo/scores`` as scores. Such files do not record the
    total variance of the training shapes; it is taken as
    ``sum(pcaVariance) + noiseVariance * (3n - k)``.

    Raises
    ------
    HortishapeError
        If the file is missing, in neither form, or not a usable model.

    Examples
    --------
    >>> import tempfile, trimesh
    >>> from hortishape.model import ShapeModel
    >>> s = trimesh.creation.icosphere(subdivisions=2, radius=30.0)
    >>> shapes = s.vertices * np.random.default_rng(0).uniform(0.8, 1.2, (6, 1, 3))
    >>> path = ShapeModel().fit(shapes, s.faces).save(tempfile.mkdtemp() + "/model.h5")
    >>> data = read_model(path)
    >>> data.mean.shape, data.components.shape[0]
    ((162, 3), 3)
    """
    p = Path(path)
    tree = read_tree(p)
    try:
        data = _from_hortishape(tree, p) if "/hortishape" in tree.groups else _from_statismo(tree, p)
        return replace(data, provenance=_provenance(tree))
    except (KeyError, ValueError, TypeError) as exc:
        raise HortishapeError(f"{p}: unusable model file ({exc})") from None


def _from_hortishape(t: H5Tree, path: Path) -> ModelData:
    h = "/hortishape"
    fmt = t.string(h, "format", "")
    if fmt != _FORMAT:
        raise HortishapeError(f"{path}: /hortishape is not a hortishape model (format {fmt!r})")
    a = t.attrs.get(h, {})
    fv = int(np.asarray(a.get("format_version", 0)).reshape(-1)[0])
    if fv > _FORMAT_VERSION:
        raise HortishapeError(
            f"{path}: model format version {fv} is newer than this hortishape reads ({_FORMAT_VERSION}); "
            "update hortishape"
        )
    for key in ("mean", "components", "explained_variance", "total_variance"):
        if f"{h}/{key}" not in t.datasets:
            raise HortishapeError(f"{path}: /hortishape/{key} is missing")
    mean = t.array(f"{h}/mean")
    components = t.array(f"{h}/components")
    variances = t.array(f"{h}/explained_variance")
    _check_loaded(path, mean, components, variances)

    def optional(key, dtype=np.float64):
        return t.array(f"{h}/{key}", dtype) if f"{h}/{key}" in t.datasets else None

    names = t.datasets.get(f"{h}/names")
    faces = optional("faces", np.int64)
    noise = optional("noise_variance")
    return ModelData(
        mean=mean,
        components=components,
        variances=variances,
        total_variance=float(t.array(f"{h}/total_variance")),
        noise_variance=None if noise is None else float(noise),
        n_samples=int(np.asarray(a["n_samples"]).reshape(-1)[0]) if "n_samples" in a else None,
        faces=faces,
        names=None if names is None else tuple([names] if isinstance(names, str) else names),
        scores=optional("scores"),
        procrustes_transforms=optional("procrustes_transforms"),
        n_components=json.loads(t.string(h, "n_components", "null")),
        procrustes=bool(np.asarray(a.get("procrustes", False)).reshape(-1)[0]),
    )


def _from_statismo(t: H5Tree, path: Path) -> ModelData:
    missing = [k for k in ("/representer", "/model/mean", "/model/pcaBasis", "/model/pcaVariance") if k not in t]
    if missing:
        raise HortishapeError(f"{path}: not a Statismo model file (missing {', '.join(missing)})")
    rep_name = t.string("/representer", "name", "")
    if rep_name in _LEGACY_REPRESENTERS:
        raise HortishapeError(
            f"{path}: a Statismo file with the legacy representer {rep_name!r} (an embedded VTK file) "
            "is not supported; convert it with a current Statismo or scalismo first"
        )
    if "/representer/points" not in t.datasets:
        raise HortishapeError(f"{path}: /representer/points is missing")
    dataset_type = t.string("/representer", "datasetType", "POLYGON_MESH")
    if dataset_type not in ("POLYGON_MESH", "POINT_SET"):
        raise HortishapeError(f"{path}: representer datasetType {dataset_type!r} is not a surface or point set")
    if "/version/majorVersion" in t.datasets:
        major = int(t.array("/version/majorVersion").reshape(-1)[0])
        minor = int(t.array("/version/minorVersion").reshape(-1)[0])
    else:
        major, minor = 0, 8
    if (major, minor) not in ((0, 8), (0, 9)) and major != 1:
        raise HortishapeError(f"{path}: unsupported Statismo file version {major}.{minor}")

    mean = t.array("/model/mean").reshape(-1)
    basis = t.array("/model/pcaBasis")
    variances = t.array("/model/pcaVariance").reshape(-1)
    if basis.ndim != 2 or basis.shape != (mean.size, variances.size):
        raise HortishapeError(
            f"{path}: /model/pcaBasis has shape {basis.shape}, expected ({mean.size}, {variances.size})"
        )
    if (major, minor) == (0, 8):  # old files store U * sqrt(lambda)
        sd = np.sqrt(np.where(variances > 0, variances, 1.0))
        basis = basis / sd
    if mean.size % 3:
        raise HortishapeError(f"{path}: /model/mean has {mean.size} values, not 3 per point")
    noise = float(t.array("/model/noiseVariance").reshape(-1)[0]) if "/model/noiseVariance" in t.datasets else 0.0
    # keep the modes with positive variance, ordered by decreasing variance
    n_file_modes = variances.size
    keep = np.flatnonzero(variances > 0)
    order = keep[np.argsort(-variances[keep], kind="stable")]
    variances, components = variances[order], basis[:, order].T
    mean_points = mean.reshape(-1, 3)
    _check_loaded(path, mean_points, components, variances)

    faces = None
    if dataset_type == "POLYGON_MESH" and "/representer/cells" in t.datasets:
        cells = t.array("/representer/cells", np.int64)
        if cells.ndim != 2 or cells.shape[0] != 3:
            raise HortishapeError(f"{path}: /representer/cells has shape {cells.shape}: not triangles (3, m)")
        faces = cells.T.copy()
        try:
            check_mesh(mean_points, faces, name=str(path))
        except MeshError as exc:
            raise HortishapeError(str(exc)) from None

    scores = None
    n_samples = None
    names = None
    if "/modelinfo/scores" in t.datasets:
        s = t.array("/modelinfo/scores")
        if s.ndim == 2 and s.shape[0] == n_file_modes and not (s.shape == (1, 1) and s[0, 0] == 0.0):
            scores = s[order].T
            n_samples = s.shape[1]
    info = "/modelinfo/modelBuilder-0/dataInfo"
    uris = sorted((k for k in t.children(info) if k.startswith("URI_")),
                  key=lambda k: int(k[4:]) if k[4:].isdigit() else 0)
    if uris:
        names = tuple(t.text(f"{info}/{k}") for k in uris)
        if n_samples is None:
            n_samples = len(names)
        elif len(names) != n_samples:
            names = None
    d, k = mean.size, len(variances)
    return ModelData(
        mean=mean_points,
        components=components,
        variances=variances,
        total_variance=float(variances.sum()) + noise * (d - k),
        noise_variance=noise,
        n_samples=n_samples,
        faces=faces,
        names=names,
        scores=scores,
        n_components=k,
        procrustes=False,
    )


def _check_loaded(path: Path, mean, components, variances) -> None:
    mean = np.asarray(mean)
    if mean.ndim != 2 or mean.shape[1] != 3 or mean.shape[0] == 0:
        raise HortishapeError(f"{path}: the mean shape has shape {mean.shape}, expected (n, 3)")
    if components.ndim != 2 or components.shape[1] != mean.size or components.shape[0] != len(variances):
        raise HortishapeError(
            f"{path}: the modes have shape {components.shape}, expected ({len(variances)}, {mean.size})"
        )
    if len(variances) == 0:
        raise HortishapeError(f"{path}: the model has no modes with positive variance")
    if not (np.isfinite(mean).all() and np.isfinite(components).all() and np.isfinite(variances).all()):
        raise HortishapeError(f"{path}: the model holds NaN or infinite values")
