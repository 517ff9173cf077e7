import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from sqfit.formats.trajectory import read_image_times
from sqfit.formats.tum import poses_to_rows, read_tum, rows_to_poses, write_tum

from _helpers import assert_bad_file  # noqa: E402


def random_poses(n, seed=0):
    rng = np.random.default_rng(seed)
    poses = np.tile(np.eye(4), (n, 1, 1))
    poses[:, :3, :3] = Rotation.random(n, random_state=seed).as_matrix()
    poses[:, :3, 3] = rng.normal(0, 3, (n, 3))
    return np.arange(n) / 30.0 + 1e9, poses


def test_round_trip_is_exact_and_bytes_deterministic(tmp_path):
    t, poses = random_poses(25)
    write_tum(tmp_path / "a.tum", t, poses)
    write_tum(tmp_path / "b.tum", t, poses)
    assert (tmp_path / "a.tum").read_bytes() == (tmp_path / "b.tum").read_bytes()
    t2, poses2 = read_tum(tmp_path / "a.tum")
    np.testing.assert_array_equal(t2, t)
    np.testing.assert_array_equal(poses2[:, :3, 3], poses[:, :3, 3])
    np.testing.assert_allclose(poses2, poses, atol=1e-14)


def test_line_is_camera_to_world_with_scalar_last_quaternion(tmp_path):
    # A camera at (1, 2, 3) turned 90 degrees about world z: its x axis points along world +y.
    pose = np.eye(4)
    pose[:3, :3] = Rotation.from_euler("z", 90, degrees=True).as_matrix()
    pose[:3, 3] = [1, 2, 3]
    write_tum(tmp_path / "p.tum", [0.5], pose[None])
    values = [float(x) for x in (tmp_path / "p.tum").read_text().splitlines()[1].split()]
    s = np.sqrt(0.5)
    np.testing.assert_allclose(values, [0.5, 1, 2, 3, 0, 0, s, s], atol=1e-15)


def test_evo_reads_ours_and_we_read_evos(tmp_path):
    pytest.importorskip("evo")
    from evo.core.trajectory import PoseTrajectory3D
    from evo.tools import file_interface

    t, poses = random_poses(10, seed=3)
    write_tum(tmp_path / "ours.tum", t, poses)
    traj = file_interface.read_tum_trajectory_file(str(tmp_path / "ours.tum"))
    np.testing.assert_array_equal(traj.timestamps, t)
    np.testing.assert_allclose(np.array(traj.poses_se3), poses, atol=1e-12)
    file_interface.write_tum_trajectory_file(str(tmp_path / "evo.tum"), PoseTrajectory3D(poses_se3=list(poses),
                                                                                         timestamps=t))
    t2, poses2 = read_tum(tmp_path / "evo.tum")
    np.testing.assert_array_equal(t2, t)
    np.testing.assert_allclose(poses2, poses, atol=1e-12)


def test_rows_helpers_round_trip():
    t, poses = random_poses(5, seed=1)
    rows = poses_to_rows(t, poses)
    assert rows.shape == (5, 8) and np.all(rows[:, 7] >= 0)
    t2, poses2 = rows_to_poses(rows)
    np.testing.assert_allclose(poses2, poses, atol=1e-14)


@pytest.mark.parametrize("name, text, match", [
    ("x.tum", "0 0 0 0 0 0 0 1\n1 0 0 0 0 0 0\n", r"x\.tum:2: expected 8 finite numbers"),
    ("x.tum", "0 0 0 0 0 0 0 1\n1 0 0 nan 0 0 0 1\n", r"x\.tum:2: expected 8 finite"),
    ("x.tum", "# c\n0 0 0 0 0 0 0 2\n", r"x\.tum:2: quaternion .* has norm 2, not a rotation"),
    ("x.tum", "0 0 0 0 0 0 0 1\n0 0 0 0 0 0 0 1\n", r"x\.tum:2: timestamps must be strictly increasing"),
    ("x.tum", "# only a comment\n", r"x\.tum: no poses"),
    # TUM RGB-D image lists ("timestamp filename"), sqfit.formats.trajectory
    ("rgb.txt", "1.0 a.png\n2.0\n", r"rgb.txt:2: expected 'timestamp filename'"),
    ("rgb.txt", "# c\nabc a.png\n", r"rgb.txt:2: expected 'timestamp filename' .*got 'abc a.png'"),
    ("rgb.txt", "inf a.png\n", r"rgb.txt:1: expected"),
    ("rgb.txt", "1.0 a.png\n2.0 b.png\n3.0 a.png\n", r"rgb.txt:3: 'a.png' is listed twice \(also line 1\)"),
    ("rgb.txt", "# nothing\n", r"rgb.txt: no entries"),
])
def test_bad_files_name_file_and_line(tmp_path, name, text, match):
    reader = read_tum if name.endswith(".tum") else read_image_times
    assert_bad_file(tmp_path / name, text, reader, match)


def test_bad_inputs(tmp_path):
    with pytest.raises(OSError, match="TUM trajectory file not found"):
        read_tum(tmp_path / "missing.tum")
    t, poses = random_poses(3)
    with pytest.raises(ValueError, match="strictly increasing"):
        write_tum(tmp_path / "y.tum", t[::-1], poses)
    poses[1, :3, :3] *= 2
    with pytest.raises(ValueError, match=r"poses\[1\] rotation block is not a proper rotation"):
        write_tum(tmp_path / "y.tum", t, poses)
    with pytest.raises(ValueError, match=r"poses must have shape \(3, 4, 4\)"):
        poses_to_rows(t, poses[:2])
    with pytest.raises(ValueError, match=r"waypoints\[0\]: quaternion"):
        rows_to_poses([[0, 0, 0, 0, 0, 0, 0, 0]], name="waypoints")
