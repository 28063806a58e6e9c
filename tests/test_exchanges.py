"""Left and right limbs exchanged for a few frames are found and put back (fix/exchanges.py), and
none is invented in a clean take."""

from __future__ import annotations

import numpy as np
import pytest
from cli_utils import run_mocapfix

from mocapfix.core.skeleton import preset
from mocapfix.fix.exchanges import put_back_exchanges
from mocapfix.io.conventions import from_z_up

BODY = preset("body21")


def exchange(x: np.ndarray, pair: tuple[str, str], start: int, frames: int) -> np.ndarray:
    left, right = list(BODY.groups[pair[0]]), list(BODY.groups[pair[1]])
    out = x.copy()
    out[start : start + frames, left + right] = x[start : start + frames, right + left]
    return out


def test_clean_takes_keep_their_labels(body21_takes):
    for x in body21_takes:
        noisy = x + np.random.default_rng(0).normal(scale=0.01, size=x.shape)  # a tracker's jitter too
        for take in (x, noisy):
            y, runs, frames = put_back_exchanges(take, BODY, 30.0)
            assert runs == 0 and np.array_equal(y, take)


def test_a_run_to_the_takes_end_is_its_own_labelling_however_short(body21_takes):
    """A 1.2-s take whose arms read exchanged from its third frame on (CMU subject 09's runs:
    their first frames off) keeps its labels: nothing after the run says which labelling is the
    slip."""
    x = body21_takes[0][:36]
    for start in (2, 20):
        swapped = exchange(x, ("left_arm", "right_arm"), start, len(x) - start)
        y, runs, _ = put_back_exchanges(swapped, BODY, 30.0)
        assert runs == 0 and np.array_equal(y, swapped)


def test_a_take_with_a_row_every_few_frames_keeps_its_labels_and_its_slips_are_found(body21_takes):
    """UTKinect's rows land 1-6 frames apart on their clock: a labelling read off the wrong way
    over a long stretch of it, cut by the holes into runs of one frame, was put back in hundreds of
    one-frame runs (575 in one of its takes). A run spans its holes; a real slip is still found."""
    rng = np.random.default_rng(5)
    for x in body21_takes[:6]:
        holed = x.copy()
        holed[rng.random(len(x)) < 0.5] = np.nan  # half the frames with no row
        y, runs, _ = put_back_exchanges(holed, BODY, 30.0)
        assert runs == 0 and np.array_equal(y, holed, equal_nan=True)
        long = exchange(holed, ("left_arm", "right_arm"), 30, len(x) - 60)  # the middle of the take, over 1.5 s
        y, runs, _ = put_back_exchanges(long, BODY, 30.0)
        assert runs == 0
        slip = exchange(holed, ("left_leg", "right_leg"), 40, 10)
        y, runs, _ = put_back_exchanges(slip, BODY, 30.0)
        assert runs == 1 and np.array_equal(y, holed, equal_nan=True)


def test_jitter_far_over_a_shoulders_width_invents_no_exchange(body21_takes):
    """Every frame 12 cm off (a heading misses by ~30 cm): a fixed 5-cm margin lost to chance
    every few frames and put back a run of arms or legs each time (the jitter remover's benchmark,
    0.1 rad on every joint, went 25.8 -> 51 mm); the margin grows with the take's own misses."""
    invented = 0
    for i, x in enumerate(body21_takes[:10]):
        noisy = x + np.random.default_rng(i).normal(scale=0.12, size=x.shape)
        _, runs, _ = put_back_exchanges(noisy, BODY, 30.0)
        invented += runs
    assert invented <= 1


@pytest.mark.parametrize("jitter_m", [0.0, 0.025])
def test_exchanges_of_3_to_30_frames_are_put_back(body21_takes, jitter_m):
    """Clean, and under 25 mm of jitter per coordinate (a depth camera's): a frame-by-frame test
    against where the limbs were heading put back 75 % of these on Bandai's takes at 25 mm (58 of
    these 90); the whole-take labelling 98.6 %."""
    rng = np.random.default_rng(2)
    put_back = tried = 0
    for x in body21_takes:
        noisy = x + rng.normal(scale=jitter_m, size=x.shape)
        for pair in (("left_arm", "right_arm"), ("left_leg", "right_leg")):
            frames = int(rng.integers(3, 31))
            if len(x) < frames + 20:
                continue
            start = int(rng.integers(10, len(x) - frames - 10))
            y, runs, n = put_back_exchanges(exchange(noisy, pair, start, frames), BODY, 30.0)
            tried += 1
            put_back += bool(np.array_equal(y, noisy) and runs == 1 and n == frames)
    assert tried >= 60 and put_back >= 0.95 * tried


def test_an_absurd_first_frame_does_not_set_the_labels(body21_takes):
    """A CMU take's first frame is a T-pose: whichever labelling it reads as, the take's own is
    that of the frames after it, and an exchange later on is put back."""
    x = body21_takes[1].copy()
    x[0] = x[0, :1] + np.random.default_rng(3).normal(scale=0.5, size=x[0].shape)  # limbs anywhere
    swapped = exchange(x, ("left_arm", "right_arm"), 30, 12)
    y, runs, n = put_back_exchanges(swapped, BODY, 30.0)
    assert runs == 1 and n == 12 and np.array_equal(y, x)


def test_an_exchange_longer_than_the_limit_is_the_takes_own_labelling(body21_takes):
    x = max(body21_takes, key=len)
    swapped = exchange(x, ("left_leg", "right_leg"), 10, len(x) - 10)  # exchanged from frame 10 on
    y, runs, _ = put_back_exchanges(swapped, BODY, 30.0)
    assert runs == 0 and np.array_equal(y, swapped)


def test_fix_both_puts_a_lifters_exchange_back_and_infill_leaves_it(tmp_path, body21_takes, capsys):
    """A Human3.6M-17 array (what video lifters write) with its arms exchanged for 8 frames."""
    x = max(body21_takes, key=len)
    h36m = [BODY.index(n) for n in ("Hips", "UpperLeg_R", "LowerLeg_R", "Foot_R", "UpperLeg_L", "LowerLeg_L",
                                     "Foot_L", "Spine", "Chest", "Neck", "Head", "UpperArm_L", "LowerArm_L",
                                     "Hand_L", "UpperArm_R", "LowerArm_R", "Hand_R")]  # fmt: skip
    clean = x[:, h36m]
    bad = clean.copy()
    bad[40:48, [11, 12, 13, 14, 15, 16]] = clean[40:48, [14, 15, 16, 11, 12, 13]]
    np.save(tmp_path / "lifted.npy", from_z_up(bad, "y").astype(np.float32))
    base = ["fix", tmp_path / "lifted.npy", "--layout", "h36m17", "--fps", "30", "--model", "xmae-cpu-bandai"]
    rc, out, err = run_mocapfix([*base, "--mode", "both"], capsys)
    assert rc == 0, err
    assert "left and right limbs exchanged in 8 frames (1 runs): put back" in out
    fixed = np.load(tmp_path / "lifted.fixed.npy")
    wrist_error = np.linalg.norm(fixed[40:48, 13] - from_z_up(clean[40:48, 13], "y"), axis=-1)
    assert wrist_error.max() < 0.1  # the left wrist is on the left again (0.3-0.6 m away while exchanged)
    rc, out, err = run_mocapfix([*base, "--mode", "infill", "--force"], capsys)
    assert rc == 0, err
    assert "exchanged" not in out
    assert np.array_equal(np.load(tmp_path / "lifted.fixed.npy"), np.load(tmp_path / "lifted.npy"))
