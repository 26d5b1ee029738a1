"""f2depth.poses: corner tracks, bundle adjustment, incremental structure from motion, the prior files."""

from __future__ import annotations

import json

import numpy as np
import pytest
from pose_scenes import HW, sequence

from f2depth.poses.bundle import bundle_adjust, so3_exp
from f2depth.poses.estimate import PairPrior, PosesConfig, ScenePoses, pair_prior
from f2depth.poses.metrics import direction_error_deg, rotation_error_deg
from f2depth.poses.reconstruct import ReconstructConfig, Reconstruction, reconstruct, triangulate_two_view
from f2depth.poses.store import PosePriors, write_poses
from f2depth.poses.tracks import TrackerConfig, Tracks, track_corners

TRACKER = TrackerConfig(margin=8)


def _umeyama(src: np.ndarray, dst: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Similarity (s, R, t) with dst ≈ s·R·src + t (least squares)."""
    mu_s, mu_d = src.mean(0), dst.mean(0)
    U, S, Vt = np.linalg.svd((dst - mu_d).T @ (src - mu_s) / len(src))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    R = U @ D @ Vt
    s = float(np.trace(np.diag(S) @ D) / ((src - mu_s) ** 2).sum(1).mean())
    return s, R, mu_d - s * R @ mu_s


@pytest.fixture(scope="module")
def room():
    frames, poses, K = sequence(21)
    tracks = track_corners(frames, np.ones(HW, bool), TRACKER)
    return frames, poses, K, reconstruct(tracks, K, ReconstructConfig())


def test_known_poses_of_a_rendered_room_are_recovered(room):
    """Every frame registered; relative rotations within 0.1°; after one similarity, camera centres within
    1.5 % of the 22 cm path (3.4 mm; measured 0.8 mm median, 1.9 mm max) and translation directions of
    10-frame pairs within 1°."""
    _, poses, _, rec = room
    assert rec.registered.all()
    est = np.linalg.inv(rec.cam_T_world)
    path = np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1).sum()
    s, R, t = _umeyama(est[:, :3, 3], poses[:, :3, 3])
    aligned = s * est[:, :3, 3] @ R.T + t
    assert np.linalg.norm(aligned - poses[:, :3, 3], axis=1).max() < 0.015 * path
    for a, b in ((10, 0), (10, 20), (0, 20), (5, 15)):
        T_est = rec.cam_T_world[b] @ est[a]
        T_true = np.linalg.inv(poses[b]) @ poses[a]
        assert rotation_error_deg(T_est[:3, :3], T_true[:3, :3]) < 0.1
        assert direction_error_deg(T_est[:3, 3], T_true[:3, 3]) < 1.0


def test_scale_is_one_per_scene_and_normalised_to_the_median_depth(room):
    _, poses, _, rec = room
    norm = rec.normalised(2.0, HW)
    assert norm.image_median_depth(HW) == pytest.approx(2.0, rel=1e-9)
    ratios = []
    for a, b in ((0, 10), (10, 20), (5, 15), (3, 13)):
        t_est = (norm.cam_T_world[b] @ np.linalg.inv(norm.cam_T_world[a]))[:3, 3]
        t_true = (np.linalg.inv(poses[b]) @ poses[a])[:3, 3]
        ratios.append(np.linalg.norm(t_est) / np.linalg.norm(t_true))
    assert np.ptp(ratios) / np.median(ratios) < 0.02  # one scale for every pair of the scene


def test_a_textureless_room_is_not_registered():
    frames, _, K = sequence(11, textureless=True)
    tracks = track_corners(frames, np.ones(HW, bool), TRACKER)
    rec = reconstruct(tracks, K, ReconstructConfig())
    assert tracks.n_tracks == 0 and not rec.registered.any() and np.isnan(rec.cam_T_world).all()
    scene = ScenePoses("blank", [f"blank/{k}" for k in range(11)], np.linalg.inv(rec.cam_T_world),
                       rec.registered, rec.shared_points(), 0, 0, 0.0)
    prior = pair_prior(scene, 5, 4, PosesConfig())
    assert not prior.reliable and prior.shared_points == 0 and np.isnan(prior.src_T_tgt).all()


def test_bundle_adjustment_converges_to_the_truth_from_a_perturbed_start():
    rng = np.random.default_rng(1)
    K = np.array([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]])
    X = rng.uniform([-2, -1.5, 2], [2, 1.5, 5], (200, 3))
    R = np.stack([so3_exp(rng.normal(0, 0.03, 3)) for _ in range(8)])
    R[0] = np.eye(3)
    centres = np.cumsum(rng.normal(0, 0.05, (8, 3)), axis=0)
    centres[0] = 0
    t = -np.einsum("cij,cj->ci", R, centres)
    cam, point = (a.ravel() for a in np.meshgrid(np.arange(8), np.arange(200), indexing="ij"))
    Xc = np.einsum("mij,mj->mi", R[cam], X[point]) + t[cam]
    uv = Xc[:, :2] / Xc[:, 2:] * 500.0 + [320, 240]
    R0 = np.stack([so3_exp(rng.normal(0, 0.01, 3)) @ r for r in R])
    R0[0] = R[0]
    t0 = t + rng.normal(0, 0.01, t.shape)
    t0[0] = t[0]
    res = bundle_adjust(K, R0, t0, X + rng.normal(0, 0.05, X.shape), cam, point, uv)
    assert np.abs(res.residuals).max() < 1e-4
    centres_est = -np.einsum("cji,cj->ci", res.R, res.t)
    s = np.linalg.norm(centres_est[-1]) / np.linalg.norm(centres[-1])  # the scale is free
    assert np.abs(centres_est / s - centres).max() < 1e-5


def test_two_view_triangulation_is_exact_without_noise():
    K = np.array([[400.0, 0, 100], [0, 400.0, 80], [0, 0, 1]])
    X = np.array([[0.3, -0.2, 3.0], [-1.0, 0.5, 5.0]])
    T2 = np.eye(4)
    T2[:3, :3], T2[:3, 3] = so3_exp(np.array([0.01, 0.05, 0.0])), [-0.2, 0.0, 0.05]
    P1, P2 = K @ np.eye(4)[:3], K @ T2[:3]
    x1 = (X @ P1[:, :3].T + P1[:, 3])
    x2 = (X @ P2[:, :3].T + P2[:, 3])
    got = triangulate_two_view(np.stack([P1] * 2), np.stack([P2] * 2), x1[:, :2] / x1[:, 2:],
                               x2[:, :2] / x2[:, 2:])
    assert np.allclose(got, X, atol=1e-9)


def test_tracks_follow_a_shifted_image_to_a_tenth_of_a_pixel():
    frames, _, _ = sequence(2)
    shifted = [frames[0], np.roll(frames[0], (2, 3), axis=(0, 1))]
    tr = track_corners(shifted, np.ones(HW, bool), TRACKER)
    first, second = tr.uv[tr.frame == 0], tr.uv[tr.frame == 1]
    both = np.intersect1d(tr.track[tr.frame == 0], tr.track[tr.frame == 1])
    assert len(both) > 50
    d = (second[np.searchsorted(tr.track[tr.frame == 1], both)]
         - first[np.searchsorted(tr.track[tr.frame == 0], both)])
    assert np.median(np.abs(d - [3, 2]), axis=0).max() < 0.1


def test_prior_files_round_trip_and_unreliable_pairs_read_as_identity(tmp_path):
    T = np.eye(4)
    T[:3, 3] = [0.1, 0.0, 0.02]
    scene = ScenePoses("s", ["s/a.ppm", "s/b.ppm"], np.stack([np.eye(4), T]), np.array([True, True]),
                       np.array([[5, 40], [40, 5]]), 40, 60, 1.0)
    priors = {"t1": (PairPrior(np.linalg.inv(T), True, 40), PairPrior(np.full((4, 4), np.nan), False, 0))}
    write_poses(tmp_path / "poses", {"s": scene}, priors, {"t1": "s"}, PosesConfig())
    data = json.loads((tmp_path / "poses" / "priors.json").read_text())
    assert data["tuples"]["t1"]["next"]["src_T_tgt"] is None
    read = PosePriors(tmp_path / "poses")["t1"]
    assert read.prev_ok and not read.next_ok
    assert np.allclose(read.T_prev, np.linalg.inv(T), atol=1e-6) and np.array_equal(read.T_next, np.eye(4))
    lines = (tmp_path / "poses" / "cameras" / "s.csv").read_text().splitlines()
    assert lines[0].startswith("raw_file,registered,r00") and lines[2].split(",")[5] == "0.1"
    with pytest.raises(Exception, match="no prior for 1 training tuple"):
        PosePriors(tmp_path / "poses").check_covers(["t1", "t2"])


def test_tracks_are_sorted_by_track_then_frame(room):
    frames, _, _, _ = room
    tr: Tracks = track_corners(frames[:6], np.ones(HW, bool), TRACKER)
    key = tr.track * 1000 + tr.frame
    assert np.all(np.diff(key) > 0)


def test_image_median_depth_weights_each_point_by_the_image_area_nearest_to_it():
    """Nine points crowd a corner at 1 m, one point alone covers the rest of the image at 4 m: the plain
    median is 1 m, the median over the image area 4 m (what a depth map of that image would give)."""
    uv = np.array([[5.0 + 3 * i, 5.0 + 3 * j] for i in range(3) for j in range(3)] + [[200.0, 150.0]])
    n = len(uv)
    tracks = Tracks(np.arange(n), np.zeros(n, np.int64), uv, 1)
    K_inv = np.linalg.inv(np.array([[100.0, 0, 160], [0, 100.0, 120], [0, 0, 1]]))
    depth = np.r_[np.ones(9), 4.0]
    points = (np.c_[uv, np.ones(n)] @ K_inv.T) * depth[:, None]
    rec = Reconstruction(np.eye(4)[None], np.array([True]), points, np.ones(n, bool), tracks)
    assert np.median(rec.observation_depths()) == pytest.approx(1.0)
    assert rec.image_median_depth((240, 320)) == pytest.approx(4.0)
    assert rec.normalised(2.0, (240, 320)).image_median_depth((240, 320)) == pytest.approx(2.0)


def test_only_pairs_of_a_sound_scene_are_reliable():
    T = np.eye(4)
    T[:3, 3] = [0.1, 0.0, 0.0]
    scene = ScenePoses("s", [f"s/{k}" for k in range(10)], np.stack([np.eye(4)] * 9 + [T]),
                       np.r_[np.ones(8, bool), False, True], np.full((10, 10), 12), 150, 200, 1.0)
    config = PosesConfig(min_registered_share=0.9, min_scene_points=100, min_shared_points=10)
    assert scene.sound(0.9, 100) and pair_prior(scene, 0, 9, config).reliable
    assert not pair_prior(scene, 0, 8, config).reliable  # frame 8 is not registered
    assert not pair_prior(scene, 0, 9, PosesConfig(min_shared_points=13)).reliable
    assert not pair_prior(scene, 0, 9, PosesConfig(min_registered_share=0.95)).reliable
