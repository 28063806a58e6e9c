"""Keypoint arrays in the published layouts (io/layouts.py, io/keypoints.py): each layout reads,
maps its joints onto the body part a person would name, and comes back through `fix` in its own
joint order, unit, shape and file type."""

from __future__ import annotations

import zipfile

import numpy as np
import pytest
from cli_utils import run_mocapfix

from mocapfix.core.clip import MotionFileError
from mocapfix.core.skeleton import preset
from mocapfix.io import read_motion
from mocapfix.io.conventions import from_z_up
from mocapfix.io.keypoints import write_keypoints
from mocapfix.io.layouts import LAYOUTS, layout_skeleton, layouts_for, parents_first
from mocapfix.rig.mapping import match_joints, onto_skeleton

BODY = preset("body21")

# What a person names each body21 joint in each layout (every layout's joints that the models'
# body has): written from the published orders, not from io/layouts.py's labels.
NAMED = {
    "h36m17": {"Hips": "Hip", "Spine": "Spine", "Chest": "Thorax", "Neck": "Neck/Nose", "Head": "Head",
               "UpperArm_L": "LShoulder", "LowerArm_L": "LElbow", "Hand_L": "LWrist", "UpperArm_R": "RShoulder",
               "LowerArm_R": "RElbow", "Hand_R": "RWrist", "UpperLeg_L": "LHip", "LowerLeg_L": "LKnee",
               "Foot_L": "LFoot", "UpperLeg_R": "RHip", "LowerLeg_R": "RKnee", "Foot_R": "RFoot"},
    "coco17": {"Head": "nose", "UpperArm_L": "left_shoulder", "LowerArm_L": "left_elbow", "Hand_L": "left_wrist",
               "UpperArm_R": "right_shoulder", "LowerArm_R": "right_elbow", "Hand_R": "right_wrist",
               "UpperLeg_L": "left_hip", "LowerLeg_L": "left_knee", "Foot_L": "left_ankle", "UpperLeg_R": "right_hip",
               "LowerLeg_R": "right_knee", "Foot_R": "right_ankle"},
    "mediapipe33": {"Head": "nose", "UpperArm_L": "left_shoulder", "LowerArm_L": "left_elbow",
                    "Hand_L": "left_wrist", "UpperArm_R": "right_shoulder", "LowerArm_R": "right_elbow",
                    "Hand_R": "right_wrist", "UpperLeg_L": "left_hip", "LowerLeg_L": "left_knee",
                    "Foot_L": "left_ankle", "Toes_L": "left_foot_index", "UpperLeg_R": "right_hip",
                    "LowerLeg_R": "right_knee", "Foot_R": "right_ankle", "Toes_R": "right_foot_index"},
    "smpl24": {"Hips": "pelvis", "Spine": "spine1", "Chest": "spine3", "Neck": "neck", "Head": "head",
               "Shoulder_L": "left_collar", "UpperArm_L": "left_shoulder", "LowerArm_L": "left_elbow",
               "Hand_L": "left_wrist", "Shoulder_R": "right_collar", "UpperArm_R": "right_shoulder",
               "LowerArm_R": "right_elbow", "Hand_R": "right_wrist", "UpperLeg_L": "left_hip",
               "LowerLeg_L": "left_knee", "Foot_L": "left_ankle", "Toes_L": "left_foot", "UpperLeg_R": "right_hip",
               "LowerLeg_R": "right_knee", "Foot_R": "right_ankle", "Toes_R": "right_foot"},
    "openpose25": {"Hips": "MidHip", "Neck": "Neck", "Head": "Nose", "UpperArm_L": "LShoulder",
                   "LowerArm_L": "LElbow", "Hand_L": "LWrist", "UpperArm_R": "RShoulder", "LowerArm_R": "RElbow",
                   "Hand_R": "RWrist", "UpperLeg_L": "LHip", "LowerLeg_L": "LKnee", "Foot_L": "LAnkle",
                   "Toes_L": "LBigToe", "UpperLeg_R": "RHip", "LowerLeg_R": "RKnee", "Foot_R": "RAnkle",
                   "Toes_R": "RBigToe"},
    "kinect20": {"Hips": "HipCenter", "Spine": "Spine", "Neck": "ShoulderCenter", "Head": "Head",
                 "UpperArm_L": "ShoulderLeft", "LowerArm_L": "ElbowLeft", "Hand_L": "WristLeft",
                 "UpperArm_R": "ShoulderRight", "LowerArm_R": "ElbowRight", "Hand_R": "WristRight",
                 "UpperLeg_L": "HipLeft", "LowerLeg_L": "KneeLeft", "Foot_L": "AnkleLeft", "Toes_L": "FootLeft",
                 "UpperLeg_R": "HipRight", "LowerLeg_R": "KneeRight", "Foot_R": "AnkleRight", "Toes_R": "FootRight"},
    "kinect25": {"Hips": "SpineBase", "Spine": "SpineMid", "Chest": "SpineShoulder", "Neck": "Neck", "Head": "Head",
                 "UpperArm_L": "ShoulderLeft", "LowerArm_L": "ElbowLeft", "Hand_L": "WristLeft",
                 "UpperArm_R": "ShoulderRight", "LowerArm_R": "ElbowRight", "Hand_R": "WristRight",
                 "UpperLeg_L": "HipLeft", "LowerLeg_L": "KneeLeft", "Foot_L": "AnkleLeft", "Toes_L": "FootLeft",
                 "UpperLeg_R": "HipRight", "LowerLeg_R": "KneeRight", "Foot_R": "AnkleRight", "Toes_R": "FootRight"},
    "azure32": {"Hips": "PELVIS", "Spine": "SPINE_NAVEL", "Chest": "SPINE_CHEST", "Neck": "NECK", "Head": "HEAD",
                "Shoulder_L": "CLAVICLE_LEFT", "UpperArm_L": "SHOULDER_LEFT", "LowerArm_L": "ELBOW_LEFT",
                "Hand_L": "WRIST_LEFT", "Shoulder_R": "CLAVICLE_RIGHT", "UpperArm_R": "SHOULDER_RIGHT",
                "LowerArm_R": "ELBOW_RIGHT", "Hand_R": "WRIST_RIGHT", "UpperLeg_L": "HIP_LEFT",
                "LowerLeg_L": "KNEE_LEFT", "Foot_L": "ANKLE_LEFT", "Toes_L": "FOOT_LEFT", "UpperLeg_R": "HIP_RIGHT",
                "LowerLeg_R": "KNEE_RIGHT", "Foot_R": "ANKLE_RIGHT", "Toes_R": "FOOT_RIGHT"},
}  # fmt: skip


def test_every_layout_is_named_here():
    assert set(NAMED) == set(LAYOUTS)


@pytest.fixture(scope="module")
def body_take(bandai_files):
    """A 15-s Bandai take on body21: (T, 21, 3) metres, z up, 30 fps."""
    path = next(f for f in bandai_files if f.name == "dataset-2_walk_elderly_002.bvh")
    clip = onto_skeleton(read_motion(path)[0], BODY)
    return clip.positions.astype(np.float64) + clip.origin


def in_layout(name: str, body: np.ndarray) -> np.ndarray:
    """body (T, 21, 3) -> (T, J, 3) in the layout's published order, from NAMED; the joints the
    body lacks (eyes, finger tips, heels) 5 cm from their parent."""
    lay = LAYOUTS[name]
    out = np.full((len(body), len(lay.joint_names), 3), np.nan)
    for body_name, joint in NAMED[name].items():
        out[:, lay.joint_names.index(joint)] = body[:, BODY.index(body_name)]
    for j in parents_first(lay.parents):
        if np.isnan(out[:, j]).all():
            out[:, j] = out[:, lay.parents[j]] + np.array([0.05, 0.0, 0.02])
    return out


@pytest.mark.parametrize("name", list(LAYOUTS))
def test_each_layout_reads_maps_and_writes_back(tmp_path, body_take, name):
    file = from_z_up(in_layout(name, body_take), "y").astype(np.float32)  # (T, J, 3) m, y up: a lifter's
    path = tmp_path / f"{name}.npy"
    np.save(path, file)
    (clip,) = read_motion(path, fps=30, layout=name)
    assert clip.meta["format"] == "keypoints-npy" and clip.meta["up_axis"] == "y" and clip.meta["unit"] == "m"
    found = match_joints(clip.skeleton, BODY)
    assert {b: clip.skeleton.joint_names[j] for b, j in found.items()} == NAMED[name]
    for body_name, joint in NAMED[name].items():  # every mapped joint where the file has it
        np.testing.assert_allclose(
            clip.positions[:, clip.skeleton.index(joint)] + clip.origin,
            body_take[:, BODY.index(body_name)],
            atol=1e-5,
        )
    write_keypoints(tmp_path / "back.npy", [clip], [clip])
    back = np.load(tmp_path / "back.npy")
    assert back.dtype == file.dtype and back.shape == file.shape
    assert np.array_equal(back, file)


@pytest.mark.parametrize("joints", sorted({len(lay.joint_names) for lay in LAYOUTS.values()}))
def test_a_layout_is_told_from_the_shape_only_where_one_has_that_many_joints(tmp_path, joints):
    path = tmp_path / "k.npy"
    np.save(path, np.random.default_rng(0).normal(size=(40, joints, 3)))
    candidates = layouts_for(joints)
    if len(candidates) == 1:
        (clip,) = read_motion(path, fps=30)
        assert clip.meta["layout"] == candidates[0].name
    else:
        with pytest.raises(MotionFileError, match="give " + " or ".join(f"--layout {c.name}" for c in candidates)):
            read_motion(path, fps=30)


def test_a_shape_no_layout_has_and_a_wrong_layout_are_one_line_errors(tmp_path):
    path = tmp_path / "k.npy"
    np.save(path, np.zeros((40, 19, 3)))
    with pytest.raises(MotionFileError, match="19 joints match no keypoint layout"):
        read_motion(path, fps=30)
    with pytest.raises(MotionFileError, match="layout coco17 has 17 joints, the file 19"):
        read_motion(path, fps=30, layout="coco17")
    with pytest.raises(MotionFileError, match="unknown keypoint layout 'coco'"):
        read_motion(path, fps=30, layout="coco")
    np.save(path, np.zeros((40, 17, 3)))
    with pytest.raises(MotionFileError, match="no frame rate: give it"):
        read_motion(path, layout="coco17")


@pytest.mark.parametrize("face", [468, 478])
def test_freemocaps_whole_skeleton_array_is_its_body_with_hands_and_face_carried(tmp_path, body_take, face, capsys):
    """FreeMoCap's `mediapipe_skeleton_3d.npy`: body 33, right hand 21, left hand 21, face 468
    (before 1.4) or 478, mm. The body is read as mediapipe33 and fixed; the other points come back
    as read, NaN included."""
    body = from_z_up(in_layout("mediapipe33", body_take), "y") * 1000.0
    rng = np.random.default_rng(0)
    rest = rng.normal(0.0, 100.0, (len(body), 42 + face, 3)) + body[:, :1]
    rest[::7, :21] = np.nan  # the right hand not detected in every 7th frame
    file = np.concatenate([body, rest], axis=1)
    wrist = LAYOUTS["mediapipe33"].joint_names.index("left_wrist")
    file[30:40, wrist] = np.nan
    np.save(tmp_path / "mediapipe_skeleton_3d.npy", file)
    (clip,) = read_motion(tmp_path / "mediapipe_skeleton_3d.npy", fps=30)
    assert clip.meta["layout"] == "mediapipe33" and clip.skeleton.num_joints == 33
    rc, out, err = run_mocapfix(
        ["fix", tmp_path / "mediapipe_skeleton_3d.npy", "--fps", "30", "--model", "xmae-cpu-bandai"], capsys
    )
    assert rc == 0, err
    back = np.load(tmp_path / "mediapipe_skeleton_3d.fixed.npy")
    assert back.shape == file.shape and np.array_equal(back[:, 33:], file[:, 33:], equal_nan=True)
    assert np.isfinite(back[30:40, wrist]).all()
    assert np.linalg.norm(back[30:40, wrist] - body[30:40, wrist], axis=-1).mean() < 60.0  # mm
    with pytest.raises(MotionFileError, match=f"layout coco17 has 17 joints, the file {75 + face}"):
        read_motion(tmp_path / "mediapipe_skeleton_3d.npy", fps=30, layout="coco17")


@pytest.mark.parametrize("name", ["h36m17", "mediapipe33"])
def test_a_camera_space_array_y_down_is_read_standing_and_written_back_so(tmp_path, body_take, name, capsys):
    """Video lifters (MotionBERT, MHFormer), MediaPipe's world landmarks and triangulation without a
    floor give camera axes: x right, y down, z away. Read standing (the head above the pelvis; a
    MediaPipe take whose legs are never seen by its shoulders above its hips) and written back
    in the file's axes."""
    body = in_layout(name, body_take)[:150]  # (T, J, 3) z up
    camera = from_z_up(body, "-y")
    if name == "mediapipe33":  # the legs out of the picture
        legs = [
            j for j, n in enumerate(LAYOUTS[name].joint_names) if any(w in n for w in ("knee", "ankle", "heel", "foot"))
        ]
        camera[:, legs] = np.nan
    np.save(tmp_path / "camera.npy", camera)
    (clip,) = read_motion(tmp_path / "camera.npy", fps=30, layout=name)
    assert clip.meta["up_axis"] == "-y"
    names = clip.skeleton.joint_names
    expected = body[:, [LAYOUTS[name].joint_names.index(n) for n in names]]
    seen = np.isfinite(expected).all(-1) & np.isfinite(
        camera[:, [LAYOUTS[name].joint_names.index(n) for n in names]]
    ).all(-1)
    np.testing.assert_allclose((clip.positions + clip.origin)[seen], expected[seen], atol=1e-5)
    rc, out, err = run_mocapfix(
        [
            "fix",
            tmp_path / "camera.npy",
            "--fps",
            "30",
            "--layout",
            name,
            "--model",
            "jitter-many",
            "--mode",
            "denoise",
        ],
        capsys,
    )
    assert rc == 0, err
    back = np.load(tmp_path / "camera.fixed.npy")
    assert np.nanmean(np.linalg.norm(back - camera, axis=-1)) < 0.01  # the same axes: millimetres apart


def test_kinect_v2_whose_tree_is_not_in_file_order_reads_in_a_parents_first_order():
    skeleton, order = layout_skeleton(LAYOUTS["kinect25"])
    assert order != list(range(25)) and sorted(order) == list(range(25))
    assert skeleton.joint_names[skeleton.parents[skeleton.index("Neck")]] == "SpineShoulder"
    assert skeleton.joint_names[skeleton.parents[skeleton.index("ShoulderLeft")]] == "SpineShoulder"


def test_a_depth_camera_take_with_confidence_comes_back_through_fix(tmp_path, body_take, capsys):
    """Azure Kinect: mm, y up, (T, 32, 4) with its confidence level; NONE (0) is a hole fix
    fills, LOW (1) stays observed; the column, the observed tokens and the shape come back as read."""
    truth = from_z_up(in_layout("azure32", body_take), "y") * 1000.0
    confidence = np.full(truth.shape[:2], 3.0)
    confidence[40:55, 5:9] = 0  # the left arm out of view for half a second
    confidence[80:84, 18:22] = 1  # the left leg predicted
    file = np.concatenate([truth, confidence[..., None]], axis=-1).astype(np.float32)
    file[confidence == 0, :3] = 0.0  # the tracker's numbers where it saw nothing
    np.save(tmp_path / "azure.npy", file)
    rc, out, err = run_mocapfix(["fix", tmp_path / "azure.npy", "--fps", "30", "--model", "xmae-cpu-bandai"], capsys)
    assert rc == 0, err
    assert "60 tokens filled" in out
    back = np.load(tmp_path / "azure.fixed.npy")
    assert back.shape == file.shape and back.dtype == file.dtype
    assert np.array_equal(back[..., 3], file[..., 3])
    seen = confidence > 0
    assert np.array_equal(back[seen], file[seen])  # observed tokens bit for bit
    error_mm = np.linalg.norm(back[~seen][:, :3] - truth[~seen], axis=-1)
    assert error_mm.mean() < 20.0  # filled near where the arm was, not left at the tracker's 0


def test_a_take_with_no_confident_joint_is_refused(tmp_path):
    np.save(tmp_path / "k.npy", np.zeros((40, 32, 4)))
    with pytest.raises(MotionFileError, match="nothing was tracked"):
        read_motion(tmp_path / "k.npy", fps=30)


def test_an_npz_without_names_is_a_keypoint_array_with_its_key_fps_and_unit_kept(tmp_path, body_take):
    file = (from_z_up(in_layout("smpl24", body_take), "y") * 100.0).astype(np.float64)  # cm
    np.savez(tmp_path / "smpl.npz", keypoints3d=file, fps=np.float64(30.0))
    (clip,) = read_motion(tmp_path / "smpl.npz")
    assert clip.meta["format"] == "keypoints-npz" and clip.meta["unit"] == "cm" and clip.fps == 30.0
    write_keypoints(tmp_path / "back.npz", [clip], [clip])
    with np.load(tmp_path / "back.npz") as back:
        assert np.array_equal(back["keypoints3d"], file) and back["fps"] == 30.0 and str(back["unit"]) == "cm"


@pytest.mark.parametrize("key", ["reconstruction", "arr_0"])
def test_a_lifters_npz_reads_under_its_own_key_and_is_written_back_under_it(tmp_path, body_take, capsys, key):
    """MHFormer's demo saves (T, 17, 3) as "reconstruction"; VideoPose3D's in-the-wild scripts
    np.savez the prediction unnamed ("arr_0"): each reads as H36M-17 and fix writes the same key."""
    file = from_z_up(in_layout("h36m17", body_take), "y").astype(np.float32)
    np.savez(tmp_path / "lifted.npz", **{key: file})
    args = ["fix", tmp_path / "lifted.npz", "--layout", "h36m17", "--fps", "30", "--model", "jitter-many"]
    rc, out, err = run_mocapfix(args, capsys)
    assert rc == 0, err
    with np.load(tmp_path / "lifted.fixed.npz") as back:
        assert back.files[0] == key and back[key].shape == file.shape and back[key].dtype == file.dtype
        assert 0 < np.abs(back[key] - file).max() < 0.05  # denoised, in the file's own metres
        assert {m.compress_type for m in back.zip.infolist()} == {zipfile.ZIP_STORED}  # np.savez's, as read
    (again,) = read_motion(tmp_path / "lifted.fixed.npz", layout="h36m17")  # its fps and unit beside it now
    assert again.fps == 30.0 and again.meta["unit"] == "m"


def test_an_npz_whose_arrays_name_no_keypoints_is_one_line_naming_its_keys(tmp_path, body_take):
    np.savez(tmp_path / "two.npz", in_layout("h36m17", body_take), np.zeros(3))  # arr_0 and arr_1: which?
    with pytest.raises(MotionFileError, match="unknown keys.*arr_0.*arr_1"):
        read_motion(tmp_path / "two.npz")


def test_a_limb_never_seen_is_left_missing_and_said_so(tmp_path, body_take, capsys):
    """An arm out of the camera's view all take long: nothing says where it was, so it is not
    filled with a body's guess (the rest of the take is fixed as usual)."""
    truth = from_z_up(in_layout("azure32", body_take), "y") * 1000.0
    confidence = np.full(truth.shape[:2], 3.0)
    arm = [LAYOUTS["azure32"].joint_names.index(n) for n in ("SHOULDER_LEFT", "ELBOW_LEFT", "WRIST_LEFT", "HAND_LEFT")]
    confidence[:, arm] = 0
    confidence[100:110, 19] = 0  # and a short hole in the left knee
    np.save(tmp_path / "azure.npy", np.concatenate([truth, confidence[..., None]], axis=-1).astype(np.float32))
    rc, out, err = run_mocapfix(["fix", tmp_path / "azure.npy", "--fps", "30", "--model", "xmae-cpu-bandai"], capsys)
    assert rc == 0, err
    assert "10 tokens filled" in out
    assert "joints never observed: UpperArm_L, LowerArm_L, Hand_L (left missing" in out
    back = np.load(tmp_path / "azure.fixed.npy")
    assert np.isnan(back[:, arm, :3]).all()
    assert np.isfinite(back[100:110, 19, :3]).all()


def test_the_jitter_remover_serves_a_layout_without_pelvis_or_spine(tmp_path, body_take, capsys):
    """COCO lacks the body's pelvis, spine, neck and clavicles: the jitter remover places them from
    the rest for its network, writes none of them, and takes most of the jitter out."""
    clean = in_layout("coco17", body_take)  # metres, z up
    noisy = clean + np.random.default_rng(0).normal(scale=0.01, size=clean.shape)
    np.save(tmp_path / "coco.npy", noisy.astype(np.float32))
    args = [
        "fix",
        tmp_path / "coco.npy",
        "--layout",
        "coco17",
        "--fps",
        "30",
        "--model",
        "jitter-many",
        "--mode",
        "denoise",
    ]
    rc, out, err = run_mocapfix(args, capsys)
    assert rc == 0, err
    assert "model joints not in the recording: Hips, Spine, Chest, Neck, Shoulder_L, Shoulder_R" in out
    back = np.load(tmp_path / "coco.fixed.npy")
    assert back.shape == noisy.shape
    error = lambda x: np.linalg.norm(x - clean, axis=-1).mean()  # noqa: E731
    assert error(back) < 0.7 * error(noisy)


def test_render_draws_a_keypoint_take_beside_its_fixed_one(tmp_path, body_take, capsys):
    np.save(tmp_path / "k.npy", in_layout("kinect20", body_take)[:60].astype(np.float32))
    rc, _, err = run_mocapfix(["render", tmp_path / "k.npy", "-o", tmp_path / "k.png"], capsys)
    assert rc == 1 and "no frame rate: give it (--fps; render: --take-fps)" in err
    rc, out, err = run_mocapfix(["render", tmp_path / "k.npy", "--take-fps", "30", "-o", tmp_path / "k.png"], capsys)
    assert rc == 0, err
    assert (tmp_path / "k.png").stat().st_size > 10_000


def test_dropped_and_repeated_frames_go_on_a_regular_clock_and_come_back_as_read(tmp_path, body_take, capsys):
    """A depth camera's take with its times: two frames dropped (a hole fix fills, not a jump
    squeezed out of the clock) and one row repeated (read once); the output has the file's rows."""
    clean = from_z_up(in_layout("kinect20", body_take), "y")[:120]  # metres, y up, 30 fps
    rows = [t for t in range(120) if t not in (50, 51)]
    rows.insert(rows.index(79) + 1, 79)  # frame 79 twice
    times = np.array(rows) / 30.0 + 1700000000.0  # a unix clock, as cameras write it
    file = clean[rows].astype(np.float32)
    np.savez(tmp_path / "k.npz", positions=file, times=times)
    (clip,) = read_motion(tmp_path / "k.npz")
    assert clip.fps == 30.0 and clip.num_frames == 120
    assert np.isnan(clip.positions[50:52]).all() and np.isfinite(np.delete(clip.positions, [50, 51], 0)).all()
    rc, out, err = run_mocapfix(["fix", tmp_path / "k.npz", "--model", "xmae-cpu-bandai"], capsys)
    assert rc == 0, err
    with np.load(tmp_path / "k.fixed.npz") as back:
        assert np.array_equal(back["positions"], file) and np.array_equal(back["times"], times)
    with pytest.raises(MotionFileError, match="times go back at row 3"):
        np.savez(tmp_path / "bad.npz", positions=file[:5], times=np.array([0.0, 0.1, 0.2, 0.1, 0.3]))
        read_motion(tmp_path / "bad.npz", fps=10)


def test_the_jitter_remover_leaves_a_limb_never_seen_missing(tmp_path, body_take, capsys):
    truth = from_z_up(in_layout("azure32", body_take), "y") * 1000.0
    confidence = np.full(truth.shape[:2], 3.0)
    arm = [LAYOUTS["azure32"].joint_names.index(n) for n in ("SHOULDER_LEFT", "ELBOW_LEFT", "WRIST_LEFT")]
    confidence[:, arm] = 0
    np.save(tmp_path / "azure.npy", np.concatenate([truth, confidence[..., None]], axis=-1).astype(np.float32))
    args = ["fix", tmp_path / "azure.npy", "--fps", "30", "--model", "jitter-many", "--mode", "denoise"]
    rc, out, err = run_mocapfix(args, capsys)
    assert rc == 0, err
    assert "joints never observed: UpperArm_L, LowerArm_L, Hand_L (left missing" in out
    back = np.load(tmp_path / "azure.fixed.npy")
    assert np.isnan(back[:, arm, :3]).all() and np.isfinite(np.delete(back, arm, axis=1)).all()


def body_prefixed(name: str) -> str:
    return "body_" + name


@pytest.mark.parametrize("case", [str.lower, str.upper, body_prefixed])
def test_a_csv_named_with_a_layouts_joints_reads_as_that_layout_and_fixes_back_as_written(
    tmp_path, body_take, case, capsys
):
    """FreeMoCap's `mediapipe_body_3d_xyz.csv`: MediaPipe's 33 landmark names as `<name>_x,_y,_z`
    columns (`body_<name>` since FreeMoCap 1.4), mm, no frame column, no tree. Read as the
    mediapipe33 layout (its tree and limbs) in the file's own names, any case; `fix` fills a hole
    and writes the same columns and unit."""
    lay = LAYOUTS["mediapipe33"]
    x = in_layout("mediapipe33", body_take)
    x = 1000.0 * x
    x[20:28, lay.joint_names.index("left_wrist")] = np.nan
    header = ",".join(f"{case(n)}_{a}" for n in lay.joint_names for a in "xyz")
    rows = ["".join(",".join("" if np.isnan(v) else f"{v:.3f}" for v in row)) for row in x.reshape(len(x), -1)]
    (tmp_path / "body.csv").write_text(header + "\n" + "\n".join(rows) + "\n")
    (clip,) = read_motion(tmp_path / "body.csv", fps=30.0, unit="mm")
    assert clip.skeleton.name == "mediapipe33" and clip.skeleton.joint_names[0] == case("nose")
    assert set(clip.skeleton.groups) == {"left_arm", "right_arm", "left_leg", "right_leg"}
    args = ["fix", str(tmp_path / "body.csv"), "--model", "xmae-cpu-bandai", "--fps", "30", "--unit", "mm"]
    rc, out, err = run_mocapfix([*args, "-o", tmp_path / "out.csv"], capsys)
    assert rc == 0, err
    written = (tmp_path / "out.csv").read_text().splitlines()
    assert written[0] == header and len(written) == len(x) + 1  # as read: no lines of mocapfix's own
    (out,) = read_motion(tmp_path / "out.csv", fps=30.0, unit="mm")
    assert np.isfinite(out.positions[20:28, lay.joint_names.index("left_wrist")]).all()


def test_a_csv_named_with_a_layout_whose_tree_is_out_of_file_order_asks_for_parents(tmp_path):
    names = LAYOUTS["kinect25"].joint_names
    (tmp_path / "k.csv").write_text(
        ",".join(f"{n}_{a}" for n in names for a in "xyz") + "\n" + ",".join(["0.1"] * 75) + "\n"
    )
    with pytest.raises(MotionFileError, match="kinect25 layout's"):
        read_motion(tmp_path / "k.csv", fps=30.0)


def test_a_landmark_csv_with_visibility_columns_holes_the_unseen_and_writes_them_back(tmp_path, body_take, capsys):
    """MediaPipe landmark dumps: `frame,<name>_x,_y,_z,_visibility` per landmark, metres, camera
    axes (y down). A landmark at or below --min-confidence is a hole fix fills; the output has the
    same header and every visibility cell as written."""
    lay = LAYOUTS["mediapipe33"]
    x = from_z_up(in_layout("mediapipe33", body_take), "-y")[:90]
    visibility = np.full((90, 33), 0.99)
    wrist = lay.joint_names.index("left_wrist")
    visibility[30:38, wrist] = 0.1
    header = "frame," + ",".join(f"{n}_{a}" for n in lay.joint_names for a in ("x", "y", "z", "visibility"))
    rows = [f"{t}," + ",".join(f"{v:.6f}" for j in range(33) for v in (*x[t, j], visibility[t, j])) for t in range(90)]
    path = tmp_path / "landmarks.csv"
    path.write_text(header + "\n" + "\n".join(rows) + "\n")
    (clip,) = read_motion(path, fps=30, min_confidence=0.5)
    assert clip.skeleton.name == "mediapipe33" and clip.meta["up_axis"] == "-y"
    assert np.isnan(clip.positions[30:38, clip.skeleton.index("left_wrist")]).all()
    args = [
        "fix",
        path,
        "--fps",
        "30",
        "--min-confidence",
        "0.5",
        "--model",
        "xmae-cpu-bandai",
        "-o",
        tmp_path / "o.csv",
    ]
    rc, out, err = run_mocapfix(args, capsys)
    assert rc == 0, err
    written = (tmp_path / "o.csv").read_text().splitlines()
    assert written[0] == header and len(written) == 91
    back = np.array([line.split(",")[1:] for line in written[1:]], dtype=float).reshape(90, 33, 4)
    assert np.array_equal(back[..., 3], np.round(visibility, 6))  # the visibility cells as read
    assert np.linalg.norm(back[30:38, wrist, :3] - x[30:38, wrist], axis=-1).mean() < 0.05  # filled near the wrist
    (tmp_path / "mixed.csv").write_text("nose_x,nose_y,nose_z,nose_visibility,eye_x,eye_y,eye_z\n0,0,0,1,0,0,0\n")
    with pytest.raises(MotionFileError, match="1 of 2 joints have a confidence column: every joint or none"):
        read_motion(tmp_path / "mixed.csv", fps=30)


def test_an_azure_kinect_csv_recorders_columns_read_as_azure32_and_come_back_as_written(tmp_path, body_take, capsys):
    """Azure Kinect CSV recorders: `PELVIS.x,PELVIS.y,PELVIS.z,...` (k4abt's joint names), mm, the
    depth camera's axes (y down), no frame column."""
    lay = LAYOUTS["azure32"]
    truth = from_z_up(in_layout("azure32", body_take), "-y")[:90] * 1000.0
    wrist = lay.joint_names.index("WRIST_LEFT")
    x = truth.copy()
    x[40:50, wrist] = np.nan
    header = ",".join(f"{n}.{a}" for n in lay.joint_names for a in "xyz")
    rows = [",".join("" if np.isnan(v) else f"{v:.2f}" for v in row) for row in x.reshape(90, -1)]
    path = tmp_path / "bodies.csv"
    path.write_text(header + "\n" + "\n".join(rows) + "\n")
    (clip,) = read_motion(path, fps=30)
    assert clip.skeleton.name == "azure32" and clip.meta["up_axis"] == "-y" and clip.meta["unit"] == "mm"
    rc, out, err = run_mocapfix(["fix", path, "--fps", "30", "--model", "xmae-cpu-bandai"], capsys)
    assert rc == 0, err
    written = (tmp_path / "bodies.fixed.csv").read_text().splitlines()
    assert written[0] == header and len(written) == 91
    back = np.array([[float(v) for v in line.split(",")] for line in written[1:]]).reshape(90, 32, 3)
    seen = np.isfinite(x).all(-1)
    assert np.allclose(back[seen], x[seen], atol=0.006)  # the file's numbers, mm, camera axes
    assert np.linalg.norm(back[40:50, wrist] - truth[40:50, wrist], axis=-1).mean() < 20.0  # filled (mm)
    (tmp_path / "both.csv").write_text("a_x,a_y,a_z,b.x,b.y,b.z\n0,0,0,0,0,0\n")
    with pytest.raises(MotionFileError, match="joint columns named both <joint>_x and <joint>.x"):
        read_motion(tmp_path / "both.csv", fps=30)
