"""``sqsim sequence``: simulate one sequence of a scene, print its visibility and drift, draw it.

The figure is a top-down view (world x to the right, y up) of the floor: object footprints
(convex hull of each mesh seen from above, labelled with its id), the true and the odometry
camera paths, and the horizontal field of view of a few frames as seen from the true pose (the
same frame from the odometry pose in the odometry colour)::

    sqsim sequence scenes/sequence.toml --figure docs/figures/sequence.png
"""

from __future__ import annotations

import numpy as np

from .figures import finish_topdown

__all__ = ["drift", "summarize", "plot_sequence", "add_arguments", "run"]

#: Depth (m) at which a frame's field of view is drawn, and frames drawn with it.
FRUSTUM_DEPTH_M, FRUSTA = 2.0, 6


def drift(true_poses, odometry_poses):
    """Per-frame odometry error.

    Parameters
    ----------
    true_poses, odometry_poses : (n, 4, 4) float

    Returns
    -------
    translation_m : (n,) float
        Distance between the true and the odometry camera centres.
    rotation_deg : (n,) float
        Angle of ``R_true^T R_odometry``.
    """
    from scipy.spatial.transform import Rotation

    true_poses, odometry_poses = np.asarray(true_poses), np.asarray(odometry_poses)
    translation = np.linalg.norm(true_poses[:, :3, 3] - odometry_poses[:, :3, 3], axis=1)
    relative = np.swapaxes(true_poses[:, :3, :3], 1, 2) @ odometry_poses[:, :3, :3]
    return translation, np.degrees(Rotation.from_matrix(relative).magnitude())


def summarize(seq):
    """Text summary of a sequence: frames, observations per object, drift at a few frames."""
    translation, rotation = drift(seq.true_poses, seq.odometry_poses)
    n = seq.n_frames
    lines = [f"{seq.name}: {n} frames over {seq.timestamps[-1] - seq.timestamps[0]:.2f} s, "
             f"{len(seq.object_ids)} objects, {int(seq.observed.sum())} observations "
             f"({seq.observed.sum(axis=1).mean():.1f} objects per frame)",
             "frames observing each object: " + ", ".join(
                 f"{oid}: {int(c)}" for oid, c in zip(seq.object_ids, seq.observed.sum(axis=0)))]
    marks = sorted({n // 4, n // 2, 3 * n // 4, n - 1})
    lines.append("odometry drift: " + ", ".join(
        f"frame {k}: {translation[k]:.3f} m / {rotation[k]:.2f} deg" for k in marks))
    return "\n".join(lines)


def _fov_triangle(intrinsics, pose, depth):
    """World xy of the camera centre and of the image row through the principal point at ``depth``."""
    k = intrinsics
    rays = np.array([[(0.0 - k.cx) / k.fx, 0.0, 1.0], [(k.width - k.cx) / k.fx, 0.0, 1.0]]) * depth
    ends = rays @ pose[:3, :3].T + pose[:3, 3]
    return np.vstack([pose[:3, 3], ends, pose[:3, 3]])[:, :2]


def plot_sequence(seq, path, frusta=FRUSTA):
    """Draw the top-down figure of a simulated sequence (module docstring) to ``path`` (PNG).

    Parameters
    ----------
    seq : sqsim.imaging.sequence.SimulatedSequence
    path : str or os.PathLike
    frusta : int
        Frames whose field of view is drawn, spread evenly over the sequence.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from scipy.spatial import ConvexHull

    fig, ax = plt.subplots(figsize=(7.5, 8.2))
    colours = plt.get_cmap("tab10")
    for i, obj in enumerate(seq.scene_objects):
        xy = np.asarray(obj.mesh.vertices)[:, :2]
        hull = xy[ConvexHull(xy).vertices]
        ax.fill(hull[:, 0], hull[:, 1], color=colours(i % 10), alpha=0.55, lw=0)
        ax.text(obj.position[0], obj.position[1], str(obj.id), ha="center", va="center", fontsize=9)
    true_xy, odo_xy = seq.true_poses[:, :2, 3], seq.odometry_poses[:, :2, 3]
    ax.plot(true_xy[:, 0], true_xy[:, 1], "-", color="black", lw=1.5, label="true trajectory")
    ax.plot(odo_xy[:, 0], odo_xy[:, 1], "--", color="tab:red", lw=1.5, label="odometry")
    ax.plot(*true_xy[0], "o", color="black", ms=6, label="first frame (odometry starts here)")
    for j, k in enumerate(np.linspace(0, seq.n_frames - 1, frusta).round().astype(int)):
        tri = _fov_triangle(seq.intrinsics, seq.true_poses[k], FRUSTUM_DEPTH_M)
        ax.plot(tri[:, 0], tri[:, 1], "-", color="tab:blue", lw=1, label="field of view (true pose)" if j == 0 else None)
        tri = _fov_triangle(seq.intrinsics, seq.odometry_poses[k], FRUSTUM_DEPTH_M)
        ax.plot(tri[:, 0], tri[:, 1], ":", color="tab:red", lw=1, label="field of view (odometry pose)" if j == 0 else None)
        ax.annotate(f"{k}", true_xy[k], textcoords="offset points", xytext=(4, 4), fontsize=8, color="tab:blue")
    translation, rotation = drift(seq.true_poses, seq.odometry_poses)
    ax.set_title(f"{seq.name}: {seq.n_frames} frames, {len(seq.object_ids)} objects\n"
                 f"odometry drift at the last frame: {translation[-1]:.2f} m, {rotation[-1]:.1f} deg", fontsize=10)
    finish_topdown(fig, ax, path, 110)


def add_arguments(parser):
    from ..world.scene import add_set_option

    parser.add_argument("scene", help="sequence scene TOML file (trajectory.kind = \"orbit\" or \"waypoints\")")
    add_set_option(parser)
    parser.add_argument("--seed", type=int, default=None, help="seed (default: experiment.seed)")
    parser.add_argument("--index", type=int, default=0, help="sequence index (trial of a dataset with this seed)")
    parser.add_argument("--figure", default=None, help="write the top-down figure (PNG) here")


def run(args):
    from ..world.scene import load_scene, scene_overrides
    from ..imaging.sequence import simulate_sequence

    seq = simulate_sequence(load_scene(args.scene, scene_overrides(args.set)), seed=args.seed, index=args.index)
    print(summarize(seq))
    if args.figure:
        plot_sequence(seq, args.figure)
        print(f"figure: {args.figure}")
    return 0
