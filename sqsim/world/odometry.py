"""Simulated visual odometry: noisy relative poses between consecutive frames, integrated.

Model (stated once, pinned by ``tests/test_sequence.py``): with true poses ``T_k``
(``T_world_camera``), the true step is ``D_k = T_{k-1}^-1 T_k`` (frame ``k`` in the camera frame of
frame ``k - 1``). A measured step is ``R(D~_k) = R(D_k) Exp(w_k)``, ``t(D~_k) = t(D_k) + d_k`` with
``w_k ~ N(0, s_r^2 I_3)`` (rotation vector, radians, ``s_r = radians(rotation_deg)``) and
``d_k ~ N(0, s_t^2 I_3)`` (metres, in the camera frame of frame ``k - 1``): the per-axis
standard deviations, as ``sqsim.imaging.noise.perturb_pose`` uses for per-view noise. The odometry
trajectory starts at the first true pose and composes the measured steps,
``O_0 = T_0``, ``O_k = O_{k-1} D~_k``, so its error is a random walk: after ``k`` steps the
rotation error angle has ``E[angle^2] ~= 3 k s_r^2`` and, with no rotation noise, the position
error has ``E[|e|^2] = 3 k s_t^2`` (rotation noise adds a faster-growing lever-arm term).
"""

from __future__ import annotations

import numpy as np

from sqfit._checks import check_shape

__all__ = ["relative_poses", "compose_steps", "noisy_steps", "integrate_odometry", "rigid_inverse"]


def rigid_inverse(poses):
    """Inverse of rigid transforms, ``[R^T, -R^T t]``.

    Parameters
    ----------
    poses : (..., 4, 4) float

    Returns
    -------
    inverse : (..., 4, 4) float
    """
    poses = np.asarray(poses, dtype=np.float64)
    out = np.zeros_like(poses)
    Rt = np.swapaxes(poses[..., :3, :3], -1, -2)
    out[..., :3, :3] = Rt
    out[..., :3, 3] = -(Rt @ poses[..., :3, 3, None])[..., 0]
    out[..., 3, 3] = 1.0
    return out


def relative_poses(poses):
    """Steps between consecutive poses, ``D_k = T_{k-1}^-1 T_k``.

    Parameters
    ----------
    poses : (n, 4, 4) float
        ``T_world_camera``, ``n >= 1``.

    Returns
    -------
    steps : (n - 1, 4, 4) float
    """
    poses = check_shape(poses, (None, 4, 4), "poses")
    return rigid_inverse(poses[:-1]) @ poses[1:]


def compose_steps(first, steps):
    """Integrate steps from a first pose: ``O_0 = first``, ``O_k = O_{k-1} steps[k-1]``.

    Parameters
    ----------
    first : (4, 4) float
    steps : (n - 1, 4, 4) float

    Returns
    -------
    poses : (n, 4, 4) float
    """
    first = check_shape(first, (4, 4), "first")
    steps = check_shape(steps, (None, 4, 4), "steps")
    out = np.empty((len(steps) + 1, 4, 4))
    out[0] = first
    for k, step in enumerate(steps, start=1):
        out[k] = out[k - 1] @ step
    return out


def noisy_steps(steps, rotation_deg, translation_m, rng=None):
    """Measured steps: each true step with rotation and translation noise (module docstring).

    Parameters
    ----------
    steps : (m, 4, 4) float
    rotation_deg, translation_m : float
        Per-axis standard deviations, >= 0.
    rng : None, int or numpy.random.Generator
        Draws ``m x 3`` rotation-vector values, then ``m x 3`` translation values.

    Returns
    -------
    noisy : (m, 4, 4) float
    """
    from scipy.spatial.transform import Rotation

    steps = check_shape(steps, (None, 4, 4), "steps")
    for name, value in (("rotation_deg", rotation_deg), ("translation_m", translation_m)):
        if not np.isfinite(value) or value < 0:
            raise ValueError(f"odometry {name} must be a finite number >= 0, got {value}")
    rng = np.random.default_rng(rng)
    rotvec = rng.normal(0.0, np.radians(rotation_deg), (len(steps), 3))
    shift = rng.normal(0.0, translation_m, (len(steps), 3))
    out = steps.copy()
    if len(steps):
        out[:, :3, :3] = steps[:, :3, :3] @ Rotation.from_rotvec(rotvec).as_matrix()
    out[:, :3, 3] += shift
    return out


def integrate_odometry(true_poses, rotation_deg, translation_m, rng=None):
    """Odometry trajectory of a true trajectory: noisy steps composed from the first true pose.

    Parameters
    ----------
    true_poses : (n, 4, 4) float
        ``T_world_camera``.
    rotation_deg, translation_m : float
        Per-step, per-axis noise standard deviations (degrees, metres), >= 0. With both 0 the
        true steps are composed unchanged (equal to ``true_poses`` up to rounding, ~1e-15).
    rng : None, int or numpy.random.Generator

    Returns
    -------
    odometry_poses : (n, 4, 4) float
    """
    true_poses = check_shape(true_poses, (None, 4, 4), "true_poses")
    if len(true_poses) == 0:
        raise ValueError("true_poses must hold at least one pose")
    steps = relative_poses(true_poses)
    if rotation_deg or translation_m:
        steps = noisy_steps(steps, rotation_deg, translation_m, rng)
    return compose_steps(true_poses[0], steps)
