import math
from pathlib import Path

import numpy as np
import pytest
import trimesh

import sqfit
from sqsim.world.objects import geometry_visible, make_object, sample_objects
from sqsim.world.scene import OBJECT_KINDS, Scene, camera_poses, load_scene, parse_scene, trial_seed
from sqsim.imaging.trial import observations, sample_trial, simulate_trial

from _helpers import assert_bad_file  # noqa: E402
from _datasets import small_parsed_scene  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
small = small_parsed_scene


def test_paper_scene_matches_table_1():
    s = load_scene(ROOT / "scenes" / "paper.toml")
    assert (s.camera.width, s.camera.height, s.camera.fx, s.camera.fy, s.camera.cx, s.camera.cy) == \
        (640, 480, 400.0, 300.0, 320.0, 240.0)
    assert (s.trajectory.radius, s.trajectory.views) == (10.0, 3)
    assert s.experiment.trials == 100 and s.masks.samples == 100
    assert s.objects.size == (0.1, 5.0) and s.objects.position == (-5.0, 5.0)
    assert s.objects.rotation == (-math.pi, math.pi) and s.objects.shape == (0.1, 1.9)
    assert (s.fit.penalty_riou, s.fit.penalty_analytic) == (1.0, 100.0)
    assert s.noise_free and s.intrinsics == sqfit.Intrinsics(640, 480, 400.0, 300.0, 320.0, 240.0)


def test_defaults_equal_paper_scene_and_round_trip():
    s = load_scene(ROOT / "scenes" / "paper.toml")
    assert parse_scene({}).to_dict() == s.to_dict()
    assert parse_scene(s.to_dict()) == parse_scene({})


def test_with_overrides_validates():
    s = parse_scene({})
    t = s.with_overrides({"noise.boundary_jitter_px": 2.0, "trajectory.views": 5})
    assert t.noise.boundary_jitter_px == 2.0 and t.trajectory.views == 5 and s.trajectory.views == 3
    assert len(t.cameras()) == 5
    with pytest.raises(ValueError, match="unknown override key 'noise.blur'"):
        s.with_overrides({"noise.blur": 1})
    with pytest.raises(ValueError, match="trajectory.views must be >= 1"):
        s.with_overrides({"trajectory.views": 0})


@pytest.mark.parametrize("text, match", [
    ("[camera]\nwidth = 640\nfoo = 1\n", r"scene.toml: unknown key 'foo' in \[camera\]"),
    ("[cameras]\nwidth = 640\n", r"scene.toml: unknown section \[cameras\]"),
    ("[camera\nwidth = 640\n", "scene.toml: malformed TOML"),
    ("camera = 3\n", r"\[camera\] must be a table"),
    ("[camera]\nwidth = 0\n", "camera.width must be >= 1"),
    ("[camera]\nwidth = 64.5\n", "camera.width must be an integer"),
    ("[camera]\nfx = -1.0\n", "camera.fx must be > 0"),
    ("[camera]\ncx = nan\n", "camera.cx must be a finite number"),
    ("[camera]\nwidth = true\n", "camera.width must be an integer"),
    ("[experiment]\nseed = -1\n", "experiment.seed must be >= 0"),
    ("[experiment]\nchains = []\n", "experiment.chains must be a non-empty list"),
    ("[experiment]\nname = 3\n", "experiment.name must be a non-empty string"),
    ("[trajectory]\nkind = \"line\"\n", "trajectory.kind must be one of"),
    ("[trajectory]\narc_deg = 0.0\n", "trajectory.arc_deg must be > 0"),
    ("[trajectory]\narc_deg = 400.0\n", "trajectory.arc_deg must be <= 360"),
    ("[trajectory]\nlook_at = [0.0, 0.0]\n", "trajectory.look_at must be a list of 3 numbers"),
    ("[objects]\nsize = [2.0, 1.0]\n", "objects.size must be \\[low, high\\] with low <= high"),
    ("[objects]\nsize = [0.0, 1.0]\n", "objects.size must be > 0"),
    ("[objects]\nshape = [0.1, 2.5]\n", "objects.shape must be <= 2.0"),
    ("[objects]\nkind = \"torus\"\n", "objects.kind must be one of"),
    ("[objects]\nkind = \"mesh\"\n", "objects.path is required"),
    ("[objects]\nkind = \"mesh\"\npath = \"nope.obj\"\n", "mesh file not found"),
    ("[objects]\npath = \"a.obj\"\n", "objects.path is only used with"),
    ("[objects]\ncount = 0\n", "objects.count must be >= 1"),
    ("[masks]\nrenderer = \"vulkan\"\n", "masks.renderer must be one of"),
    ("[masks]\nsampling = \"grid\"\n", "masks.sampling must be one of"),
    ("[masks]\nsamples = 2\n", "masks.samples must be >= 3"),
    ("[noise]\ndropout = 1.0\n", "noise.dropout must be < 1"),
    ("[noise]\nerosion_px = -1\n", "noise.erosion_px must be >= 0"),
    ("[noise]\nboundary_jitter_px = -0.5\n", "noise.boundary_jitter_px must be >= 0"),
    ("[fit]\npolygon = \"box\"\n", "fit.polygon must be one of"),
    ("[fit]\npenalty_riou = 0.0\n", "fit.penalty_riou must be > 0"),
    ("[masks]\nmax_cut_fraction = 1.0\n", "masks.max_cut_fraction must be < 1"),
    ("[masks]\nmax_cut_fraction = -0.1\n", "masks.max_cut_fraction must be >= 0"),
    ("[fit]\nocclusion_aware = 1\n", "fit.occlusion_aware must be"),
])
def test_bad_scene_files(tmp_path, text, match):
    assert_bad_file(tmp_path / "scene.toml", text, load_scene, match)


def test_missing_file_and_bad_mapping(tmp_path):
    with pytest.raises(OSError, match="scene file not found"):
        load_scene(tmp_path / "missing.toml")
    with pytest.raises(ValueError, match="a scene must be a mapping"):
        parse_scene([1, 2])


def test_mesh_path_is_relative_to_the_scene_file(tmp_path):
    trimesh.creation.icosphere().export(tmp_path / "ball.stl")
    path = tmp_path / "scene.toml"
    path.write_text("[objects]\nkind = \"mesh\"\npath = \"ball.stl\"\n")
    s = load_scene(path)
    assert Path(s.objects.path) == tmp_path / "ball.stl"
    assert parse_scene(s.to_dict()).objects.path == s.objects.path
    obj = make_object(1, "mesh", (1.0, 2.0, 0.5), None, (0, 0, 0), (0, 0, 0), s.objects.path, proportions="stretch")
    np.testing.assert_allclose(obj.mesh.bounds, [[-1, -2, -0.5], [1, 2, 0.5]], atol=1e-9)


def test_trial_seed_matches_spawn():
    for n in (5, 50):
        kids = np.random.SeedSequence(42).spawn(n)
        for i in (0, 3, 4):
            assert trial_seed(42, i).generate_state(4).tolist() == kids[i].generate_state(4).tolist()
    with pytest.raises(ValueError, match="trial index must be an integer >= 0"):
        trial_seed(0, -1)


def test_circle_cameras_look_at_the_target():
    s = parse_scene({"trajectory": {"views": 4, "radius": 5.0, "height": 2.0, "look_at": [1.0, 0.0, 0.0]}})
    poses = camera_poses(s.trajectory)
    np.testing.assert_allclose(poses[:, :3, 3], [[6, 0, 2], [1, 5, 2], [-4, 0, 2], [1, -5, 2]], atol=1e-12)
    for cam in s.cameras():
        uv, depth = sqfit.project(cam, np.array([[1.0, 0.0, 0.0]]))
        np.testing.assert_allclose(uv[0], [320.0, 240.0], atol=1e-9)
        assert depth[0] > 0
    arc = parse_scene({"trajectory": {"views": 3, "arc_deg": 90.0}})
    np.testing.assert_allclose(camera_poses(arc.trajectory)[:, :3, 3], [[10, 0, 0], [7.0710678, 7.0710678, 0],
                                                                       [0, 10, 0]], atol=1e-6)


@pytest.mark.parametrize("kind", [k for k in OBJECT_KINDS if k not in ("mesh", "household")])
def test_object_kinds_have_half_extents_a(kind):
    size = np.array([0.5, 1.0, 1.5])
    obj = make_object(1, kind, size, (1.0, 1.0), (1.0, 2.0, 3.0), (0, 0, 0))
    np.testing.assert_allclose(obj.mesh.bounds, [[0.5, 1.0, 1.5], [1.5, 3.0, 4.5]], atol=1e-9)
    assert obj.mesh.is_watertight
    assert (obj.superquadric is not None) == (kind == "superquadric")
    d = obj.to_dict()
    assert d["id"] == 1 and d["kind"] == kind and ("params" in d) == (kind == "superquadric")


def test_rotation_follows_the_euler_convention():
    obj = make_object(1, "box", (1.0, 0.1, 0.1), None, (0, 0, 0), (0.0, 0.0, np.pi / 2))
    np.testing.assert_allclose(obj.mesh.bounds, [[-0.1, -1, -0.1], [0.1, 1, 0.1]], atol=1e-9)


def test_sampling_is_seeded_and_in_range():
    s = parse_scene({})
    a = sample_objects(s.objects, np.random.default_rng(3))[0]
    b = sample_objects(s.objects, np.random.default_rng(3))[0]
    np.testing.assert_array_equal(a.superquadric.to_vector(), b.superquadric.to_vector())
    v = a.superquadric.to_vector()
    assert np.all((v[:3] >= 0.1) & (v[:3] <= 5)) and np.all((v[3:5] >= 0.1) & (v[3:5] <= 1.9))


def test_geometry_visibility_rules():
    s = parse_scene({})
    cams = s.cameras()
    ok = make_object(1, "superquadric", (0.5, 0.5, 0.5), (1, 1), (0, 0, 0), (0, 0, 0))
    around_camera = make_object(1, "superquadric", (0.5, 0.5, 0.5), (1, 1), (10, 0, 0), (0, 0, 0))
    off_image = make_object(1, "superquadric", (0.5, 0.5, 0.5), (1, 1), (0, 0, 8.0), (0, 0, 0))
    assert geometry_visible([ok], cams)
    assert not geometry_visible([around_camera], cams)
    assert not geometry_visible([off_image], cams)


def test_resampled_trials_are_observable():
    s = parse_scene({"masks": {"renderer": "polygon"}})
    total = 0
    for i in range(6):
        objects, cams, images, resampled = sample_trial(s, i)
        total += resampled
        for image in images:
            mask = image == 1
            assert mask.sum() >= s.masks.min_area_px
            assert not (mask[0].any() or mask[-1].any() or mask[:, 0].any() or mask[:, -1].any())
    assert total > 0  # the paper's ranges put some objects around a camera or out of view


def test_impossible_scene_is_reported():
    s = parse_scene({"objects": {"size": [20.0, 30.0], "max_attempts": 5}, "masks": {"renderer": "polygon"}})
    with pytest.raises(ValueError, match="no observable trial in 5 draws"):
        sample_trial(s, 0)


def test_simulate_trial_several_objects_and_noise():
    s = small(objects={"count": 3}, noise={"erosion_px": 1, "pose_rotation_deg": 1.0, "pose_translation_m": 0.1})
    sim = simulate_trial(s, 2)
    assert [o.id for o in sim.objects] == [1, 2, 3]
    assert sim.clean_images.shape == (3, 120, 160) and sim.images.dtype == np.uint16
    for oid in (1, 2, 3):
        assert ((sim.images == oid).sum() < (sim.clean_images == oid).sum())
    assert not np.allclose(sim.cameras[0].pose, sim.true_cameras[0].pose)
    again = simulate_trial(s, 2)
    np.testing.assert_array_equal(again.images, sim.images)
    np.testing.assert_array_equal(again.cameras[1].pose, sim.cameras[1].pose)
    obs = observations(sim, 2, s)
    assert len(obs) == 3 and obs[0].samples.shape == (100, 2) and obs[0].camera is sim.cameras[0]
    np.testing.assert_array_equal(observations(again, 2, s)[1].samples, obs[1].samples)


def test_observations_need_two_views():
    s = small(noise={"erosion_px": 200})
    sim = simulate_trial(s, 0)
    with pytest.raises(ValueError, match="visible in 0 view"):
        observations(sim, 1, s)


def test_single_view_scene_is_rejected_up_front():
    with pytest.raises(ValueError, match=r"trajectory.views = 1: fitting needs >= 2 views"):
        parse_scene({"trajectory": {"views": 1}})
    with pytest.raises(ValueError, match=r"trajectory.views = 1: fitting needs >= 2 views"):
        parse_scene({}).with_overrides({"trajectory.views": 1})
    assert parse_scene({"trajectory": {"views": 2}}).trajectory.views == 2


def test_scene_is_immutable():
    s = parse_scene({})
    with pytest.raises(AttributeError):
        s.noise.dropout = 0.5
    assert isinstance(s, Scene)


def test_early_rejection_agrees_with_the_full_visibility_test():
    from sqsim.world.objects import draw_objects, geometry_visible, make_objects, surely_not_visible

    scene = load_scene(ROOT / "scenes" / "paper.toml")
    cameras = scene.cameras()
    rng = np.random.default_rng(0)
    rejected = 0
    for _ in range(200):
        draws = draw_objects(scene.objects, rng)
        if surely_not_visible(scene.objects, draws, cameras):
            rejected += 1
            assert not geometry_visible(make_objects(scene.objects, draws), cameras)
    assert rejected > 100  # the paper scene rejects ~3 draws in 4, nearly all before meshing
    box = scene.with_overrides({"objects.kind": "box"})
    assert not surely_not_visible(box.objects, draw_objects(box.objects, rng), cameras)  # superquadrics only


def test_cameras_are_built_once_and_equal():
    scene = load_scene(ROOT / "scenes" / "paper.toml")
    a, b = scene.cameras(), scene.cameras()
    assert a is not b and all(x is y for x, y in zip(a, b))
    fresh = [sqfit.Camera(scene.intrinsics, T) for T in camera_poses(scene.trajectory)]
    assert all(np.array_equal(x.pose, y.pose) for x, y in zip(a, fresh))
