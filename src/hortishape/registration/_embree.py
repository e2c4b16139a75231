"""Embree through its C interface (ctypes), for a ray scene that is built once and queried once or twice.

``embreex`` copies a mesh into Embree one element at a time through Python
indexing, which takes several times as long as Embree's own tree build
(docs/design-notes.md). Filter (c) builds a scene of the deformed source in
every fine iteration and queries it once, so the copy dominates it. Here Embree reads the numpy arrays in place (shared buffers)
and rays go in packets of 16 (``rtcIntersect16``); the library is the one
``embreex`` ships, so the hits are the same. A query holds Python's lock
between packets, so it runs on one core: for a scene queried many times
(the target) ``embreex``'s threaded queries stay the faster choice.

:func:`library` returns ``None`` wherever the library cannot be found or
fails a one-triangle check, and callers then use ``embreex``.
"""

from __future__ import annotations

import ctypes
import functools
import glob
import os
import weakref

import numpy as np

_VP = ctypes.c_void_p
#: Embree 4 enumerations (rtcore_common.h, rtcore_buffer.h, rtcore_geometry.h, rtcore_scene.h).
_INDEX, _VERTEX = 0, 1
_UINT3, _FLOAT3 = 0x5003, 0x9003
_TRIANGLE = 0
_ROBUST = 1 << 2  # as embreex's scenes
#: A tree built fast rather than well: the scene answers one query.
_QUALITY = 0  # RTC_BUILD_QUALITY_LOW
_INVALID = 0xFFFFFFFF
#: RTCRayHit16 in units of 16 lanes: the ray's 12 fields, then the hit's.
_ORG, _DIR, _TFAR, _MASK = 0, 4, 8, 9
_U, _V, _PRIM, _INST = 15, 16, 17, 19  # the geometry's id (18) lies between
#: Bytes per packet slot: the struct is 1216 bytes plus 64-128 per instance
#: level the library was built with; 2048 leaves room for several.
_SLOT = 2048
_ALIGN = 64


def _candidates() -> list[str]:
    """Paths where the Embree 4 library that embreex links to may lie (wheels vendor it beside the package)."""
    import embreex

    here = os.path.dirname(embreex.__file__)
    found = []
    for folder in (os.path.join(here, os.pardir, "embreex.libs"), os.path.join(here, ".dylibs"), here):
        found += sorted(glob.glob(os.path.join(folder, "*embree4*")))
    return found


@functools.lru_cache(maxsize=1)
def library():
    """The Embree 4 library as a ctypes handle with its signatures set, or None.

    Loaded once per process (it is the same library embreex has loaded) and
    checked on one triangle before it is used.
    """
    try:
        paths = _candidates()
    except ImportError:
        return None
    for path in paths:
        try:
            lib = ctypes.CDLL(path)
            _declare(lib)
            if _works(lib):
                return lib
        except (OSError, AttributeError):
            continue
    return None


def _declare(lib) -> None:
    lib.rtcNewDevice.restype = _VP
    lib.rtcNewDevice.argtypes = [ctypes.c_char_p]
    lib.rtcReleaseDevice.argtypes = [_VP]
    lib.rtcGetDeviceError.restype = ctypes.c_int
    lib.rtcGetDeviceError.argtypes = [_VP]
    lib.rtcNewScene.restype = _VP
    lib.rtcNewScene.argtypes = [_VP]
    lib.rtcSetSceneFlags.argtypes = [_VP, ctypes.c_int]
    lib.rtcSetSceneBuildQuality.argtypes = [_VP, ctypes.c_int]
    lib.rtcSetGeometryBuildQuality.argtypes = [_VP, ctypes.c_int]
    lib.rtcNewGeometry.restype = _VP
    lib.rtcNewGeometry.argtypes = [_VP, ctypes.c_int]
    lib.rtcSetSharedGeometryBuffer.argtypes = [_VP, ctypes.c_int, ctypes.c_uint, ctypes.c_int, _VP,
                                               ctypes.c_size_t, ctypes.c_size_t, ctypes.c_size_t]
    lib.rtcCommitGeometry.argtypes = [_VP]
    lib.rtcAttachGeometry.restype = ctypes.c_uint
    lib.rtcAttachGeometry.argtypes = [_VP, _VP]
    lib.rtcReleaseGeometry.argtypes = [_VP]
    lib.rtcCommitScene.argtypes = [_VP]
    lib.rtcReleaseScene.argtypes = [_VP]
    lib.rtcIntersect16.restype = None
    lib.rtcIntersect16.argtypes = [_VP, _VP, _VP, _VP]


def _works(lib) -> bool:
    """Whether a ray down onto one triangle hits it where it should."""
    scene = PacketScene(np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]]), np.array([[0, 1, 2]]), lib=lib)
    if not scene.ok:
        return False
    face, u, v = scene.hits(np.array([[0.2, 0.3, 1.0]], np.float32), np.array([[0.0, 0, -1]], np.float32), None)
    return face.tolist() == [0] and abs(u[0] - 0.2) < 1e-6 and abs(v[0] - 0.3) < 1e-6


def _aligned(shape: tuple, dtype) -> np.ndarray:
    """A zeroed array whose data starts on a 64-byte boundary (Embree's packets require it)."""
    size = int(np.prod(shape)) * np.dtype(dtype).itemsize
    raw = np.zeros(size + _ALIGN, np.uint8)
    start = -raw.ctypes.data % _ALIGN
    return raw[start:start + size].view(dtype).reshape(shape)


def _release(lib, device, scene) -> None:
    lib.rtcReleaseScene(scene)
    lib.rtcReleaseDevice(device)


class PacketScene:
    """An Embree scene over numpy arrays shared with it, queried 16 rays at a time.

    ``ok`` is False if Embree reported an error while building it (the caller
    then builds another kind of scene). :meth:`hits` takes float32 rays in
    the scene's frame and returns Embree's raw answer, like embreex's
    ``run(..., output=1)``: the face (-1 for a miss) and the barycentric
    ``u`` and ``v`` of each hit.
    """

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, *, lib=None) -> None:
        self._lib = lib = lib or library()
        # float3 in 16-byte slots: Embree may read the last vertex with one 16-byte load
        self._vertices = _aligned((len(vertices), 4), np.float32)
        self._vertices[:, :3] = vertices
        self._faces = np.ascontiguousarray(faces, dtype=np.uint32)
        self._device = lib.rtcNewDevice(None)
        self._scene = lib.rtcNewScene(self._device)
        weakref.finalize(self, _release, lib, self._device, self._scene)
        lib.rtcSetSceneFlags(self._scene, _ROBUST)
        lib.rtcSetSceneBuildQuality(self._scene, _QUALITY)
        geom = lib.rtcNewGeometry(self._device, _TRIANGLE)
        lib.rtcSetGeometryBuildQuality(geom, _QUALITY)
        lib.rtcSetSharedGeometryBuffer(geom, _VERTEX, 0, _FLOAT3, self._vertices.ctypes.data, 0, 16, len(vertices))
        lib.rtcSetSharedGeometryBuffer(geom, _INDEX, 0, _UINT3, self._faces.ctypes.data, 0, 12, len(self._faces))
        lib.rtcCommitGeometry(geom)
        lib.rtcAttachGeometry(self._scene, geom)
        lib.rtcReleaseGeometry(geom)
        lib.rtcCommitScene(self._scene)
        self.ok = lib.rtcGetDeviceError(self._device) == 0

    def hits(self, origins: np.ndarray, directions: np.ndarray, tfar) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """First hits of float32 rays (``tfar``: per-ray float32 limits, or None)."""
        k = len(origins)
        packets = -(-k // 16)
        slot = _SLOT // 4
        buf = _aligned((packets, slot), np.float32)
        words = buf.view(np.uint32)

        def put(field: int, values) -> None:
            lanes = np.zeros(packets * 16, dtype=buf.dtype)
            lanes[:k] = values
            buf[:, field * 16:(field + 1) * 16] = lanes.reshape(packets, 16)

        for c in range(3):
            put(_ORG + c, origins[:, c])
            put(_DIR + c, directions[:, c])
        put(_TFAR, 1e37 if tfar is None else tfar)  # as embreex, where no limit is given
        words[:, _MASK * 16:(_MASK + 1) * 16] = _INVALID  # every mask bit: no ray is masked out
        words[:, _PRIM * 16:(_INST + 1) * 16] = _INVALID  # primitive, geometry, instance: none yet
        valid = _aligned((2, 16), np.int32)
        valid[0] = -1
        valid[1, :k - (packets - 1) * 16] = -1  # the last packet's rays beyond k stay inactive
        intersect, scene, base = self._lib.rtcIntersect16, self._scene, buf.ctypes.data
        full, last = valid[0].ctypes.data, valid[1].ctypes.data
        for i in range(packets - 1):
            intersect(full, scene, base + i * _SLOT, None)
        intersect(last, scene, base + (packets - 1) * _SLOT, None)

        def get(field: int, array: np.ndarray) -> np.ndarray:
            return array[:, field * 16:(field + 1) * 16].reshape(-1)[:k]

        prim = get(_PRIM, words)
        face = np.where(prim == _INVALID, -1, prim.astype(np.int64))
        return face, get(_U, buf).copy(), get(_V, buf).copy()
