"""Procedural smpl22 motion: determinism, FK consistency, a plausible body, smooth physical motion."""

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from mocapfix.core.kinematics import fk_axis_angle
from mocapfix.core.skeleton import preset
from mocapfix.io.synthetic import ACTIVITIES, generate_clips

SKEL = preset("smpl22")
J = {n: i for i, n in enumerate(SKEL.joint_names)}
FEET = [J["left_ankle"], J["right_ankle"], J["left_foot"], J["right_foot"]]
GAIT = ("walk", "turn")
STANDING = ("idle", "wave", "arm_swing")


@pytest.fixture(scope="module")
def clips():
    return generate_clips(num_clips=16, seconds=10.0, fps=30.0, seed=0)


def segments(clips, names, margin=8, min_len=30):
    """(clip, activity, frame slice) of every segment of the named activities, cross-fades trimmed off."""
    for c in clips:
        for act, f0, f1 in c.meta["segments"]:
            if act in names and f1 - f0 - 2 * margin >= min_len:
                yield c, act, slice(f0 + margin, f1 - margin)


def body_frame(c):
    """Positions relative to the pelvis, in the pelvis's own frame: (T, J, 3)."""
    rot = Rotation.from_rotvec(c.rotations[:, 0].astype(np.float64)).as_matrix()  # (T, 3, 3)
    return np.einsum("tji,tkj->tki", rot, c.positions - c.positions[:, :1])


def test_interface(clips):
    assert len(clips) == 16
    for i, c in enumerate(clips):
        T = 300
        assert c.positions.shape == (T, 22, 3) and c.positions.dtype == np.float32
        assert c.rotations.shape == (T, 22, 3) and c.rotations.dtype == np.float32
        assert c.root_translation.shape == (T, 3) and c.offsets.shape == (22, 3)
        assert c.fps == 30.0 and c.skeleton == SKEL and c.has_rotations
        assert c.name == f"synthetic_{i:04d}" and c.source == f"synthetic://0/{i}"
        assert c.meta["format"] == "synthetic" and c.meta["seed"] == 0
        assert c.meta["activity"] == [s[0] for s in c.meta["segments"]]
        assert set(c.meta["activity"]) <= set(ACTIVITIES)
        assert c.meta["segments"][0][1] == 0 and c.meta["segments"][-1][2] == T
        assert np.isfinite(c.positions).all() and np.isfinite(c.rotations).all()
    assert len({c.source for c in clips}) == len(clips)


def test_deterministic_under_seed():
    a, b = generate_clips(3, seconds=4.0, seed=5), generate_clips(3, seconds=4.0, seed=5)
    for x, y in zip(a, b):
        for field in ("positions", "rotations", "root_translation", "offsets"):
            np.testing.assert_array_equal(getattr(x, field), getattr(y, field))
        assert x.meta == y.meta
    other = generate_clips(3, seconds=4.0, seed=6)
    for x, y in zip(a, other):
        assert np.abs(x.positions - y.positions).max() > 0.1
    # A clip depends on (seed, index), not on how many clips were asked for.
    np.testing.assert_array_equal(generate_clips(2, seconds=4.0, seed=5)[1].positions, a[1].positions)


def test_positions_are_fk_of_rotations(clips):
    for c in clips:
        for dtype in (torch.float64, torch.float32):
            pos = fk_axis_angle(
                torch.from_numpy(c.rotations).to(dtype),
                torch.from_numpy(c.root_translation).to(dtype),
                torch.from_numpy(c.offsets).to(dtype),
                SKEL.parents,
            ).numpy()
            assert np.abs(pos - c.positions).max() < 1e-5
        np.testing.assert_allclose(c.root_translation, c.positions[:, 0], atol=1e-6)


def test_bone_lengths_constant_in_time_and_varied_across_clips(clips):
    lengths = []
    for c in clips:
        bones = np.linalg.norm(c.positions[:, 1:] - c.positions[:, list(SKEL.parents[1:])], axis=-1)  # (T, 21)
        assert (bones.max(0) - bones.min(0)).max() < 1e-5
        np.testing.assert_allclose(bones[0], np.linalg.norm(c.offsets[1:], axis=-1), atol=1e-5)
        lengths.append(bones[0])
    lengths = np.array(lengths)  # (clips, 21)
    thigh = lengths[:, J["left_knee"] - 1]
    assert thigh.std() > 0.015 and 0.3 < thigh.min() and thigh.max() < 0.5
    # Left and right bones match within a body (symmetric variation).
    np.testing.assert_allclose(lengths[:, J["left_knee"] - 1], lengths[:, J["right_knee"] - 1], rtol=1e-5)


def test_rest_pose_is_a_standing_person_facing_x(clips):
    for c in clips[:4]:
        rest = fk_axis_angle(
            torch.zeros(22, 3, dtype=torch.float64),
            torch.zeros(3, dtype=torch.float64),
            torch.from_numpy(c.offsets).double(),
            SKEL.parents,
        ).numpy()  # (J, 3)
        feet = rest[FEET, 2].min()
        assert 1.2 < rest[J["head"], 2] - feet < 1.9  # head above the feet (≈ 1.55 m at scale 1)
        assert 0.75 < rest[0, 2] - feet < 1.15  # pelvis height
        for name in ("hip", "knee", "ankle", "shoulder", "elbow", "wrist"):
            assert rest[J[f"left_{name}"], 1] > 0.03 and rest[J[f"right_{name}"], 1] < -0.03
        assert rest[J["left_foot"], 0] > rest[J["left_ankle"], 0] + 0.08  # toes point forward (+x)
        assert rest[J["left_wrist"], 2] < rest[J["left_elbow"], 2] < rest[J["left_shoulder"], 2]  # arms hang


def test_pelvis_height_and_ground_contact(clips):
    for c in clips:
        assert c.positions[..., 2].min() > -0.03  # nothing sinks into the floor
        assert 0.55 < c.positions[:, 0, 2].min() and c.positions[:, 0, 2].max() < 1.6
    for c, _, sl in segments(clips, GAIT + STANDING):
        pelvis = c.positions[sl, 0, 2]
        assert 0.7 < pelvis.min() and pelvis.max() < 1.2
        feet = c.positions[sl][:, FEET, 2].min(axis=1)  # lowest foot joint, per frame
        assert -0.05 < feet.min() and feet.max() < 0.1


def test_stance_foot_is_planted_while_walking(clips):
    n = 0
    for c, _, sl in segments(clips, ("walk",)):
        feet = c.positions[sl][:, FEET]  # (T, 4, 3)
        low = feet[:-1, :, 2].argmin(axis=1)
        step = np.linalg.norm(np.diff(feet[..., :2], axis=0), axis=-1) * c.fps  # (T-1, 4) m/s
        body = np.linalg.norm(np.diff(c.positions[sl, 0, :2], axis=0), axis=-1).mean() * c.fps
        assert np.median(step[np.arange(len(low)), low]) < 0.15 * body  # the lowest foot barely slides
        n += 1
    assert n > 0


def test_smooth(clips):
    for c in clips:
        vel = np.diff(c.positions, axis=0) * c.fps
        acc = np.diff(c.positions, n=2, axis=0) * c.fps**2
        assert np.linalg.norm(vel, axis=-1).max() < 12.0
        assert np.linalg.norm(acc, axis=-1).max() < 300.0


def test_walking_translates_standing_stays(clips):
    walks = runs = stands = 0
    for c, act, sl in segments(clips, ACTIVITIES):
        root = c.positions[sl, 0, :2]
        speed = np.linalg.norm(root[-1] - root[0]) / ((sl.stop - sl.start - 1) / c.fps)
        if act == "walk":
            assert 0.6 < speed < 1.8
            walks += 1
        elif act == "run":
            assert 2.2 < speed < 4.3
            runs += 1
        elif act in STANDING:
            assert speed < 0.1
            stands += 1
    assert walks and runs and stands
    # Over whole clips: every clip that walks or runs for 3 s or more gets somewhere.
    for c in clips:
        moving = sum(f1 - f0 for a, f0, f1 in c.meta["segments"] if a in ("walk", "run", "turn")) / c.fps
        if moving >= 3.0:
            assert np.linalg.norm(c.positions[:, 0, :2] - c.positions[0, 0, :2], axis=-1).max() > 1.0


def test_turns_change_heading(clips):
    n = 0
    for c, _, sl in segments(clips, ("turn",), min_len=40):
        fwd = Rotation.from_rotvec(c.rotations[sl, 0].astype(np.float64)).apply([1.0, 0.0, 0.0])
        heading = np.unwrap(np.arctan2(fwd[:, 1], fwd[:, 0]))
        assert abs(heading[-1] - heading[0]) > 0.5
        n += 1
    assert n > 0


def test_all_activities_present(clips):
    assert {a for c in clips for a in c.meta["activity"]} == set(ACTIVITIES)


def test_arms_move_and_swing_against_the_legs(clips):
    wrist_std = []
    for c in clips:
        body = body_frame(c)
        for group in ("left_arm", "right_arm"):
            wrist_std.append(body[:, SKEL.groups[group]].std(axis=0).sum(-1).mean())
    assert min(wrist_std) > 0.01 and np.mean(wrist_std) > 0.08
    # Walking: the left hand is forward when the left foot is back.
    corr = [
        np.corrcoef(body_frame(c)[sl, J["left_wrist"], 0], body_frame(c)[sl, J["left_ankle"], 0])[0, 1]
        for c, _, sl in segments(clips, ("walk",))
    ]
    assert len(corr) > 0 and max(corr) < -0.5


def test_jumps_leave_the_ground(clips):
    n = 0
    for c, _, sl in segments(clips, ("jump",), margin=0):
        feet = c.positions[sl][:, FEET, 2].min(axis=1)
        assert feet.max() > 0.12  # both feet in the air at once
        n += 1
    assert n > 0


def test_joints_not_collapsed(clips):
    iu = np.triu_indices(22, 1)
    for c in clips:
        d = np.linalg.norm(c.positions[:, iu[0]] - c.positions[:, iu[1]], axis=-1)
        assert d.min() > 0.02


def test_bad_arguments():
    for kwargs in (dict(num_clips=-1), dict(seconds=0.0), dict(fps=float("nan")), dict(seed=-1), dict(seconds=0.01)):
        with pytest.raises(ValueError):
            generate_clips(**kwargs)
    assert generate_clips(0) == []
    short = generate_clips(2, seconds=0.5, fps=60.0)
    assert short[0].positions.shape == (30, 22, 3) and np.isfinite(short[0].positions).all()
