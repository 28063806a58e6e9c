"""Untrusted input: files and options as a careless user or an attacker would hand them over.

No data file runs code (pickles in .npz members and body models), two runs never race for one
output, takes too short to judge keep what was observed, jumps of metres are found, and every
broken number or file is one line naming it, quickly and without a large allocation. Real motion:
Bandai Namco BVH clips (../shared/data) and the shipped model (no training here)."""

from __future__ import annotations

import os
import pickle
import subprocess
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
from cli_utils import run_mocapfix as run

from mocapfix.apps.main import main
from mocapfix.core.clip import MotionFileError
from mocapfix.io import list_motion_files, read_motion
from mocapfix.io.bvh import read_bvh
from mocapfix.io.files import claimed
from mocapfix.io.positions import write_positions

BANDAI_FILE = "dataset-1_bow_active_001.bvh"  # 128 frames at 30 fps; Hips has position channels 6-8
HIPS_X = 6


def one_error_line(err: str, name) -> None:
    assert err.count("\n") == 1 and err.startswith("error: ") and str(name) in err and "Traceback" not in err, err


@pytest.fixture(scope="module")
def bandai(bandai_files) -> Path:
    return {f.name: f for f in bandai_files}[BANDAI_FILE]


def bvh_with(src: Path, dst: Path, frames: int | None = None, edit=None, header=None) -> Path:
    """A copy of a BVH: its first `frames` frames, rows changed by edit(data (T, C)), header lines
    (Frames / Frame Time) replaced by header(text)."""
    text = src.read_text()
    head, motion = text.split("MOTION", 1)
    lines = motion.strip().splitlines()
    rows = np.array([[float(v) for v in ln.split()] for ln in lines[2:]])
    rows = rows[:frames] if frames else rows
    if edit is not None:
        edit(rows)
    frame_time = lines[1].split(":", 1)[1].strip()
    top = f"MOTION\nFrames: {len(rows)}\nFrame Time: {frame_time}\n"
    if header is not None:
        top = header(top)
    dst.write_text(head + top + "\n".join(" ".join(f"{v:.6f}" for v in r) for r in rows) + "\n")
    return dst


# --- no code runs from a data file ---


class _Payload:
    def __init__(self, marker: Path):
        self.marker = str(marker)

    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))


def _payload_npz(path: Path, marker: Path, key: str, **others) -> Path:
    obj = np.empty((), dtype=object)
    obj[()] = _Payload(marker)
    np.savez(path, **{key: obj}, **others)
    return path


@pytest.mark.parametrize(
    "key,others,source",
    [
        ("positions_3d", {}, "auto"),  # VideoPose3D's key: read through the restricted unpickler
        ("positions_3d", {}, "h36m"),
        ("positions", {"fps": 30.0}, "auto"),
        ("positions", {"fps": 30.0}, "positions"),
        ("gender", {"poses": np.zeros((4, 156)), "trans": np.zeros((4, 3)), "mocap_framerate": 30.0}, "amass"),
        ("poses", {"trans": np.zeros((4, 3)), "mocap_framerate": 30.0}, "amass"),
    ],
)
def test_a_pickle_in_an_npz_runs_no_code_in_any_command(tmp_path, capsys, key, others, source):
    marker = tmp_path / "PWNED"
    f = _payload_npz(tmp_path / "x.npz", marker, key, **others)
    model = tmp_path / "SMPLH_MALE.pkl"
    with open(model, "wb") as fh:  # a body model that is a payload too (AMASS reads it when given)
        pickle.dump({"v_template": _Payload(marker)}, fh)
    read = ["--source", source, "--body-model", model]
    for args in (
        ["inspect", f, *read],
        ["fix", f, "--model", "xmae-cpu-bandai", "-o", tmp_path / "out.npz", *read],
        ["render", f, "-o", tmp_path / "x.gif", *read],
    ):
        rc, out, err = run(args, capsys)
        assert rc == 1 and not marker.exists(), (args, err)
        one_error_line(err, "x.npz")
    assert not (tmp_path / "out.npz").exists()


def test_a_pickled_body_model_runs_no_code_and_says_why(tmp_path):
    from mocapfix.io.amass import load_body_model

    marker = tmp_path / "PWNED"
    model = tmp_path / "SMPLH_MALE.pkl"
    with open(model, "wb") as fh:
        pickle.dump({"v_template": _Payload(marker)}, fh, protocol=2)
    with pytest.raises(MotionFileError, match="refused, nothing was run") as e:
        load_body_model(model)
    assert not marker.exists() and "system" in str(e.value)


def test_public_object_arrays_still_read_without_pickle(tmp_path):
    """VideoPose3D's dict and a pickled AMASS gender string are data, read by the restricted unpickler."""
    from mocapfix.io.npz import npz_object

    tree = {"S1": {"Walking 1": np.random.default_rng(0).normal(size=(5, 32, 3)).astype(np.float32)}}
    np.savez(tmp_path / "h.npz", positions_3d=np.array(tree, dtype=object))
    [clip] = read_motion(tmp_path / "h.npz")
    assert clip.positions.shape == (5, 17, 3) and clip.meta["subject"] == "S1"
    np.savez(tmp_path / "g.npz", gender=np.array("female", dtype=object))
    assert npz_object(tmp_path / "g.npz", "gender").item() == "female"


# --- outputs: one run per path, nothing lost ---


def test_an_output_held_by_another_run_is_one_line_and_left_alone(tmp_path, bandai, capsys):
    f = bvh_with(bandai, tmp_path / "a.bvh", 60)
    out = tmp_path / "same.bvh"
    with claimed(out):
        rc, _, err = run(["fix", f, "--model", "xmae-cpu-bandai", "-o", out], capsys)
    assert rc == 1 and "is being written by another run" in err and not out.exists()
    one_error_line(err, out)
    rc, _, err = run(["fix", f, "--model", "xmae-cpu-bandai", "-o", out], capsys)  # the claim is gone
    assert rc == 0 and out.exists(), err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.bvh", "same.bvh"]  # no lock or staged file left


def test_two_concurrent_fix_runs_to_one_output_one_wins_whole(tmp_path, bandai):
    a = bvh_with(bandai, tmp_path / "a.bvh", 90)

    def walk_on(rows):  # another take: the same motion 50 cm along
        rows[:, HIPS_X] += 50.0

    b = bvh_with(bandai, tmp_path / "b.bvh", 90, edit=walk_on)
    out = tmp_path / "same.bvh"
    cmd = [sys.executable, "-m", "mocapfix", "fix", "--model", "xmae-cpu-bandai", "-o", str(out)]
    procs = [subprocess.Popen([*cmd[:4], str(x), *cmd[4:]], stderr=subprocess.PIPE, text=True) for x in (a, b)]
    results = [(p.wait(timeout=300), p.stderr.read()) for p in procs]
    codes = sorted(rc for rc, _ in results)
    assert codes == [0, 1], results
    winner, (_, loser_err) = (a, b)[[rc for rc, _ in results].index(0)], [r for r in results if r[0] == 1][0]
    assert loser_err.count("\n") == 1 and str(out) in loser_err, loser_err
    assert "another run" in loser_err or "exists" in loser_err
    # the file is the winner's whole output: the same as fixing the winner alone
    alone = tmp_path / "alone.bvh"
    subprocess.run([*cmd[:4], str(winner), *cmd[4:6], "-o", str(alone)], check=True, capture_output=True)
    assert out.read_bytes() == alone.read_bytes()


# --- takes too short to judge; jumps of metres ---


@pytest.mark.parametrize("frames", [1, 2])
@pytest.mark.parametrize("model", ["xmae-cpu-bandai", "motion-dvae-bandai", "jitter-many"])
def test_a_take_shorter_than_the_window_keeps_every_observed_token(tmp_path, bandai, capsys, frames, model):
    f = bvh_with(bandai, tmp_path / "short.bvh", frames)
    mode = "both" if model.startswith("xmae") else "denoise"
    rc, out, err = run(["fix", f, "--model", model, "--mode", mode, "-o", tmp_path / "out.bvh"], capsys)
    assert rc == 0, err
    assert "observed tokens kept, not judged" in out and "never observed" not in out
    before, after = read_bvh(f)[0], read_bvh(tmp_path / "out.bvh")[0]
    assert np.abs(after.positions - before.positions).max() < 1e-4  # metres; the BVH's 6 decimals


@pytest.mark.parametrize("mode", ["infill", "both", "denoise"])
def test_a_root_jump_of_1000_m_for_half_a_second_is_found_in_every_mode(tmp_path, bandai, capsys, mode):
    def jump(rows):
        rows[40:55, HIPS_X] += 100_000.0  # cm: 1,000 m, 15 frames at 30 fps

    f = bvh_with(bandai, tmp_path / "jump.bvh", edit=jump)
    truth = read_bvh(bandai)[0].positions
    rc, out, err = run(["fix", f, "--model", "xmae-cpu-bandai", "--mode", mode, "-o", tmp_path / "o.npz"], capsys)
    assert rc == 0, err
    assert "tokens no body could take" in out and "Hips" in out
    with np.load(tmp_path / "o.npz") as z:
        fixed = z["positions"]  # the file's own unit and axes: compare through the reader
    assert fixed.shape[0] == truth.shape[0]
    [back] = read_motion(tmp_path / "o.npz")
    err_m = np.linalg.norm(back.positions - truth, axis=-1)
    assert np.nanmax(err_m) < 0.5  # metres: no token kept the jump (denoise leaves the holes missing)
    if mode != "denoise":
        assert np.isfinite(back.positions).all()


def test_a_single_joint_jump_of_metres_is_missing_on_reading(tmp_path, bandai):
    clip = read_bvh(bandai, drop_joints=["joint_Root"])[0]
    pos = clip.positions.copy()
    hand = clip.skeleton.joint_names.index("Hand_L")
    pos[60:64, hand] += np.array([0.0, 3.0, 0.0], dtype=np.float32)  # 3 m for 4 frames
    write_positions(tmp_path / "p.npz", pos, clip.fps, clip.skeleton)
    [back] = read_motion(tmp_path / "p.npz")
    missing = np.isnan(back.positions).any(-1)
    assert missing[60:64, hand].all() and missing.sum() == 4
    assert back.meta["absurd_joints"] == ["Hand_L"]


def test_the_body_centre_is_numpys_nanmedian_bit_for_bit():
    """The jump test's per-frame centre (io/absurd.py) is one sort, not nanmedian's per-frame
    masking: it must give nanmedian's very numbers, missing joints, even and odd counts and
    frames with nothing seen included."""
    import warnings

    from mocapfix.io.absurd import _median_over_joints

    rng = np.random.default_rng(0)
    for _ in range(200):
        T, J = int(rng.integers(1, 40)), int(rng.integers(1, 25))
        values = rng.normal(size=(T, J, 3)) * 10.0 ** rng.integers(-3, 3)
        values[rng.random((T, J)) < rng.random()] = np.nan
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # frames with nothing seen
            expected = np.nanmedian(values, axis=1)
        assert np.array_equal(_median_over_joints(values), expected, equal_nan=True)


def test_real_takes_lose_no_token_to_the_jump_test(bandai_files):
    """A fast take (dance, punches) is motion, not jumps: every 10th Bandai file, nothing flagged."""
    for f in bandai_files[::10]:
        assert read_motion(f)[0].meta["absurd_tokens"] == 0, f.name


# --- numbers a file or an option gives ---


@pytest.mark.parametrize("frame_time", ["1e6", "1e-300", "nan", "inf", "0.5e-5"])
def test_absurd_frame_times_are_one_line_fast_and_small(tmp_path, bandai, capsys, frame_time):
    f = bvh_with(
        bandai, tmp_path / "t.bvh", 30, header=lambda t: t.replace(t.splitlines()[2], f"Frame Time: {frame_time}")
    )
    tracemalloc.start()
    t0 = time.perf_counter()
    rc, _, err = run(["fix", f, "--model", "xmae-cpu-bandai", "-o", tmp_path / "o.npz"], capsys)
    seconds = time.perf_counter() - t0
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    assert rc == 1 and ("Frame Time" in err) and not (tmp_path / "o.npz").exists(), err
    one_error_line(err, f)
    assert peak < 50 * f.stat().st_size + 20e6, peak  # bytes: nothing sized by the frame time
    assert seconds < 20


def test_broken_files_and_options_are_one_line(tmp_path, capsys, bandai):
    np.save(tmp_path / "a.npy", np.zeros((10, 3, 3)))
    (tmp_path / "a.npy").rename(tmp_path / "renamed.npz")
    rc, _, err = run(["inspect", tmp_path / "renamed.npz"], capsys)
    assert rc == 1 and "single .npy array" in err
    one_error_line(err, "renamed.npz")

    nan = read_bvh(bandai)[0]
    write_positions(tmp_path / "nan.npz", np.full_like(nan.positions[:20], np.nan), 30.0, nan.skeleton)
    rc, _, err = run(["render", tmp_path / "nan.npz", "-o", tmp_path / "nan.gif"], capsys)
    assert rc == 1 and "nothing to draw" in err and not (tmp_path / "nan.gif").exists()
    one_error_line(err, "nan.npz")

    (tmp_path / "map.yaml").write_bytes(b"Hips: \xff\xfe\n")
    rc, _, err = run(["fix", bandai, "--model", "xmae-cpu-bandai", "--joint-map", tmp_path / "map.yaml"], capsys)
    assert rc == 1 and "not UTF-8" in err
    one_error_line(err, "map.yaml")
    (tmp_path / "map.yaml").write_text("Hips: Pelvis\n")  # the model has no Pelvis
    for cmd in ("fix", "inspect"):
        rc, _, err = run([cmd, bandai, "--model", "xmae-cpu-bandai", "--joint-map", tmp_path / "map.yaml"], capsys)
        assert rc == 1 and "'Pelvis', not joints of the model" in err, err
        one_error_line(err, "map.yaml")

    for bad in (["--fps", "0"], ["--start", "-1"], ["--duration", "inf"]):
        with pytest.raises(SystemExit) as e:
            main(["render", str(bandai), "-o", str(tmp_path / "r.gif"), *bad])
        assert e.value.code == 2


def test_an_unreadable_subfolder_is_one_line_and_the_rest_still_run(tmp_path, bandai, capsys, monkeypatch):
    data = tmp_path / "data"
    (data / "locked").mkdir(parents=True)
    bvh_with(bandai, data / "a.bvh", 40)
    real_walk = os.walk

    def walk(top, onerror=None, **kw):  # as a non-root user meets a folder without read permission
        for root, dirs, files in real_walk(top, onerror=onerror, **kw):
            if Path(root).name == "locked":
                onerror(PermissionError(13, "Permission denied", root))
                continue
            yield root, dirs, files

    monkeypatch.setattr(os, "walk", walk)
    with pytest.raises(MotionFileError, match="cannot read this folder"):
        list_motion_files(data)
    rc, out, err = run(["fix", data, "--model", "xmae-cpu-bandai"], capsys)
    assert rc == 1 and "a.bvh ->" in out and (data / "a.fixed.bvh").exists()
    one_error_line(err, data / "locked")


def test_an_out_dir_inside_the_input_folder_is_not_an_input(tmp_path, bandai, capsys):
    data = tmp_path / "data"
    data.mkdir()
    bvh_with(bandai, data / "a.bvh", 40)
    for _ in range(2):
        rc, out, err = run(["fix", data, "--model", "xmae-cpu-bandai", "--out-dir", data / "fixed", "--force"], capsys)
        assert rc == 0 and out.count("\n") == 1, (out, err)
    assert sorted(p.relative_to(data).as_posix() for p in data.rglob("*.bvh")) == ["a.bvh", "fixed/a.bvh"]


def test_a_file_name_with_a_newline_stays_on_one_line(tmp_path, bandai, capsys):
    f = bvh_with(bandai, tmp_path / "a\nerror: b.bvh", 40)
    rc, out, err = run(["fix", f, "--model", "xmae-cpu-bandai", "-o", tmp_path / "o.bvh"], capsys)
    assert rc == 0 and out.count("\n") == 1 and "\\n" in out, (out, err)
    rc, _, err = run(["inspect", tmp_path / "no\nsuch.bvh"], capsys)
    assert rc == 1 and err.count("\n") == 1 and "\\n" in err


# --- BVH dialects and files that are not BVH ---


def test_bvh_dialects_byte_order_mark_tabs_and_latin1_names(tmp_path, bandai):
    text = bvh_with(bandai, tmp_path / "src.bvh", 30).read_text()
    want = read_bvh(tmp_path / "src.bvh")[0].positions
    (tmp_path / "bom.bvh").write_bytes(b"\xef\xbb\xbf" + text.encode())
    (tmp_path / "tabs.bvh").write_text(text.replace("ROOT ", "ROOT\t").replace("JOINT ", "JOINT\t\t"))
    (tmp_path / "latin1.bvh").write_bytes(text.replace("JOINT Head", "JOINT T\xeate").encode("latin-1"))
    for name in ("bom.bvh", "tabs.bvh", "latin1.bvh"):
        clip = read_bvh(tmp_path / name)[0]
        np.testing.assert_allclose(clip.positions, want, atol=1e-6)
    clip = read_bvh(tmp_path / "latin1.bvh")[0]
    assert "T\xeate" in clip.skeleton.joint_names and clip.meta["encoding"] == "latin-1"


def test_duplicate_joint_names_and_non_bvh_files_are_refused_from_their_start(tmp_path, bandai):
    text = bvh_with(bandai, tmp_path / "src.bvh", 10).read_text()
    (tmp_path / "dup.bvh").write_text(text.replace("JOINT Hand_L", "JOINT Hand_R"))
    with pytest.raises(MotionFileError, match="'Hand_R' is used by 2 joints"):
        read_bvh(tmp_path / "dup.bvh")
    big = tmp_path / "big.bvh"  # 200 MB of something else: refused from its first bytes
    with open(big, "wb") as f:
        f.truncate(200 << 20)
    tracemalloc.start()
    with pytest.raises(MotionFileError, match="not a BVH file"):
        read_bvh(big)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    assert peak < 5e6


@pytest.mark.parametrize("damage", ["missing channels", "a jump"])
def test_a_bvh_whose_rotations_were_set_aside_comes_back_as_a_bvh(tmp_path, bandai, capsys, damage):
    """Missing channel values (NaN) or a jump leave the take without exact rotations; fix still
    writes a BVH (inverse kinematics from the file's own pose), holes filled, the rest as it was."""

    def edit(rows):
        if damage == "missing channels":
            rows[40:55, 36:42] = np.nan  # Shoulder_L's channels: the left arm is missing for 0.5 s
        else:
            rows[40:45, HIPS_X] += 500.0  # cm: the body 5 m away for 5 frames

    f = bvh_with(bandai, tmp_path / "take.bvh", edit=edit)
    rc, out, err = run(["fix", f, "--model", "xmae-cpu-bandai", "-o", tmp_path / "out.bvh"], capsys)
    assert rc == 0, err
    [before], [after] = read_motion(f), read_bvh(tmp_path / "out.bvh")
    assert np.isfinite(after.positions).all() and after.skeleton.joint_names == before.skeleton.joint_names
    seen = np.isfinite(before.positions).all(-1)
    assert 0 < (~seen).sum() and np.abs(after.positions[seen] - before.positions[seen]).max() < 1e-3  # 1 mm
    truth = read_bvh(bandai)[0].positions
    assert np.linalg.norm(after.positions - truth, axis=-1).max() < 0.5  # metres: filled, no jump kept
