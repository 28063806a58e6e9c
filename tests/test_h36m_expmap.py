"""Human3.6M as exponential maps (io/h36m_expmap.py): files built here in the published layout
(99 numbers a line, root deltas then one map per joint of the 32-joint tree)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from mocapfix.core.clip import MotionFileError
from mocapfix.io import detect_source, list_motion_files, read_motion
from mocapfix.io.h36m import H36M_KEEP
from mocapfix.io.h36m_expmap import OFFSETS_MM, PARENTS


def _write(path: Path, channels: np.ndarray) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(",".join(f"{v:.7f}" for v in row) for row in channels) + "\n")
    return path


def _walk(frames: int = 120, step_mm: float = 10.0, tilt_rad: float = 0.0) -> np.ndarray:
    """(frames, 99): the rest pose walking along its own z (forward), the pelvis tilted by
    tilt_rad about x in the first frame (as the files lose the first frame's orientation)."""
    ch = np.zeros((frames, 99))
    ch[:, 2] = step_mm
    ch[0, 2] = 0.0
    ch[0, 3] = tilt_rad
    return ch


def test_rest_pose_has_the_skeletons_bones_upright_left_at_left(tmp_path):
    clip = read_motion(_write(tmp_path / "S1" / "posing_1.txt", _walk(60, 0.0)))[0]
    x = clip.positions.astype(np.float64)  # (T, 17, 3) metres, z up
    assert clip.skeleton.name == "h36m17" and clip.fps == 50.0 and x.shape == (60, 17, 3)
    assert clip.meta["subject"] == "S1" and clip.meta["action"] == "posing" and clip.meta["split"] == "train"
    names = clip.skeleton.joint_names
    at = {n: x[0, names.index(n)] for n in names}
    offsets = np.linalg.norm(np.asarray(OFFSETS_MM), axis=1) / 1000.0
    assert np.linalg.norm(at["RHip"] - at["Hip"]) == pytest.approx(offsets[1], abs=1e-6)
    assert np.linalg.norm(at["RKnee"] - at["RHip"]) == pytest.approx(offsets[2], abs=1e-6)
    assert np.linalg.norm(at["LFoot"] - at["LKnee"]) == pytest.approx(offsets[8], abs=1e-6)
    assert at["Head"][2] > at["Thorax"][2] > at["Hip"][2] > at["LKnee"][2] > at["LFoot"][2]
    assert at["LHip"][0] > at["Hip"][0] > at["RHip"][0]  # the file's left (+x) stays +x
    assert abs(at["LFoot"][2]) < 1e-6  # the ankles' floor at height 0


def test_the_root_path_is_integrated_and_a_tilted_first_frame_is_stood_up_on_its_floor(tmp_path):
    """A take whose first frame's pelvis is tilted 20 degrees walks uphill as integrated; the
    reader finds the floor from the ankles and stands it up: the hips stay at one height."""
    level = read_motion(_write(tmp_path / "S9" / "walking_1.txt", _walk()))[0].positions.astype(np.float64)
    tilted = read_motion(_write(tmp_path / "S9" / "walking_2.txt", _walk(tilt_rad=0.35)))[0]
    assert tilted.meta["split"] == "test" and tilted.name == "S9/walking 2"
    x = tilted.positions.astype(np.float64)
    for take in (level, x):
        step = np.linalg.norm(np.diff(take[:, 0], axis=0), axis=-1)
        assert np.allclose(step, 0.010, atol=1e-6)  # 10 mm a frame
        assert np.ptp(take[:, 0, 2]) < 1e-4  # level: no climb
    assert np.allclose(x[:, :, 2], level[:, :, 2], atol=1e-4)  # the same body, upright


def test_a_joint_whose_ancestors_rotation_is_not_a_number_is_missing_there(tmp_path):
    ch = _walk(20)
    ch[5, 3 + 3 * 17 : 6 + 3 * 17] = np.nan  # the 32-joint tree's 17: the left shoulder's rotation
    clip = read_motion(_write(tmp_path / "S1" / "eating_1.txt", ch))[0]
    missing = ~np.isfinite(clip.positions).all(-1)
    names = clip.skeleton.joint_names
    assert {names[j] for j in np.flatnonzero(missing[5])} == {"LElbow", "LWrist"}
    assert missing.sum() == 2
    assert H36M_KEEP[names.index("LShoulder")] == 17 and PARENTS[18] == 17


@pytest.mark.parametrize(
    "text, message",
    [
        ("1,2,3\n", "line 1 has 3 comma-separated values"),
        (",".join(["0"] * 99) + "\n" + ",".join(["x"] * 99) + "\n", "line 2: not numbers"),
        (",".join(["nan"] + ["0"] * 98) + "\n", "line 1: the root's motion is not a number"),
        ("\n\n", "empty file"),
    ],
)
def test_a_file_that_is_not_exponential_maps_is_one_line_naming_it(tmp_path, text, message):
    path = tmp_path / "S1" / "bad_1.txt"
    path.parent.mkdir()
    path.write_text(text)
    with pytest.raises(MotionFileError, match=message) as e:
        read_motion(path)
    assert str(path) in str(e.value) and "\n" not in str(e.value)


def test_txt_files_are_listed_for_h36m_only_and_read_when_named(tmp_path):
    take = _write(tmp_path / "S11" / "walking_1.txt", _walk(10))
    (tmp_path / "README.txt").write_text("notes")
    assert detect_source(take) == "h36m"
    assert list_motion_files(tmp_path, "h36m") == [tmp_path / "README.txt", take]
    assert list_motion_files(tmp_path, "auto") == []  # a folder of takes with notes beside them
