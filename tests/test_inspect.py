"""`inspect`: numbers on files whose answers are known, JSON lines, bad files, a real BVH."""

import json

import numpy as np
import pytest

from mocapfix.apps.inspect import inspect_files, main, motion_stats
from mocapfix.core.skeleton import Skeleton
from mocapfix.io import read_motion

NAMES = ["Hips", "Spine", "Head"]
PARENTS = [-1, 0, 1]


def _known(T=40):
    """Hips at 0.9 m; Spine 0.5 m above; Head 0.3 m +- 0.01 m above Spine (sigma 10 mm), people 2."""
    pos = np.zeros((2, T, 3, 3))
    pos[:, :, 0] = [0.0, 0.0, 0.9]
    pos[:, :, 1] = [0.0, 0.0, 1.4]
    pos[:, :, 2] = [0.0, 0.0, 1.7]
    pos[:, :, 2, 2] += np.where(np.arange(T) % 2, 0.01, -0.01)
    pos[:, :, :, 0] += np.linspace(0, 1, T)[:, None]  # walking along x moves nothing relative
    return pos


@pytest.fixture
def files(tmp_path):
    pos = _known()
    pos[1, :4, 2] = np.nan  # 4 missing tokens of 2 * 40 * 3
    a = tmp_path / "a.npz"
    np.savez(a, positions=pos * 1000, fps=25, joint_names=np.array(NAMES), parents=np.array(PARENTS), unit="mm")
    b = tmp_path / "b.csv"
    from mocapfix.io.positions import write_positions

    write_positions(b, pos[0], 50, Skeleton(NAMES, PARENTS), unit="cm", up_axis="y")
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a zip")
    return a, b, bad


def test_stats_known_values(files):
    s = motion_stats(read_motion(files[0]))
    assert s["format"] == "positions-npz" and s["people"] == 2 and s["frames"] == 40 and s["fps"] == 25.0
    assert s["duration_s"] == pytest.approx(1.6) and s["joints"] == 3 and s["joint_names"] == NAMES
    assert s["unit"] == "mm" and s["up_axis"] == "z"
    assert s["missing_tokens"] == 4 and s["missing_pct"] == pytest.approx(100 * 4 / 240)
    assert s["hip_joint"] == "Hips" and s["hip_height_m"] == pytest.approx(0.9, abs=1e-6)
    assert s["limb_length_mm"] == pytest.approx(400.0, abs=1e-3)  # (500 + 300) / 2
    assert s["limb_sigma_mm"] == pytest.approx(5.0, abs=1e-3)  # (0 + 10) / 2, NaN frames ignored


def test_json_lines_and_bad_file(files, capsys):
    a, b, bad = files
    code = inspect_files([str(a), str(bad), str(b)], as_json=True)
    out, err = capsys.readouterr()
    assert code == 1
    rows = [json.loads(line) for line in out.splitlines()]
    assert [r["file"] for r in rows] == [str(a), str(b)]  # the bad file did not stop the next one
    for key in (
        "file",
        "format",
        "people",
        "frames",
        "fps",
        "joints",
        "joint_names",
        "missing_tokens",
        "limb_sigma_mm",
    ):
        assert key in rows[0] and key in rows[1]
    assert rows[1]["format"] == "positions-csv" and rows[1]["unit"] == "cm" and rows[1]["up_axis"] == "y"
    assert rows[1]["hip_height_m"] == pytest.approx(0.9, abs=1e-5) and rows[1]["fps"] == 50.0
    assert rows[1]["limb_sigma_mm"] == pytest.approx(5.0, abs=1e-3)
    lines = err.splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: {bad}: ")


def test_table_and_main(files, capsys):
    a, b, _ = files
    assert inspect_files([a, b]) == 0
    out = capsys.readouterr().out
    assert str(a) in out and str(b) in out and "sigma mm" in out
    assert "joints (2 files, 3): Hips, Spine, Head" in out
    assert main([str(a.parent / "b.csv"), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["frames"] == 40
    assert main([str(a.parent / "nope.csv")]) == 1
    assert capsys.readouterr().err.startswith("error: ")


def test_folder_argument(files, capsys):
    code = inspect_files([files[0].parent], as_json=True)
    out, err = capsys.readouterr()
    assert code == 1 and len(out.splitlines()) == 2 and len(err.splitlines()) == 1


def test_folder_without_motion_files_is_an_error(tmp_path, capsys):
    (tmp_path / "notes.txt").write_text("no motion here")
    assert inspect_files([tmp_path]) == 1
    out, err = capsys.readouterr()
    assert out == "" and err.strip() == f"error: {tmp_path}: no motion files in this folder"


def test_bandai_bvh(request, capsys):
    pytest.importorskip("mocapfix.io.bvh")
    try:
        bandai = request.getfixturevalue("bandai_dir")
    except pytest.FixtureLookupError:
        pytest.skip("no bandai_dir fixture in tests/conftest.py")
    f = sorted(bandai.rglob("*.bvh"))[0]
    assert inspect_files([f], as_json=True) == 0
    row = json.loads(capsys.readouterr().out)
    assert row["format"] == "bvh" and row["fps"] == pytest.approx(30.0, abs=1e-3) and row["people"] == 1
    assert row["unit"] == "cm" and row["up_axis"] == "y" and row["missing_tokens"] == 0
    assert 0.7 < row["hip_height_m"] < 1.2 and row["hip_joint"] == "Hips"
    assert 50 < row["limb_length_mm"] < 300
    # rigid skeleton from rotations: bones keep their length (joint_Root -> Hips is no bone)
    assert row["limb_sigma_mm"] < 0.1
