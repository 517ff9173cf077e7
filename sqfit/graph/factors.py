"""GTSAM factors of the graph: thin ``gtsam.CustomFactor`` wrappers around the residual functions
of :mod:`sqfit.graph.landmark` and :mod:`sqfit.graph.quadric`.

A factor is one (frame, object) pair, never one pixel: the Python callback is the cost, so a view's
rays are evaluated together. The silhouette factors of one graph go further and share a
:class:`SilhouetteFactors` evaluator: GTSAM calls the factors one by one (``error`` at a trial point,
``linearize`` at an accepted one), and the first call at new values evaluates every factor of the
graph whose variables changed in one vectorised call
(:func:`sqfit.graph.landmark.batch_silhouette_residuals`); the factors then serve their rows from that
evaluation until their variables change again. Measured on the rendered scene (``benchmarks/
bench_graph.py``): one factor alone costs ~1 ms, nearly all numpy's per-call overhead on its 32 rays.
Every evaluation solves each ray's minimiser from its own bracket search, never warm-started from
the factor's previous evaluation: the error is then a function of the variables alone. Warm-started,
a ray kept following the local minimum it had found before (the bracket search picks the ray's
best one), so the same values could give different errors after different histories, and runs 1e-9
apart took different paths. Measured on the evaluation scenes (docs/slam-history.md "Issue 23, seventh pass", 72
runs, with the floor and the scenes' odometry noise): runs with ATE <= 0.015 m 65 -> 70, the largest
spread of a sequence's ATE over its 3 runs 0.0096 -> 0.0050 m, of its median object IoU 0.033 ->
0.020, at the same CPU time.
"""

from __future__ import annotations

import threading
from dataclasses import fields

import gtsam
import numpy as np
from gtsam.symbol_shorthand import L, S

from .floor import floor_residual
from .landmark import StackedRays, batch_silhouette_residuals, bounded_residuals, bounds_residuals, stack_rays
from .quadric import box_residuals
from .shapevar import PLAIN

__all__ = ["SilhouetteFactors", "silhouette_factor", "bounds_factor", "floor_factor", "with_floor_factors", "box_factor"]


class SilhouetteFactors:
    """The silhouette factors of one graph, evaluated together (module docstring).

    A resource with state (the last evaluation of each factor), so a class: make one per graph, add
    its factors with :meth:`factor`. Factors of different graphs must not share one (an evaluation
    reads every factor's variables from the values GTSAM passes; a factor whose variables are not
    all there is left out of it).

    Attributes
    ----------
    evaluations : int
        Vectorised evaluations so far.
    factor_evaluations : int
        Factor evaluations they contained (one factor, all its rays).
    """

    def __init__(self, variable=PLAIN):
        self.variable = variable  # the size/shape variable (sqfit.graph.shapevar)
        self._keys, self._rays, self._units = [], [], []
        self._bounds = []  # per factor: its rays' residual bound (inf: none; bounded_residuals)
        self._key_set = set()  # every factor's keys (holds)
        # Each variable's distinct values so far, by exact bytes (cheap to compare), numbered: a
        # factor's signature is the numbers of its variables' values, and it is re-evaluated when
        # that changes (a value seen before keeps its number: a rejected step's values come back).
        self._slot, self._pose, self._seen = {}, [], []  # key -> slot; per slot: a pose?, bytes -> number
        self._slots, self._signed = [], None  # per factor its keys' slots (-1: none); as an array
        # per factor: the signature of its last evaluation and its rows (None where non-finite)
        self._sig, self._out = np.zeros((0, 4), dtype=np.int64), []
        self._last = []  # per factor: its signature as a tuple (one entry per key), None before any
        # per ray count: every factor's rays stacked (StackedRays of them all) and each factor's row
        self._pool, self._row, self._unpooled = {}, [], []
        self._lock = threading.Lock()
        self.evaluations = self.factor_evaluations = 0

    def __len__(self):
        return len(self._keys)

    def holds(self, factor):
        """Whether ``factor`` (a GTSAM factor) is one of this graph's silhouette factors (by its
        variables: one silhouette factor per camera, landmark and shape; no other factor of the
        superquadric graph has those three)."""
        keys = tuple(factor.keys())
        return len(keys) >= 3 and keys in self._key_set

    def unbound(self, pose_key):
        """Lift the ray bound of every factor of the landmark ``pose_key`` (:func:`silhouette_factor`'s
        ``ray_bound``); they are evaluated afresh when next asked. GTSAM's factors stay as they
        are (the bound is read here at each evaluation), so a linearisation made before, iSAM2's,
        is stale until it is made again."""
        with self._lock:
            for i, keys in enumerate(self._keys):
                if keys[1] == pose_key:
                    self._bounds[i] = np.inf
                    self._last[i] = None
                    if i < len(self._sig):
                        self._sig[i] = -2  # no variable's number: stale

    def factor(self, noise, camera_key, pose_key, shape_key, rays, offset_key=None, offset_unit_px=1.0,
               ray_bound=np.inf):
        """A new silhouette factor of this graph (arguments: :func:`silhouette_factor`)."""
        i = len(self._keys)
        keys = (camera_key, pose_key, shape_key) + (() if offset_key is None else (offset_key,))
        for position, key in enumerate(keys):
            if key not in self._slot:
                self._slot[key] = len(self._pose)
                self._pose.append(position < 2)  # the camera and the landmark pose
                self._seen.append({})
        slots = [self._slot[key] for key in keys]
        self._keys.append(keys)
        self._key_set.add(keys)
        self._slots.append(slots + [-1] * (4 - len(slots)))
        self._signed = None
        self._units.append(float(offset_unit_px))
        self._bounds.append(float(ray_bound))
        self._rays.append(rays)
        self._row.append(None)
        self._unpooled.append(i)
        self._out.append(None)
        self._last.append(None)
        # (key, a pose?, that variable's numbered values) per key: GTSAM calls this once per factor
        # and pass, and most calls only find their variables unchanged
        checks = tuple((key, self._pose[slot], self._seen[slot]) for key, slot in zip(keys, slots))

        def error(this, values, jacobians):
            with self._lock:
                last = self._last[i]
                stale = last is None
                if not stale:
                    # a plain loop, not any(<generator>): this runs once per factor and pass
                    for (key, pose, seen), number in zip(checks, last):
                        if seen.get((values.atPose3(key).matrix() if pose else values.atVector(key)).tobytes()) != number:
                            stale = True
                            break
                if stale:
                    self._evaluate(values)
                out = self._out[i]
            if out is None:
                raise FloatingPointError(f"silhouette factor ({gtsam.DefaultKeyFormatter(camera_key)}, "
                                         f"{gtsam.DefaultKeyFormatter(pose_key)}): non-finite residual at shape "
                                         f"{values.atVector(shape_key)}")
            if jacobians is not None:
                for slot, J in enumerate(out[1:]):
                    jacobians[slot] = J
            return out[0]

        return gtsam.CustomFactor(noise, list(keys), error)

    def _signatures(self, values):
        """The numbers of the values of every variable in ``values`` (-1 where absent), by slot,
        with a last entry -1 for the unused fourth key of factors without an outline offset."""
        numbers = np.full(len(self._pose) + 1, -1, dtype=np.int64)
        read = {}
        for key, slot in self._slot.items():
            v = _read(values, key, self._pose[slot]) if values.exists(key) else None
            if v is not None:
                seen = self._seen[slot]
                numbers[slot] = seen.setdefault(v.tobytes(), len(seen))
                read[key] = v
        return numbers, read

    def _evaluate(self, values):
        """Evaluate every factor whose variables are in ``values`` and differ from its last evaluation."""
        if self._signed is None:
            self._signed = np.array(self._slots, dtype=np.int64).reshape(-1, 4)
            grown = np.full((len(self._slots), 4), -2, dtype=np.int64)
            grown[:len(self._sig)] = self._sig
            self._sig = grown
        numbers, read = self._signatures(values)
        sig = numbers[self._signed]  # (factors, 4); the fourth key's -1 where there is none
        present = np.all((sig >= 0) | (self._signed < 0), axis=1)
        stale = np.flatnonzero(present & np.any(sig != self._sig, axis=1))
        groups = {}  # evaluated together: the same number of rays, with or without an outline offset
        for i in stale.tolist():
            groups.setdefault((len(self._rays[i]), len(self._keys[i])), []).append(i)
        for (_, n_keys), idx in groups.items():
            Tc, Tl, shape = (np.stack([read[self._keys[i][slot]] for i in idx]) for slot in range(3))
            if not self.variable.plain:  # the plain variable is the shape itself: no map on this hot path
                shape, dz = self.variable.shape_and_jacobian(shape)
            unit = np.array([self._units[i] for i in idx])
            offset = None if n_keys == 3 else np.array([read[self._keys[i][3]][0] for i in idx]) * unit
            with np.errstate(all="ignore"):
                # no warm start: the rows must depend on the variables alone (module docstring)
                pool, rows = self._stack(idx)
                out = batch_silhouette_residuals(Tc, Tl, shape, pool, None, offset, rows=rows)
            finite = np.logical_and.reduce([np.isfinite(a).reshape(len(idx), -1).all(axis=1)
                                            for j, a in enumerate(out) if j != 4])
            r, Jc, Jl, Js = out[:4]
            if not self.variable.plain:
                Js = Js * dz[:, None, :]
            # the offset variable is in units of `unit` px
            Jo = () if offset is None else (out[5] * unit[:, None],)
            bound = np.array([self._bounds[i] for i in idx])
            if np.isfinite(bound).any():
                r, (Jc, Jl, Js, *Jo) = bounded_residuals(r, (Jc, Jl, Js) + Jo, bound)
            for j, i in enumerate(idx):
                # copies, not views: a view would keep this evaluation's arrays alive for as long as
                # any one of its factors is not re-evaluated (iSAM2 leaves old frames' factors alone)
                self._out[i] = ((r[j].copy(), Jc[j].copy(), Jl[j].copy(), Js[j].copy())
                                + tuple(a[j][:, None].copy() for a in Jo)) if finite[j] else None
            self._sig[idx] = sig[idx]
            for i in idx:
                self._last[i] = tuple(self._sig[i, :len(self._keys[i])].tolist())
            self.factor_evaluations += len(idx)
        self.evaluations += 1

    def _stack(self, idx):
        """``(pool, rows)``: the stacked rays of every factor with the ray count of factors ``idx``
        (all the same) and their rows in it, for :func:`batch_silhouette_residuals`, which reads
        the rows in place. Each factor's rays are stacked once, as factors are added, never per
        evaluation."""
        n = len(self._rays[idx[0]])
        new = [i for i in self._unpooled if len(self._rays[i]) == n]
        if new:
            self._unpooled = [i for i in self._unpooled if len(self._rays[i]) != n]
            pool, rows = self._pool.get(n), len(self._pool[n]) if n in self._pool else 0
            added = stack_rays([self._rays[i] for i in new])
            self._pool[n] = added if pool is None else StackedRays(*(
                np.concatenate([getattr(pool, f.name), getattr(added, f.name)]) for f in fields(StackedRays)))
            for j, i in enumerate(new):
                self._row[i] = rows + j
        return self._pool[n], np.array([self._row[i] for i in idx], dtype=np.int64)


def _read(values, key, pose):
    """A variable (a pose as its (4, 4) matrix) of ``values``."""
    return values.atPose3(key).matrix() if pose else values.atVector(key)


def silhouette_factor(noise, camera_key, pose_key, shape_key, rays, batch=None, offset_key=None,
                      offset_unit_px=1.0, ray_bound=np.inf):
    """Silhouette factor of one view of one superquadric landmark.

    Parameters
    ----------
    noise : gtsam.noiseModel.Base
        Of dimension ``len(rays)`` (robust in the graph: :func:`sqfit.graph.solve`).
    camera_key, pose_key, shape_key : int
        Keys of the camera ``Pose3``, the landmark ``Pose3`` and its size/shape vector (5,).
    rays : RaySet
        Camera-frame rays (:func:`sqfit.graph.landmark.camera_rays`).
    batch : SilhouetteFactors, optional
        The evaluator of the graph's silhouette factors; default: one of its own.
    offset_key : int, optional
        Key of the landmark's outline offset (a vector (1,), in units of ``offset_unit_px`` pixels):
        the mask's outline is taken as moved by that offset along its normal
        (:func:`sqfit.graph.landmark.batch_silhouette_residuals`); default: no offset.
    offset_unit_px : float
        Pixels per unit of the offset variable, > 0 (an optimiser's damping sees a pixel's column
        ~40 times smaller than a metre's: :data:`sqfit.fitting.grazing.OFFSET_UNIT_PX`).
    ray_bound : float
        > 0: each ray's residual is bounded by this, in the residuals' own units
        (:func:`sqfit.graph.landmark.bounded_residuals`); ``inf`` (the default): not bounded.
    """
    if not (np.isfinite(offset_unit_px) and offset_unit_px > 0):
        raise ValueError(f"offset_unit_px must be a finite number > 0, got {offset_unit_px}")
    if not ray_bound > 0:
        raise ValueError(f"ray_bound must be > 0 (inf: none), got {ray_bound}")
    return (SilhouetteFactors() if batch is None else batch).factor(noise, camera_key, pose_key, shape_key, rays,
                                                                    offset_key, offset_unit_px, ray_bound)


def bounds_factor(shape_key, weight, variable=PLAIN):
    """Unary factor of the bound penalty (:func:`sqfit.graph.landmark.bounds_residuals`);
    ``variable``: the size/shape variable's kind (:mod:`sqfit.graph.shapevar`)."""
    plain = variable.plain  # no map (and no numpy call) per evaluation for the plain variable

    def error(this, values, jacobians):
        shape = values.atVector(shape_key)
        if not plain:
            shape, d = variable.shape_and_jacobian(shape)
        r, J = bounds_residuals(shape, weight)
        if jacobians is not None:
            jacobians[0] = J if plain else J * d
        return r

    return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(5), [shape_key], error)


def floor_factor(noise, pose_key, shape_key, floor_z, variable=PLAIN):
    """Binary factor: the landmark's lowest point on the floor ``z = floor_z``
    (:func:`sqfit.graph.floor.floor_residual`); ``noise`` of dimension 1, metres; ``variable``: the
    size/shape variable's kind (:mod:`sqfit.graph.shapevar`)."""
    floor_z, plain = float(floor_z), variable.plain  # plain: no map (floor_residual avoids numpy calls)

    def error(this, values, jacobians):
        shape = values.atVector(shape_key)
        if not plain:
            shape, d = variable.shape_and_jacobian(shape)
        r, J_pose, J_shape = floor_residual(values.atPose3(pose_key).matrix(), shape, floor_z)
        if jacobians is not None:
            jacobians[0], jacobians[1] = J_pose, (J_shape if plain else J_shape * d)
        return r

    return gtsam.CustomFactor(noise, [pose_key, shape_key], error)


def with_floor_factors(graph, oids, noise, floor_z, variable=PLAIN):
    """A copy of ``graph`` whose floor factors on the landmarks ``oids`` (keys ``L(oid), S(oid)``:
    :func:`floor_factor`, the superquadric graph's only factor on exactly a landmark's pose and
    size/shape) are replaced by new ones with ``noise``; the other factors are shared."""
    floors = {(L(oid), S(oid)) for oid in oids}
    out = gtsam.NonlinearFactorGraph()
    for k in range(graph.size()):
        factor = graph.at(k)
        if tuple(factor.keys()) not in floors:
            out.add(factor)
    for oid in oids:
        out.add(floor_factor(noise, L(oid), S(oid), floor_z, variable))
    return out


def box_factor(noise, camera_key, pose_key, radii_key, K, box):
    """QuadricSLAM's bounding-box factor of one view of one dual-quadric landmark.

    Parameters
    ----------
    noise : gtsam.noiseModel.Base
        Of dimension 4 (pixels).
    camera_key, pose_key, radii_key : int
        Keys of the camera ``Pose3``, the quadric ``Pose3`` and its radii vector (3,).
    K : (3, 3) float
        Calibration matrix.
    box : (4,) float
        Detected box ``[u_min, v_min, u_max, v_max]``, pixels.
    """
    K, box = np.array(K, dtype=np.float64), np.array(box, dtype=np.float64)

    def error(this, values, jacobians):
        Tc = values.atPose3(camera_key).matrix()
        Tq = values.atPose3(pose_key).matrix()
        radii = values.atVector(radii_key)
        r, Jc, Jq, Jr = box_residuals(Tc, Tq, radii, K, box)
        if jacobians is not None:
            jacobians[0], jacobians[1], jacobians[2] = Jc, Jq, Jr
        return r

    return gtsam.CustomFactor(noise, [camera_key, pose_key, radii_key], error)
