"""CAD description of a shape model: cylindrical parameterization, B-spline surfaces, STEP/IGES.

The paper (section 2.2.4, results in 3.3 and Fig. 9) parameterizes the
*mean* surface of a shape model on a cylinder, so that every vertex has
``(u, v)`` coordinates, and approximates surfaces by B-splines on that
domain. Because all instances of the model are in correspondence with the
mean, they share its ``(u, v)``; the control points of an instance are then
a *linear* function of its coordinates, and so of its shape coefficients
``b``: the fitting operator is computed once and any instance (the mean, a
random sample, mean +/- k SD along a mode, a fitted scan) is a CAD surface
without refitting.

The steps, and how they are done here
-------------------------------------
1. **Poles** (:func:`find_poles`): the stalk and the bottom point, given as
   landmarks or found automatically. The automatic search tries each of the
   three principal axes of the area-weighted surface: the point geodesically
   farthest from the half of the surface below the mid-plane is one end;
   then each pole is taken as the *centre* of the region nearest to being
   farthest from the other pole (the point of that region farthest from its
   edge), twice, so a stalk tip or the middle of a calyx basin is found
   rather than a basin's rim. Of the three pairs, the one farthest apart
   along the surface wins (a stalk and cavities lengthen the fruit's
   meridian, so even a round apple's stalk axis wins). The stalk is the
   thinner end: the one with less surface within a geodesic ball around its
   pole.
2. **Opening and parameterization** (:func:`parameterize`): the faces around
   both poles are removed, which leaves a cylinder (a mesh with two boundary
   loops). The shortest edge path between the loops is the seam. The mesh
   is mapped onto the cylinder ``[0, 1) x [0, 1]`` (``u`` periodic) by a
   periodic Tutte embedding with mean-value weights (Floater 2003): every
   vertex is the weighted mean of its neighbours, ``u`` jumps by 1 across
   the seam, the loops lie on ``v = 0`` and ``v = 1`` spaced by arc length.
   A convex-combination map onto a flat cylinder with straight boundaries is
   one-to-one (Gortler, Gotsman and Thurston 2006), so no triangle flips; the
   result is checked (:attr:`CylinderMap.n_flipped`, and the unrolled disc
   covers the unit square exactly once). The paper builds its map through a
   progressive mesh instead; any bijective low-distortion map serves.
   A harmonic ``v`` crowds a thin stalk: a tube of radius ``r`` and length
   ``L`` takes ``L / (2 pi r)`` of the conformal height, more than half of
   it for an apple's stalk. So ``v`` is then reparameterized monotonically
   (which cannot flip a triangle) to be proportional to the mean
   *meridian arc length*, with the poles' one-rings added at both ends:
   equal steps of ``v`` are equal millimetres along the fruit.
3. **B-spline approximation** (:class:`BSplineFitter`): bicubic, periodic
   in ``u`` (uniform knots), clamped in ``v`` (uniform knots), with a
   ``k x k`` control grid whose first and last rows are each collapsed to
   one point, so the surface closes at both poles. The control points
   minimise the area-weighted squared distance to the triangle surface,
   ``integral |S(u, v) - X(u, v)|^2 dA``, evaluated on a regular grid of
   samples in ``(u, v)`` (8 per knot span; points of the triangle surface
   found by barycentric interpolation), so every knot span has data even
   where the surface is thin. The operator from vertex coordinates to control
   points is linear and is factored once.
4. **Model instances** (:class:`BSplineModel`): the mean's control points
   and one set per mode; an instance's control points are ``P_mean + sum_i
   c_i sqrt(lambda_i) P_i`` (eq. 13 carried over to control points).
5. **Export** (:func:`write_cad`): JSON (control points and knots, no extra
   dependency), STEP and IGES through OpenCascade (``pip install
   'hortishape[cad]'``, imported only when used), as one closed face
   (periodic in ``u``, degenerate at both poles) bounding a solid.
   :func:`read_cad` reads any of the three back, :func:`cad_volume` gives
   the volume of a STEP or IGES solid as OpenCascade computes it.

Conventions: control points are ``(k_u, k_v, 3)`` arrays in millimetres,
index ``[i, j]`` with ``i`` along ``u`` (around the fruit) and ``j`` along
``v`` (``v = 0`` the bottom pole, ``v = 1`` the stalk). Knots are as in
OpenCascade and STEP: distinct values and multiplicities; ``u`` periodic with
``k_u + 1`` knots of multiplicity 1 on ``[0, 1]``; ``v`` with ``k_v - 2``
distinct knots, multiplicity 4 at both ends.
"""

from __future__ import annotations

from .bspline import BSplineSurface
from .deviation import Deviation, render_deviation, surface_deviation
from .files import cad_formats, cad_volume, read_cad, write_cad
from .fit import BSplineFitter, BSplineModel
from .parameterize import CylinderMap, grid_map, parameterize
from .poles import Poles, find_poles

__all__ = [
    "BSplineFitter",
    "BSplineModel",
    "BSplineSurface",
    "CylinderMap",
    "Deviation",
    "Poles",
    "cad_formats",
    "cad_volume",
    "find_poles",
    "grid_map",
    "parameterize",
    "read_cad",
    "render_deviation",
    "surface_deviation",
    "write_cad",
]
