"""A graph with its settled past held fixed: the sub-problem of the batch's window solves.

A window solve of the batch (:mod:`sqfit.graph.solve`) re-optimises only the *active* variables (the
poses of the last frames and the landmarks those frames see); every other variable stays at its
current estimate. Conditioning on those fixed values turns the graph into:

- the factors whose variables are all active, as they are (nonlinear);
- the factors that mix active and fixed variables (the older views of an active landmark, the
  odometry step into the first active frame), linearised at the current values with the fixed
  variables' columns dropped, stacked per set of active variables into one
  ``gtsam.JacobianFactor`` and wrapped in a ``gtsam.LinearContainerFactor`` (GTSAM's carrier of a
  linearised factor in a nonlinear graph, as its fixed-lag smoothers use for marginals): each window
  solve relinearises them once, so a landmark's history costs one evaluation per window instead of
  one per Levenberg-Marquardt iteration; with ``most``, a group of more than ``most`` such factors
  (a landmark seen in many old frames) is represented by ``most`` of them, evenly spread over the
  group in the graph's order, their rows scaled by ``sqrt(group / most)`` so the group keeps its
  weight: a window's cost then stays bounded however long the landmark's history;
- the factors of fixed variables only, dropped (constant).

The whole graph is still solved at the end (the last window), so the fixed past is an approximation
of the path to the solution, not of the solution.
"""

from __future__ import annotations

import gtsam
import numpy as np

__all__ = ["condition_on_past", "evenly_spread"]


def _subset(values, keys):
    """A copy of ``values`` restricted to ``keys`` (any variable types)."""
    out = gtsam.Values(values)
    for key in list(out.keys()):
        if key not in keys:
            out.erase(key)
    return out


def _sampled(mixed, most):
    """``(factor, keys, row weight)`` of the mixed factors, at most ``most`` per group (0: all):
    :func:`evenly_spread`, each kept factor's rows weighted ``sqrt(group / kept)``."""
    for group in mixed.values():
        kept = evenly_spread(group, most)
        weight = np.sqrt(len(group) / len(kept))
        for factor, keys in kept:
            yield factor, keys, weight


def _jacobian(keys, blocks, b):
    """One whitened ``JacobianFactor`` on 1-3 ``keys`` (GTSAM's Python constructors stop at 3)."""
    if not 1 <= len(keys) <= 3:
        raise ValueError(f"a conditioned factor must keep 1 to 3 active variables, got {len(keys)}")
    model = gtsam.noiseModel.Unit.Create(len(b))
    args = [a for key, block in zip(keys, blocks) for a in (key, block)]
    return gtsam.JacobianFactor(*args, b, model)


def evenly_spread(items, most):
    """At most ``most`` of ``items`` (all of them with 0), evenly spread, the first and the last kept."""
    if most == 0 or len(items) <= most:
        return list(items)
    return [items[i] for i in np.unique(np.round(np.linspace(0, len(items) - 1, most)).astype(int))]


def condition_on_past(graph, values, active, most=0):
    """The graph on the ``active`` variables with every other variable fixed at ``values``.

    Parameters
    ----------
    graph : gtsam.NonlinearFactorGraph or sequence of gtsam factors
        Factors without an active variable may be left out of a sequence (they would be dropped).
    values : gtsam.Values
        Holds every variable of ``graph``.
    active : set of int
        Keys of the variables to re-optimise.
    most : int
        At most this many linearised factors per set of active variables (module docstring); 0: all.

    Returns
    -------
    graph : gtsam.NonlinearFactorGraph
        Only on ``active`` keys (module docstring).
    values : gtsam.Values
        ``values`` restricted to the active keys that the returned graph uses.

    Raises
    ------
    ValueError
        A factor mixing active and fixed variables keeps more than 3 active ones, or linearises to a
        constrained (hard) noise model.
    """
    active, most = set(active), int(most)
    if most < 0:
        raise ValueError(f"most must be >= 0, got {most}")
    if isinstance(graph, gtsam.NonlinearFactorGraph):
        graph = [graph.at(k) for k in range(graph.size())]
    kept, mixed = gtsam.NonlinearFactorGraph(), {}
    for factor in graph:
        keys = list(factor.keys())
        on = tuple(key for key in keys if key in active)
        if len(on) == len(keys):
            kept.add(factor)
        elif on:
            mixed.setdefault(on, []).append((factor, keys))
    if mixed:
        # only the sampled factors' variables: a silhouette factor is evaluated with every other
        # one whose variables the values hold (sqfit.graph.factors.SilhouetteFactors)
        sampled = list(_sampled(mixed, most))
        at = _subset(values, active | {key for _, keys, _ in sampled for key in keys})
        zero = at.zeroVectors()
        groups = {}
        for factor, keys, weight in sampled:
            lin = gtsam.JacobianFactor(factor.linearize(at))
            if lin.isConstrained():
                raise ValueError(f"cannot condition a constrained factor on keys {keys}")
            # copies: getA / getb are views into `lin`'s memory, freed when `lin` is replaced
            A, b, offset, cols = np.array(lin.getA()), np.array(lin.getb()), 0, []
            for key in lin.keys():
                dim = zero.at(key).size
                if key in active:
                    cols.append((key, A[:, offset:offset + dim]))
                offset += dim
            group = groups.setdefault(tuple(key for key, _ in cols), ([], []))
            group[0].append(weight * np.hstack([block for _, block in cols]))
            group[1].append(weight * b)
        for keys, (blocks, bs) in groups.items():
            A, b = np.vstack(blocks), np.concatenate(bs)
            dims = np.cumsum([0] + [zero.at(key).size for key in keys])
            jf = _jacobian(keys, [A[:, dims[i]:dims[i + 1]] for i in range(len(keys))], b)
            kept.add(gtsam.LinearContainerFactor(jf, _subset(at, set(keys))))
    used = {key for k in range(kept.size()) for key in kept.at(k).keys()}
    return kept, _subset(values, used & active)
