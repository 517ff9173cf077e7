"""Exact silhouettes of superquadrics in pinhole cameras (their 2D IoU: :mod:`sqfit.geometry.polygon`).

The silhouette of a convex superquadric is computed from its *support function*, not from a
point sample of the surface, so it has no discretisation noise and is smooth in the parameters
(which matters for the finite differences of the R-IOU costs, stages 3A/3B/3F):

- A superquadric is the unit ball of the nested norm ``N(u) = ||(||(u1, u2)||_p2, u3)||_p1`` of
  ``u = t / a`` with ``p1 = 2 / e1`` and ``p2 = 2 / e2`` (``F = N ** p1``, eq. 2). For convex
  shapes (``e <= 2``) its support function is the dual norm
  ``h(n) = ||(||(w1, w2)||_q2, w3)||_q1`` of ``w = a * n`` with ``q = 2 / (2 - e)``, and the
  touching point is ``a * grad h(w)``; both are evaluated with scaled ratios so they stay finite
  for ``e`` in ``[0.01, 1.99]`` (exponents up to 200).
- For an image direction ``u`` (unit 2-vector), the image line ``<x, u> = h`` back-projects to the
  plane through the camera centre with normal ``n(h) = (u1 fx, u2 fy, u1 cx + u2 cy - h)``
  (camera frame). The supporting line of the silhouette is the ``h`` where that plane touches the
  superquadric: ``g(h) = n(h) . c + h_sq(M^T n(h)) = 0``. ``g`` is convex and decreasing
  (``g' = -z*``, minus the depth of the touching point), and ``g >= 0`` at the projected centre,
  so Newton's method from there converges monotonically (typically 4 to 8 steps).
- The silhouette polygon is the projection of the ``K`` touching points, one per direction
  ``2 pi k / K``: it is inscribed in the exact silhouette, exact at corners of box-like shapes,
  counter-clockwise (positive shoelace area in image coordinates ``(u, v)``). For a round
  silhouette the relative area error is about ``(2 pi / K)**2 / 6`` (0.16 % at ``K = 64``).

A superquadric with any point at camera depth <= :data:`ZNEAR` (1 mm; behind or
straddling the camera plane) has no bounded silhouette: :func:`silhouette` returns an empty
``(0, 2)`` array, and :func:`sqfit.geometry.polygon.polygon_iou` of an empty polygon is 0. Nothing raises.
"""

from __future__ import annotations

from functools import lru_cache
from typing import NamedTuple

import numpy as np

from .superquadric import euler_to_matrix, rotation_and_derivatives

__all__ = ["silhouette", "batch_silhouettes", "SilhouetteStart", "vertex_velocities", "silhouette_gradient",
           "camera_arrays", "rotation_stack", "ZNEAR", "DEFAULT_DIRECTIONS", "E_RANGE", "NEWTON_TOL", "MAX_NEWTON"]

#: Minimum camera depth (metres) of every superquadric point for a silhouette to exist.
ZNEAR = 1e-3
#: Directions (polygon vertices) of a silhouette by default.
DEFAULT_DIRECTIONS = 64
#: Shape exponents are clamped to this range inside the support function (q = 2 / (2 - e)).
E_RANGE = (0.01, 1.99)
#: Newton on the support line: stop when every step is below this (pixels), or after MAX_NEWTON.
NEWTON_TOL = 1e-7
MAX_NEWTON = 40
#: :meth:`SilhouetteStart.refreshed` re-adapts directions past this change of aspect ratio.
REFRESH_DISTORTION = 1.1
_TINY = 1e-300


class SilhouetteStart(NamedTuple):
    """The image directions and support values of a silhouette solve, to warm-start a nearby one
    (:func:`batch_silhouettes`), and what :meth:`refreshed` needs.

    Attributes
    ----------
    directions : (b, v, K, 2) float
        Unit image directions, one per vertex.
    h : (b, v, K) float
        Support values found.
    metric : (b, v, 2, 2) float
        The inverse of the polygon's vertex covariance when these directions were first used,
        scaled to determinant 1; NaN until :meth:`refreshed` records it.
    polygons : (b, v, K, 2) float
    valid : (b, v) bool
    normals : (b, v, K, 3) float or None
        Camera-frame normals of the planes through the camera centre and the image lines
        ``<x, direction> = 0`` (a cache; None after the directions change).
    """

    directions: np.ndarray
    h: np.ndarray
    metric: np.ndarray
    polygons: np.ndarray
    valid: np.ndarray
    normals: np.ndarray = None

    def refreshed(self, max_distortion=REFRESH_DISTORTION):
        """The same start, with directions re-adapted to the polygons found where they have drifted.

        :func:`batch_silhouettes` keeps the directions of its ``start``, so over a fit they can
        drift away from the silhouettes (an elongating silhouette would get its vertices bunched
        at the ends). The shape of a silhouette is measured by the vertex covariance ``C`` of
        its polygon (for vertices at evenly spaced parametric angles of an ellipse, half the
        ellipse's shape matrix). The first call after the directions were set records ``C`` (as
        ``metric``); later calls compare: where the ratio of the extreme eigenvalues of
        ``metric C`` (an aspect-ratio change, independent of scale) exceeds ``max_distortion``,
        uniform angles are mapped through ``C`` instead and each support value starts at the
        polygon's own support in its new direction (a lower bound, as Newton needs: the polygon
        is inscribed). Elsewhere the directions stay, so the cost a fit sees stays the same
        function between refreshes.
        """
        polys = self.polygons
        with np.errstate(all="ignore"):
            d = polys - polys.sum(axis=-2, keepdims=True) / polys.shape[-2]
            C = np.swapaxes(d, -1, -2) @ d  # K times the covariance: the scale does not matter
            det = C[..., 0, 0] * C[..., 1, 1] - C[..., 0, 1] ** 2
            # The eigenvalue ratio r of metric C (det(metric) = 1) has (1 + r)^2 / r = tr^2 / det.
            tr = (self.metric * C).sum(axis=(-2, -1))
            new = self.valid & np.isnan(tr)  # no metric yet: record this one
            stale = self.valid & (tr * tr > (1.0 + max_distortion) ** 2 / max_distortion * det)
            if not (stale.any() or new.any()):
                return self
            metric = np.where(new[..., None, None], _unit_metric(C), self.metric)
            if not stale.any():
                return self._replace(metric=metric)
            L = np.zeros_like(C)
            L[..., 0, 0] = np.sqrt(C[..., 0, 0])
            L[..., 1, 0] = C[..., 1, 0] / L[..., 0, 0]
            L[..., 1, 1] = np.sqrt(C[..., 1, 1] - L[..., 1, 0] ** 2)
            ok = stale & np.isfinite(L[..., 1, 1]) & (L[..., 0, 0] > 0) & (L[..., 1, 1] > 0)
            U = _adapted_directions(L, ok, polys.shape[-2])
            h = np.max(U @ np.swapaxes(polys, -1, -2), axis=-1)
        return self._replace(directions=np.where(ok[..., None, None], U, self.directions),
                             h=np.where(ok[..., None], h, self.h),
                             metric=np.where(ok[..., None, None], np.nan, metric), normals=None)


def _unit_metric(S):
    """``S^-1`` scaled to determinant 1 (``adj(S) / sqrt(det S)``) for positive definite ``(..., 2, 2)``
    (NaN where ``S`` is not)."""
    adj = np.empty_like(S)
    adj[..., 0, 0], adj[..., 1, 1] = S[..., 1, 1], S[..., 0, 0]
    adj[..., 0, 1], adj[..., 1, 0] = -S[..., 0, 1], -S[..., 1, 0]
    with np.errstate(all="ignore"):
        return adj / np.sqrt(S[..., 0, 0] * S[..., 1, 1] - S[..., 0, 1] * S[..., 1, 0])[..., None, None]


@lru_cache(maxsize=16)
def _directions(k):
    theta = 2.0 * np.pi * np.arange(k) / k
    d = np.stack([np.cos(theta), np.sin(theta)], axis=1)
    d.flags.writeable = False
    return d


def _pnorm2(x, y, q):
    """``(|x|^q + |y|^q)^(1/q)`` for ``x, y >= 0`` and the weight ``x^q / sum`` (that of ``y`` is
    one minus it)."""
    big = np.maximum(x, y)
    t = np.minimum(x, y)
    t /= big + 1e-300
    tq = t ** q
    total = tq + 1.0
    norm = total ** (1.0 / q)
    norm *= big
    w_small = tq / total
    return norm, np.where(x >= y, 1.0 - w_small, w_small)


def dual_support(w, q1, q2):
    """Support function of the unit-size superquadric and its gradient.

    Uses ``d h / d w_i = h * sigma * rho_i / w_i`` where ``sigma``, ``rho_i`` are the power-mean
    weights of the two nested norms, so only four powers are needed per point.

    Parameters
    ----------
    w : (..., 3) float
        ``a * n``: a direction ``n`` in superquadric coordinates scaled by the size.
    q1, q2 : float or (...,) float
        Dual exponents ``2 / (2 - e1)``, ``2 / (2 - e2)``, each > 1.

    Returns
    -------
    h : (...,) float
        ``max over the superquadric of n . t``.
    grad : (..., 3) float
        Gradient of ``h`` with respect to ``w``; the touching point is ``a * grad``.
    """
    aw = np.abs(w)
    s, rho1 = _pnorm2(aw[..., 0], aw[..., 1], q2)
    h, sig_s = _pnorm2(s, aw[..., 2], q1)
    hs = h * sig_s
    grad = np.empty_like(aw)
    np.multiply(hs, rho1, out=grad[..., 0])  # h sig_s rho1
    np.subtract(hs, grad[..., 0], out=grad[..., 1])  # h sig_s rho2
    np.subtract(h, hs, out=grad[..., 2])  # h sig_3
    # w_i = 0 has weight 0: the tiny offset keeps 0 / 0 out without a branch.
    grad /= w + np.copysign(1e-300, w)
    return h, grad


def _silhouette_ellipses(a, R_sq, p, rotations, centers, intrinsics):
    """Silhouette ellipses of the quadrics (e = 1) with the given sizes and poses, closed form.

    The dual conic is ``C* = P Q* P^T`` with ``Q* = T diag(1, 1, 1, -1) T^T``.

    Returns
    -------
    x0 : (b, v, 2) float
        Ellipse centres, image coordinates.
    L : (b, v, 2, 2) float
        Lower Cholesky factors of the shape matrices ``S`` (ellipse ``(x-x0)^T S^-1 (x-x0) = 1``).
    ok : (b, v) bool
        False where the quadric is not entirely in front of the camera.
    """
    b, v = len(a), len(rotations)
    Tq = np.zeros((b, 4, 4))
    Tq[:, :3, :3] = R_sq * a[:, None, :]
    Tq[:, :3, 3] = p
    Tq[:, 3, 3] = 1.0
    Qd = Tq @ np.diag([1.0, 1.0, 1.0, -1.0]) @ np.swapaxes(Tq, 1, 2)
    K = np.zeros((v, 3, 3))
    K[:, 0, 0], K[:, 1, 1] = intrinsics[:, 0], intrinsics[:, 1]
    K[:, 0, 2], K[:, 1, 2], K[:, 2, 2] = intrinsics[:, 2], intrinsics[:, 3], 1.0
    Rt = np.swapaxes(rotations, 1, 2)
    P = K @ np.concatenate([Rt, -(Rt @ centers[:, :, None])], axis=2)
    Cd = P[None] @ Qd[:, None] @ np.swapaxes(P, 1, 2)[None]  # (b, v, 3, 3)
    L = np.zeros((b, v, 2, 2))
    with np.errstate(all="ignore"):
        lam = -Cd[..., 2, 2]
        x0 = -Cd[..., :2, 2] / lam[..., None]
        S = Cd[..., :2, :2] / lam[..., None, None] + x0[..., :, None] * x0[..., None, :]
        L[..., 0, 0] = np.sqrt(S[..., 0, 0])
        L[..., 1, 0] = S[..., 1, 0] / L[..., 0, 0]
        L[..., 1, 1] = np.sqrt(S[..., 1, 1] - L[..., 1, 0] ** 2)
    ok = (lam > 0) & np.all(np.isfinite(L), axis=(2, 3)) & (L[..., 0, 0] > 0) & (L[..., 1, 1] > 0)
    return x0, L, ok


def _projection_rows(intrinsics):
    """``(v, 2, 3) float``: the first two rows ``[[fx, 0, cx], [0, fy, cy]]`` of the camera matrices."""
    P = np.zeros((len(intrinsics), 2, 3))
    P[:, 0, 0], P[:, 1, 1], P[:, :, 2] = intrinsics[:, 0], intrinsics[:, 1], intrinsics[:, 2:4]
    return P


def _adapted_directions(L, ok, k):
    """Image directions spread evenly around the silhouette rather than evenly in angle.

    Uniform angles put nearly every touching point at the two ends of an elongated silhouette
    (a 160 x 10 px needle lost 13 % of its area at K = 64). We map uniform angles through the
    silhouette ellipse of the quadric with the same size and pose: with ``S = L L^T`` its shape
    matrix, normals ``L^-T u`` touch that ellipse at evenly spaced parametric angles. ``L^-T``
    preserves orientation, so the polygon stays counter-clockwise. Uniform angles where the
    ellipse does not exist.

    Returns
    -------
    directions : (b, v, k, 2) float
        Unit vectors.
    """
    base = _directions(k)
    with np.errstate(all="ignore"):
        l00, l10, l11 = L[..., 0, 0, None], L[..., 1, 0, None], L[..., 1, 1, None]
        # L^-T = [[1/l00, -l10/(l00 l11)], [0, 1/l11]], scaled by l00 l11.
        u = np.stack([l11 * base[:, 0] - l10 * base[:, 1], l00 * base[:, 1]], axis=-1)
        u /= np.linalg.norm(u, axis=-1, keepdims=True)
    return np.where(ok[..., None, None], u, base)


def batch_silhouettes(xi, rotations, centers, intrinsics, n_directions=DEFAULT_DIRECTIONS, start=None,
                      touching=False, tol=NEWTON_TOL):
    """Silhouettes of several superquadrics in several cameras at once.

    Parameters
    ----------
    xi : (b, 11) float
        Parameter vectors (the sign of ``a`` is ignored, ``e`` is clamped to [0.01, 1.99]).
    rotations : (v, 3, 3) float
        Camera -> world rotations.
    centers : (v, 3) float
        Camera centres, world frame.
    intrinsics : (v, 4) float
        ``fx, fy, cx, cy`` per camera.
    n_directions : int
        ``K``, vertices per silhouette.
    start : SilhouetteStart, optional
        The directions and support values of a nearby solve (the ``start`` this function returns
        for a nearby ``xi``; arrays broadcast to ``(b, v, K)``): the same image directions are
        used and Newton starts from those support values (from the projected centre where they
        are not finite). Default: directions adapted to, and support values of, the silhouette
        ellipse of the quadric with the same size and pose (:func:`_adapted_directions`).
    touching : bool
        Also return the touching points (for :func:`vertex_velocities`).
    tol : float
        Newton stops when every step is below this (pixels). The vertices are the touching
        points of the support values before the last step, so they are off by about that much.
        Finite differences need the default; an analytic Jacobian does well with 1e-3 px (one
        Newton step fewer on a warm start).

    Returns
    -------
    polygons : (b, v, K, 2) float
        Counter-clockwise silhouettes in image coordinates (garbage where not ``valid``).
    valid : (b, v) bool
        False where part of the superquadric is at depth <= :data:`ZNEAR`.
    start : SilhouetteStart
        The directions used and the support values found (image offsets of the support lines),
        to warm-start a nearby solve (:meth:`SilhouetteStart.refreshed` adapts the directions
        to the silhouettes found).
    unit_points, points : (b, v, K, 3) float
        Only if ``touching``: the touching points on the unit-size superquadric (superquadric
        frame) and the touching points (camera frames).
    """
    xi = np.atleast_2d(xi)
    a = np.abs(xi[:, 0:3])
    e = np.minimum(np.maximum(xi[:, 3:5], E_RANGE[0]), E_RANGE[1])
    q1 = (2.0 / (2.0 - e[:, 0]))[:, None, None]
    q2 = (2.0 / (2.0 - e[:, 1]))[:, None, None]
    R_sq = euler_to_matrix(xi[:, 8:11])  # (b, 3, 3)
    # SQ -> camera rotation M and SQ centre c in camera frames: (b, v, 3, 3), (b, v, 3).
    # (matmul rather than einsum throughout: several times faster on these small stacks)
    Rt = np.swapaxes(rotations, 1, 2)
    M = Rt[None] @ R_sq[:, None]
    c = (Rt[None] @ (xi[:, None, 5:8] - centers[None])[..., None])[..., 0]
    k = int(n_directions)
    wz = (a[:, None, :] * M[:, :, 2, :])[:, :, None, :]  # (b, v, 1, 3)
    if start is None:
        x0, L, ok = _silhouette_ellipses(a, R_sq, xi[:, 5:8], rotations, centers, intrinsics)
        U = _adapted_directions(L, ok, k)
        metric = np.full((len(xi), len(rotations), 2, 2), np.nan)
        n0 = None
    else:
        U, metric, n0 = start.directions, start.metric, start.normals
        if U.shape[0] != len(xi):  # one start for a batch (finite differences)
            U, metric = (np.broadcast_to(x, (len(xi),) + x.shape[1:]) for x in (U, metric))
            if n0 is not None:
                n0 = np.broadcast_to(n0, (len(xi),) + n0.shape[1:])
    # n(h) = n0 - h e_z (camera frame); w(h) = a * M^T n(h) = w0 - h wz.
    P2 = _projection_rows(intrinsics)  # (v, 2, 3)
    if n0 is None:
        n0 = U @ P2  # (b, v, K, 3)
    w0 = (n0 @ M) * a[:, None, None, :]
    n0c = (n0 @ c[..., None])[..., 0]
    with np.errstate(all="ignore"):
        # Start: the support of the quadric's ellipse (exact for e = 1, close otherwise) or the
        # given support values; else the projected centre, where g >= 0.
        if start is None:
            h = (U @ x0[..., None])[..., 0] + np.linalg.norm(U @ L, axis=-1)
            if not ok.all():
                h = np.where(ok[..., None], h, np.nan)
        else:
            h = start.h if start.h.shape[0] == len(xi) else np.broadcast_to(start.h, n0c.shape)
        if not np.isfinite(h).all():
            h = np.where(np.isfinite(h), h, n0c / np.where(c[..., 2] > 0, c[..., 2], 1.0)[..., None])
        # The first support evaluation also gives the nearest depth of the superquadric in each
        # camera, c_z - h(-e_z) (an extra direction -e_z, whose w is wz).
        hs, grad = dual_support(np.concatenate([w0 - h[..., None] * wz, wz], axis=2), q1, q2)
        zmin = c[..., 2] - hs[..., k]
        hs, grad = hs[..., :k], grad[..., :k, :]
        valid = np.isfinite(zmin) & (zmin > ZNEAR)
        cz = np.where(valid, c[..., 2], 1.0)[..., None]  # (b, v, 1)
        all_valid = bool(valid.all())
        wz_col = np.swapaxes(wz, -1, -2)  # (b, v, 3, 1)
        for it in range(MAX_NEWTON):
            if it:
                hs, grad = dual_support(w0 - h[..., None] * wz, q1, q2)
            # g(h) = n(h) . c + h_sq; g'(h) = -z* (depth of the touching point).
            g = n0c - h * cz + hs
            step = g / (cz + (grad @ wz_col)[..., 0])
            if not all_valid:  # invalid silhouettes take no steps (their g may be NaN)
                step = np.where(valid[..., None], step, 0.0)
            h = h + step
            if not np.abs(step).max() > tol:
                break
        # ``grad`` is the touching point of the last support value but one: the last step was
        # below ``tol``, so re-evaluating it at ``h`` would move the vertices by about that much.
        point = c[:, :, None, :] + (grad * a[:, None, None, :]) @ np.swapaxes(M, -1, -2)
        z = point[..., 2:] if all_valid else np.where(valid[..., None, None], point[..., 2:], 1.0)
        polys = (point @ np.swapaxes(P2, -1, -2)) / z
    valid &= np.isfinite(polys.reshape(polys.shape[:2] + (-1,)).sum(axis=-1))
    start = SilhouetteStart(U, h, metric, polys, valid, n0)
    if touching:
        return polys, valid, start, grad, point
    return polys, valid, start


def rotation_stack(xi):
    """Rotations ``(b, 3, 3)`` of parameter vectors ``(b, 11)`` and their derivatives ``(b, 3, 3, 3)``
    (one per angle)."""
    if len(xi) == 1:  # the optimiser's case: no stacking
        R, dR = rotation_and_derivatives(xi[0, 8:11])
        return R[None], dR[None]
    R, dR = zip(*(rotation_and_derivatives(r) for r in xi[:, 8:11]))
    return np.stack(R), np.stack(dR)


def _shape_logs(s, e):
    """``ln A`` with ``A = ||(s1, s2)||_(2/e2)`` ``(b, v, K)`` and ``s ln|s|`` ``(b, v, K, 3)`` (0 at
    ``s = 0``, the limit) for points ``s`` (b, v, K, 3) of unit superquadrics with exponents ``e``
    (b, 2). ``ln A >= ln(1e-300)``, so ``s_i ln A`` is 0 where ``s_i`` is."""
    e2 = e[:, 1, None, None]
    with np.errstate(all="ignore"):
        aw = np.abs(s)
        big = np.maximum(aw[..., 0], aw[..., 1])
        t = np.minimum(aw[..., 0], aw[..., 1]) / (big + _TINY)
        log_a = np.log(big + _TINY) + 0.5 * e2 * np.log1p(t ** (2.0 / e2))
        slog = np.where(aw > 0, s * np.log(aw + _TINY), 0.0)
    return log_a, slog


def _unit_point_shape_derivatives(s, e):
    """Derivatives of points ``s`` (b, v, K, 3) of the unit superquadric with respect to ``e1, e2``
    at fixed angles ``(eta, omega)`` of the parametrisation
    ``s = (c_eta^e1 c_omega^e2, c_eta^e1 s_omega^e2, s_eta^e1)`` (signed powers).

    From ``s`` alone: ``|c_eta|^e1 = A = ||(s1, s2)||_(2/e2)``, so ``ds_i/de1 = s_i ln(A) / e1``
    (``i = 1, 2``), ``ds_3/de1 = s_3 ln|s_3| / e1``, ``ds_i/de2 = s_i ln(|s_i| / A) / e2``. Terms
    ``s ln|s|`` are 0 at ``s = 0`` (their limit).

    Returns
    -------
    ds : (b, v, K, 2, 3) float
        ``ds[..., j, :] = d s / d e_(j+1)``.
    """
    e1, e2 = e[:, 0, None, None, None], e[:, 1, None, None, None]
    log_a, slog = _shape_logs(s, e)
    s_log_a = s[..., :2] * log_a[..., None]
    ds = np.zeros(s.shape[:3] + (2, 3))
    ds[..., 0, :2] = s_log_a / e1
    ds[..., 0, 2] = slog[..., 2] / e1[..., 0]
    ds[..., 1, :2] = (slog[..., :2] - s_log_a) / e2
    return ds


def vertex_velocities(xi, unit_points, points, rotations, intrinsics):
    """Image velocities of silhouette vertices with respect to the 11 parameters.

    Each vertex is the projection of a touching point ``y = M (a * s) + c`` (camera frame) with
    ``s`` on the unit superquadric. Its velocity is the derivative of that projection with the
    surface point held fixed in the superquadric's parametrisation (``s`` moves only through the
    shape exponents). By the envelope theorem the component along the outward normal of the
    silhouette is the exact velocity of the supporting line, and at a corner the touching point
    does not slide, so the normal flux of these velocities across the polygon's edges is the
    first-order change of its area (:func:`sqfit.geometry.polygon.convex_iou_jacobian`). The fitter contracts them with
    the IoU's vertex weights without forming them (:func:`silhouette_gradient`).

    Parameters
    ----------
    xi : (b, 11) float
    unit_points : (b, v, K, 3) float
        ``s``, touching points on the unit-size superquadric, superquadric frame.
    points : (b, v, K, 3) float
        ``y``, touching points, camera frames (from :func:`batch_silhouettes`).
    rotations : (v, 3, 3) float
        Camera -> world rotations.
    intrinsics : (v, 4) float

    Returns
    -------
    dpolys : (b, v, K, 2, 11) float
        ``d (u, v) / d xi`` of every vertex; 0 for a shape exponent outside [0.01, 1.99], where
        the silhouette clamps it. Not finite where the touching point is at depth 0.
    """
    xi = np.atleast_2d(xi)
    R_sq, dR = rotation_stack(xi)
    a = np.abs(xi[:, 0:3])
    fx, fy = intrinsics[:, 0][None, :, None], intrinsics[:, 1][None, :, None]
    iz = 1.0 / points[..., 2]
    # d pi / d y (camera frame) as two rows, then in the world frame (d pi / d p) and the
    # superquadric frame.
    rows = np.zeros(points.shape[:3] + (2, 3))
    rows[..., 0, 0] = fx * iz
    rows[..., 1, 1] = fy * iz
    rows[..., 0, 2] = -fx * points[..., 0] * iz ** 2
    rows[..., 1, 2] = -fy * points[..., 1] * iz ** 2
    # Small stacked matrix products: matmul is several times faster than einsum here.
    rows_w = rows @ np.swapaxes(rotations, 1, 2)[None, :, None]
    rows_sq = rows_w @ R_sq[:, None, None]
    out = np.empty(points.shape[:3] + (2, 11))
    sign = np.where(xi[:, 0:3] < 0, -1.0, 1.0)[:, None, None, None, :]
    out[..., 0:3] = rows_sq * (unit_points[..., None, :] * sign)
    e = np.minimum(np.maximum(xi[:, 3:5], E_RANGE[0]), E_RANGE[1])
    inside = (e == xi[:, 3:5])[:, None, None, :, None]
    ds = _unit_point_shape_derivatives(unit_points, e) * a[:, None, None, None, :] * inside
    out[..., 3:5] = rows_sq @ np.swapaxes(ds, -1, -2)
    out[..., 5:8] = rows_w
    b, v, k = points.shape[:3]
    # d x / d r_j = dR_j (a * s) for the three angles at once: (b, v, K, 3 angles, 3 coords).
    local = (unit_points * a[:, None, None, :]).reshape(b, v * k, 3)
    dx = (local @ np.swapaxes(dR.reshape(b, 9, 3), 1, 2)).reshape(b, v, k, 3, 3)
    out[..., 8:11] = rows_w @ np.swapaxes(dx, -1, -2)
    return out


def camera_arrays(cameras):
    """Stack cameras for :func:`batch_silhouettes`: rotations (v,3,3), centres (v,3), (v,4) fx fy cx cy."""
    rotations = np.stack([cam.rotation for cam in cameras])
    centers = np.stack([cam.center for cam in cameras])
    intr = np.array([[c.intrinsics.fx, c.intrinsics.fy, c.intrinsics.cx, c.intrinsics.cy] for c in cameras])
    return rotations, centers, intr


def silhouette(sq, camera, n_directions=DEFAULT_DIRECTIONS):
    """The silhouette of a superquadric in a camera, as a convex polygon.

    Parameters
    ----------
    sq : Superquadric
    camera : Camera
    n_directions : int
        Number of vertices ``K`` >= 3 (one touching point per direction ``2 pi k / K``).

    Returns
    -------
    polygon : (K, 2) or (0, 2) float
        Image coordinates ``(u, v)``, counter-clockwise (positive shoelace area), inscribed in the
        exact silhouette; consecutive vertices may coincide at corners. Empty when part of the
        superquadric is at depth <= :data:`ZNEAR` (behind or around the camera).
    """
    if int(n_directions) != n_directions or n_directions < 3:
        raise ValueError(f"n_directions must be an integer >= 3, got {n_directions}")
    polys, valid, _ = batch_silhouettes(sq.to_vector()[None], *camera_arrays([camera]), int(n_directions))
    return polys[0, 0] if valid[0, 0] else np.zeros((0, 2))


def silhouette_gradient(xi, weights, unit_points, points, rotations, intrinsics):
    """``sum_k W_k . d vertex_k / d xi`` for silhouettes from :func:`batch_silhouettes`.

    The same as contracting :func:`vertex_velocities` with the vertex weights ``W`` (e.g. from
    :func:`sqfit.geometry.polygon.convex_iou_jacobian`), without forming the ``(b, v, K, 2, 11)`` velocities: ``W`` is
    pulled back to a gradient ``G_k`` with respect to each touching point (camera frame), then
    to the world frame, and summed over the vertices per parameter group.

    Parameters
    ----------
    xi : (b, 11) float
    weights : (b, v, K, 2) float
    unit_points, points : (b, v, K, 3) float
        As for :func:`vertex_velocities`.
    rotations : (v, 3, 3) float
    intrinsics : (v, 4) float

    Returns
    -------
    gradient : (b, v, 11) float
        Not finite where a touching point is at depth 0.
    """
    xi = np.atleast_2d(xi)
    b, v = points.shape[:2]
    R_sq, dR = rotation_stack(xi)
    a = np.abs(xi[:, 0:3])
    out = np.empty((b, v, 11))
    with np.errstate(all="ignore"):
        iz = 1.0 / points[..., 2]
        G = np.empty(points.shape)
        G[..., 0] = weights[..., 0] * intrinsics[:, 0, None] * iz
        G[..., 1] = weights[..., 1] * intrinsics[:, 1, None] * iz
        G[..., 2] = -(G[..., 0] * points[..., 0] + G[..., 1] * points[..., 1]) * iz
        Gw = G @ rotations.swapaxes(1, 2)  # world frame
        out[..., 5:8] = Gw.sum(axis=-2)
        H = Gw @ R_sq[:, None]  # superquadric frame
        sign = np.where(xi[:, 0:3] < 0, -1.0, 1.0)[:, None, :]
        out[..., 0:3] = np.sum(H * unit_points, axis=-2) * sign
        # Shape: the derivatives of s of _unit_point_shape_derivatives, contracted with a * H.
        e = np.minimum(np.maximum(xi[:, 3:5], E_RANGE[0]), E_RANGE[1])
        s = unit_points
        log_a, slog = _shape_logs(s, e)
        Ha = H * a[:, None, None, :]
        planar = (Ha[..., 0] * s[..., 0] + Ha[..., 1] * s[..., 1]) * log_a
        # Clamped exponents have no derivative.
        scale = np.where(e == xi[:, 3:5], 1.0 / e, 0.0)[:, None, :]
        out[..., 3] = np.sum(planar + Ha[..., 2] * slog[..., 2], axis=-1) * scale[..., 0]
        out[..., 4] = np.sum(Ha[..., 0] * slog[..., 0] + Ha[..., 1] * slog[..., 1] - planar, axis=-1) * scale[..., 1]
        # Rotation: sum_k Gw_k . (dR_j (a s_k)) = <dR_j, sum_k Gw_k (a s_k)^T>.
        Gs = Gw.swapaxes(-1, -2) @ (unit_points * a[:, None, None, :])  # (b, v, 3, 3)
        out[..., 8:11] = Gs.reshape(b, v, 9) @ dR.reshape(b, 3, 9).swapaxes(1, 2)
    return out
