"""`mocapfix demo`: how it breaks a take, how it scores the outputs, which take it holds out, and
the whole run (slow: a fit, a fix and an animation)."""

from __future__ import annotations

import numpy as np
import pytest

from mocapfix.apps.demo import JUMP_M, _choose_data, break_take, main, score_table
from mocapfix.core.skeleton import preset
from mocapfix.data.windows import split_of
from mocapfix.io.synthetic import generate_clips
from mocapfix.rig.mapping import onto_skeleton


@pytest.fixture(scope="module")
def take():
    return onto_skeleton(generate_clips(1, 8.0, 30.0, seed=3)[0], preset("body21"))


def test_break_take_removes_holes_and_moves_one_arm(take):
    truth, broken, damage = break_take(take)
    x, y = truth.positions, broken.positions
    assert np.isnan(y[damage.holes]).all() and np.isfinite(y[~damage.holes]).all()
    groups = take.skeleton.groups
    # the three holes: the whole body for 0.5 s, the left arm and the right leg
    assert damage.holes.all(1).sum() == 15
    assert damage.holes[:, list(groups["left_arm"])].all(1).sum() == 15 + 27
    assert damage.holes[:, list(groups["right_leg"])].all(1).sum() == 15 + 21
    jumped = np.linalg.norm(y - x, axis=-1)[damage.jumped]
    assert damage.jumped.any(0).nonzero()[0].tolist() == list(groups["right_arm"])
    np.testing.assert_allclose(jumped, JUMP_M, rtol=1e-5)
    assert (y[damage.clean] == x[damage.clean]).all()
    # the same take is broken the same way
    assert np.array_equal(break_take(take)[2].holes, damage.holes)


def test_score_table_measures_against_the_unbroken_take(take):
    truth, broken, damage = break_take(take)
    x, y = truth.positions, broken.positions
    perfect = score_table(x, y, x, damage, take.skeleton.parents, {"limb": 10})
    rows = {line.split()[0]: line for line in perfect.splitlines()[2:-1]}
    assert rows["input"].split()[1] == "missing"
    assert float(rows["input"].split()[2]) == pytest.approx(1000 * JUMP_M, rel=1e-3)
    assert rows["mocapfix"].split()[1:3] == ["0.0", "0.0"]
    assert "0 of" in rows["mocapfix"]
    # the spline fills the holes and keeps the jumped arm where the file has it
    spline = rows["cubic"].split()
    assert 0 < float(spline[2]) and float(spline[3]) == pytest.approx(1000 * JUMP_M, rel=1e-3)
    # an output that moved clean tokens says how many
    moved = x.copy()
    moved[: take.num_frames // 10, 0] += 0.01
    line = score_table(x, y, moved, damage, take.skeleton.parents).splitlines()[-2]
    assert line.startswith("mocapfix") and f"{int(damage.clean[: take.num_frames // 10, 0].sum())} of" in line
    # the last line names the best classical fill over the holes and which fill filled them
    holes = {
        "cubic spline": rows["cubic"].split()[2],
        "Hermite": rows["Hermite"].split()[1],
        "limb fill": rows["limb"].split()[2],
    }
    lowest = min(holes.values(), key=float)
    verdict = perfect.splitlines()[-1]
    assert any(
        verdict.startswith(f"holes: mocapfix 0.0 mm, the best classical fill ({name}) {lowest} mm; ") for name in holes
    )
    assert verdict.endswith(
        "filled by limb 10: the model filled none (it fills a kind of hole only where it beat every "
        "classical fill on holes cut into this take)"
    )


def test_the_held_out_take_is_from_the_test_split_and_not_fitted(bandai_dir):
    take, data_args, _ = _choose_data(str(bandai_dir), takes=12)
    fitted = data_args[data_args.index("--data.path") + 1].strip("[]").split(", ")
    assert len(fitted) == 12
    assert {split_of(f, 0.1, 0.1, 0) for f in fitted} <= {"train", "val"}
    assert any(split_of(f, 0.1, 0.1, 0) == "val" for f in fitted)
    assert take.skeleton.joint_names == preset("body21").joint_names
    assert take.num_frames >= 6 * take.fps
    held_out = next(f for f in bandai_dir.rglob(f"{take.name}.*"))
    assert split_of(str(held_out), 0.1, 0.1, 0) == "test"


def test_a_missing_folder_is_one_line(tmp_path, capsys):
    assert main(["--data", str(tmp_path / "none")]) == 1
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "none" in err


@pytest.mark.slow
def test_the_demo_beats_or_equals_the_spline(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(["--steps", "6"]) == 0
    out = capsys.readouterr().out
    rows = {line.split()[0]: line.split() for line in out.splitlines() if line.startswith(("cubic", "mocapfix  "))}
    spline, fixed = rows["cubic"], rows["mocapfix"]
    assert float(fixed[1]) <= float(spline[2]) + 0.05  # holes: "cubic spline" is two words
    assert float(fixed[2]) < 0.5 * float(spline[3])  # the jumped arm
    assert (tmp_path / "logs" / "demo" / "fixed_take" / "demo.gif").stat().st_size > 10_000
    assert (tmp_path / "checkpoints" / "demo" / "last.ckpt").is_file()
