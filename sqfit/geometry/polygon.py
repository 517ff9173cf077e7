"""2D polygons: area, convexity and the intersection over union the R-IOU costs and metrics use.

Polygons are ``(k, 2)`` arrays of image coordinates, not closed (the first vertex is not
repeated); counter-clockwise means a positive shoelace area in ``(u, v)``. Convex pairs --
silhouettes from :mod:`sqfit.geometry.silhouette` against hull observations -- use a vectorised
Cyrus-Beck / Green's-theorem intersection with an analytic Jacobian (:func:`convex_iou`,
:func:`convex_iou_jacobian`); other pairs use shapely. An empty or zero-area polygon has IoU 0.
"""

from __future__ import annotations

import numpy as np

from .._checks import check_shape

__all__ = ["polygon_area", "polygon_moments", "batch_polygon_moments", "is_convex", "half_planes", "convex_iou", "convex_iou_jacobian", "polygon_iou",
           "batch_iou", "MIN_EDGE"]

#: Polygon edges shorter than this (pixels) do not act as clipping half-planes.
MIN_EDGE = 1e-7


def polygon_area(polygon):
    """Signed shoelace area, ``(k, 2) float`` -> float (> 0 for counter-clockwise)."""
    p = np.asarray(polygon, dtype=np.float64)
    if len(p) < 3:
        return 0.0
    x, y = p[:, 0], p[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


def polygon_moments(polygon):
    """Area, centroid and covariance of the uniform distribution over a simple polygon's region.

    Green's theorem over the edges (exact for the polygon; either orientation), computed about
    the first vertex for precision.

    Parameters
    ----------
    polygon : (k, 2) float
        Vertices, not closed, k >= 3, non-zero area.

    Returns
    -------
    area : float
        Unsigned area.
    centroid : (2,) float
    covariance : (2, 2) float
        ``E[(x - centroid)(x - centroid)^T]`` over the region.

    Raises
    ------
    ValueError
        If ``polygon`` is not ``(k, 2)`` finite with k >= 3, or its area is zero.
    """
    area, centroid, covariance = batch_polygon_moments([polygon])
    return float(area[0]), centroid[0], covariance[0]


def batch_polygon_moments(polygons):
    """:func:`polygon_moments` of several polygons in one vectorised pass.

    Parameters
    ----------
    polygons : sequence of (k_i, 2) float
        At least one; each as :func:`polygon_moments` (the message names the index).

    Returns
    -------
    area : (b,) float
    centroid : (b, 2) float
    covariance : (b, 2, 2) float
    """
    checked = [check_shape(p, (None, 2), "polygon" if len(polygons) == 1 else f"polygons[{i}]")
               for i, p in enumerate(polygons)]
    if not checked:
        raise ValueError("polygons must hold at least one polygon")
    lengths = np.array([len(p) for p in checked])
    if lengths.min() < 3:
        raise ValueError(f"polygon must have >= 3 vertices, got {lengths.min()}")
    starts = np.concatenate([[0], np.cumsum(lengths)[:-1]])
    p = np.concatenate(checked)
    q = p - np.repeat(p[starts], lengths, axis=0)  # about each polygon's first vertex
    following = np.arange(1, len(p) + 1)
    following[starts + lengths - 1] = starts
    x, y = q[:, 0], q[:, 1]
    xn, yn = x[following], y[following]
    cross = x * yn - xn * y
    terms = np.stack([cross, (x + xn) * cross, (y + yn) * cross, (x * x + x * xn + xn * xn) * cross,
                      (y * y + y * yn + yn * yn) * cross, (2.0 * (x * y + xn * yn) + x * yn + xn * y) * cross])
    twice_area, sx, sy, sxx, syy, sxy = np.add.reduceat(terms, starts, axis=1)
    if not np.all(np.abs(twice_area) > 0):
        raise ValueError("polygon has zero area")
    mean = np.stack([sx, sy], axis=1) / (3.0 * twice_area[:, None])
    second = np.stack([np.stack([sxx / 6.0, sxy / 12.0], axis=1), np.stack([sxy / 12.0, syy / 6.0], axis=1)],
                      axis=1) / twice_area[:, None, None]
    covariance = second - mean[:, :, None] * mean[:, None, :]
    return np.abs(0.5 * twice_area), mean + p[starts], covariance


def is_convex(polygon, tol=1e-9):
    """Whether a polygon (``(k, 2) float``, either orientation) is convex (collinear runs allowed)."""
    p = np.asarray(polygon, dtype=np.float64)
    if len(p) < 3:
        return False
    d = np.roll(p, -1, axis=0) - p
    cross = d[:, 0] * np.roll(d[:, 1], -1) - d[:, 1] * np.roll(d[:, 0], -1)
    scale = tol * max(1.0, float(np.abs(p).max())) ** 2
    return bool(np.all(cross >= -scale) or np.all(cross <= scale))


def half_planes(Q):
    """Half-planes ``n_j . x <= n_j . q_j`` of convex CCW polygons, and their shoelace terms.

    Parameters
    ----------
    Q : (..., m, 2) float

    Returns
    -------
    n : (..., m, 2) float
        Outward edge normals scaled by the edge lengths. Edges shorter than :data:`MIN_EDGE` get
        ``n = 0`` (no constraint): their direction is rounding noise.
    cross : (..., m) float
        ``cross(q_j, q_(j+1) - q_j)``, twice the area each edge contributes (Green's theorem).
    area : (...,) float
        Shoelace areas.
    """
    e = np.roll(Q, -1, axis=-2) - Q
    use = np.hypot(e[..., 0], e[..., 1]) > MIN_EDGE
    n = np.stack([e[..., 1], -e[..., 0]], axis=-1) * use[..., None]
    cross = Q[..., 0] * e[..., 1] - Q[..., 1] * e[..., 0]
    return n, cross, 0.5 * np.sum(cross, axis=-1)


def convex_iou(S, Q, q_planes=None):
    """IoU of convex counter-clockwise polygons, vectorised over leading axes.

    Parameters
    ----------
    S : (..., k, 2) float
    Q : (..., m, 2) float
        Consecutive duplicate vertices are allowed (pad a polygon by repeating its last vertex).
    q_planes : tuple, optional
        :func:`half_planes` of ``Q`` if already known.

    Returns
    -------
    iou : (...,) float
    """
    return convex_overlap(S, Q, q_planes)[0]


def convex_overlap(S, Q, q_planes):
    """IoU of convex CCW polygons and the intermediate results :func:`convex_iou_jacobian` reuses.

    Green's theorem: the area of ``S n Q`` is half the sum of ``cross(a, b)`` over the pieces
    ``[a, b]`` of both boundaries inside the other polygon. The pieces come from Cyrus-Beck
    clipping of each edge against the other polygon's half-planes ``n . x <= n . x0`` (outward
    normals ``n`` scaled by the edge lengths): along ``x0 + t d`` the constraint ``n_j`` gives
    ``t (n_j . d) <= n_j . (q_j - x0)``. Both passes share the differences ``q_j - s_i`` and the
    denominators (``n^Q_j . d^S_i = cross(d^S_i, d^Q_j) = -n^S_i . d^Q_j``). An edge lying on
    the other polygon's boundary and running the same way counts as inside in the first pass
    (S's edges) and outside in the second, so a shared edge is counted once; running the opposite
    way (polygons touching from outside) it counts in neither. Edges shorter than :data:`MIN_EDGE` constrain
    nothing (their direction is rounding noise): Q's have ``n = 0`` (:func:`half_planes`); S's
    get numerator 1, so with a denominator below ``1e-7 |d^Q|`` in magnitude they only yield
    ``t < 0`` or ``t > 1``.

    Returns
    -------
    iou : (...,) float
    parts : tuple
        ``d`` (edges of S), ``t_lo, t_hi`` (the pieces of S's edges inside Q), ``inter, union,
        area_s, area_q``.
    """
    nq, cross_q, area_q = half_planes(Q) if q_planes is None else q_planes
    d = np.empty_like(S)
    np.subtract(S[..., 1:, :], S[..., :-1, :], out=d[..., :-1, :])
    np.subtract(S[..., :1, :], S[..., -1:, :], out=d[..., -1:, :])
    sx, sy, dx, dy = S[..., 0], S[..., 1], d[..., 0], d[..., 1]
    cross_s = sx * dy - sy * dx
    area_s = 0.5 * cross_s.sum(axis=-1)
    with np.errstate(all="ignore"):
        Dx = Q[..., None, :, 0] - sx[..., :, None]  # (..., k, m): q_j - s_i
        Dy = Q[..., None, :, 1] - sy[..., :, None]
        nqx, nqy = nq[..., None, :, 0], nq[..., None, :, 1]
        # Exact zeros of the denominators become -tiny: a parallel edge outside (numerator < 0)
        # then gets t = +huge (empty), one inside t = -huge (no constraint).
        den = dx[..., :, None] * nqx + dy[..., :, None] * nqy - 1e-300
        # An edge of S on a boundary line of Q counts as inside only if the two run the same way
        # (both interiors on one side); running opposite ways (polygons touching from outside),
        # the numerator 0 becomes negative: outside, as in the strict second pass.
        anti = np.minimum(dy[..., :, None] * nqx - dx[..., :, None] * nqy, 0.0)  # d^S . d^Q < 0
        t = (nqx * Dx + nqy * Dy + 1e-300 * anti) / den
        neg = den < 0
        t_lo = np.max(np.where(neg, t, 0.0), axis=-1, initial=0.0)
        t_hi = np.min(np.where(neg, 1.0, t), axis=-1, initial=1.0)
        # Q's edges against S's half-planes n_i = (dy_i, -dx_i): numerator n_i . (s_i - q_j),
        # minus tiny (strict), or 1 for a short edge of S (no constraint).
        free = np.where(dx * dx + dy * dy > MIN_EDGE ** 2, -1e-300, 1.0)[..., :, None]
        den = -2e-300 - den
        t = (dx[..., :, None] * Dy - dy[..., :, None] * Dx + free) / den
        neg = den < 0
        length_q = np.maximum(np.min(np.where(neg, 1.0, t), axis=-2, initial=1.0)
                              - np.max(np.where(neg, t, 0.0), axis=-2, initial=0.0), 0.0)
        inter = 0.5 * (np.sum(np.maximum(t_hi - t_lo, 0.0) * cross_s, axis=-1) + np.sum(length_q * cross_q, axis=-1))
        union = area_s + area_q - inter
        iou = np.clip(np.where(union > 0, inter / union, 0.0), 0.0, 1.0)
    return iou, (d, t_lo, t_hi, inter, union, area_s, area_q)


def convex_iou_jacobian(S, Q, q_planes=None):
    """IoU of convex CCW polygons (as :func:`convex_iou`), and its derivative in the vertices of ``S``.

    The vertices of ``S`` move with velocities ``dS_k``; ``Q`` is fixed. The area of ``S``
    changes by the flux of the (edge-wise linear) velocity field across its edges, and the
    intersection area by the flux across the pieces of those edges inside ``Q``
    (:func:`convex_overlap`): with ``N_k`` the outward normal of edge ``k`` scaled by its
    length, the piece ``[t0, t1]`` contributes ``(t1 - t0) f0 + (t1^2 - t0^2) / 2 (f1 - f0)``,
    where ``f0 = dS_k . N_k`` and ``f1 = dS_(k+1) . N_k``. Collecting the terms of each vertex
    gives ``d iou = sum_k W_k . dS_k``.

    Parameters
    ----------
    S : (..., k, 2) float
    Q : (..., m, 2) float
    q_planes : tuple, optional
        :func:`half_planes` of ``Q``.

    Returns
    -------
    iou : (...,) float
    weights : callable
        ``weights()`` returns ``W`` ``(..., k, 2)``, the gradient of the IoU with respect to the
        vertices of ``S``; 0 where the polygons do not overlap (IoU 0 has no gradient). Call it
        only when needed: the IoU alone is cheaper.
    """
    iou, (d, t_lo, t_hi, inter, union, area_s, area_q) = convex_overlap(S, Q, q_planes)
    ok = (union > 0) & (inter > 0)

    def weights():
        with np.errstate(all="ignore"):
            normal = np.stack([d[..., 1], -d[..., 0]], axis=-1)  # outward for CCW, |N| = edge length
            # Empty pieces (t_hi <= t_lo, where t_lo may be huge for a degenerate edge): t1 = t0.
            t0 = np.minimum(t_lo, 1.0)
            t1 = np.maximum(t_hi, t0)
            half_sq = 0.5 * (t1 * t1 - t0 * t0)
            # d iou = c1 d_inter - c2 d_area; per edge k: (c1 (t1 - t0 - half_sq) - c2 / 2) f0
            # + (c1 half_sq - c2 / 2) f1.
            c1 = ((area_s + area_q) / union ** 2)[..., None]
            c2 = (0.5 * inter / union ** 2)[..., None]
            w0 = (c1 * (t1 - t0 - half_sq) - c2)[..., None] * normal
            w1 = (c1 * half_sq - c2)[..., None] * normal
            W = w0 + np.roll(w1, 1, axis=-2)  # f1 of edge k - 1 moves vertex k
        return np.where(ok[..., None, None] & np.isfinite(W), W, 0.0)

    return iou, weights


def polygon_iou(p, q):
    """2D intersection over union of two simple polygons.

    Parameters
    ----------
    p, q : (k, 2) float
        Image coordinates, either orientation, not closed (first vertex not repeated). A polygon
        with fewer than 3 vertices or zero area (e.g. the empty silhouette of a superquadric
        behind the camera) gives IoU 0.

    Returns
    -------
    iou : float
        In ``[0, 1]``. Convex-convex pairs use a vectorised Cyrus-Beck / Green's-theorem
        intersection (exact up to rounding); other pairs use shapely.
    """
    p = check_shape(p, (None, 2), "p")
    q = check_shape(q, (None, 2), "q")
    ap, aq = polygon_area(p), polygon_area(q)
    if abs(ap) <= 0 or abs(aq) <= 0:
        return 0.0
    p = p if ap > 0 else p[::-1]
    q = q if aq > 0 else q[::-1]
    if is_convex(p) and is_convex(q):
        origin = q.mean(axis=0)  # a local origin keeps the cross products small
        return float(convex_iou(p - origin, q - origin))
    return _shapely_iou(p, q)


def _shapely_iou(p, q):
    import shapely

    a, b = shapely.make_valid(shapely.Polygon(p)), shapely.make_valid(shapely.Polygon(q))
    inter = shapely.area(shapely.intersection(a, b))
    union = shapely.area(a) + shapely.area(b) - inter
    return float(inter / union) if union > 0 else 0.0


def batch_iou(polys, valid, targets, convex, q_planes=None):
    """IoU of batched silhouettes with one observation polygon per view.

    Parameters
    ----------
    polys : (b, v, K, 2) float
    valid : (b, v) bool
    targets : (v, m, 2) float if ``convex`` (CCW, padded by repeating a vertex), else a list of
        v ``(m_i, 2)`` polygons
    convex : bool
        Use the vectorised convex path (hull observations) or shapely (contour observations).
    q_planes : tuple, optional
        ``half_planes(targets)`` if already known (convex path).

    Returns
    -------
    iou : (b, v) float
        0 where not ``valid``.
    """
    if convex:
        iou = convex_iou(polys, targets[None], q_planes)
    else:
        import shapely

        b, v = valid.shape
        sil = shapely.polygons(polys.reshape(b * v, -1, 2))
        tgt = np.array([shapely.make_valid(shapely.Polygon(t)) for t in targets], dtype=object)
        tgt = np.tile(tgt, b)
        try:
            inter = shapely.area(shapely.intersection(sil, tgt))
        except shapely.errors.GEOSException:  # a self-intersecting silhouette (far off the image)
            sil = shapely.make_valid(sil)
            inter = shapely.area(shapely.intersection(sil, tgt))
        union = shapely.area(sil) + shapely.area(tgt) - inter
        with np.errstate(divide="ignore", invalid="ignore"):
            iou = np.where(union > 0, inter / union, 0.0).reshape(b, v)
    return np.where(valid & np.isfinite(iou), iou, 0.0)
