"""Human3.6M in VideoPose3D's layout, on a small data_3d_h36m.npz written here."""

import numpy as np
import pytest

from mocapfix.core.clip import MotionFileError
from mocapfix.core.skeleton import PRESETS
from mocapfix.io import detect_source, read_motion
from mocapfix.io.h36m import H36M_KEEP, H36M_SPLIT, read_h36m


def _seq(T, seed):
    """(T, 32, 3) where joint j's x is j: shows which of the 32 joints were kept."""
    pos = np.random.default_rng(seed).normal(scale=0.2, size=(T, 32, 3)).astype(np.float32)
    pos[..., 0] = np.arange(32, dtype=np.float32)
    return pos


def _write(path, tree):
    np.savez(path, positions_3d=tree)  # a dict becomes a pickled 0-d object array, as in VideoPose3D
    return path


@pytest.fixture
def h36m_file(tmp_path):
    tree = {
        "S11": {"Walking 1": _seq(7, 0)},
        "S1": {"Walking": _seq(5, 1), "Directions 1": _seq(3, 2)},
        "S9": {"Eating": _seq(4, 3)},
    }
    return _write(tmp_path / "data_3d_h36m.npz", tree), tree


def test_read_h36m(h36m_file):
    path, tree = h36m_file
    clips = read_h36m(path)
    # subjects in natural order (S1 < S9 < S11), actions sorted
    assert [c.name for c in clips] == ["S1/Directions 1", "S1/Walking", "S9/Eating", "S11/Walking 1"]
    for c in clips:
        subject, action = c.name.split("/")
        assert c.meta["subject"] == subject and c.meta["action"] == action and c.meta["format"] == "h36m"
        assert c.fps == 50.0 and c.skeleton == PRESETS["h36m17"] and c.source == str(path)
        assert c.meta["unit"] == "m" and c.meta["up_axis"] == "z"
        np.testing.assert_array_equal(c.positions, tree[subject][action][:, H36M_KEEP])
    assert clips[1].positions[0, :, 0].tolist() == [0, 1, 2, 3, 6, 7, 8, 12, 13, 14, 15, 17, 18, 19, 25, 26, 27]


def test_split_by_subject(h36m_file):
    clips = read_motion(h36m_file[0])  # auto: positions_3d means Human3.6M
    assert detect_source(h36m_file[0]) == "h36m"
    train = [c.name for c in clips if c.meta["subject"] in H36M_SPLIT["train"]]
    test = [c.name for c in clips if c.meta["subject"] in H36M_SPLIT["test"]]
    assert train == ["S1/Directions 1", "S1/Walking"] and test == ["S9/Eating", "S11/Walking 1"]


def test_missing_key(tmp_path):
    f = tmp_path / "data_2d_h36m_gt.npz"
    np.savez(f, positions_2d={"S1": {}})
    with pytest.raises(MotionFileError, match="positions_3d") as e:
        read_h36m(f)
    assert str(f) in str(e.value) and "\n" not in str(e.value)


@pytest.mark.parametrize("bad", [np.zeros((5, 31, 3)), np.zeros((5, 32, 2)), np.zeros((5, 96)), np.zeros((0, 32, 3))])
def test_wrong_shape(tmp_path, bad):
    f = _write(tmp_path / "d.npz", {"S1": {"Walking": np.zeros((3, 32, 3)), "Bad": bad}})
    with pytest.raises(MotionFileError, match="S1/Bad") as e:
        read_h36m(f)
    assert str(e.value).startswith(str(f)) and "\n" not in str(e.value)


def test_not_a_dict(tmp_path):
    f = tmp_path / "d.npz"
    np.savez(f, positions_3d=np.zeros((3, 32, 3)))
    with pytest.raises(MotionFileError, match="subject"):
        read_h36m(f)
