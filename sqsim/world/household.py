"""Household objects: a catalogue of everyday things as watertight meshes with seeded proportions.

Every kind is a builder ``(rng) -> trimesh.Trimesh`` registered in :data:`CATALOGUE`; it draws
its dimensions (metres, uniform in the ranges of its ``*_DIMENSIONS`` table, in the table's order)
from ``rng`` and builds the solid from primitives (boxes, cylinders, spheres, tori, revolved
profiles) joined with exact booleans (manifold3d, through ``trimesh.boolean``).
:func:`build_household` calls a builder and centres the result.

Canonical frame (every kind): metres, world +z up, the object standing on its base; the mesh is
centred on its axis-aligned bounding box (the base is at ``z = -height / 2``); the front faces
-y (a viewer at -y sees a monitor's or laptop's screen, a chair's seat edge, a book's spine);
a mug's handle points to +x. Meshes are closed, outward-facing, single solids.

Containers (mug, bowl) hold contents up to a drawn fraction of their inner depth: no silhouette
reveals the cavity of a container, so an empty thin shell would score every mask-based method by
its wall thickness rather than by its fit; the contents leave a visible recess below the rim.

>>> import numpy as np
>>> mug = build_household("mug", np.random.default_rng(0))
>>> bool(mug.is_watertight and mug.volume > 0)
True
>>> np.allclose(mug.bounds.sum(axis=0), 0.0)
True
"""

from __future__ import annotations

import numpy as np
import trimesh
from trimesh.creation import box, cylinder, icosphere, revolve, torus

__all__ = ["CATALOGUE", "build_household", "check_catalogue"]

#: Facets of round primitives (per revolution).
SECTIONS = 64
#: Icosphere subdivisions of the round parts of soft shapes (642 vertices a sphere).
SPHERE_SUBDIVISIONS = 3


# --- helpers --------------------------------------------------------------------------------------

def _draw(table, rng):
    """One value per key of ``table`` (``key -> (low, high)``), uniform, in the table's order."""
    return {key: float(rng.uniform(lo, hi)) for key, (lo, hi) in table.items()}


def _union(*meshes):
    return trimesh.boolean.union(meshes, engine="manifold")


def _difference(a, b):
    return trimesh.boolean.difference([a, b], engine="manifold")


def _box(extents, centre):
    return box(extents=extents, transform=trimesh.transformations.translation_matrix(centre))


def _rod(radius, z0, z1, xy=(0.0, 0.0)):
    """A vertical cylinder from ``z0`` to ``z1`` over ``xy``."""
    return cylinder(radius=radius, segment=[(*xy, z0), (*xy, z1)], sections=SECTIONS)


def _lathe(profile):
    """A solid of revolution about +z from ``(r, z)`` points that start and end on the axis."""
    mesh = revolve(np.asarray(profile, dtype=np.float64), sections=SECTIONS)
    if mesh.volume < 0:  # the profile ran clockwise in the (r, z) plane
        mesh.invert()
    return mesh


def _blob(centre, radii):
    """An ellipsoid with semi-axes ``radii``."""
    mesh = icosphere(subdivisions=SPHERE_SUBDIVISIONS)
    mesh.apply_scale(radii)
    mesh.apply_translation(centre)
    return mesh


def _quarter(n):
    """``(n,)`` angles from 0 to pi / 2 for quarter-ellipse profiles."""
    return np.linspace(0.0, np.pi / 2, n)


# --- the catalogue --------------------------------------------------------------------------------

MUG_DIMENSIONS = {"radius": (0.035, 0.05), "height": (0.08, 0.12), "wall": (0.004, 0.007),
                  "bottom": (0.006, 0.01), "fill": (0.75, 0.95), "handle_radius": (0.2, 0.28),
                  "handle_thickness": (0.006, 0.01), "handle_stretch": (1.0, 1.3)}


def mug(rng):
    """A cylindrical cup with a ring handle on +x (its radius a fraction ``handle_radius`` of the
    height, ``handle_stretch`` times taller than wide: it stays below the rim), filled to ``fill``
    of its inner depth (``MUG_DIMENSIONS``; containers: module docstring)."""
    d = _draw(MUG_DIMENSIONS, rng)
    r, h = d["radius"], d["height"]
    handle = torus(d["handle_radius"] * h, d["handle_thickness"], major_sections=SECTIONS, minor_sections=16)
    handle.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, (1, 0, 0)))
    handle.apply_scale((1.0, 1.0, d["handle_stretch"]))
    handle.apply_translation((r, 0.0, h / 2))
    level = d["bottom"] + d["fill"] * (h - d["bottom"])
    cavity = _rod(r - d["wall"], level, h + 0.01)
    return _difference(_union(_rod(r, 0.0, h), handle), cavity)


BOTTLE_DIMENSIONS = {"radius": (0.03, 0.045), "body": (0.14, 0.22), "shoulder": (0.03, 0.06),
                     "neck_radius": (0.011, 0.016), "neck": (0.03, 0.06), "cap": (0.015, 0.025)}


def bottle(rng):
    """A closed bottle: body, rounded shoulder, neck and a slightly wider cap (``BOTTLE_DIMENSIONS``)."""
    d = _draw(BOTTLE_DIMENSIONS, rng)
    r, rn, zb = d["radius"], d["neck_radius"], d["body"]
    t = _quarter(12)
    shoulder = np.stack([rn + (r - rn) * np.cos(t), zb + d["shoulder"] * np.sin(t)], axis=1)
    z_neck = zb + d["shoulder"] + d["neck"]
    cap = rn + 0.002
    profile = [(0.0, 0.0), (r, 0.0), *shoulder, (rn, z_neck), (cap, z_neck), (cap, z_neck + d["cap"]),
               (0.0, z_neck + d["cap"])]
    return _lathe(profile)


CAN_DIMENSIONS = {"radius": (0.03, 0.04), "height": (0.09, 0.16), "rim_inset": (0.002, 0.005),
                  "rim_height": (0.005, 0.01)}


def can(rng):
    """A drink or food can: a cylinder with bevelled rims (``CAN_DIMENSIONS``)."""
    d = _draw(CAN_DIMENSIONS, rng)
    r, h, i, e = d["radius"], d["height"], d["rim_inset"], d["rim_height"]
    return _lathe([(0.0, 0.0), (r - i, 0.0), (r, e), (r, h - e), (r - i, h), (0.0, h)])


BOWL_DIMENSIONS = {"radius": (0.07, 0.12), "depth": (0.35, 0.55), "wall": (0.004, 0.008),
                   "foot_radius": (0.4, 0.55), "foot_height": (0.006, 0.012), "fill": (0.6, 0.9)}


def bowl(rng):
    """A round bowl on a foot, filled to ``fill`` of its inner depth; ``depth`` and
    ``foot_radius`` are fractions of the radius (``BOWL_DIMENSIONS``; containers: module
    docstring)."""
    d = _draw(BOWL_DIMENSIONS, rng)
    r, w, zf = d["radius"], d["wall"], d["foot_height"]
    rf, depth = d["foot_radius"] * r, d["depth"] * r
    t = _quarter(16)
    outer = np.stack([rf + (r - rf) * np.sin(t), zf + depth * (1.0 - np.cos(t))], axis=1)
    # Inner wall, a quarter ellipse from the rim down to the contents' level (1 - cos t = fill).
    s = np.linspace(np.pi / 2, np.arccos(1.0 - d["fill"]), 12)
    inner = np.stack([(r - w) * np.sin(s), zf + w + (depth - w) * (1.0 - np.cos(s))], axis=1)
    return _lathe([(0.0, 0.0), (rf, 0.0), *outer, *inner, (0.0, inner[-1, 1])])


BOOK_DIMENSIONS = {"height": (0.18, 0.28), "width": (0.12, 0.2), "thickness": (0.015, 0.05),
                   "cover": (0.0015, 0.003), "inset": (0.003, 0.006)}


def book(rng):
    """A closed hardback standing on its bottom edge, spine to -y, pages recessed between the
    covers (``BOOK_DIMENSIONS``)."""
    d = _draw(BOOK_DIMENSIONS, rng)
    h, w, t, c, i = d["height"], d["width"], d["thickness"], d["cover"], d["inset"]
    covers = [_box((c, w, h), (s * (t - c) / 2, 0.0, h / 2)) for s in (-1, 1)]
    spine = _box((t, c, h), (0.0, -(w - c) / 2, h / 2))
    pages = _box((t - c, w - i, h - 2 * i), (0.0, -i / 2, h / 2))
    return _union(*covers, spine, pages)


MONITOR_DIMENSIONS = {"width": (0.45, 0.7), "aspect": (0.5, 0.65), "thickness": (0.02, 0.05),
                      "lift": (0.06, 0.14), "neck_width": (0.04, 0.07), "neck_depth": (0.02, 0.03),
                      "base_width": (0.18, 0.28), "base_depth": (0.15, 0.22), "base_height": (0.01, 0.02)}


def monitor(rng):
    """A flat screen (``aspect`` = height / width) on a neck and base plate, screen facing -y
    (``MONITOR_DIMENSIONS``)."""
    d = _draw(MONITOR_DIMENSIONS, rng)
    w, h, t = d["width"], d["aspect"] * d["width"], d["thickness"]
    zb, z0 = d["base_height"], d["base_height"] + d["lift"]
    y_neck = t / 2 + d["neck_depth"] / 2
    screen = _box((w, t, h), (0.0, 0.0, z0 + h / 2))
    neck = _box((d["neck_width"], d["neck_depth"], d["lift"] + h / 2), (0.0, y_neck, zb + (d["lift"] + h / 2) / 2))
    base = _box((d["base_width"], d["base_depth"], zb), (0.0, y_neck, zb / 2))
    return _union(screen, neck, base)


LAPTOP_DIMENSIONS = {"width": (0.3, 0.38), "depth": (0.2, 0.26), "base": (0.012, 0.022), "lid": (0.006, 0.01),
                     "opening_deg": (95.0, 125.0)}


def laptop(rng):
    """An open laptop: base slab and a lid hinged at its back (+y) edge, opened by ``opening_deg``
    from closed, screen towards -y (``LAPTOP_DIMENSIONS``)."""
    d = _draw(LAPTOP_DIMENSIONS, rng)
    w, depth, zb, tl = d["width"], d["depth"], d["base"], d["lid"]
    base = _box((w, depth, zb), (0.0, 0.0, zb / 2))
    # Lid laid flat behind the hinge line (y = depth / 2, z = zb), centred on it in thickness and
    # reaching ``tl`` in front of it, so that it sinks into the base; then turned up about the
    # hinge by 180 deg - opening (90 deg stands it upright).
    lid = _box((w, depth + tl, tl), (0.0, depth - tl / 2, zb))
    angle = np.radians(180.0 - d["opening_deg"])
    lid.apply_transform(trimesh.transformations.rotation_matrix(angle, (1, 0, 0), (0.0, depth / 2, zb)))
    return _union(base, lid)


CHAIR_DIMENSIONS = {"width": (0.4, 0.5), "depth": (0.38, 0.48), "seat_height": (0.42, 0.48),
                    "seat": (0.03, 0.06), "leg": (0.03, 0.045), "back_height": (0.35, 0.5),
                    "back": (0.02, 0.04), "panel": (0.4, 0.6)}


def chair(rng):
    """Four square legs, a seat, two back posts and a backrest panel (its height a fraction
    ``panel`` of the back's) at +y (``CHAIR_DIMENSIONS``)."""
    d = _draw(CHAIR_DIMENSIONS, rng)
    w, dp, zs, s, g = d["width"], d["depth"], d["seat_height"], d["seat"], d["leg"]
    x, y = (w - g) / 2, (dp - g) / 2
    legs = [_box((g, g, zs - s), (sx * x, sy * y, (zs - s) / 2)) for sx in (-1, 1) for sy in (-1, 1)]
    seat = _box((w, dp, s), (0.0, 0.0, zs - s / 2))
    top = zs + d["back_height"]
    posts = [_box((g, g, d["back_height"]), (sx * x, y, zs + d["back_height"] / 2)) for sx in (-1, 1)]
    panel_h = d["panel"] * d["back_height"]
    panel = _box((w, d["back"], panel_h), (0.0, y, top - panel_h / 2))
    return _union(*legs, seat, *posts, panel)


TABLE_DIMENSIONS = {"width": (0.8, 1.6), "depth": (0.5, 0.9), "height": (0.7, 0.78), "top": (0.025, 0.05),
                    "leg": (0.04, 0.07), "inset": (0.03, 0.1)}


def table(rng):
    """A rectangular top on four square legs set in by ``inset`` (``TABLE_DIMENSIONS``)."""
    d = _draw(TABLE_DIMENSIONS, rng)
    w, dp, h, t, g, i = d["width"], d["depth"], d["height"], d["top"], d["leg"], d["inset"]
    x, y = w / 2 - i - g / 2, dp / 2 - i - g / 2
    legs = [_box((g, g, h - t), (sx * x, sy * y, (h - t) / 2)) for sx in (-1, 1) for sy in (-1, 1)]
    return _union(_box((w, dp, t), (0.0, 0.0, h - t / 2)), *legs)


LAMP_DIMENSIONS = {"base_radius": (0.06, 0.1), "base": (0.015, 0.03), "pole_radius": (0.008, 0.014),
                   "pole": (0.25, 0.45), "shade_radius": (0.1, 0.16), "shade_taper": (0.5, 0.75),
                   "shade": (0.12, 0.2)}


def lamp(rng):
    """A table lamp: disc base, pole, and a solid conical shade (top radius = ``shade_taper`` x
    bottom radius) around the pole's top (``LAMP_DIMENSIONS``)."""
    d = _draw(LAMP_DIMENSIONS, rng)
    zb, zp, hs = d["base"], d["base"] + d["pole"], d["shade"]
    rb, rt = d["shade_radius"], d["shade_radius"] * d["shade_taper"]
    z0 = zp - 0.6 * hs
    shade = _lathe([(0.0, z0), (rb, z0), (rt, z0 + hs), (0.0, z0 + hs)])
    return _union(_rod(d["base_radius"], 0.0, zb), _rod(d["pole_radius"], zb / 2, zp), shade)


PLANT_POT_DIMENSIONS = {"radius": (0.05, 0.08), "flare": (1.2, 1.45), "height": (0.1, 0.16),
                        "rim": (0.012, 0.02), "lip": (0.005, 0.01), "foliage": (0.6, 0.95), "stretch": (0.9, 1.5)}


def plant_pot(rng):
    """A flared pot (top radius = ``flare`` x bottom) with a rim and a bushy plant: a central
    ellipsoid (radius ``foliage`` x the pot's top, ``stretch`` times taller) and two side lumps
    at azimuths drawn after the table (``PLANT_POT_DIMENSIONS``)."""
    d = _draw(PLANT_POT_DIMENSIONS, rng)
    r0, h = d["radius"], d["height"]
    r1 = r0 * d["flare"]
    rim_in = r0 + (r1 - r0) * (h - d["rim"]) / h
    pot = _lathe([(0.0, 0.0), (r0, 0.0), (rim_in, h - d["rim"]), (r1 + d["lip"], h - d["rim"]),
                  (r1 + d["lip"], h), (0.0, h)])
    rf = d["foliage"] * r1
    tall = rf * d["stretch"]
    lumps = [_blob((0.0, 0.0, h + 0.75 * tall), (rf, rf, tall))]
    for angle in rng.uniform(0.0, 2 * np.pi, 2):
        offset = 0.8 * rf * np.array([np.cos(angle), np.sin(angle)])
        lumps.append(_blob((*offset, h + 0.6 * tall), (0.55 * rf, 0.55 * rf, 0.6 * tall)))
    return _union(pot, *lumps)


TOY_DIMENSIONS = {"body_width": (0.08, 0.11), "body_depth": (0.07, 0.09), "body_height": (0.1, 0.14),
                  "head": (0.06, 0.08), "ear": (0.018, 0.028), "limb": (0.025, 0.035), "arm_spread": (0.5, 1.1)}


def toy(rng):
    """A soft toy (teddy-like blob): ellipsoid body, round head with ears and a snout (to -y),
    arms turned out from hanging by ``arm_spread`` (rad) and two legs forward (``TOY_DIMENSIONS``)."""
    d = _draw(TOY_DIMENSIONS, rng)
    bw, bd, bh, rh, rl = d["body_width"], d["body_depth"], d["body_height"], d["head"], d["limb"]
    zb = bh + rl  # body centre: its bottom rests on the legs' top half
    zh = zb + bh + 0.6 * rh
    parts = [_blob((0.0, 0.0, zb), (bw, bd, bh)), _blob((0.0, 0.0, zh), (rh, rh, rh)),
             _blob((0.0, -0.95 * rh, zh - 0.2 * rh), (0.35 * rh, 0.3 * rh, 0.28 * rh))]
    arm_length = 0.9 * bh
    for s in (-1, 1):
        parts.append(_blob((s * 0.7 * rh, 0.0, zh + 0.75 * rh), (d["ear"], 0.6 * d["ear"], d["ear"])))
        arm = _blob((0.0, 0.0, -arm_length / 2), (rl, rl, arm_length / 2))  # hanging from the origin
        arm.apply_transform(trimesh.transformations.rotation_matrix(-s * d["arm_spread"], (0, 1, 0)))
        arm.apply_translation((s * 0.75 * bw, -0.15 * bd, zb + 0.5 * bh))
        parts.append(arm)
        parts.append(_blob((s * 0.5 * bw, -0.6 * bd, rl), (1.2 * rl, 2.0 * rl, rl)))
    return _union(*parts)


#: Household kinds: name -> builder ``(rng) -> trimesh.Trimesh`` (metres, z up, front to -y).
CATALOGUE = {"mug": mug, "bottle": bottle, "can": can, "bowl": bowl, "book": book, "monitor": monitor,
             "laptop": laptop, "chair": chair, "table": table, "lamp": lamp, "plant_pot": plant_pot, "toy": toy}


# --- public face ----------------------------------------------------------------------------------

def check_catalogue(names):
    """Validate a list of catalogue names.

    Parameters
    ----------
    names : list of str

    Returns
    -------
    names : tuple of str
        In the given order, duplicates removed.

    Raises
    ------
    ValueError
        Not a non-empty list of strings, or an unknown name (the message lists the valid names).
    """
    if not isinstance(names, (list, tuple)) or not names or not all(isinstance(n, str) for n in names):
        raise ValueError(f"must be a non-empty list of household kinds, got {names!r}")
    unknown = [n for n in names if n not in CATALOGUE]
    if unknown:
        raise ValueError(f"has unknown household kind(s) {unknown} (valid: {', '.join(CATALOGUE)})")
    return tuple(dict.fromkeys(names))


def build_household(name, rng=None):
    """A household object of kind ``name`` with seeded proportions, in the canonical frame.

    Parameters
    ----------
    name : str
        A key of :data:`CATALOGUE`.
    rng : numpy.random.Generator or int or None
        Seeds the proportions (``np.random.default_rng(rng)``).

    Returns
    -------
    mesh : trimesh.Trimesh
        Watertight, outward-facing, metres; centred on its bounding box, +z up, front to -y.
    """
    if name not in CATALOGUE:
        raise ValueError(f"unknown household kind {name!r} (valid: {', '.join(CATALOGUE)})")
    mesh = CATALOGUE[name](np.random.default_rng(rng))
    mesh.apply_translation(-mesh.bounds.mean(axis=0))
    return mesh
