"""Azure Kinect body tracking JSON (io/azure_kinect.py): depth-camera axes and millimetres, each
body ID a person, the frames on the camera's clock, and fix's output the file's own structure."""

from __future__ import annotations

import json

import numpy as np
import pytest
from cli_utils import run_mocapfix
from test_keypoints import body_take, in_layout  # noqa: F401  (body_take: the fixture)

from mocapfix.core.clip import MotionFileError
from mocapfix.io import read_motion
from mocapfix.io.layouts import LAYOUTS

NAMES = list(LAYOUTS["azure32"].joint_names)


def camera_mm(x: np.ndarray) -> np.ndarray:
    """(T, 32, 3) metres, z up -> the depth camera's mm: x right, y down, z away (the person 3 m off)."""
    return np.stack([x[..., 0], -x[..., 2] + 1.0, x[..., 1] + 3.0], axis=-1) * 1000.0


def document(bodies: dict[int, np.ndarray], frames: list[int]) -> dict:
    """bodies: id -> (T, 32, 3) mm per camera frame index (NaN rows: absent); frames: the frame
    indices written (a gap: a frame the processor dropped)."""
    out = []
    for i in frames:
        present = [
            {"body_id": k, "joint_positions": x[i].tolist(), "joint_orientations": [[1.0, 0.0, 0.0, 0.0]] * 32}
            for k, x in bodies.items()
            if np.isfinite(x[i]).all()
        ]
        out.append({"frame_id": i, "timestamp_usec": 33333 * i + 500, "num_bodies": len(present), "bodies": present})
    return {"joint_names": NAMES, "bone_list": [], "frames": out, "k4abt_sdk_version": "1.1.2"}


def test_two_bodies_a_dropped_frame_and_fix_in_the_files_structure(tmp_path, body_take, capsys):  # noqa: F811
    a = camera_mm(in_layout("azure32", body_take)[:90])
    b = a + np.array([800.0, 0.0, 400.0])
    b[:30] = np.nan  # the second person walks in at frame 30
    frames = [i for i in range(90) if i not in (50, 51)]  # two frames dropped
    path = tmp_path / "take.json"
    path.write_text(json.dumps(document({1: a, 2: b}, frames)))
    clips = read_motion(path)
    assert [c.meta["person_id"] for c in clips] == ["1", "2"]
    first = clips[0]
    assert first.fps == 30.0 and first.num_frames == 90 and first.meta["unit"] == "mm"
    assert np.isnan(first.positions[50:52]).all() and np.isfinite(first.positions[52:]).all()
    head = first.skeleton.index("HEAD")
    assert (first.positions[:, head, 2] > first.positions[:, first.skeleton.index("PELVIS"), 2])[:50].all()  # up is up
    rc, out, err = run_mocapfix(["fix", path, "--model", "xmae-cpu-bandai"], capsys)
    assert rc == 0, err
    back = json.loads((tmp_path / "take.fixed.json").read_text())
    sent = json.loads(path.read_text())
    assert back["joint_names"] == NAMES and [f["frame_id"] for f in back["frames"]] == frames
    for f_back, f_sent in zip(back["frames"], sent["frames"]):  # nothing observed was moved
        for b_back, b_sent in zip(f_back["bodies"], f_sent["bodies"]):
            np.testing.assert_allclose(b_back["joint_positions"], b_sent["joint_positions"], atol=1e-6)
    # the jitter remover moves every position: each written back in the camera's axes and mm
    args = ["fix", path, "--model", "jitter-many", "--mode", "denoise", "--force"]
    rc, out, err = run_mocapfix(args, capsys)
    assert rc == 0, err
    back = json.loads((tmp_path / "take.fixed.json").read_text())
    moved = [
        np.linalg.norm(np.subtract(b_back["joint_positions"], b_sent["joint_positions"]), axis=-1)
        for f_back, f_sent in zip(back["frames"], sent["frames"])
        for b_back, b_sent in zip(f_back["bodies"], f_sent["bodies"])
    ]
    assert 0.01 < np.mean(moved) < 20.0  # mm: moved, and by a jitter remover's amount on a clean take


def test_a_file_that_is_not_body_tracking_is_one_line(tmp_path):
    (tmp_path / "other.json").write_text(json.dumps({"hello": 1}))
    with pytest.raises(MotionFileError, match="no 'frames' list"):
        read_motion(tmp_path / "other.json")
    (tmp_path / "empty.json").write_text(json.dumps({"frames": [{"bodies": []}] * 3}))
    with pytest.raises(MotionFileError, match="3 frames and no body in any"):
        read_motion(tmp_path / "empty.json")
