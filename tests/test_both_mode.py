"""`fix --mode both` on performers the model never saw (CMU takes, the shipped Bandai model):
clean data stays as recorded, a jumped arm is found and put back, and a BVH written back keeps
every joint fix did not replace where it was recorded."""

from __future__ import annotations

import json

import numpy as np
import pytest

from mocapfix.apps.main import main
from mocapfix.fix import fix_clips
from mocapfix.fix.fixers import load_fixer
from mocapfix.io import read_motion
from mocapfix.io.bvh import write_bvh
from mocapfix.pretrained import pretrained_path


@pytest.fixture(scope="module")
def fixer():
    return load_fixer(str(pretrained_path("xmae-cpu-bandai")))


@pytest.fixture(scope="module")
def take(cmu_files):
    """A 4-s dance take of CMU subject 06 (120 fps)."""
    [f] = [f for f in cmu_files if f.name == "06_01.bvh"]
    return f


def _both_bvh(path, tmp_path, capsys):
    out = tmp_path / "out.bvh"
    capsys.readouterr()
    assert main(["fix", str(path), "--model", "xmae-cpu-bandai", "--mode", "both", "-o", str(out), "--json"]) == 0
    report = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    [fixed] = read_motion(out)
    return fixed, report


def test_both_on_a_clean_take_keeps_what_it_does_not_replace(take, fixer, tmp_path, capsys):
    [clip] = read_motion(take)
    [direct], _ = fix_clips([clip], fixer, "both")
    kept = (direct.positions == clip.positions).all(-1)  # (T, J) what fix did not replace
    assert kept.mean() >= 0.99
    fixed, report = _both_bvh(take, tmp_path, capsys)
    moved = np.linalg.norm(fixed.positions - clip.positions, axis=-1)  # (T, J) metres
    assert (moved > 0.001).mean() <= 0.01, (moved > 0.001).mean()
    assert moved[kept].max() <= 0.001, moved[kept].max()  # the BVH's IK keeps them within 1 mm


def test_both_puts_a_jumped_arm_back(take, fixer, tmp_path, capsys):
    """The left upper arm's rotation jumps by 2.5 rad for 0.5 s twice (a marker swap that the
    solver followed; elbow and hand 0.4-0.6 m away): the arm is found and put back, with its
    fingers; what was not replaced stays within 1 mm."""
    [clip] = read_motion(take)
    arm = clip.skeleton.index("LeftArm")
    below = [j for j in range(clip.skeleton.num_joints) if arm in _chain(clip.skeleton.parents, j)[1:]]
    rotations = clip.rotations.copy()
    jumped = np.zeros(clip.positions.shape[:2], dtype=bool)
    for start in (90, 300):
        rotations[start : start + 60, arm] += np.array([0.0, 0.0, 2.5], dtype=np.float32)
        jumped[start : start + 60, below] = True
    path = tmp_path / "jumped.bvh"
    write_bvh(path, clip.replace(rotations=rotations), template=take)
    [bad] = read_motion(path)
    before = np.linalg.norm(bad.positions - clip.positions, axis=-1)
    assert before[jumped].min() > 0.3 and before[~jumped].max() < 1e-3
    fixed, report = _both_bvh(path, tmp_path, capsys)
    after = np.linalg.norm(fixed.positions - clip.positions, axis=-1)
    assert after[jumped].mean() <= 0.2 * before[jumped].mean(), (after[jumped].mean(), before[jumped].mean())
    assert (after[~jumped] > 0.001).mean() <= 0.01


def _chain(parents, j):
    """j and its ancestors."""
    out = []
    while j >= 0:
        out.append(j)
        j = parents[j]
    return out
