"""A limb held in a flipped pose for a moment (fix/flips.py) is found, `fix --mode both` fills it
again, and clean takes are left alone."""

from __future__ import annotations

import numpy as np
import pytest
from cli_utils import run_mocapfix
from scipy.spatial.transform import Rotation

from mocapfix.core.skeleton import preset
from mocapfix.fix.flips import LIMBS, flipped_segments
from mocapfix.io.positions import write_positions

BODY = preset("body21")


def flip(x: np.ndarray, limb: str, start: int, frames: int, degrees: float, axis=(0.3, -0.5, 0.8)) -> np.ndarray:
    joints = list(BODY.groups[limb])
    turn = Rotation.from_rotvec(np.asarray(axis) / np.linalg.norm(axis) * np.deg2rad(degrees)).as_matrix()
    out, top = x.copy(), joints[0]
    span = slice(start, start + frames)
    for j in joints[1:]:
        out[span, j] = (x[span, j] - x[span, top]) @ turn.T + x[span, top]
    return out


def test_clean_takes_have_no_flip(body21_takes):
    assert sum(len(flipped_segments(x, list(BODY.groups[g]), 30.0)) for x in body21_takes for g in LIMBS) == 0


@pytest.mark.parametrize("limb", ["left_arm", "right_leg"])
def test_a_limb_turned_for_0_2_to_0_6_s_is_found_where_it_is(body21_takes, limb):
    """Flips that move the limb by 10 cm or more on average (a turn about the limb's own line
    moves it little: a twist, which positions cannot show)."""
    rng = np.random.default_rng(3)
    joints = list(BODY.groups[limb])
    found = tried = 0
    for x in body21_takes:
        frames = int(rng.integers(6, 19))
        start = int(rng.integers(15, len(x) - frames - 15))
        bad = flip(x, limb, start, frames, rng.uniform(45, 90), rng.normal(size=3))
        if np.linalg.norm(bad[:, joints] - x[:, joints], axis=-1)[start : start + frames].mean() < 0.1:
            continue
        segments = flipped_segments(bad, joints, 30.0)
        tried += 1
        found += any(abs(a - start) <= 2 and abs(b - start - frames) <= 2 for a, b in segments)
    assert tried >= 20 and found >= 0.9 * tried


def test_fix_both_fills_a_flipped_arm_again_and_infill_leaves_it(tmp_path, body21_takes, capsys):
    x = max(body21_takes, key=len)
    bad = flip(x, "left_arm", 60, 12, 60.0)  # 60 degrees for 0.4 s, the hand 0.2-0.4 m away
    write_positions(tmp_path / "take.npz", bad, 30.0, BODY)
    base = ["fix", tmp_path / "take.npz", "--model", "xmae-cpu-bandai"]
    rc, out, err = run_mocapfix([*base, "--mode", "both"], capsys)
    assert rc == 0, err
    assert "1 limbs held in a flipped pose for a moment" in out
    with np.load(tmp_path / "take.fixed.npz") as data:
        y = data["positions"].astype(np.float64)
    arm, span = list(BODY.groups["left_arm"]), slice(60, 72)
    before = np.linalg.norm(bad[span][:, arm] - x[span][:, arm], axis=-1).mean()
    after = np.linalg.norm(y[span][:, arm] - x[span][:, arm], axis=-1).mean()
    assert after < 0.2 * before
    rc, out, err = run_mocapfix([*base, "--mode", "infill", "--force"], capsys)
    assert rc == 0 and "flipped pose" not in out
