"""Stage 3U (sqfit.fitting.two_parts): its L- and V-shaped starts, the union's silhouette IoU, gradient and sample, its
kernels, the stage on a true superquadric and on a chair (the `whole` chain's fit where it keeps no part);
scripts/two_part_probe.py's arguments."""

from dataclasses import replace

import numpy as np
import pytest
import shapely

import sqfit
from sqfit.fitting import two_parts
from sqfit.fitting.costs import ObservationSet
from sqfit.geometry.silhouette import silhouette
from sqfit.fitting.stages import to_superquadric
from sqfit.geometry.superquadric import contains, euler_to_matrix, volume
from sqfit.kernels.backend import compiled, set_kernels
from sqfit.testing import paper_trial
from sqfit.views.visibility import BORDER
from _helpers import SCRIPTS, script_module

SCRIPT = SCRIPTS / "two_part_probe.py"


def _script():
    return script_module(SCRIPT)


def test_the_starts_are_slabs_on_two_adjacent_faces_of_the_fits_box():
    xi = np.r_[1.0, 2.0, 3.0, 1.0, 1.0, 0.5, -0.5, 2.0, 0.3, -0.2, 1.1]
    starts = two_parts.l_starts(xi)
    assert starts.shape == (12, 2, 11)
    R = euler_to_matrix(xi[8:11])
    faces = set()
    for pair in starts:
        thin_axes = []
        for part in pair:
            assert np.allclose(part[8:11], xi[8:11]) and np.allclose(part[3:5], 0.2)
            thin = int(np.argmax(np.abs(part[0:3] - xi[0:3])))
            assert np.isclose(part[thin], two_parts.THIN * xi[thin])
            offset = R.T @ (part[5:8] - xi[5:8])  # in the box's frame: on the face, inside the box
            assert np.isclose(abs(offset[thin]), xi[thin] * (1 - two_parts.THIN))
            assert np.allclose(np.delete(offset, thin), 0.0)
            thin_axes.append((thin, np.sign(offset[thin])))
        assert thin_axes[0][0] != thin_axes[1][0]  # two different faces, adjacent
        faces.add(tuple(sorted(thin_axes)))
    assert len(faces) == 12


def test_the_v_starts_are_two_slabs_from_a_sides_midpoint_to_the_far_corners_across_the_thinnest_axis():
    xi = np.r_[2.0, 0.5, 3.0, 1.0, 1.0, 0.5, -0.5, 2.0, 0.3, -0.2, 1.1]  # thinnest along y (axis 1)
    starts = two_parts.v_starts(xi)
    assert starts.shape == (4, 2, 11)
    a, R, p = xi[0:3], euler_to_matrix(xi[8:11]), xi[5:8]
    seen = set()
    for pair in starts:
        ends, hinge_axes = [], set()
        for part in pair:
            assert np.allclose(part[3:5], 0.2)
            frame = euler_to_matrix(part[8:11])
            assert np.isclose(np.linalg.det(frame), 1.0)
            local = R.T @ frame  # the part's axes in the box's frame
            hinge_axis = int(np.argmax(np.abs(local[:, 1])))
            assert hinge_axis != 1 and np.isclose(abs(local[hinge_axis, 1]), 1.0)  # a longer axis is the hinge
            assert np.isclose(part[1], a[hinge_axis]) and np.isclose(part[2], two_parts.THIN * a[1])
            centre, arm = R.T @ (part[5:8] - p) / a, local[:, 0] * part[0] / a  # in box units
            assert np.isclose(centre[hinge_axis], 0.0) and np.isclose(arm[hinge_axis], 0.0)
            ends.append([centre - arm, centre + arm])
            hinge_axes.add(hinge_axis)
        assert len(hinge_axes) == 1
        # the arms share one end, the midpoint of a side across the thinnest axis; their other ends are the two
        # corners of the opposite side
        shared = [e for e in ends[0] if any(np.allclose(e, f) for f in ends[1])]
        assert len(shared) == 1
        hinge = shared[0]
        assert np.isclose(abs(hinge[1]), 1.0) and np.allclose(np.delete(hinge, 1), 0.0)
        far = [e for end in ends for e in end if not np.allclose(e, hinge)]
        fan = 3 - 1 - hinge_axes.pop()
        assert sorted(np.round([f[fan] for f in far], 9)) == [-1.0, 1.0]
        assert all(np.isclose(f[1], -hinge[1]) for f in far)
        seen.add((fan, float(np.sign(hinge[1]))))
    assert seen == {(0, -1.0), (0, 1.0), (2, -1.0), (2, 1.0)}


@pytest.mark.parametrize("thinnest, with_v", [(0.5, True), (0.7 * 2.0, True), (0.71 * 2.0, False), (1.9, False)])
def test_the_starts_add_the_v_shaped_ones_only_where_the_fits_box_is_flat(thinnest, with_v):
    xi = np.r_[2.0, thinnest, 3.0, 1.0, 1.0, 0.5, -0.5, 2.0, 0.3, -0.2, 1.1]  # middle half-axis 2
    assert two_parts.V_ASPECT == 0.7
    expected = [two_parts.l_starts(xi)] + ([two_parts.v_starts(xi)] if with_v else [])
    assert np.array_equal(two_parts.starts(xi), np.concatenate(expected))


def test_the_unions_silhouette_iou_is_the_single_ones_for_one_part_or_the_same_part_twice():
    trial = paper_trial(0)
    obs, truth = ObservationSet(trial.observations), trial.gt
    xi = truth.to_vector()
    one = two_parts.union_ious(xi[None, None], obs)[0]
    twice = two_parts.union_ious(np.stack([xi, xi])[None], obs)[0]
    assert np.allclose(one, twice)
    for v, o in enumerate(trial.observations):
        sil = shapely.Polygon(silhouette(truth, o.camera, two_parts.VERTICES))
        contour = shapely.Polygon(o.contour).buffer(0)
        inter = sil.intersection(contour).area
        assert np.isclose(one[v], inter / (sil.area + contour.area - inter))
    assert one.min() > 0.95  # the truth's silhouettes match its masks


def test_the_compiled_union_overlap_agrees_with_shapely():
    trial = paper_trial(3)
    obs, xi = ObservationSet(trial.observations), trial.gt.to_vector()
    rng = np.random.default_rng(0)
    X = []
    for _ in range(6):  # two parts about the truth: overlapping, nested or apart
        a, b = xi.copy(), xi.copy()
        a[0:3] *= rng.uniform(0.3, 1.0, 3)
        b[0:3] *= rng.uniform(0.3, 1.0, 3)
        a[5:8] += rng.normal(0.0, 0.5, 3)
        b[5:8] += rng.normal(0.0, 0.5, 3)
        b[8:11] += rng.normal(0.0, 0.5, 3)
        X.append([a, b])
    X = np.array(X)
    previous = set_kernels("numba")
    try:
        fast = two_parts.union_ious(X, obs)
        set_kernels("numpy")
        slow = two_parts.union_ious(X, obs)
    finally:
        set_kernels(previous)
    assert np.all(slow > 0) and np.all(slow < 1)
    assert np.allclose(fast, slow, atol=1e-9)


def test_the_part_kept_is_the_one_of_higher_3d_iou_with_the_union():
    a = sqfit.Superquadric((1.0, 0.2, 1.0), (0.5, 0.5), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))  # a slab
    b = sqfit.Superquadric((0.2, 1.0, 0.7), (0.5, 0.5), (0.9, 0.7, 0.1), (0.0, 0.0, 0.3))  # another, crossing it
    rng = np.random.default_rng(0)
    points = rng.uniform(-3.0, 3.0, (400000, 3))
    in_a, in_b = contains(a, points), contains(b, points)
    iou = [(in_q & (in_a | in_b)).sum() / (in_a | in_b).sum() for in_q in (in_a, in_b)]  # Monte Carlo
    X = np.stack([a.to_vector(), b.to_vector()])
    assert two_parts.pick_part(X) == int(np.argmax(iou)) and abs(iou[0] - iou[1]) > 0.05
    assert two_parts.pick_part(X[::-1]) == 1 - int(np.argmax(iou))


def test_the_union_overlap_kernel_on_known_squares():
    previous = set_kernels("numba")
    try:
        k = compiled("unions")
    finally:
        set_kernels(previous)
    square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    pair = np.stack([square, square + [0.5, 0.0]])  # overlapping by half: the union is 1.5 x 1
    apart = np.stack([square, square + [3.0, 0.0]])
    polys = np.ascontiguousarray(np.stack([pair, apart])[:, :, None])  # (2, 2, 1 view, 4, 2)
    # two views: the contour the first square (view 0), a 6 x 2 box around both pairs (view 1)
    contours = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0],
                         [-1.0, -0.5], [5.0, -0.5], [5.0, 1.5], [-1.0, 1.5]])
    starts = np.array([0, 4, 8])
    polys = np.ascontiguousarray(np.repeat(polys, 2, axis=2))
    pairs = np.array([[0, 0], [0, 1], [1, 0], [1, 1]])
    inter, area, ok = k.union_overlaps(polys, pairs, contours, starts, 1e-9)
    assert ok.all()
    assert np.allclose(area, [1.5, 1.5, 2.0, 2.0])
    assert np.allclose(inter, [1.0, 1.5, 1.0, 2.0])


def test_the_unions_gradient_follows_its_finite_differences():
    trial = paper_trial(3)
    obs, xi = ObservationSet(trial.observations), trial.gt.to_vector()
    rng = np.random.default_rng(2)
    for _ in range(3):  # two overlapping parts about the truth, as the fit meets them
        X = np.stack([xi, xi])
        X[:, 0:3] *= rng.uniform(0.5, 0.9, (2, 3))
        X[:, 5:8] += rng.normal(0.0, 0.3, (2, 3))
        X[1, 8:11] += rng.normal(0.0, 0.3, 3)
        iou, grad = two_parts.union_gradient(X, obs)
        assert np.allclose(iou, two_parts.union_ious(X[None], obs)[0])
        x, diff = X.ravel(), np.zeros_like(grad)
        for j in range(22):
            h = 1e-5 * max(abs(x[j]), 1.0)
            up, down = x.copy(), x.copy()
            up[j] += h
            down[j] -= h
            diff[:, j] = (two_parts.union_ious(up.reshape(1, 2, 11), obs)[0]
                          - two_parts.union_ious(down.reshape(1, 2, 11), obs)[0]) / (2 * h)
        # the midpoint sums and the polygon's vertex model: a few per cent, the same direction
        assert np.linalg.norm(grad - diff) < 0.15 * np.linalg.norm(diff)
        assert (grad * diff).sum() > 0.99 * np.linalg.norm(grad) * np.linalg.norm(diff)


def test_the_union_fit_lowers_its_objective_and_returns_what_it_found():
    """L-BFGS-B from two shrunken, displaced copies of a true superquadric: the parts it returns are the
    best point it evaluated, below the start, within its budget (its last line search may end past it),
    and their IoUs are the union's."""
    trial = paper_trial(3)
    obs, xi = ObservationSet(trial.observations), trial.gt.to_vector()
    start = np.stack([xi, xi])
    start[:, 0:3] *= [[0.6, 0.7, 0.8], [0.8, 0.6, 0.7]]
    start[0, 5:8] += 0.2
    reference = volume(trial.gt)

    def objective(X):
        volume_term = two_parts.MU * two_parts.volumes(X[None])[0] / reference
        return (1.0 - two_parts.union_ious(X[None], obs)[0]).sum() + volume_term

    for differences in (False, True):
        X, ious, value, nfev = two_parts.fit_union(start, obs, two_parts.MU, reference, differences=differences)
        assert X.shape == (2, 11) and 0 < nfev <= two_parts.EVALUATIONS + 20  # the last line search ends
        assert np.array_equal(ious, two_parts.union_ious(X[None], obs)[0])
        assert value == pytest.approx(objective(X)) and value < objective(start) - 0.1
        assert ious.mean() > 0.9


def test_the_union_fits_variables_are_scaled_by_the_starts_size():
    start = np.zeros((2, 11))
    start[0, 0:3], start[1, 0:3] = [0.2, -1.5, 0.3], [0.4, 0.5, 0.6]
    scale = two_parts.union_scale(start)
    assert scale.shape == (22,)
    assert np.array_equal(scale[0:11], [1.5, 1.5, 1.5, 0.5, 0.5, 1.5, 1.5, 1.5, 0.5, 0.5, 0.5])
    assert np.array_equal(scale[11:], scale[0:11])
    assert np.all(two_parts.union_scale(np.zeros((2, 11))) > 0)  # never a zero scale to divide by


def test_bad_arguments_are_refused_by_name(capsys):
    probe = _script()
    for argv, message in ((["--trials", "0"], "--trials must be >= 1, got 0"), (["--mu", "-1"], "--mu must be >= 0")):
        with pytest.raises(SystemExit):
            probe.main(argv)
        assert message in capsys.readouterr().err


def test_the_compiled_gradient_is_the_numpy_one():
    trial = paper_trial(3)
    obs, xi = ObservationSet(trial.observations), trial.gt.to_vector()
    rng = np.random.default_rng(5)
    previous = set_kernels("numba")
    try:
        for _ in range(3):
            X = np.stack([xi, xi])
            X[:, 0:3] *= rng.uniform(0.5, 0.9, (2, 3))
            X[:, 5:8] += rng.normal(0.0, 0.3, (2, 3))
            X[1, 8:11] += rng.normal(0.0, 0.3, 3)
            set_kernels("numba")
            fast = two_parts.union_gradient(X, obs)
            set_kernels("numpy")
            slow = two_parts.union_gradient(X, obs)
            assert np.abs(slow[1]).max() > 0
            assert np.allclose(fast[0], slow[0], atol=1e-9) and np.allclose(fast[1], slow[1], rtol=1e-9, atol=1e-9)
    finally:
        set_kernels(previous)


def test_the_volumes_are_the_parts_volumes_as_a_fit_reads_them():
    rng = np.random.default_rng(1)
    X = rng.uniform(-2.0, 2.0, (4, 2, 11))
    X[..., 3:5] = rng.uniform(-0.5, 2.5, (4, 2, 2))  # outside the shape domain too: clipped, as to_superquadric does
    expected = [sum(volume(to_superquadric(x)) for x in row) for row in X]
    assert np.allclose(two_parts.volumes(X), expected, rtol=1e-12)


def test_the_default_keeps_the_whole_chains_fit_on_a_true_superquadric():
    trial = paper_trial(1)
    whole = sqfit.fit(trial.observations, chain="whole")
    three_u = sqfit.fit(trial.observations)
    assert three_u.chain == "1-2M-3H-3R-3U" and whole.chain == "1-2M-3H-3R-3V-3W"
    assert np.array_equal(three_u.superquadric.to_vector(), whole.superquadric.to_vector())
    assert three_u.stages[-1].message.startswith("3U: its trigger does not hold (3G cost above 0.01, contour R-IOU-M "
                                                 "below 0.9); 3W: ")


def test_the_trigger_asks_for_a_cost_above_its_floor_and_contours_matched_below_3ts_score(monkeypatch):
    from sqfit.fitting import outline
    from sqfit.fitting.stages import FitState

    scores = []

    def contour_score(state, obs):
        scores.append(state.cost)
        return 0.5 if state.cost < 1.0 else 0.95

    monkeypatch.setattr(outline, "contour_score", contour_score)
    xi = np.r_[1.0, 1.0, 1.0, 1.0, 1.0, np.zeros(6)]
    state = lambda cost: FitState(xi, cost=cost)  # noqa: E731
    assert not two_parts.triggers(state(None), None) and not two_parts.triggers(state(two_parts.TRIGGER_COST), None)
    assert not scores  # not scored below the cost floor
    assert two_parts.triggers(state(0.015), None)  # below 3T's cost trigger (0.02): a laptop 3T missed
    assert not two_parts.triggers(state(2.0), None)  # the contours matched at 0.95
    assert scores == [0.015, 2.0]
    assert not outline.triggers(state(0.015), None)  # 3T's own floor stays 0.02


def test_on_a_laptop_that_3t_leaves_alone_the_stage_keeps_a_part_closer_to_the_laptop(household):
    """Laptop 15 of seed 0: one superquadric fills the wedge between base and lid at a 3G cost (0.017) below
    3T's trigger, its silhouettes matching the contours at 0.79 only; 3U fits two parts (the laptop at 0.11 ->
    0.66 when measured)."""
    from sqfit.metrics import iou_3d_mesh

    laptop, obs = household("laptop", 0, 15)
    whole, default = sqfit.fit(obs, chain="whole"), sqfit.fit(obs)
    assert ": kept the input" in whole.stages[-2].message  # 3V (3T) left the input alone
    assert ": kept part" in default.stages[-1].message, default.stages[-1].message
    assert iou_3d_mesh(default.superquadric, laptop.mesh) > iou_3d_mesh(whole.superquadric, laptop.mesh) + 0.3


def test_on_a_laptop_along_its_wedges_bisector_the_v_starts_find_the_base_or_the_lid(household):
    """Laptop 5 of seed 4: 3V's fit lies along the bisector of base and lid, so the slabs along its box's faces
    (:func:`l_starts`) fit unions across the wedge (matching the opened masks at 0.92, every part 0.37 or less inside
    the laptop) and 3U kept one at 0.096; from the V-shaped starts the union matches them at 0.98 and its part is
    the base or the lid (0.609 when measured)."""
    from sqfit.metrics import iou_3d_mesh

    laptop, obs = household("laptop", 4, 5)
    default = sqfit.fit(obs)
    message = default.stages[-1].message
    assert ": kept part" in message, message
    assert iou_3d_mesh(default.superquadric, laptop.mesh) > 0.5


def test_on_a_monitor_the_stage_keeps_a_part_for_a_gain_below_the_old_gate(household):
    """Monitor 15 of seed 0: the union gains 0.108 in mean silhouette IoU over 3V's fit, refused while
    :data:`GATE` was 0.12; the part kept, the screen, is the monitor's better fit (0.388 -> 0.758 when
    measured)."""
    from sqfit.metrics import iou_3d_mesh

    monitor, obs = household("monitor", 0, 15)
    whole, default = sqfit.fit(obs, chain="whole"), sqfit.fit(obs)
    message = default.stages[-1].message
    assert ": kept part" in message, message
    assert iou_3d_mesh(default.superquadric, monitor.mesh) > iou_3d_mesh(whole.superquadric, monitor.mesh) + 0.25


@pytest.fixture
def chair_trial(household):
    """Chair 1 of ``scenes/household.toml`` (seed 0): the object and its observations."""
    return household("chair", 0, 1)


def test_on_a_chair_the_stage_keeps_one_of_two_parts_closer_to_the_chair(chair_trial):
    from sqfit.metrics import iou_3d_mesh

    chair, obs = chair_trial
    three_v, three_u = sqfit.fit(obs, chain="1-2M-3H-3R-3V"), sqfit.fit(obs, chain="two-parts")
    message = three_u.stages[-1].message
    assert message.startswith("3U: two parts match the opened masks at") and ": kept part" in message, message
    # the default fills the wedge between seat and back; the part is the seat or the back
    before, after = iou_3d_mesh(three_v.superquadric, chair.mesh), iou_3d_mesh(three_u.superquadric, chair.mesh)
    assert before < 0.2 and after > before + 0.2
    assert volume(three_u.superquadric) < 0.5 * volume(three_v.superquadric)


def test_the_stage_does_not_fit_two_parts_where_a_view_is_cut(monkeypatch, chair_trial):
    chair, obs = chair_trial
    calls = []
    monkeypatch.setattr(two_parts, "fit_union", lambda *args, **kw: calls.append(1))
    cut = [replace(o, contour_labels=np.where(np.arange(len(o.contour_labels)) < 5, BORDER, o.contour_labels))
           if i == 0 else o for i, o in enumerate(obs)]
    result = sqfit.fit(cut, chain="two-parts")
    assert not calls and "cut by the image border or occluded: no two parts" in result.stages[-1].message


def test_the_gate_asks_the_union_to_match_the_masks_better_on_average_in_most_views_and_well():
    singles = np.array([0.70, 0.70, 0.70, 0.70])
    assert two_parts.passes_gate(singles, [0.90, 0.85, 0.86, 0.88])
    assert not two_parts.passes_gate(singles, [0.80, 0.80, 0.85, 0.85])  # better by 0.125, but the union at 0.825
    # well and better in the median view by 0.11, but on average by 0.0725 only
    assert not two_parts.passes_gate([0.8, 0.8, 0.8, 0.8], [0.92, 0.91, 0.91, 0.75])
    # one view carries it: 3V's fit at 0.06 in it (a table of seed 4), the union worse in the others
    assert not two_parts.passes_gate([0.83, 0.06, 0.97, 0.98], [0.73, 0.81, 0.93, 0.94])
    assert two_parts.passes_gate([0.83, 0.50, 0.70, 0.70], [0.93, 0.90, 0.82, 0.82])  # the median view: +0.12


@pytest.fixture
def chair_fits(chair_trial):
    """The chair's observations, its stage-3V fit and chain ``whole``'s (3W on it)."""
    _, obs = chair_trial
    return (obs, sqfit.fit(obs, chain="1-2M-3H-3R-3V").superquadric.to_vector(),
            sqfit.fit(obs, chain="whole").superquadric.to_vector())


def _stub_union(monkeypatch, union, gate=True, part=0):
    """3U with its union's fit, gate and part choice replaced: ``union`` the parts ``(2, 11)`` every union fit
    returns (matching the masks at 0.95), or a function in place of ``fit_union``; ``gate`` what
    ``passes_gate`` says; ``part`` the index ``pick_part`` gives."""
    if callable(union):
        fit_union = union
    else:
        def fit_union(start, obs, mu, reference, **kw):
            return union, np.full(len(obs), 0.95), 0.1, 1
    monkeypatch.setattr(two_parts, "fit_union", fit_union)
    monkeypatch.setattr(two_parts, "passes_gate", lambda singles, unions: gate)
    monkeypatch.setattr(two_parts, "pick_part", lambda X, hull=None: part)


@pytest.mark.parametrize("union, kept", [(True, "part"), (False, "whole")])
def test_the_stage_keeps_the_part_where_the_gate_passes(monkeypatch, union, kept, chair_fits):
    obs, three_v, whole = chair_fits
    assert not np.array_equal(whole, three_v)  # 3W moved it
    part = three_v.copy()
    part[0:3] = [0.05, 0.5, 0.6]  # a slab
    _stub_union(monkeypatch, np.stack([part, three_v]), gate=union)
    fit = sqfit.fit(obs, chain="two-parts")
    assert np.array_equal(fit.superquadric.to_vector(), part if kept == "part" else whole)


def test_the_stage_keeps_the_smaller_slab_where_the_visual_hull_says_so(monkeypatch, chair_fits):
    obs, three_v, _ = chair_fits
    larger, smaller = three_v.copy(), three_v.copy()
    larger[0:3], smaller[0:3] = [0.05, 0.5, 0.6], [0.04, 0.4, 0.5]
    _stub_union(monkeypatch, np.stack([larger, smaller]))
    hulls = []

    def pick(X, hull=None):
        hulls.append(hull)
        return 0 if hull is None else 1

    monkeypatch.setattr(two_parts, "pick_part", pick)
    fit = sqfit.fit(obs, chain="two-parts")
    assert np.array_equal(fit.superquadric.to_vector(), smaller)
    assert "kept part 1 of two (the smaller, more of it inside the visual hull)" in fit.stages[-1].message
    assert hulls[0] is None and hulls[1].occupied.any()  # the masks' visual hull


def test_the_stage_polishes_the_near_best_unions_without_the_volume_term_and_keeps_the_best_matching(monkeypatch,
                                                                                                      chair_fits):
    """The starts are fitted with the volume term; those ending within POLISH_WITHIN of the lowest objective
    are fitted again without it (from where they ended), and the part kept comes from the polished union whose
    silhouettes match the masks best."""
    obs, three_v, _ = chair_fits
    n = len(two_parts.starts(np.asarray(three_v)))
    ends = [np.stack([three_v, three_v]) for _ in range(n)]
    for i, X in enumerate(ends):
        X[0, 0:3] *= 0.5 + 0.01 * i  # each start ends somewhere else
    objectives = [0.5] * n
    objectives[3], objectives[7] = 0.1, 0.1 + 0.9 * two_parts.POLISH_WITHIN  # two near-best ends, start 3 lowest
    polished = {3: np.stack([three_v, three_v]), 7: np.stack([three_v, three_v])}
    polished[3][1, 0:3], polished[7][1, 0:3] = [0.5, 0.05, 0.4], [0.6, 0.06, 0.5]  # slabs
    matches = {3: 0.90, 7: 0.95}  # start 7's polished union matches the masks better
    calls = []

    def fit_union(start, obs, mu, reference, **kw):
        calls.append((np.array(start), mu))
        if mu == 0:
            i = next(i for i, X in enumerate(ends) if np.array_equal(start, X))
            return polished[i], np.full(len(obs), matches[i]), float(len(obs) * (1 - matches[i])), 1
        i = sum(m > 0 for _, m in calls) - 1
        return ends[i], np.full(len(obs), 0.95), objectives[i], 1

    _stub_union(monkeypatch, fit_union, part=1)
    fit = sqfit.fit(obs, chain="two-parts")
    assert [mu for _, mu in calls] == [two_parts.MU] * n + [0.0, 0.0]
    assert np.array_equal(calls[-2][0], ends[3]) and np.array_equal(calls[-1][0], ends[7])
    assert np.array_equal(fit.superquadric.to_vector(), polished[7][1])
    assert "polished without the volume term" in fit.stages[-1].message


def test_polish_keeps_the_start_of_the_lowest_objective_alone_within_zero_and_an_end_whose_polish_fails(monkeypatch):
    ends = [np.full((2, 11), float(i)) for i in range(3)]
    fits = [(ends[0], np.array([0.9, 0.9]), 0.3, 5), (ends[1], np.array([0.8, 0.8]), 0.2, 5),
            (ends[2], np.array([0.99, 0.99]), 0.21, 5)]

    def fit_union(start, obs, mu, reference, **kw):
        if start[0, 0] == 2.0:
            raise np.linalg.LinAlgError("singular")
        return start + 10.0, np.array([0.85, 0.85]), 0.3, 7

    monkeypatch.setattr(two_parts, "fit_union", fit_union)
    X, evaluations = two_parts.polish(fits, None, 1.0, within=0.0)
    assert np.array_equal(X, ends[1] + 10.0) and evaluations == 7
    # start 2's polish fails: it stays as it ended, scored by its own IoUs (0.99), and is kept
    X, evaluations = two_parts.polish(fits, None, 1.0, within=0.05)
    assert np.array_equal(X, ends[2]) and evaluations == 7


def _box_hull(lower, upper, voxel=0.05):
    """A VoxelHull occupied over the box [lower, upper] (world), in a grid around it."""
    from sqfit.views.carving import VoxelHull

    origin = np.array([-1.5, -1.5, -1.5])
    centres = origin + voxel * np.stack(np.meshgrid(*[np.arange(n) for n in (60, 60, 100)], indexing="ij"), axis=-1)
    occupied = np.all((centres >= lower) & (centres <= upper), axis=-1)
    return VoxelHull(occupied, origin, voxel)


def test_the_part_kept_is_the_larger_unless_the_other_slab_lies_more_inside_the_visual_hull():
    larger = np.r_[0.05, 1.0, 1.0, 0.2, 0.2, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]
    smaller = np.r_[0.04, 0.5, 0.5, 0.2, 0.2, 0.0, 0.0, 2.0, 0.0, 0.0, 0.0]
    X = np.stack([smaller, larger])
    everything = _box_hull([-9, -9, -9], [9, 9, 9])
    upper_half = _box_hull([-9, -9, 0.0], [9, 9, 9])  # half of the larger part, all of the smaller
    assert two_parts.hull_share(larger, everything) == 1.0 and two_parts.hull_share(smaller, upper_half) == 1.0
    assert abs(two_parts.hull_share(larger, upper_half) - 0.5) < 0.05
    assert two_parts.pick_part(X) == 1 and two_parts.pick_part(X, everything) == 1
    assert two_parts.pick_part(X, upper_half) == 0
    assert two_parts.pick_part(X[::-1], upper_half) == 1
    # within the margin: the larger
    corner = _box_hull([-9, -9, -9], [9, -0.78, -0.78])  # a corner of the larger part carved away
    nearly = replace(everything, occupied=everything.occupied & ~corner.occupied)
    assert 0 < 1.0 - two_parts.hull_share(larger, nearly) < two_parts.HULL_MARGIN
    assert two_parts.pick_part(X, nearly) == 1
    # the other part only if both are slabs
    bar = smaller.copy()
    bar[0:3] = [0.3, 0.3, 0.5]
    assert two_parts.pick_part(np.stack([bar, larger]), upper_half) == 1
    assert two_parts.hull_share(np.r_[0.05, 1.0, 1.0, 0.2, 0.2, 5.0, 5.0, 5.0, 0.0, 0.0, 0.0], everything) == 0.0


def test_the_choice_script_refuses_no_trials():
    choice = script_module(SCRIPTS / "two_part_choice.py")
    with pytest.raises(SystemExit):
        choice.main(["--trials", "0"])


def test_a_part_is_a_slab_between_a_sheet_and_a_bar():
    slab = np.r_[0.05, 0.5, 0.6, 0.2, 0.2, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]
    assert two_parts.is_slab(slab) and two_parts.is_slab(slab * np.r_[-1, 1, 1, [1] * 8])  # the signs do not matter
    low, high = two_parts.SLAB
    for ratio, slab_or_not in ((low, True), (high, True), (low * 0.9, False), (high * 1.1, False)):
        xi = slab.copy()
        xi[0:3] = [0.6, ratio * 0.5, 0.5]  # in any order
        assert two_parts.is_slab(xi) == slab_or_not
    bottle_body = slab.copy()
    bottle_body[0:3] = [0.3, 0.31, 1.2]  # round: not two slabs' part
    assert not two_parts.is_slab(bottle_body)


@pytest.mark.parametrize("thinnest", [1e-3, 0.3])
def test_the_stage_keeps_no_part_that_is_not_a_slab(monkeypatch, chair_fits, thinnest):
    """A part collapsed to a sheet (the union fit's bound) or as thick as it is wide: 3W on 3V's fit, as ``whole``."""
    obs, three_v, whole = chair_fits
    part = three_v.copy()
    part[0:3] = [thinnest, 0.5, 0.6]
    _stub_union(monkeypatch, np.stack([part, three_v]))
    fit = sqfit.fit(obs)
    assert np.array_equal(fit.superquadric.to_vector(), whole)
    assert "would not be a slab" in fit.stages[-1].message



def test_the_near_best_fits_are_those_within_the_margin_of_the_lowest_objective():
    fits = [(None, None, objective, 1) for objective in (0.30, 0.20, 0.26, 0.21, 0.25)]
    assert two_parts.near_best(fits, within=0.05) == [1, 3, 4]
    assert two_parts.near_best(fits, within=0.0) == [1]
    assert two_parts.near_best(fits) == two_parts.near_best(fits, within=two_parts.POLISH_WITHIN)
