"""Trajectory metrics: Umeyama/Horn alignment, both ATE variants (vs evo and SplaTAM's code), RPE, association."""

from __future__ import annotations

import copy
import dataclasses
import json

import evo.core.metrics as evo_metrics  # evo is a pinned test dependency (pyproject [test])
import numpy as np
import pytest
from evo.core import sync
from evo.core.trajectory import PoseTrajectory3D

from gsjax.camera import invert_transform, quaternion_to_rotation_np, rotation_angle_np, se3_inverse_np
from gsjax.eval.association import associate_timestamps
from gsjax.eval.trajectory import (
    Alignment,
    ate_rmse_c2w,
    ate_splatam_mean_w2c,
    drift,
    evaluate_trajectory,
    ground_truth_on_estimate,
    rpe,
    umeyama_alignment,
)


def random_rotation(rng, n=None):
    q = rng.standard_normal((4,) if n is None else (n, 4))
    return quaternion_to_rotation_np(q / np.linalg.norm(q, axis=-1, keepdims=True))


def axis_rotation(axis, angle):
    k = np.asarray(axis, float) / np.linalg.norm(axis)
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * kx + (1 - np.cos(angle)) * kx @ kx


def pose(rotation=np.eye(3), translation=(0.0, 0.0, 0.0)):
    out = np.eye(4)
    out[:3, :3] = rotation
    out[:3, 3] = translation
    return out


def smooth_trajectory(rng, n=120):
    """A hand-held-like c2w trajectory: a wobbly loop with slowly turning orientation."""
    s = np.linspace(0, 2 * np.pi, n)
    centres = np.stack([1.5 * np.cos(s), 0.3 * np.sin(3 * s), 1.0 * np.sin(s)], 1) + 0.01 * rng.standard_normal((n, 3))
    poses = np.stack(
        [pose(axis_rotation([0.1, 1.0, 0.2], si) @ axis_rotation([1, 0, 0], 0.2 * np.sin(2 * si)), c)
         for si, c in zip(s, centres)]
    )
    return poses


def perturb(rng, c2w, trans_sigma=0.02, rot_sigma=0.02):
    out = c2w.copy()
    for i in range(len(out)):
        out[i, :3, :3] = axis_rotation(rng.standard_normal(3), rot_sigma * rng.standard_normal()) @ out[i, :3, :3]
        out[i, :3, 3] += trans_sigma * rng.standard_normal(3)
    return out


def evo_traj(c2w, stamps=None):
    stamps = np.arange(len(c2w), dtype=float) if stamps is None else stamps
    return PoseTrajectory3D(poses_se3=list(c2w), timestamps=np.asarray(stamps, float))


def evo_ape_rmse(est_c2w, gt_c2w, correct_scale):
    traj_est, traj_ref = evo_traj(est_c2w), evo_traj(gt_c2w)
    traj_est.align(traj_ref, correct_scale=correct_scale)
    ape = evo_metrics.APE(evo_metrics.PoseRelation.translation_part)
    ape.process_data((traj_ref, traj_est))
    return ape.get_statistic(evo_metrics.StatisticsType.rmse)


# --------------------------------------------------------------------------------------------- alignment


@pytest.mark.parametrize("with_scale, scale", [(False, 1.0), (True, 2.7)])
def test_umeyama_recovers_a_known_transform(with_scale, scale):
    rng = np.random.default_rng(0)
    source = rng.standard_normal((50, 3))
    truth = Alignment(random_rotation(rng), rng.standard_normal(3), scale)
    found = umeyama_alignment(source, truth.apply_points(source), with_scale=with_scale)
    np.testing.assert_allclose(found.rotation, truth.rotation, atol=1e-12)
    np.testing.assert_allclose(found.translation, truth.translation, atol=1e-12)
    assert found.scale == pytest.approx(scale, abs=1e-12)


def test_umeyama_returns_a_proper_rotation_for_mirrored_points():
    rng = np.random.default_rng(1)
    source = rng.standard_normal((30, 3))
    target = source * np.array([1.0, 1.0, -1.0])  # a reflection fits exactly; a rotation must not be one
    found = umeyama_alignment(source, target)
    assert np.linalg.det(found.rotation) == pytest.approx(1.0, abs=1e-12)


def test_ate_rmse_c2w_is_zero_after_rigid_change_of_world_and_recovers_it():
    rng = np.random.default_rng(2)
    gt = smooth_trajectory(rng)
    world = Alignment(random_rotation(rng), rng.standard_normal(3))
    est = world.apply_c2w(gt)
    result = ate_rmse_c2w(est, gt)
    assert result.value_m < 1e-12
    # the alignment maps est onto gt, i.e. it is the inverse of `world`
    np.testing.assert_allclose(result.alignment.rotation, world.rotation.T, atol=1e-12)
    np.testing.assert_allclose(result.alignment.translation, -world.rotation.T @ world.translation, atol=1e-12)


def test_ate_rmse_c2w_with_scale_is_zero_after_similarity_and_recovers_the_scale():
    rng = np.random.default_rng(3)
    gt = smooth_trajectory(rng)
    est = Alignment(random_rotation(rng), rng.standard_normal(3), 0.4).apply_c2w(gt)
    assert ate_rmse_c2w(est, gt, with_scale=True).value_m < 1e-12
    assert ate_rmse_c2w(est, gt, with_scale=True).alignment.scale == pytest.approx(2.5, rel=1e-12)
    assert ate_rmse_c2w(est, gt, with_scale=False).value_m > 0.1  # rigid alignment cannot undo the scale


@pytest.mark.parametrize("with_scale", [False, True])
def test_ate_rmse_c2w_agrees_with_evo_ape(with_scale):
    rng = np.random.default_rng(4)
    gt = smooth_trajectory(rng)
    est = perturb(rng, Alignment(random_rotation(rng), rng.standard_normal(3), 0.8).apply_c2w(gt))
    ours = ate_rmse_c2w(est, gt, with_scale=with_scale).value_m
    assert ours > 0.01  # the fixture is noisy
    assert abs(ours - evo_ape_rmse(est, gt, with_scale)) < 1e-9


# ------------------------------------------------------------------------------------------ SplaTAM ATE


def splatam_align(model, data):
    """SplaTAM's utils/eval_helpers.py:align (Horn, GT 'model' onto estimate 'data'), re-typed without np.matrix."""
    model_zc = model - model.mean(1).reshape((3, -1))
    data_zc = data - data.mean(1).reshape((3, -1))
    w = np.zeros((3, 3))
    for column in range(model.shape[1]):
        w += np.outer(model_zc[:, column], data_zc[:, column])
    u, _, vh = np.linalg.svd(w.transpose())
    s = np.identity(3)
    if np.linalg.det(u) * np.linalg.det(vh) < 0:
        s[2, 2] = -1
    rot = u @ s @ vh
    trans = data.mean(1).reshape((3, -1)) - rot @ model.mean(1).reshape((3, -1))
    err = rot @ model + trans - data
    return np.sqrt(np.sum(err * err, 0))


def test_ate_splatam_matches_splatams_own_computation():
    rng = np.random.default_rng(5)
    gt_c2w = smooth_trajectory(rng)
    # SplaTAM: GT made relative to frame 0 at load time; the estimate starts at the identity.
    gt_rel = np.linalg.inv(gt_c2w[0]) @ gt_c2w
    est_rel = perturb(rng, gt_rel, 0.03, 0.03)
    est_rel = np.linalg.inv(est_rel[0]) @ est_rel
    gt_w2c, est_w2c = np.linalg.inv(gt_rel), np.linalg.inv(est_rel)
    expected = splatam_align(gt_w2c[:, :3, 3].T, est_w2c[:, :3, 3].T).mean()
    # our function gets the raw GT (in its own world frame) and an estimate in yet another world frame
    other_world = Alignment(random_rotation(rng), rng.standard_normal(3)).apply_c2w(est_rel)
    assert ate_splatam_mean_w2c(other_world, gt_c2w).value_m == pytest.approx(expected, rel=1e-12, abs=1e-12)
    assert ate_splatam_mean_w2c(other_world, gt_c2w).value_m != pytest.approx(
        ate_rmse_c2w(other_world, gt_c2w).value_m, rel=1e-3
    )


# ------------------------------------------------------------------------------------------------- RPE


def test_rpe_matches_hand_computation():
    gt = np.stack([pose(translation=(0, 0, 0)), pose(translation=(1, 0, 0)), pose(translation=(2, 0, 0))])
    est1 = pose(translation=(1.1, 0, 0))  # first step 10 cm too long
    est2 = est1 @ pose(axis_rotation([0, 0, 1], np.radians(2.0)), (1, 0, 0))  # second step turns 2 deg too much
    est = np.stack([np.eye(4), est1, est2])
    valid = np.ones(3, bool)
    # three frames are the minimum for an alignment; RPE itself needs none
    result = rpe(est, gt, valid)
    np.testing.assert_allclose(result.trans_errors_m, [0.1, 0.0], atol=1e-12)
    np.testing.assert_allclose(result.rot_errors_deg, [0.0, 2.0], atol=1e-12)
    assert result.trans_rmse_m == pytest.approx(np.sqrt(0.01 / 2))
    assert result.trans_mean_m == pytest.approx(0.05)
    assert result.rot_rmse_deg == pytest.approx(np.sqrt(2.0))
    assert result.rot_mean_deg == pytest.approx(1.0)


def test_rpe_agrees_with_evo():
    rng = np.random.default_rng(6)
    gt = smooth_trajectory(rng)
    est = perturb(rng, gt)
    ours = rpe(est, gt)
    for relation, values in (
        (evo_metrics.PoseRelation.translation_part, ours.trans_errors_m),
        (evo_metrics.PoseRelation.rotation_angle_deg, ours.rot_errors_deg),
    ):
        metric = evo_metrics.RPE(relation, delta=1, delta_unit=evo_metrics.Unit.frames)
        metric.process_data((evo_traj(gt), evo_traj(est)))
        np.testing.assert_allclose(values, metric.error, atol=1e-9)


def test_rpe_skips_pairs_that_span_an_invalid_frame():
    rng = np.random.default_rng(7)
    gt = smooth_trajectory(rng, 10)
    est = perturb(rng, gt)
    valid = np.ones(10, bool)
    valid[4] = False
    result = rpe(est, gt, valid)
    assert [tuple(p) for p in result.pairs] == [(i, i + 1) for i in (0, 1, 2, 5, 6, 7, 8)]
    np.testing.assert_allclose(result.trans_errors_m, np.delete(rpe(est, gt).trans_errors_m, [3, 4]))


def test_rotation_angle_is_accurate_for_tiny_angles():
    angle = 1e-9
    assert rotation_angle_np(axis_rotation([1, 2, 3], angle)) == pytest.approx(angle, rel=1e-6)
    assert rotation_angle_np(axis_rotation([1, 2, 3], np.pi - 1e-3)) == pytest.approx(np.pi - 1e-3, rel=1e-9)


# -------------------------------------------------------------------------------------- validity masks


def test_invalid_gt_frames_are_skipped_exactly():
    rng = np.random.default_rng(8)
    gt = smooth_trajectory(rng, 40)
    est = perturb(rng, gt)
    gt_bad = gt.copy()
    gt_bad[3] = np.nan
    gt_bad[10, 0, 3] = -np.inf
    mask = np.ones(40, bool)
    mask[20] = False
    keep = np.setdiff1d(np.arange(40), [3, 10, 20])
    for fn in (ate_rmse_c2w, ate_splatam_mean_w2c):
        result = fn(est, gt_bad, mask)
        assert result.value_m == pytest.approx(fn(est[keep], gt[keep]).value_m, rel=1e-12)
        assert result.used.sum() == 37


def test_non_finite_estimate_at_a_valid_frame_is_an_error():
    rng = np.random.default_rng(9)
    gt = smooth_trajectory(rng, 10)
    est = gt.copy()
    est[6, 1, 3] = np.nan
    with pytest.raises(ValueError, match="non-finite pose.*frame 6"):
        ate_rmse_c2w(est, gt)
    gt_invalid = gt.copy()
    gt_invalid[6] = np.nan
    assert ate_rmse_c2w(est, gt_invalid).value_m < 1e-12  # fine where the GT is skipped anyway


def test_too_few_valid_frames_is_an_error():
    gt = np.stack([np.eye(4)] * 4)
    gt[1:3] = np.nan
    with pytest.raises(ValueError, match="at least 3 frames"):
        ate_rmse_c2w(gt, gt)


# ----------------------------------------------------------------------------------------- association


def test_association_takes_the_nearest_stamp_within_max_dt():
    est = np.array([0.0, 1.0, 2.0, 3.0, 10.0])
    gt = np.array([3.015, 0.5, 2.03, 0.99, 1.02, -0.01])  # unsorted on purpose
    est_idx, gt_idx = associate_timestamps(est, gt, max_dt=0.02)
    assert est_idx.tolist() == [0, 1, 3]
    assert gt_idx.tolist() == [5, 3, 0]


def test_association_breaks_ties_towards_the_earlier_stamp():
    _, gt_idx = associate_timestamps(np.array([1.0]), np.array([0.99, 1.01]), max_dt=0.02)
    assert gt_idx.tolist() == [0]


def test_association_agrees_with_evo():
    rng = np.random.default_rng(10)
    gt = np.cumsum(rng.uniform(0.005, 0.015, 400))  # ~100 Hz
    est = np.sort(rng.uniform(gt[0] - 0.1, gt[-1] + 0.1, 90))  # sparser, some outside the GT span
    ours = associate_timestamps(est, gt, max_dt=0.01)
    theirs = sync.matching_time_indices(est, gt, max_diff=0.01)
    assert ours[0].tolist() == theirs[0]
    assert ours[1].tolist() == theirs[1]


# ------------------------------------------------------------------------------------ evaluate_trajectory


def test_evaluate_trajectory_agrees_with_evo_after_timestamp_association():
    rng = np.random.default_rng(11)
    gt_t = 1000.0 + 0.01 * np.arange(600)  # 100 Hz GT
    gt = smooth_trajectory(rng, 600)
    pick = np.arange(0, 600, 3)[:-2]
    est_t = gt_t[pick] + rng.uniform(-0.004, 0.004, len(pick))  # 33 Hz with jitter
    est = perturb(rng, Alignment(random_rotation(rng), rng.standard_normal(3)).apply_c2w(gt[pick]))
    est_t = np.append(est_t, 2000.0)  # one pose without GT
    est = np.concatenate([est, est[-1:]])
    metrics = evaluate_trajectory(est_t, est, gt_t, gt, max_dt=0.02)

    traj_ref, traj_est = sync.associate_trajectories(evo_traj(gt, gt_t), evo_traj(est, est_t), max_diff=0.02)
    traj_est = copy.deepcopy(traj_est)
    traj_est.align(traj_ref)
    ape = evo_metrics.APE(evo_metrics.PoseRelation.translation_part)
    ape.process_data((traj_ref, traj_est))
    assert metrics.num_associated == traj_est.num_poses == len(pick)
    assert metrics.num_unassociated_est == 1
    assert abs(metrics.ate_rmse_c2w_m - ape.get_statistic(evo_metrics.StatisticsType.rmse)) < 1e-9
    assert metrics.ate_rmse_c2w_cm == pytest.approx(100 * metrics.ate_rmse_c2w_m)


def test_evaluate_trajectory_counts_invalid_gt_and_is_json_serialisable():
    rng = np.random.default_rng(12)
    gt = smooth_trajectory(rng, 50)
    est = perturb(rng, gt)
    stamps = np.arange(50) * 0.1
    gt[7] = np.nan
    gt_valid = np.ones(50, bool)
    gt_valid[30] = False
    metrics = evaluate_trajectory(stamps, est, stamps, gt, gt_valid=gt_valid)
    assert metrics.num_skipped_invalid_gt == 2
    assert metrics.num_evaluated == 48
    assert metrics.num_rpe_pairs == 49 - 4
    decoded = json.loads(json.dumps(dataclasses.asdict(metrics), allow_nan=False))
    assert decoded["ate_splatam_mean_w2c_m"] == metrics.ate_splatam_mean_w2c_m
    for key, value in dataclasses.asdict(metrics).items():
        if isinstance(value, float) and not key.endswith("_s"):
            assert key.endswith(("_m", "_cm", "_deg")), key


def test_evaluate_trajectory_does_not_depend_on_the_estimates_world_frame():
    rng = np.random.default_rng(13)
    gt = smooth_trajectory(rng, 60)
    est = perturb(rng, gt)
    stamps = np.arange(60) * 0.1
    a = evaluate_trajectory(stamps, est, stamps, gt)
    moved = Alignment(random_rotation(rng), rng.standard_normal(3)).apply_c2w(est)
    b = evaluate_trajectory(stamps, moved, stamps, gt)
    for key in ("ate_rmse_c2w_m", "ate_splatam_mean_w2c_m", "rpe_trans_rmse_m", "rpe_rot_rmse_deg"):
        assert getattr(b, key) == pytest.approx(getattr(a, key), rel=1e-9), key


def test_evaluate_trajectory_without_overlap_is_an_error():
    gt = np.stack([np.eye(4)] * 5)
    with pytest.raises(ValueError, match="no estimated pose"):
        evaluate_trajectory(np.arange(5.0), gt, np.arange(5.0) + 100, gt)


def test_invert_rigid_is_the_matrix_inverse():
    rng = np.random.default_rng(14)
    poses = np.stack([pose(random_rotation(rng), rng.standard_normal(3)) for _ in range(5)])
    np.testing.assert_allclose(se3_inverse_np(poses) @ poses, np.broadcast_to(np.eye(4), (5, 4, 4)), atol=1e-12)


def test_invert_transform_is_exact_where_invert_rigid_assumes_orthonormality():
    """A float32 pose is rigid only to rounding: invert_transform inverts the matrix itself (what the files keep),
    se3_inverse_np the nearest rigid transform; the two agree to the pose's orthonormality error."""
    rng = np.random.default_rng(15)
    poses = np.stack([pose(random_rotation(rng), rng.standard_normal(3)) for _ in range(5)]).astype(np.float32)
    exact = invert_transform(poses)
    assert exact.dtype == np.float64
    np.testing.assert_allclose(exact @ poses.astype(np.float64), np.broadcast_to(np.eye(4), (5, 4, 4)), atol=1e-12)
    np.testing.assert_allclose(se3_inverse_np(poses), exact, atol=1e-5)
    assert np.abs(se3_inverse_np(poses) - exact).max() > 0  # not the same function


def test_evaluate_trajectory_per_frame_errors_are_the_ones_behind_the_statistics():
    rng = np.random.default_rng(14)
    gt = smooth_trajectory(rng, 40)
    est = perturb(rng, gt)
    stamps = np.arange(40) * 0.1
    gt_valid = np.ones(40, bool)
    gt_valid[[5, 6, 20]] = False
    metrics = evaluate_trajectory(stamps, est, stamps, gt, gt_valid=gt_valid)
    per_frame = metrics.per_frame
    assert per_frame["est_index"] == [i for i in range(40) if gt_valid[i]]
    assert np.sqrt(np.mean(np.square(per_frame["ate_c2w_m"]))) == pytest.approx(metrics.ate_rmse_c2w_m, rel=1e-12)
    assert per_frame["rpe_est_index"] == [i + 1 for i in range(39) if gt_valid[i] and gt_valid[i + 1]]
    rms = lambda values: np.sqrt(np.mean(np.square(values)))  # noqa: E731
    assert rms(per_frame["rpe_trans_m"]) == pytest.approx(metrics.rpe_trans_rmse_m, rel=1e-12)
    assert rms(per_frame["rpe_rot_deg"]) == pytest.approx(metrics.rpe_rot_rmse_deg, rel=1e-12)


def test_ground_truth_on_estimate_starts_at_the_estimates_pose_and_keeps_the_relative_motion():
    rng = np.random.default_rng(15)
    gt = smooth_trajectory(rng, 30)
    moved = Alignment(random_rotation(rng), rng.standard_normal(3)).apply_c2w(gt)  # the same path in another frame
    valid = np.ones(30, bool)
    valid[:2] = False  # the first frames have no GT: the first one with GT anchors
    frames, drawn = ground_truth_on_estimate(moved, gt, valid)
    assert frames.tolist() == list(range(2, 30))
    np.testing.assert_allclose(drawn, moved[2:], atol=1e-9)  # an exact estimate is drawn exactly on the GT
    est = perturb(rng, moved)
    frames, drawn = ground_truth_on_estimate(est, gt, valid)
    np.testing.assert_allclose(drawn[0], est[2], atol=1e-12)
    relative = lambda poses: se3_inverse_np(poses[0]) @ poses  # noqa: E731
    np.testing.assert_allclose(relative(drawn), relative(gt[2:]), atol=1e-9)
    assert ground_truth_on_estimate(est, gt, np.zeros(30, bool)) is None


def test_drift_is_the_error_where_it_enters_in_any_world_frame():
    rng = np.random.default_rng(16)
    gt = smooth_trajectory(rng, 40)
    moved = Alignment(random_rotation(rng), rng.standard_normal(3)).apply_c2w(gt)  # another world frame
    found = drift(moved, gt)
    assert found.frames.tolist() == list(range(40))
    np.testing.assert_allclose(found.error_m, 0, atol=1e-9)
    np.testing.assert_allclose(found.error_deg, 0, atol=1e-5)
    # From frame 20 on, the estimate slips 1 cm per frame along its own x axis and turns 0.5 deg about its z axis:
    # the unaligned error is exactly that, frame by frame (an ATE would spread it over the run).
    slipped = moved.copy()
    for t in range(20, 40):
        slip = pose(axis_rotation([0, 0, 1], np.radians(0.5 * (t - 19))), (0.01 * (t - 19), 0.0, 0.0))
        slipped[t] = moved[t] @ slip
    found = drift(slipped, gt)
    expected = np.maximum(np.arange(40) - 19, 0)
    np.testing.assert_allclose(found.error_m, 0.01 * expected, atol=1e-9)
    np.testing.assert_allclose(found.error_deg, 0.5 * expected, atol=1e-5)
    assert drift(moved, gt, np.zeros(40, bool)) is None
