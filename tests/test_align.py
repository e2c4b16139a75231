"""Tests of hortishape.align: principal axes (eqs. 1-7), candidates, least squares."""

import numpy as np
import pytest
import trimesh

from hortishape.align import (
    axis_alignments,
    fruit_axis,
    apply_transform,
    candidate_alignments,
    pca_alignment,
    principal_axes,
    rigid_fit,
    rigid_transform,
    rotation_about,
    rotation_angle,
)
from hortishape.errors import MeshError
from hortishape.mesh import Mesh


def _egg(n=4000, seed=0):
    """Points of an egg-like, asymmetric body: axes and signs are identifiable."""
    rng = np.random.default_rng(seed)
    p = rng.normal(size=(n, 3))
    p /= np.linalg.norm(p, axis=1, keepdims=True)
    p *= [30.0, 20.0, 12.0]
    p[:, 0] += 0.01 * p[:, 0] ** 2  # skew along x
    p[:, 1] += 0.02 * p[:, 1] ** 2  # skew along y
    return p


def test_principal_axes_of_ellipsoid():
    s = trimesh.creation.icosphere(4)
    v = s.vertices * [30.0, 20.0, 10.0] + [1.0, 2.0, 3.0]
    pa = principal_axes(v)
    np.testing.assert_allclose(pa.centroid, [1, 2, 3], atol=1e-6)
    np.testing.assert_allclose(np.abs(pa.axes), np.eye(3), atol=1e-6)
    assert pa.variances[0] > pa.variances[1] > pa.variances[2]
    assert np.isclose(np.linalg.det(pa.axes), 1.0)


def test_surface_principal_axes_do_not_depend_on_the_vertex_spread():
    # an egg whose triangles on one diagonal half are split into four: the
    # same surface with its vertices crowded there, as a marching-cubes scan
    # crowds them where the surface runs obliquely to the voxel grid
    s = trimesh.creation.icosphere(3)
    v = s.vertices * [30.0, 20.0, 12.0]
    v[:, 0] += 0.01 * v[:, 0] ** 2
    v[:, 1] += 0.02 * v[:, 1] ** 2
    egg = trimesh.Trimesh(v, s.faces, process=False)
    crowded_faces = np.flatnonzero(egg.triangles_center @ [1.0, 1.0, 0.0] > 0)
    crowded = egg.subdivide(crowded_faces)
    assert len(crowded.vertices) > 1.4 * len(egg.vertices)
    a = principal_axes(egg.vertices, egg.faces)
    b = principal_axes(crowded.vertices, crowded.faces)
    np.testing.assert_allclose(b.centroid, a.centroid, atol=1e-9)
    np.testing.assert_allclose(b.axes, a.axes, atol=1e-9)
    np.testing.assert_allclose(b.variances, a.variances, rtol=1e-9)
    # the vertices' own axes are pulled towards the crowded half
    pv, pc = principal_axes(egg.vertices), principal_axes(crowded.vertices)
    assert np.linalg.norm(pc.centroid - pv.centroid) > 5.0  # measured 7.2 mm
    assert np.degrees(np.arccos(abs(pc.axes[:, 0] @ pv.axes[:, 0]))) > 10.0  # measured 18
    # candidates built on the surfaces' moments agree too
    ca = candidate_alignments(egg.vertices, egg.vertices, source_faces=egg.faces, target_faces=egg.faces)
    cb = candidate_alignments(egg.vertices, crowded.vertices, source_faces=egg.faces, target_faces=crowded.faces)
    np.testing.assert_allclose(cb, ca, atol=1e-8)
    np.testing.assert_allclose(ca[0], np.eye(4), atol=1e-9)
    with pytest.raises(MeshError, match="no area"):
        principal_axes(np.zeros((4, 3)), [[0, 1, 2], [1, 2, 3]])


def test_pca_alignment_recovers_rotation_with_deterministic_signs():
    src = _egg()
    r = rotation_about([1.0, -2.0, 0.5], 2.2)
    t = pca_alignment(src, src @ r.T + [10.0, -5.0, 3.0])
    np.testing.assert_allclose(t[:3, :3], r, atol=1e-6)
    np.testing.assert_allclose(apply_transform(t, src), src @ r.T + [10.0, -5.0, 3.0], atol=1e-6)


def test_candidates_are_24_proper_rotations_including_truth():
    src = _egg()
    r = rotation_about([0.3, 1.0, -0.2], 1.3)
    cands = candidate_alignments(src, src @ r.T)
    assert cands.shape == (24, 4, 4)
    dets = np.linalg.det(cands[:, :3, :3])
    np.testing.assert_allclose(dets, 1.0, atol=1e-9)
    # all different, and the true rotation is among them (first: eq. 7's order)
    flat = cands[:, :3, :3].reshape(24, 9)
    assert len(np.unique(flat.round(6), axis=0)) == 24
    assert np.allclose(cands[0, :3, :3], r, atol=1e-6)


def test_candidates_with_axis_hint_keep_the_axis():
    src = _egg()
    up_s = np.array([0.0, 0.0, 1.0])
    r = rotation_about([1.0, 1.0, 0.0], 0.8)
    cands = candidate_alignments(src, src @ r.T, source_up=up_s, target_up=r @ up_s, n_twists=6)
    assert len(cands) == 8
    for c in cands:
        np.testing.assert_allclose(c[:3, :3] @ up_s, r @ up_s, atol=1e-9)
    with pytest.raises(ValueError):
        candidate_alignments(src, src, source_up=up_s)


def test_rigid_fit_known_motion_and_weights():
    rng = np.random.default_rng(3)
    s = rng.normal(size=(200, 3)) * 20
    r = rotation_about([2, 1, 0], 0.9)
    q = s @ r.T + [4.0, 5.0, 6.0]
    t = rigid_fit(s, q)
    np.testing.assert_allclose(t, rigid_transform(r, [4, 5, 6]), atol=1e-9)
    # outliers with zero weight do not matter
    q2 = q.copy()
    q2[:20] += 100.0
    w = np.ones(200)
    w[:20] = 0
    np.testing.assert_allclose(rigid_fit(s, q2, weights=w), t, atol=1e-9)
    # never a reflection
    assert np.isclose(np.linalg.det(rigid_fit(s, s * [1, 1, -1])[:3, :3]), 1.0)


def test_inputs_not_mutated_and_bad_input():
    src = _egg()
    before = src.copy()
    pca_alignment(src, src)
    np.testing.assert_array_equal(src, before)
    with pytest.raises(MeshError):
        principal_axes(np.zeros((2, 3)))
    with pytest.raises(MeshError):
        principal_axes(np.full((10, 3), np.nan))


def test_rotation_angle():
    assert rotation_angle(np.eye(3)) == 0.0
    for degrees in (0.5, 45.0, 120.0, 180.0):
        r = rotation_about([0.3, -1.0, 2.0], np.radians(degrees))
        assert abs(rotation_angle(r) - degrees) < 1e-6


# --------------------------------------------------------------------------
# fruit_axis, axis_alignments
# --------------------------------------------------------------------------


def _angle(a, b):
    return np.degrees(np.arccos(np.clip(a @ b / np.linalg.norm(a) / np.linalg.norm(b), -1.0, 1.0)))


def _dimpled(depth_top=10.0, depth_bottom=0.0):
    """An oblate body of revolution about z with a cavity at the top (and optionally the bottom)."""
    s = trimesh.creation.icosphere(5, radius=40.0)
    v = s.vertices * [1.0, 1.0, 0.85]
    bump = np.exp(-((v[:, 0] ** 2 + v[:, 1] ** 2) / 100.0))
    v[:, 2] -= np.where(v[:, 2] > 0, depth_top, -depth_bottom) * bump
    return v, s.faces


@pytest.mark.parametrize("seed", range(4))
def test_fruit_axis_finds_the_axis_of_revolution_and_the_cavity_end_in_any_pose(seed):
    v, f = _dimpled()
    # wider one way than the other, so the principal axes are not the answer's
    v = v * [1.0, 1.04, 1.0]
    r = trimesh.transformations.random_rotation_matrix(np.random.default_rng(seed).random(3))[:3, :3]
    ax = fruit_axis(v @ r.T + [5.0, -3.0, 2.0], f)
    assert _angle(ax.direction, r @ [0.0, 0.0, 1.0]) < 2.0
    assert ax.contrast == 1.0 and ax.cavities[0] > 0.01
    np.testing.assert_allclose(ax.centre, r @ (v.mean(axis=0)) + [5.0, -3.0, 2.0], atol=1.0)


def test_fruit_axis_contrast_is_low_when_both_ends_have_a_cavity():
    v, f = _dimpled(depth_top=10.0, depth_bottom=9.0)
    ax = fruit_axis(v, f)
    assert _angle(ax.direction, [0.0, 0.0, 1.0]) < 2.0 or _angle(ax.direction, [0.0, 0.0, -1.0]) < 2.0
    assert ax.contrast < 0.3


def test_fruit_axis_on_the_real_scans(ycb):
    """Hand-marked poles: the axis within 30 degrees, and a cavity end told apart is the stalk end."""
    told = 0
    for name, (mesh, stalk, blossom) in ycb.items():
        ax = fruit_axis(mesh.vertices, mesh.faces)
        err = _angle(ax.direction, stalk - blossom)
        # 30 degrees is where an axis counts as right. The peach comes out at 28.9 (its blossom
        # mark is in doubt; the same to 0.01 degree with its vertices moved by 1e-6 mm), the
        # others within 10
        assert min(err, 180.0 - err) < 30.0, name
        if ax.contrast >= 0.5:
            told += 1
            assert err < 30.0, name
    assert told >= 3


def test_fruit_axis_on_synthetic_fruit_in_a_random_pose():
    from hortishape.synth import make_instance

    for product in ("apple", "pepper", "pear"):
        inst = make_instance(product, random_state=300, pose="random", n_vertices=8000)
        ax = fruit_axis(inst.mesh.vertices, inst.mesh.faces)
        assert _angle(ax.direction, inst.landmarks["stalk_tip"] - inst.landmarks["bottom"]) < 12.0, product


def _bent(bend=25.0, club=0.15):
    """A zucchini-like body 5 times longer than wide along z, thicker towards -z, bent in x; no end features."""
    s = trimesh.creation.icosphere(5)
    v = s.vertices * [20.0, 20.0, 100.0]
    v[:, :2] *= (1.0 + club * np.clip(-v[:, 2] / 100.0, 0.0, 1.0))[:, None]
    v[:, 0] += bend * (v[:, 2] / 100.0) ** 2
    return v, s.faces


def test_fruit_axis_does_not_tell_an_elongated_fruits_ends_by_its_bend():
    # the concave side of the bend lies below the hull towards both ends; an
    # END_CONE seen from the centroid took more of it at the thin end
    # (contrast 0.19)
    ax = fruit_axis(*_bent())
    assert min(_angle(ax.direction, [0.0, 0.0, 1.0]), _angle(ax.direction, [0.0, 0.0, -1.0])) < 5.0
    assert ax.contrast == 0.0


def test_fruit_axis_tells_an_elongated_fruits_ends_by_a_cavity_on_its_axis():
    from hortishape.synth import make_instance

    for seed in (1001, 1003):  # synthetic zucchini whose stalk sits in a cavity
        inst = make_instance("zucchini", random_state=seed, pose="random", n_vertices=8000)
        ax = fruit_axis(inst.mesh.vertices, inst.mesh.faces)
        assert ax.contrast >= 0.15, seed
        assert _angle(ax.direction, inst.landmarks["stalk_tip"] - inst.landmarks["bottom"]) < 15.0, seed


def test_axis_alignments_put_the_axis_on_the_axis_both_ways():
    a = fruit_axis(*_dimpled())
    r = rotation_about([1.0, 2.0, 0.5], 1.1)
    v, f = _dimpled()
    b = fruit_axis(v @ r.T + [10.0, 0.0, 0.0], f)
    ts = axis_alignments(a, b, n_turns=6)
    assert ts.shape == (12, 4, 4)
    for k, t in enumerate(ts):
        turned = t[:3, :3] @ a.direction
        assert _angle(turned, b.direction if k < 6 else -b.direction) < 1e-6
        np.testing.assert_allclose(apply_transform(t, a.centre[None])[0], b.centre, atol=1e-9)
    # one of the six turns is the true rotation (up to the sampling of the turn)
    assert min(rotation_angle(t[:3, :3] @ r.T) for t in ts[:6]) < 31.0
    assert axis_alignments(a, b, n_turns=6, both_ends=False).shape == (6, 4, 4)


def test_a_hole_at_an_end_leaves_that_end_untold():
    # the docstring's ellipsoid with a dimple at one end of its axis, then with the dimple cut away (as a
    # scanner misses a stalk cavity it cannot see into) and the hole closed by a patch
    from hortishape.registration import RegistrationConfig
    from hortishape.registration.orientation import _ends_told
    from hortishape.surface import fill_holes

    s = trimesh.creation.icosphere(5, radius=40.0)
    v = s.vertices * [1.0, 1.0, 0.8]
    v[:, 2] -= 12.0 * np.exp(-((v[:, 0] ** 2 + v[:, 1] ** 2) / 120.0)) * (v[:, 2] > 0)
    whole = fruit_axis(v, s.faces)
    assert whole.contrast == 1.0 and whole.hidden.tolist() == [0.0, 0.0]
    assert _ends_told(whole, RegistrationConfig())
    centres = v[s.faces].mean(axis=1)
    cut = trimesh.Trimesh(v, s.faces[~((centres[:, 2] > 0) & (np.hypot(centres[:, 0], centres[:, 1]) < 9.0))])
    cut.remove_unreferenced_vertices()
    closed = fill_holes(Mesh(cut.vertices, cut.faces))
    seen = fruit_axis(closed.mesh.vertices, closed.mesh.faces, observed=~closed.filled)
    assert abs(seen.direction[2]) > 0.99  # the axis is still found
    assert seen.hidden.max() > RegistrationConfig().end_cavity  # about 3 % of the surface under the patch
    assert not _ends_told(seen, RegistrationConfig())  # so both ends are searched
