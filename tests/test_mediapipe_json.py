"""MediaPipe world landmarks dumped as JSON (io/mediapipe_json.py): the frames in their common
shapes, visibility as confidence, numbered frames on the clock, image landmarks and crowds refused
in one line, and fix's output the file's own structure with only the changed landmarks new."""

from __future__ import annotations

import json

import numpy as np
import pytest
from cli_utils import run_mocapfix
from test_keypoints import body_take, in_layout  # noqa: F401  (body_take: the fixture)

from mocapfix.core.clip import MotionFileError
from mocapfix.io import read_motion
from mocapfix.io.conventions import from_z_up
from mocapfix.io.layouts import layout

NAMES = layout("mediapipe33").joint_names


def world_landmarks(body) -> np.ndarray:
    """body (T, 21, 3) z up -> (T, 33, 3) as MediaPipe gives them: metres about the hips' midpoint,
    x right, y down, z away from the camera."""
    x = from_z_up(in_layout("mediapipe33", body), "-y")
    hips = x[:, [NAMES.index("left_hip"), NAMES.index("right_hip")]].mean(1, keepdims=True)
    return x - hips


def points(x, visibility) -> list[dict]:
    return [
        {"x": float(p[0]), "y": float(p[1]), "z": float(p[2]), "visibility": float(v)} for p, v in zip(x, visibility)
    ]


def test_numbered_frames_with_visibility_on_the_clock_and_fix_writes_the_structure_back(
    tmp_path,
    body_take,  # noqa: F811
    capsys,
):
    x = world_landmarks(body_take)[:90]
    visibility = np.full((90, 33), 0.98)
    wrist = NAMES.index("left_wrist")
    visibility[40:50, wrist] = 0.2  # guessed: a hole at --min-confidence 0.5
    kept = [t for t in range(90) if t not in (20, 21, 60)]  # frames with no detection are not written
    document = [{"frame": t, "pose_world_landmarks": points(x[t], visibility[t]), "note": "kept"} for t in kept]
    path = tmp_path / "take.json"
    path.write_text(json.dumps(document, indent=2))
    (clip,) = read_motion(path, fps=30, min_confidence=0.5)
    assert clip.num_frames == 90 and clip.fps == 30.0 and clip.meta["layout"] == "mediapipe33"
    missing = np.isnan(clip.positions).all((1, 2))
    assert missing.nonzero()[0].tolist() == [20, 21, 60]
    j = clip.skeleton.index("left_wrist")
    assert np.isnan(clip.positions[40:50, j]).all() and np.isfinite(clip.positions[50:60, j]).all()
    head, ankle = clip.skeleton.index("nose"), clip.skeleton.index("left_ankle")
    assert (clip.positions[:, head, 2] > clip.positions[:, ankle, 2] + 1.0)[~missing].all()  # y down read as z up
    args = ["fix", path, "--fps", "30", "--min-confidence", "0.5", "--model", "xmae-cpu-bandai"]
    rc, out, err = run_mocapfix(args, capsys)
    assert rc == 0, err
    back = json.loads((tmp_path / "take.fixed.json").read_text())
    assert [e["frame"] for e in back] == kept and all(e["note"] == "kept" for e in back)
    for e, was in zip(back, document):
        for k, (new, old) in enumerate(zip(e["pose_world_landmarks"], was["pose_world_landmarks"])):
            assert new["visibility"] == old["visibility"]
            if not (40 <= e["frame"] < 50 and k == wrist):
                assert new == old  # every landmark fix left alone as read
    filled = np.array(
        [[p[a] for a in "xyz"] for e in back if 40 <= e["frame"] < 50 for p in [e["pose_world_landmarks"][wrist]]]
    )
    assert np.linalg.norm(filled - x[40:50, wrist], axis=-1).mean() < 0.05  # near where the wrist was, metres


def test_a_bare_list_of_frames_and_one_frame_read(tmp_path, body_take):  # noqa: F811
    x = world_landmarks(body_take)[:30]
    path = tmp_path / "frames.json"
    path.write_text(json.dumps([[{"x": float(a), "y": float(b), "z": float(c)} for a, b, c in frame] for frame in x]))
    (clip,) = read_motion(path, fps=30)
    assert clip.num_frames == 30 and np.isfinite(clip.positions).all()
    path.write_text(json.dumps(points(x[0], np.ones(33))))
    (clip,) = read_motion(path, fps=30)
    assert clip.num_frames == 1


def test_image_landmarks_crowds_and_strangers_are_one_line_errors(tmp_path, body_take):  # noqa: F811
    x = world_landmarks(body_take)[:10]
    image = x * 0.3 + 0.5  # fractions of the picture: the hips near (0.5, 0.5)
    path = tmp_path / "take.json"
    path.write_text(json.dumps([{"frame": t, "landmarks": points(image[t], np.ones(33))} for t in range(10)]))
    with pytest.raises(MotionFileError, match="image landmarks .* save pose_world_landmarks"):
        read_motion(path, fps=30)
    path.write_text(json.dumps([{"pose_landmarks": points(image[t], np.ones(33))} for t in range(10)]))
    with pytest.raises(MotionFileError, match="image landmarks"):
        read_motion(path, fps=30)
    two = [[points(x[t], np.ones(33)), points(x[t], np.ones(33))] for t in range(10)]
    path.write_text(json.dumps(two))
    with pytest.raises(MotionFileError, match="frame 0: 2 people: .* save one person's"):
        read_motion(path, fps=30)
    path.write_text(json.dumps([points(x[t][:17], np.ones(17)) for t in range(10)]))
    with pytest.raises(MotionFileError, match="frame 0: 17 landmarks, not MediaPipe Pose's 33"):
        read_motion(path, fps=30)
    path.write_text(json.dumps([points(x[t], np.ones(33)) for t in range(10)]))
    with pytest.raises(MotionFileError, match="hold no frame rate: give --fps"):
        read_motion(path)
    path.write_text("[" * 100_000)
    with pytest.raises(MotionFileError, match="not readable JSON"):
        read_motion(path, fps=30)
