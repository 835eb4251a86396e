import numpy as np
import pytest

from sensor_envs.geometry import (
    angular_interval,
    as_segments,
    closest_corner,
    from_frame,
    occluded_fraction,
    point_segment_distance,
    raycast,
    raycast_pose,
    rectangle_corners,
    rectangle_segments,
    sample_free_poses,
    to_frame,
)

WALL = as_segments([[[2.0, -1.0], [2.0, 1.0]]])  # vertical wall at x = 2


def test_perpendicular_wall():
    r, inc, idx = raycast_pose([0.0, 0.0, 0.0], [0.0], WALL)
    assert r[0] == pytest.approx(2.0) and inc[0] == pytest.approx(0.0) and idx[0] == 0


def test_oblique_ray_range_and_incidence():
    a = np.deg2rad(20.0)
    r, inc, _ = raycast_pose([0.0, 0.0, 0.0], [a], WALL)
    assert r[0] == pytest.approx(2.0 / np.cos(a))
    assert inc[0] == pytest.approx(a)


def test_pose_heading_rotates_bearings():
    r, _, _ = raycast_pose([0.0, 0.0, np.pi / 2], [-np.pi / 2], WALL)
    assert r[0] == pytest.approx(2.0)


def test_corner_hit_and_nearest_of_two():
    segs = as_segments([[[1, 0], [1, 1]], [[1, 1], [0, 1]]])  # corner at (1, 1)
    r, _, idx = raycast_pose([0.0, 0.0, 0.0], [np.pi / 4], segs)
    assert r[0] == pytest.approx(np.sqrt(2.0))
    assert idx[0] in (0, 1)
    segs2 = as_segments([[[3, -1], [3, 1]], [[1.5, -1], [1.5, 1]]])
    r2, _, idx2 = raycast_pose([0.0, 0.0, 0.0], [0.0], segs2)
    assert r2[0] == pytest.approx(1.5) and idx2[0] == 1


def test_parallel_ray_misses_and_collinear_ray_hits_near_end():
    seg = as_segments([[[1.0, 0.5], [3.0, 0.5]]])
    r, inc, idx = raycast_pose([0.0, 0.0, 0.0], [0.0], seg)
    assert np.isinf(r[0]) and np.isnan(inc[0]) and idx[0] == -1
    col = as_segments([[[1.0, 0.0], [3.0, 0.0]]])
    r, inc, _ = raycast_pose([0.0, 0.0, 0.0], [0.0], col)
    assert r[0] == pytest.approx(1.0) and inc[0] == pytest.approx(np.pi / 2)


def test_ray_from_a_segment_end_ignores_that_segment():
    # The origin sits on the end (and inside the line) of a wall: rays leaving it do not hit it at 0.
    segs = as_segments([[[0.0, 0.0], [0.0, 2.0]], [[2.0, -1.0], [2.0, 1.0]]])
    r, _, idx = raycast_pose([0.0, 0.0, 0.0], [0.0, np.pi / 2, np.pi], segs)
    assert r[0] == pytest.approx(2.0) and idx[0] == 1
    assert np.isinf(r[1])  # along the wall it starts on: that wall is not seen
    assert np.isinf(r[2])
    # Inside a segment, looking across it: not seen either; looking along: neither.
    r, _, _ = raycast_pose([0.0, 1.0, 0.0], [0.0, np.pi, np.pi / 2], segs)
    assert r[0] == pytest.approx(2.0) and np.isinf(r[1]) and np.isinf(r[2])


def test_max_range_and_batch_shapes():
    poses = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    r, inc, idx = raycast_pose(poses, np.array([0.0, np.pi]), WALL, max_range=1.5)
    assert r.shape == (2, 2)
    assert np.isinf(r[0, 0]) and r[1, 0] == pytest.approx(1.0) and np.isinf(r[:, 1]).all()


def test_raycast_matches_brute_force_reference():
    rng = np.random.default_rng(0)
    segs = as_segments(rng.uniform(-3, 3, size=(40, 2, 2)))
    angles = rng.uniform(-np.pi, np.pi, size=50)
    r, _, _ = raycast(np.zeros((1, 2)), angles[None, :], segs)
    for k, a in enumerate(angles):
        best = np.inf
        d = np.array([np.cos(a), np.sin(a)])
        for p, q in segs:
            m = np.column_stack([d, p - q])
            if abs(np.linalg.det(m)) < 1e-12:
                continue
            t, u = np.linalg.solve(m, p)
            if t > 1e-9 and 0 <= u <= 1:
                best = min(best, t)
        assert r[0, k] == pytest.approx(best)


@pytest.mark.parametrize(
    "bad, msg",
    [
        (np.zeros((0, 2, 2)), "no segments"),
        ([[[0, 0], [np.nan, 1]]], "NaN"),
        ([[[1, 1], [1, 1]]], "zero length"),
        (np.zeros((3, 3)), "expected shape"),
    ],
)
def test_bad_segments_raise_clear_errors(bad, msg):
    with pytest.raises(ValueError, match=msg):
        as_segments(bad, name="my_map")


def test_point_segment_distance_and_frames():
    d = point_segment_distance([[0.0, 0.0], [3.0, 2.0]], WALL)
    assert d[:, 0] == pytest.approx([2.0, np.hypot(1.0, 1.0)])
    pose = np.array([1.0, 2.0, 0.7])
    pts = np.array([[3.0, -1.0], [0.5, 0.2]])
    assert from_frame(to_frame(pts, pose), pose) == pytest.approx(pts)
    assert to_frame([[2.0, 2.0]], [1.0, 2.0, np.pi / 2])[0] == pytest.approx([0.0, -1.0])


def test_closest_corner_and_occlusion():
    boxes = rectangle_corners([10.0, 20.0, 10.0], [0.0, 0.0, 8.0], [0.0, 0.0, 0.0], [4.0, 4.0, 4.0], [2.0, 2.0, 2.0])
    corner, idx = closest_corner(boxes)
    assert corner[0] == pytest.approx([8.0, 1.0]) or corner[0] == pytest.approx([8.0, -1.0])
    assert corner[2] == pytest.approx([8.0, 7.0])
    occ = occluded_fraction(boxes)
    assert occ[0] == 0.0  # nearest box is free
    assert occ[1] == pytest.approx(1.0)  # directly behind the first, same size, farther: fully hidden
    assert occ[2] == 0.0  # off to the side


# ---------------------------------------------------------------------- occlusion vs its reference


def _occluded_fraction_reference(corners, origin=(0.0, 0.0), n_rays=16):
    """The original implementation (full :func:`raycast`, incidence and collinear handling): the reference."""
    n = corners.shape[0]
    if n < 2:
        return np.zeros(n)
    o = np.asarray(origin, dtype=np.float64)
    lo, hi = angular_interval(corners, o)
    f = (np.arange(n_rays) + 0.5) / n_rays
    ang = lo[:, None] + (hi - lo)[:, None] * f[None, :]
    segs = rectangle_segments(corners)
    owner = np.repeat(np.arange(n), 4)
    rng, _, idx = raycast(np.broadcast_to(o, (n, 2)), ang, segs)
    own = np.isfinite(rng) & (owner[np.maximum(idx, 0)] == np.arange(n)[:, None])
    hit_other = np.isfinite(rng) & ~own
    return hit_other.mean(axis=1)


def _random_scene(rng, n):
    """``n`` rectangles scattered around the origin: traffic-like (aligned lanes) or arbitrary headings, may overlap."""
    if rng.random() < 0.5:
        x, y = rng.uniform(-60.0, 80.0, n), rng.choice([-8.0, -4.0, 0.0, 4.0, 8.0], n) + rng.normal(0, 0.3, n)
        heading = rng.normal(0.0, 0.05, n)
    else:
        r, a = rng.uniform(2.0, 40.0, n), rng.uniform(-np.pi, np.pi, n)
        x, y, heading = r * np.cos(a), r * np.sin(a), rng.uniform(-np.pi, np.pi, n)
    return rectangle_corners(x, y, heading, rng.uniform(1.0, 12.0, n), rng.uniform(0.5, 3.0, n))


@pytest.mark.parametrize("seed", range(4))
def test_occluded_fraction_equals_the_raycast_reference(seed):
    rng = np.random.default_rng(seed)
    for _ in range(100):
        boxes = _random_scene(rng, int(rng.integers(0, 14)))
        origin = rng.normal(0.0, 1.0, 2)
        n_rays = int(rng.choice([1, 5, 16]))
        expected = _occluded_fraction_reference(boxes, origin, n_rays)
        assert np.array_equal(occluded_fraction(boxes, origin, n_rays), expected)
        targets = np.flatnonzero(rng.random(len(boxes)) < 0.5)
        assert np.array_equal(occluded_fraction(boxes, origin, n_rays, targets=targets), expected[targets])


def test_occluded_fraction_with_rays_along_edges_matches_the_reference():
    # Box 0 is symmetric about the x axis, so its single ray runs along the x axis: exactly along the
    # lower edge of box 1 (y = 0, collinear) and parallel to box 2's edges (the raycast fallback).
    boxes = rectangle_corners([10.0, 5.0, 7.0], [0.0, 1.0, 3.0], [0.0, 0.0, 0.0], [4.0, 2.0, 2.0], [2.0, 2.0, 2.0])
    for n_rays in (1, 2, 16):
        expected = _occluded_fraction_reference(boxes, (0.0, 0.0), n_rays)
        assert np.array_equal(occluded_fraction(boxes, (0.0, 0.0), n_rays), expected)
    assert occluded_fraction(boxes, (0.0, 0.0), 1)[0] == 1.0  # the collinear edge's near end hides it


def test_occluded_fraction_edge_cases():
    one = rectangle_corners([5.0], [0.0], [0.0], [4.0], [2.0])
    assert occluded_fraction(one).shape == (1,) and occluded_fraction(one)[0] == 0.0
    assert occluded_fraction(np.zeros((0, 4, 2))).shape == (0,)
    two = rectangle_corners([5.0, 15.0], [0.0, 0.0], [0.0, 0.0], [4.0, 4.0], [2.0, 2.0])
    assert occluded_fraction(two, targets=[]).shape == (0,)
    assert occluded_fraction(two, targets=[1]).tolist() == [1.0]
    assert occluded_fraction(two, targets=[-1, 0]).tolist() == [1.0, 0.0]
    with pytest.raises(IndexError):
        occluded_fraction(two, targets=[2])


def test_compiled_raycast_gives_the_numpy_numbers(monkeypatch, compiled_kernels):
    """The numba kernel (``fast`` extra) and the numpy path: same ranges, incidence and indices, bit for bit."""
    from sensor_envs import geometry

    assert geometry._compiled_kernel() is not None
    rng = np.random.default_rng(3)
    for trial in range(12):
        if trial % 3 == 0:  # integer grid: rays along the axes and diagonals meet ends and collinear segments
            ends = rng.integers(-3, 4, size=(30, 2, 2)).astype(float)
            segs = as_segments(ends[np.abs(ends[:, 1] - ends[:, 0]).sum(axis=1) > 0])
            o = rng.integers(-3, 4, size=(6, 2)).astype(float)
            ang = np.tile(np.arange(8) * np.pi / 4, (6, 1))
        else:
            segs = as_segments(rng.uniform(-3, 3, size=(int(rng.integers(1, 30)), 2, 2)))
            o, ang = rng.uniform(-3, 3, size=(6, 2)), rng.uniform(-np.pi, np.pi, size=(6, 40))
        for max_range in (np.inf, 2.0):
            fast = raycast(o, ang, segs, max_range)
            ref = geometry._raycast_numpy(o, np.cos(ang), np.sin(ang), segs, max_range)
            assert all(np.array_equal(x, y, equal_nan=True) for x, y in zip(fast, ref, strict=True))
            pose = np.column_stack([o, ang[:, 0]])  # raycast_pose: the bearings rotated by the heading
            fast_pose = geometry.raycast_pose(pose, ang[0] - ang[0, 0], segs, max_range)
            with monkeypatch.context() as m:
                m.setattr(geometry, "_compiled_kernel", lambda: None)
                ref_pose = geometry.raycast_pose(pose, ang[0] - ang[0, 0], segs, max_range)
            assert all(np.array_equal(x, y, equal_nan=True) for x, y in zip(fast_pose, ref_pose, strict=True))
            for x, y in zip(fast, ref, strict=True):
                assert x.dtype == y.dtype and np.array_equal(x, y, equal_nan=True)


def test_compiled_nearest_wall_distance_gives_the_numpy_numbers(monkeypatch, compiled_kernels):
    """The compiled nearest-wall loop and ``point_segment_distance(...).min(axis=1)``: the same bits."""
    from sensor_envs import geometry

    rng = np.random.default_rng(4)
    segs = as_segments(rng.uniform(-3, 3, size=(9, 2, 2)))
    pts = np.vstack([rng.uniform(-4, 4, size=(50, 2)), segs[:, 0], segs[:, 1]])  # ends: distance 0
    fast = geometry.nearest_wall_distance(pts, segs)
    poses = geometry.nearest_wall_distance(np.column_stack([pts, rng.uniform(-3, 3, len(pts))]), segs)
    with monkeypatch.context() as m:
        m.setattr(geometry, "compiled", lambda loops: None)
        ref = geometry.nearest_wall_distance(pts, segs)
    assert np.array_equal(fast, ref) and np.array_equal(poses, ref)
    assert np.array_equal(ref, geometry.point_segment_distance(pts, segs).min(axis=1)) and (ref == 0).sum() >= 9


def test_sample_free_poses_draws_uniform_candidates_and_keeps_the_free_enclosed_ones():
    """Candidates are ``rng.uniform(lo, hi, (4 n, 2))``'s numbers; kept: clear of walls, far from ``away_from``,
    enclosed; the headings are drawn after. Checked against that rule written plainly."""
    room = as_segments([[[0, 0], [4, 0]], [[4, 0], [4, 3]], [[4, 3], [0, 3]], [[0, 3], [0, 0]], [[1, 1], [2, 1]]])
    room = np.concatenate([room, as_segments([[[6, 0], [7, 0]]])])  # a wall outside the room: unenclosed space
    for seed in range(5):
        got = sample_free_poses(room, 3, np.random.default_rng(seed), 0.3, away_from=(1.0, 2.0), min_distance=1.0)
        rng = np.random.default_rng(seed)
        lo, hi = room.reshape(-1, 2).min(0), room.reshape(-1, 2).max(0)
        kept: list = []
        while len(kept) < 3:
            xy = rng.uniform(lo, hi, (12, 2))
            ok = point_segment_distance(xy, room).min(axis=1) >= 0.3
            ok &= np.hypot(*(xy - [1.0, 2.0]).T) >= 1.0
            ok &= np.isfinite(raycast(xy, np.arange(4) * (np.pi / 2), room)[0]).all(axis=1)
            kept.extend(xy[ok])
        want = np.column_stack([np.asarray(kept[:3]), rng.uniform(-np.pi, np.pi, 3)])
        assert np.array_equal(got, want)
        assert (got[:, 0] < 4).all()  # never in the open space beside the room
