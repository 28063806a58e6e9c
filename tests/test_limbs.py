"""Limbs held at one length (fix/limbs.py): a tracker's bones that breathe come out rigid, what
is not a limb's bone and what is missing stay as they were, and a take whose bones were rigid
already is left where it was; the torso's distances come out as the recording had them."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from cli_utils import run_mocapfix
from test_keypoints import BODY, in_layout

from mocapfix.fix.limbs import hold_limb_lengths, hold_torso_lengths, limb_bones, torso_bones
from mocapfix.io import read_motion
from mocapfix.io.layouts import LAYOUTS, layout_skeleton
from mocapfix.models.jitter import lowpass
from mocapfix.rig.mapping import onto_skeleton

ALL = np.arange(BODY.num_joints)  # a take with every model joint: index is the identity
WALK = "dataset-2_walk_elderly_002.bvh"
KINECT_TORSO = "HipCenter Spine ShoulderCenter Head ShoulderLeft ShoulderRight HipLeft HipRight".split()


@pytest.fixture(scope="module")
def body_take(bandai_files):
    """A 15-s Bandai take on body21: (T, 21, 3) metres, z up, 30 fps; its bones rigid."""
    clip = onto_skeleton(read_motion(next(f for f in bandai_files if f.name == WALK))[0], BODY)
    return clip.positions.astype(np.float64) + clip.origin


def breathing(x: np.ndarray, bones, sd_m: float, seed: int) -> np.ndarray:
    """Each bone's lower end moved along the bone by slow noise (a tracker's bone lengths: as
    slow as the motion), its joints below with it."""
    rng = np.random.default_rng(seed)
    out = x.copy()
    kernel = np.hanning(31) / np.hanning(31).sum()
    for a, b in bones:
        slow = np.convolve(rng.normal(0, sd_m * 4, len(x) + 30), kernel, mode="valid")[: len(x)]  # (T,)
        d = out[:, b] - out[:, a]
        shift = slow[:, None] * d / np.linalg.norm(d, axis=-1, keepdims=True)
        below = [j for j in range(BODY.num_joints) if j == b or b in _above(j)]
        out[:, below] += shift[:, None]
    return out


def _above(j: int) -> list[int]:
    out = []
    while BODY.parents[j] >= 0:
        j = BODY.parents[j]
        out.append(j)
    return out


def lengths(x, bones) -> np.ndarray:
    return np.stack([np.linalg.norm(x[:, b] - x[:, a], axis=-1) for a, b in bones], -1)


def test_the_limbs_bones_are_upper_arm_forearm_thigh_shank_and_foot():
    names = [(BODY.joint_names[a], BODY.joint_names[b]) for a, b in limb_bones(BODY, ALL)]
    assert ("UpperArm_L", "LowerArm_L") in names and ("LowerArm_R", "Hand_R") in names
    assert ("UpperLeg_L", "LowerLeg_L") in names and ("Foot_R", "Toes_R") in names
    assert len(names) == 10 and not any("Spine" in a or "Chest" in a or "Shoulder" in a for a, _ in names)
    no_left_hand = ALL.copy()
    no_left_hand[BODY.index("Hand_L")] = -1  # a layout without it: the forearm is skipped, not invented
    assert len(limb_bones(BODY, no_left_hand)) == 9


def test_breathing_bones_come_out_at_their_median_length_and_nearer_the_truth(body_take):
    bones = limb_bones(BODY, ALL)
    noisy = breathing(body_take, bones, 0.02, seed=1)
    noisy[40:60, BODY.index("LowerArm_L")] = np.nan  # a hole stays a hole
    held, spread_mm = hold_limb_lengths(noisy, bones)
    assert spread_mm > 10.0  # what it found: 2 cm of breathing
    after = lengths(held, bones)
    assert np.nanmax(np.nanstd(after, 0)) < 1e-4  # every bone one length (within 0.1 mm)
    np.testing.assert_allclose(np.nanmedian(after, 0), np.nanmedian(lengths(noisy, bones), 0), atol=1e-4)
    assert np.isnan(held[40:60, BODY.index("LowerArm_L")]).all()
    torso = [BODY.index(n) for n in ("Hips", "Spine", "Chest", "Neck", "Head", "Shoulder_L", "UpperArm_L")]
    assert np.array_equal(held[:, torso], noisy[:, torso])  # the torso, shoulders and hips stay put
    # errors along the bones (a depth camera's) are taken out; isotropic ones neither grow nor shrink
    limb = sorted({j for bone in bones for j in bone})
    error = {k: np.nanmean(np.linalg.norm(v - body_take, axis=-1)[:, limb]) for k, v in (("in", noisy), ("out", held))}
    assert error["out"] < 0.8 * error["in"], error
    rng = np.random.default_rng(3)
    isotropic = body_take + rng.normal(0, 0.01, body_take.shape)
    held, _ = hold_limb_lengths(isotropic, bones)
    before, after = (np.linalg.norm(v - body_take, axis=-1)[:, limb].mean() for v in (isotropic, held))
    assert after < 1.03 * before, (before, after)


def test_a_take_whose_bones_are_rigid_is_left_where_it_was(body_take):
    held, spread_mm = hold_limb_lengths(body_take, limb_bones(BODY, ALL))
    assert spread_mm < 0.5  # the BVH's bones, through float rounding
    assert np.abs(held - body_take).max() < 2e-3


@pytest.mark.parametrize("name", ["kinect25", "h36m17"])
def test_fix_denoise_holds_a_depth_cameras_limbs_and_says_so(tmp_path, body_take, capsys, name):
    """A keypoint take whose limbs breathe by 2 cm: fix's jitter remover (which a low-pass alone
    cannot do) brings the limb sigma it reports down by far more than the low-pass did."""
    x = in_layout(name, breathing(body_take, limb_bones(BODY, ALL), 0.02, seed=2))
    np.save(tmp_path / "take.npy", x.astype(np.float32))
    args = ["fix", tmp_path / "take.npy", "--layout", name, "--fps", "30", "--model", "jitter-many", "--json"]
    rc, out, err = run_mocapfix(args, capsys)
    assert rc == 0, err
    assert "limbs' long bones held at each take's median length" in out
    back = np.load(tmp_path / "take.fixed.npy").astype(np.float64)
    lay = LAYOUTS[name]
    pairs = [("LShoulder", "LElbow"), ("LKnee", "LFoot")] if name == "h36m17" else [("ShoulderLeft", "ElbowLeft")]
    for a, b in pairs:
        ia, ib = lay.joint_names.index(a), lay.joint_names.index(b)
        before = np.linalg.norm(x[:, ib] - x[:, ia], axis=-1).std()
        after = np.linalg.norm(back[:, ib] - back[:, ia], axis=-1).std()
        assert before > 0.01 and after < 0.001, (a, b, before, after)


def test_a_bvh_take_keeps_its_own_bones(tmp_path, bandai_files, capsys):
    path = next(f for f in bandai_files if f.name == WALK)
    rc, out, err = run_mocapfix(["fix", path, "-o", tmp_path / "out.bvh", "--model", "jitter-many", "--json"], capsys)
    assert rc == 0, err
    assert "held at each take's median length" not in out  # its hierarchy's bones are rigid already


def test_the_torso_bones_are_the_recordings_own_between_the_joints_the_model_uses():
    lay = LAYOUTS["kinect20"]
    skeleton, _ = layout_skeleton(lay)
    names = "HipCenter Spine ShoulderCenter Head ShoulderLeft ElbowLeft HipLeft KneeLeft".split()
    columns = np.array([lay.joint_names.index(n) for n in names])
    limbs = [(4, 5), (6, 7)]  # (ShoulderLeft, ElbowLeft), (HipLeft, KneeLeft) as columns
    found = {(names[a], names[b]) for a, b in torso_bones(skeleton.parents, columns, limbs)}
    # a Kinect's shoulder hangs from its shoulder centre (the model's would from a chest it lacks)
    assert found == {
        ("HipCenter", "Spine"),
        ("Spine", "ShoulderCenter"),
        ("ShoulderCenter", "Head"),
        ("ShoulderCenter", "ShoulderLeft"),
        ("HipCenter", "HipLeft"),
    }


def test_the_torso_keeps_what_the_tracker_holds_steadier(body_take):
    """Each torso joint moved on its own by a few millimetres (what the learned correction does),
    the recording's torso rigid but for a spine that bows slowly: its distances come back to the
    recording's, low-passed; a distance the recording has unsteadier (a hip jittering on its
    own) is left as the moved take has it."""
    torso = [BODY.index(n) for n in ("Hips", "Spine", "Chest", "Neck", "Head", "UpperArm_L", "UpperLeg_L")]
    bones = [(0, 1), (1, 2), (2, 3), (3, 4), (2, 5), (0, 6)]  # in the columns of `torso`
    recorded = body_take[:, torso].copy()  # (T, 7, 3): rigid distances
    t = np.arange(len(recorded)) / 30.0
    recorded[:, 1:] += (0.01 * np.sin(2 * np.pi * 0.2 * t))[:, None, None] * np.array([0.0, 0.0, 1.0])  # a bow
    rng = np.random.default_rng(5)
    moved = recorded + rng.normal(0, 0.004, recorded.shape)
    recorded[:, 6] += rng.normal(0, 0.02, (len(recorded), 3))  # the recording's hip jitters by 2 cm
    moved[30:40, 4] = np.nan  # a missing head stays missing, its bone left alone there
    held = hold_torso_lengths(moved, bones, recorded, 30.0, 6.0)
    assert np.isnan(held[30:40, 4]).all() and np.isfinite(held[:30]).all()
    want = lowpass(torch.from_numpy(lengths(recorded, bones))[None], 30.0, 6.0)[0].numpy()[:, :5]
    before, after = lengths(moved, bones), lengths(held, bones)
    assert np.nanstd(before[:, :5] - want, 0).min() > 2e-3  # breathing by millimetres before
    seen = np.isfinite(after[:, :5])
    np.testing.assert_allclose(after[:, :5][seen], want[seen], atol=2e-5)
    assert np.array_equal(held[:, 6], moved[:, 6])  # the hip: its bone left as the moved take has it
    # moved along the bones, by about what their lengths were off, not pulled anywhere else
    off = np.nanmax(np.abs(before[:, :5] - want))
    assert np.nanmax(np.linalg.norm(held - moved, axis=-1)) < 3 * off


def test_fix_denoise_leaves_a_trackers_rigid_torso_rigid(tmp_path, body_take, capsys):
    """A Kinect v1 take whose tracker holds the torso rigid (its keypoints jitter together, as a
    fitted body model's do) and whose arms and legs jitter joint by joint: the torso's distances
    come out as they went in (through the jitter remover's low-pass), where its learned correction
    made them breathe by millimetres."""
    rng = np.random.default_rng(6)
    x = in_layout("kinect20", body_take)
    names = LAYOUTS["kinect20"].joint_names
    torso = [names.index(n) for n in KINECT_TORSO]
    rest = [j for j in range(len(names)) if j not in torso]
    x[:, torso] += rng.normal(0, 0.01, (len(x), 1, 3))  # the whole torso shifted at once
    x[:, rest] += rng.normal(0, 0.01, (len(x), len(rest), 3))
    np.save(tmp_path / "take.npy", x.astype(np.float32))
    args = ["fix", tmp_path / "take.npy", "--layout", "kinect20", "--fps", "30", "--model", "jitter-many", "--json"]
    rc, out, err = run_mocapfix(args, capsys)
    assert rc == 0, err
    back = np.load(tmp_path / "take.fixed.npy").astype(np.float64)
    for a, b in (("ShoulderCenter", "ShoulderLeft"), ("HipCenter", "HipRight"), ("Spine", "ShoulderCenter")):
        ia, ib = names.index(a), names.index(b)
        before = np.linalg.norm(x[:, ib] - x[:, ia], axis=-1)  # a spine's bow in the Bandai take, slow
        want = lowpass(torch.from_numpy(before)[None, :, None], 30.0, 6.0)[0, :, 0].numpy()  # the model's cutoff
        after = np.linalg.norm(back[:, ib] - back[:, ia], axis=-1)
        assert np.abs(after - want).max() < 1e-4, (a, b, np.abs(after - want).max())
