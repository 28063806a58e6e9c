"""BVH reader/writer and Clip.select_joints, checked against an independent FK written here.

The reference FK below shares nothing with mocapfix: its own token parser, scipy's Euler
conventions (uppercase = intrinsic, so "ZXY" is Rz @ Rx @ Ry, the BVH rule) and a plain loop.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from mocapfix.core.clip import Clip, MotionFileError
from mocapfix.core.kinematics import fk_axis_angle
from mocapfix.core.skeleton import Skeleton
from mocapfix.io.bvh import _frame_rate, read_bvh, write_bvh

CM_Y_UP = np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]]) * 0.01  # file (cm, y up) -> metres, z up: (x, -z, y)


def reference_fk(text: str) -> tuple[list[str], np.ndarray]:
    """BVH text -> joint names, positions (T, J, 3) in the file's units and axes."""
    tok = text.split()
    names, parents, offsets, chans, stack, i = [], [], [], [], [], 0
    while tok[i] != "MOTION":
        t = tok[i]
        if t in ("ROOT", "JOINT"):
            names.append(tok[i + 1])
            parents.append(stack[-1] if stack else -1)
            offsets.append(None)
            chans.append([])
            pending, i = len(names) - 1, i + 2
        elif t == "End":  # End Site
            pending, i = None, i + 2
        elif t == "{":
            stack.append(pending)
            i += 1
        elif t == "}":
            stack.pop()
            i += 1
        elif t == "OFFSET":
            if stack[-1] is not None:
                offsets[stack[-1]] = np.array(tok[i + 1 : i + 4], dtype=float)
            i += 4
        elif t == "CHANNELS":
            n = int(tok[i + 1])
            chans[stack[-1]] = tok[i + 2 : i + 2 + n]
            i += 2 + n
        else:
            i += 1
    n_frames = int(tok[i + 2])
    data = np.array(tok[i + 6 :], dtype=float).reshape(n_frames, -1)
    T, J = n_frames, len(names)
    pos = np.zeros((T, J, 3))
    glob = [None] * J
    col = 0
    for j in range(J):
        trans = np.tile(offsets[j], (T, 1))
        order, angles = "", []
        for c in chans[j]:
            if c.endswith("position"):
                trans[:, "XYZ".index(c[0])] = data[:, col]
            else:
                order += c[0]
                angles.append(data[:, col])
            col += 1
        local = Rotation.from_euler(order, np.stack(angles, 1), degrees=True) if order else Rotation.identity(T)
        if parents[j] < 0:
            pos[:, j], glob[j] = trans, local
        else:
            p = parents[j]
            pos[:, j] = pos[:, p] + glob[p].apply(trans)
            glob[j] = glob[p] * local
    return names, pos


def fk(clip) -> np.ndarray:
    return fk_axis_angle(
        torch.from_numpy(clip.rotations),
        torch.from_numpy(clip.root_translation),
        torch.from_numpy(clip.offsets),
        clip.skeleton.parents,
    ).numpy()


# --- a small file with every channel layout ---


def unusual_bvh(T: int = 9, moving_head: bool = False, seed: int = 0) -> str:
    """Root: 6 channels, positions first then Y X Z rotations; Spine: 3 channels; Head: 6 channels,
    rotations and positions interleaved; LeftUpLeg: one position channel + 3 rotations; LeftFoot:
    one rotation channel. Head translation moves over time only when moving_head."""
    rng = np.random.default_rng(seed)
    hier = """HIERARCHY
ROOT Hips
{
  OFFSET 1 2 3
  CHANNELS 6 Xposition Yposition Zposition Yrotation Xrotation Zrotation
  JOINT Spine
  {
    OFFSET 0 10 0
    CHANNELS 3 Xrotation Zrotation Yrotation
    JOINT Head
    {
      OFFSET 0 20 2
      CHANNELS 6 Zrotation Xposition Yrotation Zposition Xrotation Yposition
      End Site
      {
        OFFSET 0 5 0
      }
    }
  }
  JOINT LeftUpLeg
  {
    OFFSET 9 -5 0
    CHANNELS 4 Yposition Zrotation Xrotation Yrotation
    JOINT LeftFoot
    {
      OFFSET 0 -40 0
      CHANNELS 1 Xrotation
      End Site
      {
        OFFSET 0 0 5
      }
    }
  }
}
"""
    rows = []
    for _ in range(T):
        root = list(rng.uniform(-50, 50, 3)) + list(rng.uniform(-180, 180, 3))
        spine = list(rng.uniform(-90, 90, 3))
        head_t = rng.uniform(-3, 3, 3) if moving_head else np.array([0.5, 21.0, 1.5])
        head = [rng.uniform(-90, 90), head_t[0], rng.uniform(-90, 90), head_t[2], rng.uniform(-90, 90), head_t[1]]
        leg = [-6.0] + list(rng.uniform(-120, 120, 3))
        foot = [rng.uniform(0, 150)]
        rows.append(" ".join(f"{v:.6f}" for v in root + spine + head + leg + foot))
    return hier + f"MOTION\nFrames: {T}\nFrame Time: 0.04\n" + "\n".join(rows) + "\n"


def test_unusual_channels_match_reference_fk(tmp_path):
    text = unusual_bvh()
    f = tmp_path / "odd.bvh"
    f.write_text(text)
    names, ref = reference_fk(text)
    clip = read_bvh(f, unit="cm", up_axis="y")[0]
    assert clip.skeleton.joint_names == ("Hips", "Spine", "Head", "LeftUpLeg", "LeftFoot")  # End Sites are no joints
    assert clip.skeleton.parents == (-1, 0, 1, 0, 3)
    assert clip.fps == pytest.approx(25.0) and clip.name == "odd" and clip.source == str(f)
    assert clip.meta == {"format": "bvh", "unit": "cm", "unit_source": "option", "up_axis": "y", "frame_time": 0.04}
    np.testing.assert_allclose(clip.positions, ref @ CM_Y_UP.T, atol=1e-5)
    # metres, z up: the same numbers
    raw = read_bvh(f, unit="m", up_axis="z")[0]
    np.testing.assert_allclose(raw.positions, ref, rtol=1e-6, atol=1e-4)
    # position channels replace the OFFSET components they name (Head, LeftUpLeg's y)
    head = clip.positions[:, 2] - clip.positions[:, 1]
    assert np.allclose(np.linalg.norm(head, axis=-1), np.linalg.norm([0.5, 21.0, 1.5]) * 0.01, atol=1e-6)
    # constant translations below the root: rotations reproduce the positions
    assert clip.has_rotations and clip.rotations.dtype == np.float32
    assert np.abs(fk(clip) - clip.positions).max() < 1e-5
    np.testing.assert_allclose(clip.offsets[3], np.array([9.0, -6.0, 0.0]) @ CM_Y_UP.T, atol=1e-6)


def test_moving_translation_below_root_gives_no_rotations(tmp_path):
    text = unusual_bvh(moving_head=True)
    f = tmp_path / "moving.bvh"
    f.write_text(text)
    clip = read_bvh(f, unit="cm", up_axis="y")[0]
    np.testing.assert_allclose(clip.positions, reference_fk(text)[1] @ CM_Y_UP.T, atol=1e-5)
    assert not clip.has_rotations and "Head" in clip.meta["no_rotations"]
    # dropping the moving joint (a leaf) leaves a rigid tree: rotations come back, exact
    kept = read_bvh(f, unit="cm", up_axis="y", drop_joints=["Head"])[0]
    assert kept.skeleton.joint_names == ("Hips", "Spine", "LeftUpLeg", "LeftFoot")
    assert kept.has_rotations and np.abs(fk(kept) - kept.positions).max() < 1e-5
    np.testing.assert_allclose(kept.positions, clip.positions[:, [0, 1, 3, 4]], atol=1e-7)


def test_write_round_trip_and_template(tmp_path):
    f = tmp_path / "odd.bvh"
    f.write_text(unusual_bvh())
    clip = read_bvh(f, unit="cm", up_axis="y")[0]
    out = tmp_path / "out.bvh"
    write_bvh(out, clip, template=f)
    back = read_bvh(out, unit="cm", up_axis="y")[0]  # random poses: nothing to guess the up axis from
    assert back.skeleton.joint_names == clip.skeleton.joint_names and back.fps == pytest.approx(clip.fps)
    assert np.abs(back.positions - clip.positions).max() < 1e-4
    text = out.read_text()
    assert "OFFSET 0.000000 5.000000 0.000000" in text  # the template's End Site under Head
    assert sorted(p.name for p in tmp_path.iterdir()) == ["odd.bvh", "out.bvh"]  # no temp file left
    # a clip without rotations cannot be written; the old file stays as it was
    with pytest.raises(MotionFileError):
        write_bvh(out, clip.replace(rotations=None))
    assert out.read_text() == text
    write_bvh(tmp_path / "new" / "folder" / "out.bvh", clip, template=f)  # folders made as needed
    assert (tmp_path / "new" / "folder" / "out.bvh").read_text() == text


@pytest.mark.parametrize(
    "text, fps",
    [
        ("0.0333333", 30.0),
        ("0.033333333", 30.0),
        ("0.008333", 120.0),
        ("0.0333667", 29.97),
        ("0.041708", 23.976),
        ("3.33333e-02", 30.0),
        ("0.0123456789", 1 / 0.0123456789),
    ],
)
def test_frame_rate_is_the_roundest_that_prints_as_the_frame_time(text, fps):
    # 1 / 0.0333333 is 30.00003: the file means 30, and 30 spares every clip a resampling
    assert _frame_rate(text) == pytest.approx(fps, rel=1e-12)


def test_crlf_and_non_finite_values(tmp_path):
    text = unusual_bvh()
    f = tmp_path / "crlf.bvh"
    f.write_bytes(text.replace("\n", "\r\n").encode())
    ref = reference_fk(text)[1] @ CM_Y_UP.T
    np.testing.assert_allclose(read_bvh(f, unit="cm", up_axis="y")[0].positions, ref, atol=1e-5)
    # a non-finite channel (Spine's first rotation, frame 2) makes the joints below Spine (Head)
    # missing in that frame, nothing else; such a clip has no rotations
    lines = text.split("\n")
    row = lines.index("Frame Time: 0.04") + 3
    vals = lines[row].split()
    vals[6] = "inf"  # (nan reads the same; inf is the one numpy warns about)
    lines[row] = " ".join(vals)
    f.write_text("\n".join(lines))
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)  # missing joints are data: no numpy warnings either
        clip = read_bvh(f, unit="cm", up_axis="y")[0]
    missing = clip.missing_mask()
    assert missing[2].tolist() == [False, False, True, False, False] and missing.sum() == 1
    np.testing.assert_allclose(clip.positions[~missing], ref[~missing], atol=1e-5)
    assert not clip.has_rotations and "non-finite" in clip.meta["no_rotations"]


def test_groups_explicit_and_guessed(tmp_path):
    f = tmp_path / "odd.bvh"
    f.write_text(unusual_bvh())
    assert read_bvh(f, unit="cm", up_axis="y")[0].skeleton.groups == {"left_leg": (3, 4)}
    clip = read_bvh(f, unit="cm", up_axis="y", groups={"left_leg": ["LeftFoot"], "head": [2]})[0]
    assert clip.skeleton.groups == {"left_leg": (4,), "head": (2,)}
    with pytest.raises(MotionFileError, match="bad groups"):
        read_bvh(f, unit="cm", up_axis="y", groups={"left_leg": ["Tail"]})


# --- errors: one line, naming the file ---


def _error_cases() -> dict[str, tuple[str | None, str]]:
    text = unusual_bvh(T=5)
    hier, motion = text.split("MOTION\n")
    rows = motion.strip().split("\n")[2:]
    header = "MOTION\nFrames: 5\nFrame Time: 0.04\n"
    extra = rows[:2] + [rows[2] + " 1.0"] + rows[3:]
    word = rows[:1] + [rows[1].replace(rows[1].split()[3], "abc", 1)] + rows[2:]
    return {
        "missing": (None, "not found"),
        "empty": ("", "empty"),
        "blank": ("  \n\n", "empty"),
        "no_hierarchy": (header + "\n".join(rows), "HIERARCHY"),
        "no_motion": (hier, "MOTION"),
        "fewer_rows": (hier + header + "\n".join(rows[:3]) + "\n", "truncated"),
        "partial_last_row": (hier + header + "\n".join(rows[:4]) + "\n" + rows[4][:20], "truncated"),
        "wrong_columns": (hier + header + "\n".join(extra), "expected 20 values, got 21"),
        "non_numeric": (hier + header + "\n".join(word), "non-numeric value"),
        "extra_rows": (hier + header + "\n".join(rows + rows[:1]), "6 frame rows"),
        "no_frames_line": (hier + header.replace("Frames: 5\n", "") + "\n".join(rows), "Frames:"),
        "zero_frame_time": (hier + header.replace("0.04", "0") + "\n".join(rows), "Frame Time"),
        "no_frame_time": (hier + header.replace("Frame Time: 0.04\n", "") + "\n".join(rows), "Frame Time"),
        "bad_channel": (
            hier.replace("Xrotation Zrotation Yrotation", "Xrotation Zrotation Wrotation") + header + "\n".join(rows),
            "is not one of Xposition",  # the line's number, not its text
        ),
        "unbalanced": (hier.rstrip().rstrip("}") + header + "\n".join(rows), "HIERARCHY"),
    }


@pytest.mark.parametrize("case", sorted(_error_cases()))
def test_bad_files_raise_one_line(tmp_path, case):
    content, expect = _error_cases()[case]
    f = tmp_path / f"bad_{case}.bvh"
    if content is not None:
        f.write_text(content)
    with pytest.raises(MotionFileError) as e:
        read_bvh(f, unit="cm", up_axis="y")
    msg = str(e.value)
    assert "\n" not in msg and f.name in msg and expect in msg, msg


def test_wrong_column_count_names_the_line(tmp_path):
    f = tmp_path / "cols.bvh"
    f.write_text(_error_cases()["wrong_columns"][0])
    lines = f.read_text().split("\n")
    bad_line = next(i for i, ln in enumerate(lines, 1) if len(ln.split()) == 21)
    with pytest.raises(MotionFileError, match=rf"line {bad_line} \(frame 2\)"):
        read_bvh(f, unit="cm", up_axis="y")


# --- the real data ---


def test_bandai_reference_fk(bandai_files):
    # 4 clips across both parts of the set, and one whose joint_Root moves
    for f in bandai_files[::120] + [f for f in bandai_files if f.name == "dataset-1_dash_normal_001.bvh"]:
        text = f.read_text()
        names, ref = reference_fk(text)
        clip = read_bvh(f, keep_joints=names)[0]
        assert clip.skeleton.joint_names == tuple(names) and len(names) == 22
        np.testing.assert_allclose(clip.positions, ref @ CM_Y_UP.T, atol=1e-5)
        # with joint_Root kept, Hips' moving translation has no constant offset: no rotations
        assert not clip.has_rotations and "joint_Root" in clip.meta["no_rotations"]
        rerooted = read_bvh(f, drop_joints=["joint_Root"])[0]
        np.testing.assert_allclose(rerooted.positions, clip.positions[:, 1:], atol=1e-6)
        # joint_Root is a helper (one child, a rotation that never changes): dropped unasked
        default = read_bvh(f)[0]
        assert default.meta["dropped_root"] == "joint_Root" and default.has_rotations
        np.testing.assert_array_equal(default.positions, rerooted.positions)
        np.testing.assert_array_equal(default.rotations, rerooted.rotations)


@pytest.mark.slow  # minutes of CPU; `make test-all` runs it
def test_every_bandai_clip(bandai_files):
    """Batch over all 384 clips: geometry, guessed units, rotations, re-rooting."""
    assert len(bandai_files) == 384
    hips_heights, clips = [], []
    for f in bandai_files:
        clip = read_bvh(f, drop_joints=["joint_Root"])[0]
        sk = clip.skeleton
        assert clip.meta["unit"] == "cm" and clip.meta["up_axis"] == "y", f.name
        assert clip.fps == pytest.approx(30.0, rel=1e-4) and sk.num_joints == 21 and sk.joint_names[0] == "Hips"
        assert set(sk.groups) == {"left_arm", "right_arm", "left_leg", "right_leg"}
        p = clip.positions.astype(np.float64)
        bones = np.linalg.norm(p[:, [c for _, c in sk.limbs]] - p[:, [q for q, _ in sk.limbs]], axis=-1)  # (T, B)
        assert np.abs(bones - bones.mean(0)).max() < 1e-4, f.name
        hips_heights.append(p[:, sk.index("Hips"), 2].mean())
        feet = [j for j, n in enumerate(sk.joint_names) if n.startswith(("Foot", "Toes"))]
        assert -0.05 < p[:, feet, 2].min() < 0.15, f.name
        assert clip.has_rotations, f.name
        clips.append(clip)
    # one FK call for all frames of all clips (per-frame offsets), checked per clip
    lengths = [c.num_frames for c in clips]
    pos = fk_axis_angle(
        torch.from_numpy(np.concatenate([c.rotations for c in clips])),
        torch.from_numpy(np.concatenate([c.root_translation for c in clips])),
        torch.from_numpy(np.concatenate([np.broadcast_to(c.offsets, c.positions.shape) for c in clips])),
        clips[0].skeleton.parents,
    ).numpy()
    for c, p in zip(clips, np.split(pos, np.cumsum(lengths)[:-1])):
        assert np.abs(p - c.positions).max() < 1e-5, c.name
    hips_heights = np.array(hips_heights)
    # standing, walking, running actors: the pelvis sits 0.83-0.95 m up (running lowers it)
    assert 0.8 < hips_heights.min() and hips_heights.max() < 1.05 and 0.85 < np.median(hips_heights) < 1.0


def test_bandai_select_joints(bandai_files):
    clip = read_bvh(bandai_files[7], drop_joints=["joint_Root"])[0]
    names = clip.skeleton.joint_names
    # dropping leaves (toes, head) keeps exact rotations on the smaller tree
    keep = [j for j, n in enumerate(names) if not n.startswith(("Toes", "Head"))]
    sub = clip.select_joints(keep)
    assert sub.skeleton.joint_names == tuple(names[j] for j in keep)
    np.testing.assert_array_equal(sub.positions, clip.positions[:, keep])
    assert sub.has_rotations and np.abs(fk(sub) - sub.positions).max() < 1e-5
    leg = {sub.skeleton.index(n) for n in ("UpperLeg_L", "LowerLeg_L", "Foot_L")}
    assert set(sub.skeleton.groups["left_leg"]) == leg
    # dropping a joint that bends (Spine) leaves no constant offset Hips -> Chest: no rotations
    bent = clip.select_joints([j for j, n in enumerate(names) if n != "Spine"])
    assert not bent.has_rotations and bent.skeleton.parents[bent.skeleton.index("Chest")] == 0
    np.testing.assert_array_equal(bent.positions, clip.positions[:, [j for j, n in enumerate(names) if n != "Spine"]])
    # keep_joints in the reader = select_joints after it
    kept = read_bvh(bandai_files[7], keep_joints=[names[j] for j in keep])[0]
    np.testing.assert_allclose(kept.positions, sub.positions, atol=1e-6)
    assert kept.has_rotations and np.abs(fk(kept) - kept.positions).max() < 1e-5


def test_bandai_write_round_trip(bandai_files, tmp_path):
    for f in bandai_files[5::125]:
        clip = read_bvh(f, drop_joints=["joint_Root"])[0]
        out = tmp_path / f.name
        write_bvh(out, clip, template=f)
        back = read_bvh(out)[0]
        assert back.meta["unit"] == "cm" and back.meta["up_axis"] == "y"
        assert back.skeleton.joint_names == clip.skeleton.joint_names
        assert np.abs(back.positions - clip.positions).max() < 1e-4, f.name
        assert back.has_rotations and np.abs(fk(back) - back.positions).max() < 1e-5


@pytest.mark.parametrize("unit,up", [("m", "z"), ("mm", "y"), ("inch", "z")])
def test_unit_and_up_axis_guessed(bandai_files, tmp_path, unit, up):
    clip = read_bvh(bandai_files[3], drop_joints=["joint_Root"])[0]
    out = tmp_path / "converted.bvh"
    write_bvh(out, clip.replace(meta={**clip.meta, "unit": unit, "up_axis": up}))
    back = read_bvh(out)[0]
    assert (back.meta["unit"], back.meta["up_axis"]) == (unit, up)
    assert np.abs(back.positions - clip.positions).max() < 1e-4


def test_write_bvh_writes_channels_in_the_order_its_hierarchy_lists_joints(tmp_path):
    # Joints breadth first (root; A, B under it; C under A, D under B, E under C): the hierarchy
    # lists them depth first, 0 1 3 5 2 4, and a frame's channels must follow that order, or B's
    # rotation turns C's bone and C's turns B's.
    names, parents = ("Root", "A", "B", "C", "D", "E"), (-1, 0, 0, 1, 2, 3)
    offsets = np.array([[0, 0, 0], [0.1, 0, 0], [-0.1, 0, 0], [0, 0, 0.3], [0, 0, 0.3], [0, 0.2, 0]], dtype=np.float32)
    rng = np.random.default_rng(0)
    rotations = rng.uniform(-1, 1, (5, 6, 3)).astype(np.float32)
    root = rng.uniform(-1, 1, (5, 3)).astype(np.float32)
    positions = fk_axis_angle(
        torch.from_numpy(rotations).double(),
        torch.from_numpy(root).double(),
        torch.from_numpy(offsets).double(),
        list(parents),
    ).numpy()
    clip = Clip(positions, 30.0, Skeleton(names, parents), rotations=rotations, root_translation=root, offsets=offsets)
    write_bvh(tmp_path / "out.bvh", clip)
    back = read_bvh(tmp_path / "out.bvh", unit="m", up_axis="z")[0]
    order = [back.skeleton.joint_names.index(n) for n in names]
    assert np.abs(back.positions[:, order] - positions).max() < 1e-5
