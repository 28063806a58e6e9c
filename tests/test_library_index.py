"""fix --library-index: the --library takes kept in a file between runs (fix/library_file.py),
read back only when they were made from the same files, and never trusted to run code."""

from __future__ import annotations

import os

import numpy as np
import pytest

from mocapfix.apps.main import main
from mocapfix.core.clip import MotionFileError
from mocapfix.io.positions import write_positions
from mocapfix.io.synthetic import generate_clips


@pytest.fixture()
def run(tmp_path):
    """A holed take and a library folder of three others; run(*extra) -> (output bytes, stderr)."""
    clips = generate_clips(4, 6.0, 30.0, seed=3)
    x = clips[0].positions.copy()
    x[60:75, 10:14] = np.nan  # two holes of 0.5 s in a few joints
    x[120:135, 3:6] = np.nan
    write_positions(tmp_path / "take.npz", x, clips[0].fps, clips[0].skeleton)
    (tmp_path / "library").mkdir()
    for i, clip in enumerate(clips[1:]):
        write_positions(tmp_path / "library" / f"other{i}.npz", clip.positions, clip.fps, clip.skeleton)

    def fix(*extra: str, capsys=None) -> tuple[bytes, str]:
        out = tmp_path / "fixed.npz"
        argv = ["fix", str(tmp_path / "take.npz"), "-o", str(out), "--force", "--model", "xmae-cpu-bandai"]
        argv += ["--library", str(tmp_path / "library"), *extra]
        assert main(argv) == 0
        return out.read_bytes(), capsys.readouterr().err

    return fix


def test_the_index_is_written_once_read_after_and_changes_nothing(tmp_path, run, capsys):
    plain, _ = run(capsys=capsys)
    index = str(tmp_path / "takes.index.npz")
    first, said = run("--library-index", index, capsys=capsys)
    assert "index written" in said, said
    again, said = run("--library-index", index, capsys=capsys)
    assert "from the index" in said and "index written" not in said, said
    assert first == plain and again == plain  # byte for byte: the index is the takes as read


def test_a_changed_take_makes_the_index_again(tmp_path, run, capsys):
    index = str(tmp_path / "takes.index.npz")
    run("--library-index", index, capsys=capsys)
    other = tmp_path / "library" / "other1.npz"
    stat = other.stat()
    os.utime(other, ns=(stat.st_atime_ns, stat.st_mtime_ns + 1_000_000_000))  # touched: maybe edited
    _, said = run("--library-index", index, capsys=capsys)
    assert "index written" in said and "from the index" not in said, said


def test_a_damaged_or_foreign_index_is_made_again_with_a_warning(tmp_path, run, capsys):
    index = tmp_path / "takes.index.npz"
    plain, _ = run(capsys=capsys)
    index.write_bytes(b"PK\x03\x04 not really a zip")
    out, said = run("--library-index", str(index), capsys=capsys)
    assert "warning: --library-index:" in said and "index written" in said, said
    assert out == plain
    _, said = run("--library-index", str(index), capsys=capsys)
    assert "from the index" in said, said


class _Boom:
    def __reduce__(self):
        return (os.system, ("touch SHOULD_NOT_EXIST",))


def test_an_index_holding_a_pickle_is_refused_and_nothing_runs(tmp_path, monkeypatch):
    from mocapfix.core.skeleton import preset
    from mocapfix.fix.library_file import load_library

    monkeypatch.chdir(tmp_path)
    path = tmp_path / "evil.npz"
    boom = np.empty(1, dtype=object)
    boom[0] = _Boom()
    names = ["format", "signature", "lengths", "fps", "key_files", "key_clips"]
    with open(path, "wb") as f:
        np.savez(f, positions=boom, **{k: np.zeros(1) for k in names})
    with pytest.raises(MotionFileError, match="evil.npz"):
        load_library(path, "anything", preset("body21"))
    assert not (tmp_path / "SHOULD_NOT_EXIST").exists()


def test_an_index_with_values_of_the_wrong_kind_is_one_clear_error(tmp_path):
    from mocapfix.core.skeleton import preset
    from mocapfix.fix.library_file import load_library

    body = preset("body21")
    good = {
        "format": np.int64(1),
        "signature": np.array("s"),
        "positions": np.zeros((30, body.num_joints, 3), np.float32),
        "lengths": np.array([30]),
        "fps": np.array([30.0]),
        "key_files": np.array(["a.npz"]),
        "key_clips": np.array([0]),
    }
    broken = [
        {"format": np.array("1")},
        {"fps": np.array(["thirty"])},
        {"fps": np.array([1e9])},
        {"key_clips": np.array(["zero"])},
        {"lengths": np.array([], dtype=np.int64), "positions": np.zeros((0, body.num_joints, 3), np.float32)},
        {"lengths": np.array([29])},
        {"positions": np.full((30, body.num_joints, 3), np.inf, np.float32)},
    ]
    for i, change in enumerate(broken):
        np.savez(tmp_path / f"i{i}.npz", **{**good, **change})
        with pytest.raises(MotionFileError, match=f"i{i}.npz"):
            load_library(tmp_path / f"i{i}.npz", "s", body)
    np.savez(tmp_path / "ok.npz", **good)
    assert load_library(tmp_path / "ok.npz", "s", body)[0].keys == [("a.npz", 0)]


def test_an_index_made_for_other_joints_or_takes_is_not_used(tmp_path):
    from mocapfix.core.skeleton import preset
    from mocapfix.fills.motion_matching import MotionLibrary
    from mocapfix.fix.library_file import library_signature, load_library, save_library

    body = preset("body21")
    x = np.zeros((30, body.num_joints, 3), np.float32)
    take = tmp_path / "a.npz"
    take.write_bytes(b"x")
    signature = library_signature([take], body, {"source": "auto"})
    save_library(tmp_path / "i.npz", MotionLibrary([(x, 30.0)], [(str(take), 0)]), signature, 1, 0)
    library, read, unread = load_library(tmp_path / "i.npz", signature, body)
    assert library.keys == [(str(take), 0)] and (read, unread) == (1, 0)
    assert np.array_equal(library.takes[0][0], x) and library.takes[0][1] == 30.0
    assert load_library(tmp_path / "i.npz", library_signature([take], body, {"source": "bvh"}), body) is None
    take.write_bytes(b"xy")  # another size: another take
    assert load_library(tmp_path / "i.npz", library_signature([take], body, {"source": "auto"}), body) is None
    assert load_library(tmp_path / "none.npz", signature, body) is None


def test_an_index_needs_library_takes(tmp_path, capsys):
    with pytest.raises(SystemExit):
        main(["fix", str(tmp_path / "t.npz"), "--model", "xmae-cpu-bandai", "--library-index", str(tmp_path / "i.npz")])
    assert "--library-index keeps the takes of --library" in capsys.readouterr().err


def test_a_take_is_known_in_the_library_however_its_path_is_spelled(tmp_path, monkeypatch):
    """The policy's cut holes must not find their own truth in the library's copy of the take:
    `fix takes/a.npz --library /abs/takes` names one file twice; the run's library holds it once."""
    from mocapfix.fix import load_fixer, motion_library
    from mocapfix.io import read_motion
    from mocapfix.pretrained import pretrained_path

    [clip] = generate_clips(1, 4.0, 30.0, seed=5)
    (tmp_path / "takes").mkdir()
    write_positions(tmp_path / "takes" / "a.npz", clip.positions, clip.fps, clip.skeleton)
    monkeypatch.chdir(tmp_path)
    fixer = load_fixer(str(pretrained_path("xmae-cpu-bandai")), "cpu")
    relative = read_motion("takes/a.npz")
    absolute = read_motion(tmp_path / "takes" / "a.npz")
    library = motion_library([relative], fixer, None, motion_library([absolute], fixer))
    assert len(library.keys) == 1
