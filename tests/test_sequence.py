"""Sequences: trajectories, ground layout, odometry drift, per-frame visibility, validation."""

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import sqfit
from sqfit.formats.tum import write_tum
from sqsim.world.layout import LAYOUT_GAP_M, footprint_radius, ground_layout
from sqsim.world.odometry import compose_steps, integrate_odometry, noisy_steps, relative_poses
from sqsim.world.scene import parse_scene
from sqsim.imaging.sequence import MIN_OBSERVATIONS, observed_objects, simulate_sequence
from sqsim.world.trajectory import orbit_poses, sequence_poses, waypoint_poses

SMALL = {
    "camera": {"width": 160, "height": 120, "fx": 100.0, "fy": 75.0, "cx": 80.0, "cy": 60.0},
    "trajectory": {"kind": "orbit", "frames": 12, "radius": 5.0, "radius_amplitude": 1.0, "height": 1.5,
                   "height_amplitude": 0.3, "look_at": [0.0, 0.0, 0.3], "look_at_wander": 0.8},
    "objects": {"count": 5, "layout": "ground", "upright": True, "size": [0.2, 0.5], "position": [-1.8, 1.8]},
    "masks": {"min_area_px": 15},
    "noise": {"odometry_rotation_deg": 0.5, "odometry_translation_m": 0.02},
}


def scene(**sections):
    data = {k: dict(v) for k, v in SMALL.items()}
    for name, values in sections.items():
        data.setdefault(name, {}).update(values)
        data[name] = {k: v for k, v in data[name].items() if v is not None}  # None: drop the key
    return parse_scene(data)


def angle_deg(R):
    return np.degrees(Rotation.from_matrix(R).magnitude())


# --- trajectories -----------------------------------------------------------------------------------

def test_orbit_frames_are_timestamped_and_leave_the_circle():
    s = scene(trajectory={"frames": 40, "frame_rate_hz": 20.0})
    t, poses = sequence_poses(s.trajectory)
    assert poses.shape == (40, 4, 4) and np.allclose(t, np.arange(40) / 20.0) and np.all(np.diff(t) > 0)
    centres = poses[:, :3, 3]
    r = np.hypot(centres[:, 0], centres[:, 1])
    assert r.min() == pytest.approx(4.0, abs=0.05) and r.max() == pytest.approx(6.0, abs=0.05)
    assert np.ptp(centres[:, 2]) == pytest.approx(0.6, abs=0.02)
    # the optical axes do not all meet at look_at: the gaze wanders up to look_at_wander
    z = poses[:, :3, 2]
    to_centre = np.asarray(s.trajectory.look_at) - centres
    miss = np.linalg.norm(np.cross(z, to_centre), axis=1)
    assert miss.max() > 0.5 and miss.max() <= 0.8 * math.sqrt(2 + 0.25 ** 2)  # |w(u)| bound
    assert len(s.cameras()) == 40 and np.array_equal(s.cameras()[5].pose, poses[5])


def test_orbit_without_variation_is_the_circle():
    s = scene(trajectory={"radius_amplitude": 0.0, "height_amplitude": 0.0, "look_at_wander": 0.0, "frames": 8})
    circle = parse_scene({"trajectory": {"radius": 5.0, "height": 1.5, "views": 8, "look_at": [0.0, 0.0, 0.3]}})
    np.testing.assert_allclose(orbit_poses(s.trajectory)[1], np.stack([c.pose for c in circle.cameras()]),
                               atol=1e-12)


def test_orbit_laps_revisit_from_other_places_and_gazes():
    one = scene(trajectory={"frames": 20})
    two = scene(trajectory={"frames": 40, "laps": 2})
    assert one.trajectory.laps == 1 and two.trajectory.laps == 2
    t1, p1 = sequence_poses(one.trajectory)
    t2, p2 = sequence_poses(two.trajectory)
    assert np.allclose(t2, np.arange(40) / 10.0)
    # the camera's bearing about look_at advances 360 * 2 / 40 = 18 degrees per frame: two turns
    c1, c2 = p1[:, :3, 3], p2[:, :3, 3]
    bearing = np.unwrap(np.arctan2(c2[:, 1], c2[:, 0]))  # look_at is above the origin
    np.testing.assert_allclose(np.diff(np.degrees(bearing)), 18.0, atol=1e-9)
    # the first lap passes the bearings of the one-lap orbit, the second lap the same bearings again
    np.testing.assert_allclose(np.arctan2(c2[:20, 1], c2[:20, 0]), np.arctan2(c1[:, 1], c1[:, 0]), atol=1e-12)
    np.testing.assert_allclose(np.arctan2(c2[20:, 1], c2[20:, 0]), np.arctan2(c1[:, 1], c1[:, 0]), atol=1e-12)
    # ... from other places and gazes: a revisit, not the same images again
    assert np.linalg.norm(c2[20:] - c2[:20], axis=1).max() > 0.5
    assert angle_deg(np.einsum("kji,kjl->kil", p2[20:, :3, :3], p2[:20, :3, :3])).max() > 5.0
    r2 = np.hypot(c2[:, 0], c2[:, 1])
    # radius and height keep their ranges over the whole run
    assert r2.min() == pytest.approx(4.0, abs=0.05) and r2.max() == pytest.approx(6.0, abs=0.05)
    # one lap is today's orbit
    np.testing.assert_array_equal(sequence_poses(scene(trajectory={"frames": 20, "laps": 1}).trajectory)[1], p1)



@pytest.mark.parametrize("laps", [2, 3, 4])
def test_orbit_laps_by_lap_extend_the_shorter_run(laps):
    # lap_pattern = "lap": each lap a one-lap orbit of the same step, the cycles shifted lap by lap, so
    # the first lap of any run is the one-lap orbit and a longer run is a shorter one plus laps like it
    one = scene(trajectory={"frames": 20})
    many = scene(trajectory={"frames": 20 * laps, "laps": laps, "lap_pattern": "lap"})
    assert many.trajectory.lap_pattern == "lap" and one.trajectory.lap_pattern == "run"
    p1, pn = sequence_poses(one.trajectory)[1], sequence_poses(many.trajectory)[1]
    np.testing.assert_allclose(pn[:20], p1, atol=1e-12)
    if laps in (2, 4):  # the sweep k * laps / frames is then exactly the one-lap orbit's k / 20
        np.testing.assert_array_equal(pn[:20], p1)
        half = sequence_poses(scene(trajectory={"frames": 20 * laps // 2, "laps": laps // 2,
                                                "lap_pattern": "lap"}).trajectory)[1]
        np.testing.assert_array_equal(pn[:len(half)], half)
    c1, cn = p1[:, :3, 3], pn[:, :3, 3]
    r1, rn = np.hypot(c1[:, 0], c1[:, 1]), np.hypot(cn[:, 0], cn[:, 1])
    for lap in range(1, laps):
        part = slice(20 * lap, 20 * (lap + 1))
        # the same bearings, 18 degrees a frame ...
        np.testing.assert_allclose(np.arctan2(cn[part, 1], cn[part, 0]), np.arctan2(c1[:, 1], c1[:, 0]), atol=1e-9)
        # ... from other places and gazes than every lap before it
        for before in range(lap):
            other = slice(20 * before, 20 * (before + 1))
            assert np.linalg.norm(cn[part] - cn[other], axis=1).max() > 0.5
            assert angle_deg(np.einsum("kji,kjl->kil", pn[part, :3, :3], pn[other, :3, :3])).max() > 5.0
        # each lap swings through the radius and height of one lap (within its samples' reach)
        assert np.ptp(rn[part]) > 0.8 * np.ptp(r1) and np.ptp(cn[part, 2]) > 0.8 * np.ptp(c1[:, 2])
    assert rn.min() >= 4.0 - 1e-9 and rn.max() <= 6.0 + 1e-9


def test_a_lap_pattern_set_in_code_is_checked_too():
    # scene files are checked as they are read; a scene changed in code (dataclasses.replace, as
    # benchmarks/bench_graph.py does) must not fall back to "run" silently
    from dataclasses import replace

    from sqsim.world.trajectory import check_sequence_keys

    s = scene(trajectory={"frames": 40, "laps": 2})
    with pytest.raises(ValueError, match=r"trajectory\.lap_pattern must be one of \['run', 'lap', 'revisit'\], got 'turn'"):
        check_sequence_keys(replace(s, trajectory=replace(s.trajectory, lap_pattern="turn")))


def test_orbit_lap_pattern_changes_nothing_on_one_lap():
    p_run = sequence_poses(scene(trajectory={"frames": 20}).trajectory)[1]
    for pattern in ("lap", "revisit"):
        p_lap = sequence_poses(scene(trajectory={"frames": 20, "lap_pattern": pattern}).trajectory)[1]
        np.testing.assert_array_equal(p_run, p_lap)


@pytest.mark.parametrize("laps", [2, 3, 4])
def test_orbit_laps_revisit_one_path_between_the_earlier_frames(laps):
    # lap_pattern = "revisit": every lap the one-lap orbit's path, its frames shifted along it, so a
    # longer run is a shorter one plus laps over the same places, never on an earlier frame
    p1 = sequence_poses(scene(trajectory={"frames": 20}).trajectory)[1]
    pn = sequence_poses(scene(trajectory={"frames": 20 * laps, "laps": laps, "lap_pattern": "revisit"}).trajectory)[1]
    np.testing.assert_array_equal(pn[:20], p1)
    if laps == 4:
        np.testing.assert_array_equal(pn[:40], sequence_poses(scene(trajectory={
            "frames": 40, "laps": 2, "lap_pattern": "revisit"}).trajectory)[1])
    # the one-lap path, densely: each frame of every lap lies on it, with its gaze
    dense = sequence_poses(scene(trajectory={"frames": 20 * 500}).trajectory)[1]
    for k in range(20, 20 * laps):
        gap = np.linalg.norm(dense[:, :3, 3] - pn[k, :3, 3], axis=1)
        j = int(np.argmin(gap))
        assert gap[j] < 5e-3
        assert angle_deg(dense[j, :3, :3].T @ pn[k, :3, :3]) < 0.5
    # 18 degrees a frame within each lap, and each lap's frames off every earlier lap's
    centres = pn[:, :3, 3]
    bearing = np.unwrap(np.arctan2(centres[:, 1], centres[:, 0]))
    for lap in range(1, laps):
        part = slice(20 * lap, 20 * (lap + 1))
        np.testing.assert_allclose(np.degrees(np.diff(bearing[part])), 18.0, atol=1e-9)
        shift = np.mod(np.degrees(bearing[part] - bearing[:20]), 360.0) / 18.0
        assert np.ptp(shift) < 1e-9 and 0.1 < shift[0] < 0.9
        for before in range(lap):
            other = slice(20 * before, 20 * (before + 1))
            assert np.min(np.linalg.norm(centres[part, None] - centres[None, other], axis=2)) > 0.1


def test_waypoints_interpolate_linearly_and_slerp(tmp_path):
    rows = [[0.0, 0, 0, 1, 0, 0, 0, 1], [2.0, 4, 0, 1, *Rotation.from_euler("z", 90, degrees=True).as_quat()],
            [3.0, 4, 2, 1, *Rotation.from_euler("z", 180, degrees=True).as_quat()]]
    s = scene(trajectory={"kind": "waypoints", "frames": 7, "waypoints": rows, "radius_amplitude": None,
                          "height_amplitude": None, "look_at_wander": None})
    t, poses = sequence_poses(s.trajectory)
    np.testing.assert_allclose(t, np.linspace(0, 3, 7))
    # t = 1.0: halfway between waypoints 0 and 1 -> position (2, 0, 1), rotation 45 degrees about z
    np.testing.assert_allclose(poses[2, :3, 3], [2, 0, 1], atol=1e-12)
    np.testing.assert_allclose(poses[2, :3, :3], Rotation.from_euler("z", 45, degrees=True).as_matrix(), atol=1e-12)
    # a frame at a waypoint's time has its pose
    np.testing.assert_allclose(poses[4, :3, 3], [4, 0, 1], atol=1e-12)
    np.testing.assert_allclose(poses[6, :3, :3], Rotation.from_euler("z", 180, degrees=True).as_matrix(), atol=1e-12)
    # the same waypoints from a TUM file next to the scene file
    _, wp = sqfit.formats.tum.rows_to_poses(rows)
    write_tum(tmp_path / "path.tum", [r[0] for r in rows], wp)
    text = ('[trajectory]\nkind = "waypoints"\nframes = 7\nwaypoints_file = "path.tum"\n')
    (tmp_path / "s.toml").write_text(text)
    from sqsim.world.scene import load_scene
    s2 = load_scene(tmp_path / "s.toml")
    np.testing.assert_allclose(sequence_poses(s2.trajectory)[1], poses, atol=1e-12)
    np.testing.assert_allclose(waypoint_poses([r[0] for r in rows], wp, 7)[1], poses, atol=1e-12)


ORBIT_KEYS = {"radius_amplitude": None, "height_amplitude": None, "look_at_wander": None}


@pytest.mark.parametrize("sections, match", [
    ({"trajectory": {"frames": 0}}, r"trajectory\.frames must be >= 2, got 0"),
    ({"trajectory": {"frames": 1}}, r"trajectory\.frames must be >= 2"),
    ({"noise": {"odometry_rotation_deg": -0.1}}, r"noise\.odometry_rotation_deg must be >= 0"),
    ({"noise": {"odometry_translation_m": -1.0}}, r"noise\.odometry_translation_m must be >= 0"),
    ({"trajectory": {"kind": "waypoints", **ORBIT_KEYS,
                     "waypoints": [[0, 0, 0, 0, 0, 0, 0, 1], [1, 1, 0, 0, 0, 0.5, 0, 1]]}},
     r"trajectory\.waypoints row\[1\]: quaternion .* not a rotation"),
    ({"trajectory": {"kind": "waypoints", **ORBIT_KEYS, "waypoints": [[0, 0, 0, 0, 0, 0, 0, 1], [0, 1, 0, 0, 0, 0, 0, 1]]}},
     r"trajectory\.waypoints row\[1\]: times must be strictly increasing"),
    ({"trajectory": {"kind": "waypoints", **ORBIT_KEYS, "waypoints": [[0, 0, 0, 0, 0, 0, 0, 1]]}},
     r"trajectory\.waypoints must be a list of at least 2 rows"),
    ({"trajectory": {"kind": "waypoints", **ORBIT_KEYS, "waypoints": [[0, 0, 0, 0, 0, 0, 1], [1, 0, 0, 0, 0, 0, 0, 1]]}},
     r"trajectory\.waypoints row\[0\] must be 8 numbers"),
    ({"trajectory": {"kind": "waypoints", **ORBIT_KEYS}}, r"needs exactly one of trajectory\.waypoints"),
    ({"trajectory": {"kind": "waypoints", "radius_amplitude": None, "height_amplitude": None,
                     "waypoints": [[0, 0, 0, 0, 0, 0, 0, 1], [1, 0, 0, 0, 0, 0, 0, 1]]}},
     r"trajectory\.look_at_wander is only used with kind = \"orbit\""),
    ({"trajectory": {"waypoints_file": "x.tum"}}, r"trajectory\.waypoints_file is only used with kind = \"waypoints\""),
    ({"trajectory": {"kind": "waypoints", **ORBIT_KEYS, "waypoints_file": "/nonexistent/x.tum"}},
     r"trajectory\.waypoints_file: TUM file not found"),
    ({"trajectory": {"radius_amplitude": 5.0}}, r"trajectory\.radius_amplitude must be < trajectory\.radius"),
    ({"trajectory": {"laps": 0}}, r"trajectory\.laps must be >= 1, got 0"),
    ({"trajectory": {"laps": 1.5}}, r"trajectory\.laps must be an integer"),
    ({"trajectory": {"laps": 2, "arc_deg": 300.0}}, r"trajectory\.laps > 1 needs full turns \(trajectory\.arc_deg = 360\)"),
    ({"trajectory": {"laps": 2, "lap_pattern": "turn"}}, r"trajectory\.lap_pattern must be one of \['run', 'lap', 'revisit'\]"),
    ({"trajectory": {"kind": "waypoints", **ORBIT_KEYS, "lap_pattern": "lap",
                     "waypoints": [[0, 0, 0, 0, 0, 0, 0, 1], [1, 0, 0, 0, 0, 0, 0, 1]]}},
     r"trajectory\.lap_pattern is only used with kind = \"orbit\""),
    ({"trajectory": {"kind": "waypoints", **ORBIT_KEYS, "laps": 2,
                     "waypoints": [[0, 0, 0, 0, 0, 0, 0, 1], [1, 0, 0, 0, 0, 0, 0, 1]]}},
     r"trajectory\.laps is only used with kind = \"orbit\""),
    ({"trajectory": {"look_at_wander": 4.5}}, r"trajectory\.look_at_wander must be <"),
    ({"noise": {"pose_rotation_deg": 1.0}}, r"noise\.pose_rotation_deg is per-view noise"),
    ({"noise": {"pose_translation_m": 0.1}}, r"noise\.pose_translation_m is per-view noise"),
    ({"objects": {"layout": "free"}}, r"objects\.upright is only used with objects\.layout = \"ground\""),
    ({"objects": {"layout": "sky"}}, r"objects\.layout must be one of \['free', 'ground'\]"),
    ({"objects": {"count": 30, "size": [0.5, 0.6]}}, r"objects\.count = 30 objects .* cannot rest side by side"),
])
def test_bad_sequence_values_name_the_key(sections, match):
    with pytest.raises(ValueError, match=match):
        scene(**sections)


@pytest.mark.parametrize("trajectory, noise, match", [
    ({"frames": 10}, {}, r"trajectory\.frames is only used by sequences"),
    ({"look_at_wander": 1.0}, {}, r"trajectory\.look_at_wander is only used by sequences"),
    ({"lap_pattern": "lap"}, {}, r"trajectory\.lap_pattern is only used by sequences"),
    ({}, {"odometry_rotation_deg": 0.5}, r"noise\.odometry_rotation_deg is only used by sequences"),
])
def test_sequence_keys_on_a_circle_scene(trajectory, noise, match):
    with pytest.raises(ValueError, match=match):
        parse_scene({"trajectory": trajectory, "noise": noise})


def test_bad_waypoints_file_names_the_line(tmp_path):
    (tmp_path / "w.tum").write_text("0 0 0 0 0 0 0 1\n1 0 0 0 0 0 0 3\n")
    with pytest.raises(ValueError, match=r"trajectory\.waypoints_file: .*w\.tum:2: quaternion"):
        scene(trajectory={"kind": "waypoints", **ORBIT_KEYS, "waypoints_file": str(tmp_path / "w.tum")})


def test_multi_view_scenes_are_unchanged():
    assert parse_scene({}).to_dict() == parse_scene(parse_scene({}).to_dict()).to_dict()
    assert "frames" not in parse_scene({}).to_dict()["trajectory"]


# --- odometry ---------------------------------------------------------------------------------------

def test_noise_free_odometry_reproduces_the_true_trajectory():
    s = scene(trajectory={"frames": 60}, noise={"odometry_rotation_deg": 0.0, "odometry_translation_m": 0.0})
    _, true = sequence_poses(s.trajectory)
    np.testing.assert_allclose(integrate_odometry(true, 0.0, 0.0), true, rtol=0, atol=1e-12)
    np.testing.assert_allclose(compose_steps(true[0], relative_poses(true)), true, rtol=0, atol=1e-12)
    # zero noise through the noisy path too (the noise model adds exactly nothing)
    np.testing.assert_allclose(compose_steps(true[0], noisy_steps(relative_poses(true), 0.0, 0.0, 1)), true,
                               rtol=0, atol=1e-12)


def drift(true, rot_deg, trans_m, draws, seed=0):
    """Rotation error angles (rad) and position errors (m) after every step, for many draws."""
    rng = np.random.default_rng(seed)
    angles, errors = [], []
    for _ in range(draws):
        odo = integrate_odometry(true, rot_deg, trans_m, rng)
        rel = np.swapaxes(true[:, :3, :3], 1, 2) @ odo[:, :3, :3]
        angles.append(Rotation.from_matrix(rel).magnitude())
        errors.append(np.linalg.norm(odo[:, :3, 3] - true[:, :3, 3], axis=1))
    return np.array(angles), np.array(errors)


def test_rotation_drift_grows_as_sqrt_k_times_the_step_noise():
    # E[angle_k^2] = 3 k s^2 for a random walk of isotropic rotation-vector steps (std s per axis).
    # 400 draws: the mean of angle^2 / (3 k s^2) (a chi^2_3 / 3 mean) has std 0.82 / 20 = 0.041,
    # so a 0.15 tolerance fails with probability < 3e-4 and catches a noise off by 10 %.
    true = sequence_poses(scene(trajectory={"frames": 41}).trajectory)[1]
    sigma = math.radians(0.5)
    angles, _ = drift(true, 0.5, 0.0, 400)
    for k in (1, 10, 40):
        ratio = np.mean(angles[:, k] ** 2) / (3 * k * sigma ** 2)
        assert abs(ratio - 1) < 0.15, (k, ratio)
    rms = np.sqrt(np.mean(angles ** 2, axis=0))
    assert rms[40] / rms[10] == pytest.approx(2.0, rel=0.12)  # sqrt(40 / 10)
    assert angles[:, 0].max() == 0.0  # starts at the first true pose


def test_translation_drift_matches_the_step_noise():
    true = sequence_poses(scene(trajectory={"frames": 41}).trajectory)[1]
    _, errors = drift(true, 0.0, 0.02, 400, seed=1)
    for k in (1, 10, 40):
        ratio = np.mean(errors[:, k] ** 2) / (3 * k * 0.02 ** 2)
        assert abs(ratio - 1) < 0.15, (k, ratio)
    assert errors[:, 0].max() == 0.0


def test_odometry_noise_validation():
    with pytest.raises(ValueError, match="odometry rotation_deg must be a finite number >= 0"):
        noisy_steps(np.tile(np.eye(4), (2, 1, 1)), -1.0, 0.0)
    with pytest.raises(ValueError, match=r"true_poses must have shape \(n, 4, 4\)"):
        integrate_odometry(np.eye(4), 0.0, 0.0)


# --- layout and visibility ------------------------------------------------------------------------

@pytest.mark.parametrize("kind", ["superquadric", "box", "cone"])
def test_ground_layout_rests_on_the_floor_without_interpenetration(kind):
    s = scene(objects={"kind": kind, "count": 10, "position": [-3.0, 3.0], "upright": False})
    rng = np.random.default_rng(0)
    layouts = [o for o in (ground_layout(s.objects, rng) for _ in range(20)) if o is not None]
    assert len(layouts) >= 15
    for objects in layouts:
        for o in objects:
            v = np.asarray(o.mesh.vertices)
            assert v[:, 2].min() == pytest.approx(0.0, abs=1e-9)  # resting on z = 0
            assert -3.0 <= o.position[0] <= 3.0 and -3.0 <= o.position[1] <= 3.0
            if o.superquadric is not None:
                assert o.superquadric.position == o.position
        # footprints (from the meshes themselves) are disjoint, so the objects are
        for i, a in enumerate(objects):
            for b in objects[i + 1:]:
                gap = np.hypot(a.position[0] - b.position[0], a.position[1] - b.position[1])
                assert gap >= footprint_radius(a) + footprint_radius(b) + LAYOUT_GAP_M - 1e-9


def test_upright_objects_turn_about_the_vertical_only():
    s = scene()
    objects = ground_layout(s.objects, np.random.default_rng(3))
    assert all(o.rotation[0] == 0.0 and o.rotation[1] == 0.0 for o in objects)
    assert len({o.rotation[2] for o in objects}) == len(objects)


def test_observed_objects_counts_pixels():
    images = np.zeros((2, 4, 5), dtype=np.uint16)
    images[0, :2, :2] = 1
    images[1, 0, 0] = 2
    observed, areas = observed_objects(images, [1, 2, 3], min_area_px=2)
    np.testing.assert_array_equal(areas, [[4, 0, 0], [0, 1, 0]])
    np.testing.assert_array_equal(observed, [[True, False, False], [False, False, False]])
    assert observed_objects(images, [2], 0)[0][1, 0]  # min_area_px 0 still needs one pixel


@pytest.fixture(scope="module")
def simulated():
    s = scene(trajectory={"frames": 20, "look_at_wander": 1.5})
    return s, [simulate_sequence(s, seed=seed) for seed in range(3)]


def test_simulated_sequence_fields_and_visibility(simulated):
    s, seqs = simulated
    border = hidden = missing = 0
    for seq in seqs:
        n, m = 20, 5
        assert seq.timestamps.shape == (n,) and seq.true_poses.shape == (n, 4, 4)
        assert seq.odometry_poses.shape == (n, 4, 4) and seq.images.shape == (n, 120, 160)
        assert seq.images.dtype == np.uint16 and seq.observed.shape == (n, m)
        assert sorted(seq.objects) == [1, 2, 3, 4, 5] and all(isinstance(q, sqfit.Superquadric) for q in seq.objects.values())
        np.testing.assert_array_equal(seq.odometry_poses[0], seq.true_poses[0])
        assert seq.observed.sum(axis=0).min() >= MIN_OBSERVATIONS
        observed, areas = observed_objects(seq.clean_images, seq.object_ids, s.masks.min_area_px)
        np.testing.assert_array_equal(observed, seq.observed)
        missing += int((~seq.observed).sum())
        for k in range(n):
            for i, oid in enumerate(seq.object_ids):
                if not seq.observed[k, i]:
                    continue
                mask = seq.images[k] == oid
                border += bool(mask[0].any() or mask[-1].any() or mask[:, 0].any() or mask[:, -1].any())
                # hidden in part: the object's own projection is larger than its visible mask
                alone = seq.scene_objects[i]
                from sqsim.imaging.render import get_renderer
                full = get_renderer(s.masks.renderer, s.intrinsics).render([alone], [seq.cameras("true")[k]])[0]
                hidden += bool((full != 0).sum() > mask.sum())
    # frames cut by the border or hidden by others are kept, and some frames miss some objects
    assert border > 0 and hidden > 0 and missing > 0
    assert seqs[0].cameras()[3].pose is not None and len(seqs[0].frames_observing(1)) >= 2


def test_sequence_is_deterministic_and_seeded(simulated):
    s, seqs = simulated
    again = simulate_sequence(s, seed=0)
    np.testing.assert_array_equal(again.images, seqs[0].images)
    np.testing.assert_array_equal(again.odometry_poses, seqs[0].odometry_poses)
    assert not np.array_equal(seqs[1].images, seqs[0].images)
    assert not np.allclose(seqs[1].odometry_poses[-1], seqs[0].odometry_poses[-1])


def test_impossible_or_wrong_scenes():
    with pytest.raises(ValueError, match=r"not a sequence"):
        simulate_sequence(parse_scene({}))
    far = scene(objects={"position": [40.0, 45.0], "max_attempts": 3})
    with pytest.raises(ValueError, match=r"no draw in 3 attempts where every object is observed in >= 2 frames"):
        simulate_sequence(far)


def test_multi_view_trials_refuse_a_sequence_scene():
    from sqsim.imaging.trial import sample_trial

    with pytest.raises(ValueError, match=r"trajectory\.kind = 'orbit' is an image sequence"):
        sample_trial(scene(), 0)



def test_sequence_command_prints_drift_and_draws(tmp_path, capsys, simulated):
    from sqsim.cli import main
    from sqsim.reports.sequence import drift

    _, seqs = simulated
    translation, rotation = drift(seqs[0].true_poses, seqs[0].odometry_poses)
    assert translation[0] == 0 and rotation[0] == 0 and translation[-1] > 0
    (tmp_path / "s.toml").write_text(
        '[camera]\nwidth = 160\nheight = 120\nfx = 100.0\nfy = 75.0\ncx = 80.0\ncy = 60.0\n'
        '[trajectory]\nkind = "orbit"\nframes = 10\nradius = 5.0\nheight = 1.5\n'
        '[objects]\ncount = 3\nlayout = "ground"\nsize = [0.2, 0.5]\nposition = [-1.5, 1.5]\n'
        '[masks]\nmin_area_px = 15\n[noise]\nodometry_rotation_deg = 0.5\n')
    assert main(["sequence", str(tmp_path / "s.toml"), "--figure", str(tmp_path / "f.png")]) == 0
    out = capsys.readouterr().out
    assert "10 frames" in out and "odometry drift: frame 2:" in out and "frame 9:" in out
    assert (tmp_path / "f.png").read_bytes()[:4] == b"\x89PNG"


@pytest.mark.parametrize("name", ["sequence.toml", "sequence-waypoints.toml"])
def test_shipped_sequence_scenes(name):
    from pathlib import Path

    from sqsim.world.scene import load_scene

    s = load_scene(Path(__file__).resolve().parents[1] / "scenes" / name)
    t, poses = sequence_poses(s.trajectory)
    assert len(t) == s.trajectory.frames >= 40 and s.objects.count >= 6 and s.objects.layout == "ground"
    assert (s.noise.odometry_rotation_deg, s.noise.odometry_translation_m) == (0.5, 0.02)
    assert np.all(np.diff(t) > 0) and poses.shape == (len(t), 4, 4)
