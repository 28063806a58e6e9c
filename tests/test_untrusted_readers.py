"""Readers as untrusted input, round two (issue 45): a name that is not a regular file (a FIFO,
a link to /dev/zero) is refused at once, folder walks are bounded, legal BVH dialects read
(joints with fewer than 3 rotation channels, old Mac line endings), and a message about a file
never quotes its contents or prints numpy's warnings."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import threading
import time
import warnings
from pathlib import Path

import numpy as np
import pytest
from cli_utils import run_mocapfix as run

from mocapfix.core.clip import MotionFileError
from mocapfix.io import list_motion_files, read_motion
from mocapfix.io.bvh import read_bvh

BANDAI_FILE = "dataset-1_bow_active_001.bvh"
MODEL = ["--model", "xmae-cpu-bandai"]
fifos = pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this system")


@pytest.fixture(scope="module")
def bandai(bandai_files) -> Path:
    return {f.name: f for f in bandai_files}[BANDAI_FILE]


def within(seconds: float, work, fifos=()):
    """work() run in a thread; fails unless it ends within `seconds`. A reader blocked on one of
    the FIFOs is released (a writer opens and closes it) so that the thread ends either way."""
    result = {}

    def target():
        try:
            result["value"] = work()
        except BaseException as e:  # noqa: BLE001 -- handed to the test below
            result["error"] = e

    thread = threading.Thread(target=target, daemon=True)
    thread.start()
    thread.join(seconds)
    hung = thread.is_alive()
    for f in fifos if hung else ():
        try:
            os.close(os.open(f, os.O_WRONLY | os.O_NONBLOCK))
        except OSError:
            pass
    thread.join(5)
    assert not hung, f"still running after {seconds} s"
    if "error" in result:
        raise result["error"]
    return result["value"]


def one_line(err: str, name) -> None:
    assert err.count("\n") == 1 and str(name) in err and "Traceback" not in err, err


def bvh_with_channels(src: Path, dst: Path, kept: dict[str, list[str]], frames: int = 40, newline="\n") -> Path:
    """A copy of a BVH whose joints in `kept` have only the channels listed (their other columns
    removed from the frame rows)."""
    text = src.read_text()
    head, motion = text.split("MOTION", 1)
    lines = motion.strip().splitlines()
    rows = np.array([[float(v) for v in ln.split()] for ln in lines[2 : 2 + frames]])
    out, columns, col, joint = [], [], 0, None
    for ln in head.splitlines():
        m = re.match(r"\s*(ROOT|JOINT)\s+(\S+)", ln)
        if m:
            joint = m.group(2)
        if "CHANNELS" in ln:
            names = ln.split()[2:]
            keep = kept.get(joint, names)
            columns += [col + k for k, n in enumerate(names) if n in keep]
            col += len(names)
            ln = ln[: len(ln) - len(ln.lstrip())] + f"CHANNELS {len(keep)} {' '.join(keep)}".rstrip()
        out.append(ln)
    body = "\n".join(" ".join(f"{v:.6f}" for v in r) for r in rows[:, columns])
    text = "\n".join(out) + f"\nMOTION\nFrames: {len(rows)}\nFrame Time: 0.0333333\n{body}\n"
    dst.write_bytes(text.replace("\n", newline).encode())
    return dst


# --- names that are not regular files ---


@fifos
@pytest.mark.parametrize("name", ["take.bvh", "take.csv", "take.npz", "take.skl"])
def test_a_fifo_as_input_is_refused_at_once(tmp_path, name):
    f = tmp_path / name
    os.mkfifo(f)
    with pytest.raises(MotionFileError, match=r"not a regular file \(a FIFO\)"):
        within(5, lambda: read_motion(f), [f])


@fifos
def test_a_fifo_as_input_joint_map_library_or_checkpoint_is_one_line_at_once(tmp_path, bandai, capsys):
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    for link in ("take.bvh", "map.yaml", "lib.bvh", "model.ckpt"):
        (tmp_path / link).symlink_to(fifo)
    out = tmp_path / "o.bvh"

    rc, _, err = within(30, lambda: run(["inspect", tmp_path / "take.bvh"], capsys), [fifo])
    assert rc == 1 and "not a regular file (a FIFO)" in err
    one_line(err, "take.bvh")

    rc, _, err = within(30, lambda: run(["fix", bandai, *MODEL, "--joint-map", tmp_path / "map.yaml"], capsys), [fifo])
    assert rc == 1 and "not a regular file (a FIFO)" in err
    one_line(err, "map.yaml")

    rc, _, err = within(30, lambda: run(["fix", bandai, "--ckpt", tmp_path / "model.ckpt", "-o", out], capsys), [fifo])
    assert rc == 1 and not out.exists()
    one_line(err, "model.ckpt")

    args = ["fix", bandai, *MODEL, "-o", out, "--library", tmp_path / "lib.bvh"]
    rc, _, err = within(60, lambda: run(args, capsys), [fifo])
    assert rc == 0 and out.exists(), err  # the library is evidence: an unreadable one is left out, said once
    assert "lib.bvh" in err and "not a regular file (a FIFO)" in err and err.count("lib.bvh") == 1, err


def test_a_link_to_dev_zero_is_refused_without_reading_it(tmp_path):
    if not Path("/dev/zero").exists():
        pytest.skip("no /dev/zero")
    (tmp_path / "zero.csv").symlink_to("/dev/zero")
    (tmp_path / "zero.bvh").symlink_to("/dev/zero")
    # In a child process with 3 GB of address space: a reader that reads on runs out of it
    # (a MemoryError) instead of taking the machine's memory.
    code = (
        "import resource, sys\n"
        "resource.setrlimit(resource.RLIMIT_AS, (3 << 30, 3 << 30))\n"
        "from mocapfix.core.clip import MotionFileError\n"
        "from mocapfix.io import read_motion\n"
        "for f in sys.argv[1:]:\n"
        "    try:\n"
        "        read_motion(f)\n"
        "    except MotionFileError as e:\n"
        "        print(e)\n"
    )
    names = [tmp_path / "zero.csv", tmp_path / "zero.bvh"]
    env = {**os.environ, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}
    done = subprocess.run(
        [sys.executable, "-c", code, *map(str, names)], capture_output=True, text=True, timeout=60, env=env
    )
    assert done.returncode == 0, done.stderr[-500:]
    lines = done.stdout.splitlines()
    assert len(lines) == 2 and all("not a regular file (a character device)" in ln for ln in lines), done.stdout


# --- folder walks ---


def test_the_file_system_root_is_not_a_folder_of_takes(tmp_path, bandai, capsys):
    start = time.monotonic()
    with pytest.raises(MotionFileError, match="file system root"):
        within(5, lambda: list_motion_files(Path(os.sep)))
    rc, out, err = within(30, lambda: run(["inspect", os.sep], capsys))
    assert rc == 1 and "file system root" in err
    one_line(err, os.sep)
    args = ["fix", bandai, *MODEL, "-o", tmp_path / "o.bvh", "--library", os.sep]
    rc, out, err = within(60, lambda: run(args, capsys))
    # the library is evidence: one it cannot use is a warning, and the take is still fixed
    assert rc == 0 and (tmp_path / "o.bvh").exists(), err
    assert err.startswith("warning: --library: /: the file system root") and err.count("file system root") == 1, err
    assert time.monotonic() - start < 60


def test_a_folder_walk_is_bounded_and_follows_no_folder_links(tmp_path, bandai, caplog):
    data = tmp_path / "data"
    (data / "a" / "b").mkdir(parents=True)
    (data / "a" / "b" / "loop").symlink_to(data, target_is_directory=True)  # a cycle if followed
    (data / "a" / "take.bvh").write_bytes(bandai.read_bytes())
    os.mkfifo(data / "a" / "pipe.bvh") if hasattr(os, "mkfifo") else None
    with caplog.at_level("WARNING", logger="mocapfix"):
        assert within(5, lambda: list_motion_files(data)) == [data / "a" / "take.bvh"]
    # the link left is said, once, by name: a folder of linked folders is not "no takes" in silence
    said = [r.getMessage() for r in caplog.records]
    assert said == [
        f"warning: {data}: links to folders are not followed, 1 here ({data / 'a' / 'b' / 'loop'}): "
        "give a linked folder itself to read its takes"
    ], said

    wide = tmp_path / "wide"
    for k in range(30):
        (wide / f"d{k}").mkdir(parents=True)
        for i in range(10):
            (wide / f"d{k}" / f"f{i}.txt").touch()
    with pytest.raises(MotionFileError, match="more than 100 files and folders"):
        within(5, lambda: list_motion_files(wide, max_entries=100))
    assert len(list_motion_files(wide, "auto", max_entries=1000)) == 0


# --- BVH dialects ---


@pytest.mark.parametrize(
    "kept",
    [
        {"Head": ["Xposition", "Yposition", "Zposition"]},  # 0 rotation channels
        {"Head": []},  # CHANNELS 0
        {"Neck": ["Xposition", "Yposition", "Zposition", "Zrotation", "Yrotation"]},  # 2 rotation channels
        {"Hand_L": ["Xposition", "Yposition", "Zposition", "Xrotation"]},  # 1
    ],
)
def test_joints_with_fewer_than_3_rotation_channels_fix_end_to_end(tmp_path, bandai, capsys, kept):
    f = bvh_with_channels(bandai, tmp_path / "take.bvh", kept)
    want = read_bvh(f)[0]
    rc, out, err = run(["fix", f, *MODEL, "-o", tmp_path / "out.bvh"], capsys)
    assert rc == 0, err
    channels = [ln.strip() for ln in f.read_text().splitlines() if "CHANNELS" in ln]
    written = (tmp_path / "out.bvh").read_text()
    assert [ln.strip() for ln in written.splitlines() if "CHANNELS" in ln] == channels  # the input's layout
    got = read_bvh(tmp_path / "out.bvh")[0]
    np.testing.assert_allclose(got.positions, want.positions, atol=1e-4)  # metres: a complete take as it was


def test_a_bvh_with_old_mac_line_endings_reads_and_fixes(tmp_path, bandai, capsys):
    lf = bvh_with_channels(bandai, tmp_path / "lf.bvh", {})
    cr = bvh_with_channels(bandai, tmp_path / "cr.bvh", {}, newline="\r")
    assert b"\n" not in cr.read_bytes()
    np.testing.assert_array_equal(read_bvh(cr)[0].positions, read_bvh(lf)[0].positions)
    rc, _, err = run(["fix", cr, *MODEL, "-o", tmp_path / "out.bvh"], capsys)
    assert rc == 0, err
    np.testing.assert_allclose(read_bvh(tmp_path / "out.bvh")[0].positions, read_bvh(lf)[0].positions, atol=1e-4)


# --- messages never carry the file's contents ---

ESCAPE = "\x1b[31m"
JUNK = "x" * (1 << 20)


FIRST_VALUE = "<first frame value>"


def _bvh_damaged(bandai: Path, tmp_path: Path, name: str, old: str, new: str) -> Path:
    """A 5-frame BVH with `old` replaced by `new`; old FIRST_VALUE: the first value of frame 0."""
    text = bvh_with_channels(bandai, tmp_path / "src.bvh", {}, frames=5).read_text()
    if old == FIRST_VALUE:
        head, rows = text.split("Frame Time: 0.0333333\n")
        text = head + "Frame Time: 0.0333333\n" + new + rows[rows.index(" ") :]
    else:
        assert old in text
        text = text.replace(old, new, 1)
    (tmp_path / name).write_text(text)
    return tmp_path / name


def short_and_clean(text: str, names_ok: bool = False, longest: int = 300) -> None:
    """One short line without the file's text: no escape code, no junk; a joint or column name
    only quoted and cut short (names_ok), a line only by its number."""
    assert "\x1b" not in text and "\n" not in text and len(text) < longest, text[:300]
    assert "x" * 50 not in text, text[:300]
    if not names_ok:
        assert "[31m" not in text, text


@pytest.mark.parametrize(
    "old,new,names_ok",
    [
        ("JOINT Spine", f"JOINT Spine\n  {ESCAPE}{JUNK}", False),  # a line that means nothing in HIERARCHY
        ("OFFSET 15.7357 0 0", f"OFFSET 15.7357 {ESCAPE} {JUNK}", False),
        ("Zrotation", f"Zrot{ESCAPE}{JUNK}", False),
        ("Frame Time: 0.0333333", f"Frame Time: {ESCAPE}{JUNK}", False),
        ("Frames: 5", f"Frames: {ESCAPE}{JUNK}", False),
        (FIRST_VALUE, f"{ESCAPE}{JUNK}", False),  # a non-numeric frame value
        ("JOINT Spine", f"JOINT {ESCAPE}{JUNK}", True),  # a joint name of junk, used twice (below)
    ],
)
def test_a_bvh_error_names_the_line_never_its_text(tmp_path, bandai, old, new, names_ok):
    f = _bvh_damaged(bandai, tmp_path, "bad.bvh", old, new)
    if names_ok:
        f.write_text(f.read_text().replace("JOINT Chest", f"JOINT {ESCAPE}{JUNK}", 1))
    with pytest.raises(MotionFileError) as e:
        read_motion(f)
    short_and_clean(str(e.value), names_ok)
    assert str(e.value).startswith(str(f))
    if not names_ok:
        assert re.search(r": line \d+", str(e.value)), str(e.value)


@pytest.mark.parametrize(
    "csv",
    [
        f"# fps=30\nperson,A_x,A_y,A_z\n0,1,2,{ESCAPE}{JUNK}\n",  # a cell
        f"# fps=30\nperson,A_x,A_y,{ESCAPE}{JUNK}\n0,1,2,3\n",  # a header
        f"# fps={ESCAPE}{JUNK}\nA_x,A_y,A_z\n1,2,3\n",  # a comment value
        f"# fps=30 parents=-1 unit={ESCAPE}{JUNK}\nA_x,A_y,A_z\n1,2,3\n",
        f"# fps=30 parents=-1 up_axis={ESCAPE}{JUNK}\nA_x,A_y,A_z\n1,2,3\n",
        f"# fps=30 parents={ESCAPE}{JUNK}\nA_x,A_y,A_z\n1,2,3\n",
        f"# fps=30\nperson,A_x,A_y,A_z\n{ESCAPE}{JUNK},1,2,3\n{ESCAPE}{JUNK},1,2,3\n",  # one person twice a frame
        f"# fps=30\nframe,A_x,A_y,A_z\n{ESCAPE}{JUNK},1,2,3\n",
    ],
)
def test_a_csv_error_names_the_line_never_its_text(tmp_path, csv):
    f = tmp_path / "bad.csv"
    f.write_text(csv)
    with pytest.raises(MotionFileError) as e:
        read_motion(f)
    short_and_clean(str(e.value), names_ok=True)  # a header's name may be shown, escaped and cut


def test_a_joint_map_error_never_quotes_the_map(tmp_path, bandai, capsys):
    for text in (f"Hips: {JUNK}\n", f"Hips: [{JUNK}\n", f"Hips: Hips\n{ESCAPE}\n"):
        (tmp_path / "map.yaml").write_text(text)
        rc, _, err = run(["fix", bandai, *MODEL, "--joint-map", tmp_path / "map.yaml"], capsys)
        assert rc == 1
        short_and_clean(err.strip(), names_ok=True, longest=500)  # it lists the model's 24 joints
        one_line(err, "map.yaml")


# --- no numpy warnings before (or instead of) the one line ---

PARENTS = "# fps=30 parents=-1,0\n"


@pytest.mark.parametrize(
    "name,text",
    [
        ("frame.csv", PARENTS + "frame,A_x,A_y,A_z,B_x,B_y,B_z\n1e300,0,0,0,0,0,1\n"),  # not an int64
        ("times.csv", "# parents=-1\ntime,A_x,A_y,A_z\n0,1,2,3\n1e308,1,2,3\n-1e308,1,2,3\n"),  # steps overflow
    ],
)
def test_a_csv_error_comes_without_numpy_warnings(tmp_path, capsys, name, text):
    f = tmp_path / name
    f.write_text(text)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a RuntimeWarning would be raised instead of the MotionFileError
        with pytest.raises(MotionFileError):
            read_motion(f)
    rc, _, err = run(["inspect", f], capsys)
    assert rc == 1
    one_line(err, name)


def test_absurd_bvh_numbers_read_without_numpy_warnings(tmp_path, bandai):
    f = _bvh_damaged(bandai, tmp_path, "absurd.bvh", FIRST_VALUE, "1e308")  # a root position of 1e308 units
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        read_motion(f)
