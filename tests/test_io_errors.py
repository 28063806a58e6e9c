"""Bad input files: one-line MotionFileError naming the file, never a numpy/zip traceback."""

import zipfile

import numpy as np
import pytest

from mocapfix.core.clip import MotionFileError
from mocapfix.io import list_motion_files, read_motion

PARENTS = np.array([-1, 0, 1])


def _raises(path, match=None, **kw):
    with pytest.raises(MotionFileError, match=match) as e:
        read_motion(path, **kw)
    msg = str(e.value)
    assert msg.startswith(f"{path}: ") and "\n" not in msg and len(msg) < 400, msg
    return msg


def _npz(tmp_path, name="x.npz", **arrays):
    f = tmp_path / name
    np.savez(f, **arrays)
    return f


@pytest.mark.parametrize("ext", [".csv", ".npz", ".bvh"])
def test_empty_file(tmp_path, ext):
    if ext == ".bvh":
        pytest.importorskip("mocapfix.io.bvh")
    f = tmp_path / f"empty{ext}"
    f.write_bytes(b"")
    _raises(f)


@pytest.mark.parametrize("shape", [(10, 3), (10, 3, 2), (2, 10, 3, 4), (1, 2, 10, 3, 3), (0, 3, 3)])
def test_positions_wrong_shape(tmp_path, shape):
    f = _npz(tmp_path, positions=np.zeros(shape), fps=30, parents=PARENTS)
    _raises(f, "positions must be")


@pytest.mark.parametrize(
    "fps,match",
    [
        (None, "no 'fps'"),
        (0, "outside 1-10000 fps"),
        (-30, "outside 1-10000 fps"),
        (np.nan, "outside 1-10000 fps"),
        (np.array([30, 60]), "one number"),
        ("thirty", "one number"),
    ],
)
def test_positions_bad_fps(tmp_path, fps, match):
    arrays = {"positions": np.zeros((4, 3, 3)), "parents": PARENTS}
    if fps is not None:
        arrays["fps"] = fps
    _raises(_npz(tmp_path, **arrays), match)


def test_positions_bad_skeleton(tmp_path):
    _raises(_npz(tmp_path, positions=np.zeros((4, 3, 3)), fps=30, parents=np.array([-1, 0])), "2 parents for 3 joints")
    _raises(_npz(tmp_path, positions=np.zeros((4, 3, 3)), fps=30, parents=np.array([-1, 2, 0])), "parents must come")
    _raises(
        _npz(tmp_path, positions=np.zeros((4, 3, 3)), fps=30, joint_names=np.array(["a", "b"]), parents=PARENTS),
        "2 joint names",
    )
    _raises(_npz(tmp_path, positions=np.array([["a"] * 3] * 3)[None], fps=30, parents=PARENTS), "numbers")
    _raises(_npz(tmp_path, positions=np.zeros((4, 3, 3)), fps=30, parents=PARENTS, unit="furlong"), "unknown unit")


def test_truncated_npz(tmp_path):
    good = _npz(
        tmp_path, "good.npz", positions=np.random.default_rng(0).normal(size=(200, 3, 3)), fps=30, parents=PARENTS
    )
    f = tmp_path / "truncated.npz"
    f.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    _raises(f, "not a readable npz")


def test_text_file_named_npz(tmp_path):
    f = tmp_path / "notes.npz"
    f.write_text("frame,x,y,z\n0,1,2,3\n")
    assert "allow_pickle" not in _raises(f, "not an npz file")


def test_corrupt_member_of_npz(tmp_path):
    """A valid zip whose compressed positions are damaged: fails when the array is read."""
    f = tmp_path / "corrupt.npz"
    np.savez_compressed(f, positions=np.random.default_rng(0).normal(size=(200, 3, 3)), fps=30, parents=PARENTS)
    data = bytearray(f.read_bytes())
    with zipfile.ZipFile(f) as z:
        info = z.getinfo("positions.npy")
    start = info.header_offset + 30 + len(info.filename) + 40
    data[start : start + 64] = bytes(64)
    f.write_bytes(bytes(data))
    _raises(f)


def test_csv_problems(tmp_path):
    f = tmp_path / "x.csv"
    head = "# fps=30 parents=-1,0\nframe,A_x,A_y,A_z,B_x,B_y,B_z\n"
    f.write_text("# fps=30\n\n")
    _raises(f, "no header")
    f.write_text(head)
    _raises(f, "no data rows")
    f.write_text(head + "0,1,2,3,4,5,6\n1,1,2,3,4,5\n")
    assert "line 4" in _raises(f, "6 cells, the header has 7")
    f.write_text(head + "0,1,2,3,4,5,6\n1,1,2,abc,4,5,6\n")
    msg = _raises(f, "not a number")
    assert "line 4" in msg and "column 4 ('A_z') is not a number" in msg and "abc" not in msg
    f.write_text(head + "0,1,2,3,4,5,6\n0,1,2,3,4,5,6\n")
    _raises(f, "appears twice")
    f.write_text(head + "0.5,1,2,3,4,5,6\n")
    _raises(f, "frame must be an integer")
    f.write_text("# fps=30 parents=-1,0\nframe,A_x,A_y,B_x,B_y,B_z\n0,1,2,4,5,6\n")
    _raises(f, "not <joint>_x")
    f.write_text("# fps=30 parents=-1,0,x\nframe,A_x,A_y,A_z,B_x,B_y,B_z\n0,1,2,3,4,5,6\n")
    _raises(f, "parents")
    f.write_bytes(b"\xff\xfe\x00garbage\x81")
    _raises(f, "cannot read as text")


def test_unknown_source_and_file_types(tmp_path):
    f = _npz(tmp_path, positions=np.zeros((4, 3, 3)), fps=30, parents=PARENTS)
    msg = _raises(f, "unknown source type 'c3d'", source="c3d")
    assert all(s in msg for s in ("bvh", "positions", "h36m", "amass"))
    g = tmp_path / "take.c3d"
    g.write_bytes(b"\x00" * 10)
    _raises(g, "unknown file type")
    _raises(_npz(tmp_path, "y.npz", something=np.zeros(3)), "unknown keys")
    _raises(tmp_path / "missing.csv", "no such file")
    with pytest.raises(MotionFileError, match="unknown source type"):
        list_motion_files(tmp_path, "c3d")


def test_list_motion_files(tmp_path):
    for rel in ["a/1.bvh", "a/b/2.CSV", "3.npz", "a/shape.npz", "notes.txt", ".a.npz.tmp", ".hidden.npz"]:
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_text("")
    rel = lambda ps: [p.relative_to(tmp_path).as_posix() for p in ps]  # noqa: E731
    assert rel(list_motion_files(tmp_path)) == ["3.npz", "a/1.bvh", "a/b/2.CSV"]
    assert rel(list_motion_files(tmp_path, "bvh")) == ["a/1.bvh"]
    assert rel(list_motion_files(tmp_path, "positions")) == ["3.npz", "a/b/2.CSV"]
    assert list_motion_files(tmp_path / "notes.txt") == [tmp_path / "notes.txt"]  # a file is taken as given
    with pytest.raises(MotionFileError, match="no such file"):
        list_motion_files(tmp_path / "nope")
