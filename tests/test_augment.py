"""Body augmentations (data/augment.py), tempo and per-source weights in the data module, and the
compact archive: what training on many people rests on."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from mocapfix.core.skeleton import Skeleton, preset
from mocapfix.data.augment import BodyAugment, BodyAugmenter, mirror_index
from mocapfix.data.datamodule import DeviceBatches, MotionDataModule
from mocapfix.data.windows import load_clips, save_clips
from mocapfix.io.synthetic import generate_clips

BODY = preset("body21")
PARENTS = [max(p, 0) for p in BODY.parents]


def _windows(n=6, T=20, seed=0) -> torch.Tensor:
    """(n, T, 21, 3) body21 windows from the synthetic motion's smpl22 bodies, feet near z = 0."""
    clips = generate_clips(2, 2.0, 30.0, seed)
    from mocapfix.rig.mapping import onto_skeleton

    x = np.stack([onto_skeleton(c, BODY).positions[i * 5 : i * 5 + T] for c in clips for i in range(n // 2)])
    return torch.from_numpy(x.astype(np.float32))


def _bone_lengths(x):
    return (x - x[:, :, PARENTS]).norm(dim=-1)[:, :, 1:]  # (B, T, J-1)


def test_stature_scales_every_bone_and_height_by_one_factor():
    x = _windows()
    torch.manual_seed(0)
    y = BodyAugmenter(BODY, BodyAugment(stature_range=0.15))(x)
    ratio = _bone_lengths(y) / _bone_lengths(x)  # (B, T, J-1)
    per_sample = ratio[:, :1, :1]
    assert torch.allclose(ratio, per_sample.expand_as(ratio), atol=1e-4)  # one factor per window
    assert ratio.min() >= 0.85 - 1e-4 and ratio.max() <= 1.15 + 1e-4
    assert (per_sample.flatten() - 1).abs().max() > 0.02  # it did something
    # every height scales by the same factor: feet on the floor stay on it
    assert torch.allclose(y[..., 2], x[..., 2] * per_sample, atol=1e-4)


def test_limb_proportions_differ_by_part_and_match_left_right():
    x = _windows()
    torch.manual_seed(1)
    y = BodyAugmenter(BODY, BodyAugment(limb_range=0.2))(x)
    ratio = (_bone_lengths(y) / _bone_lengths(x))[:, 0]  # (B, J-1), joint j+1's bone
    j = BODY.joint_names.index
    # both arms alike, both legs alike, arms and legs apart
    assert torch.allclose(ratio[:, j("LowerArm_L") - 1], ratio[:, j("LowerArm_R") - 1], atol=1e-4)
    assert torch.allclose(ratio[:, j("LowerLeg_L") - 1], ratio[:, j("LowerLeg_R") - 1], atol=1e-4)
    assert (ratio[:, j("LowerArm_L") - 1] - ratio[:, j("LowerLeg_L") - 1]).abs().max() > 0.01
    assert ratio.min() >= 0.8 - 1e-4 and ratio.max() <= 1.2 + 1e-4


def test_mirror_swaps_sides_and_twice_is_identity():
    x = _windows()
    aug = BodyAugmenter(BODY, BodyAugment(mirror_prob=1.0))
    y = aug(x)
    hl, hr = BODY.joint_names.index("Hand_L"), BODY.joint_names.index("Hand_R")
    assert torch.allclose(y[:, :, hl, 0], -x[:, :, hr, 0]) and torch.allclose(y[:, :, hl, 1:], x[:, :, hr, 1:])
    assert torch.allclose(aug(y), x)


def test_joint_shift_is_constant_in_time_and_within_its_ball():
    x = _windows()
    y = BodyAugmenter(BODY, BodyAugment(joint_shift_m=0.03))(x)
    shift = y - x  # (B, T, J, 3)
    assert torch.allclose(shift, shift[:, :1].expand_as(shift), atol=1e-6)
    assert shift.norm(dim=-1).max() <= 0.03 + 1e-6 and shift.norm(dim=-1).max() > 0.005


def test_missing_stays_missing_and_a_lost_bone_loses_its_chain():
    x = _windows()
    elbow = BODY.joint_names.index("LowerArm_L")
    x[0, 3, elbow] = torch.nan
    y = BodyAugmenter(BODY, BodyAugment(stature_range=0.1, limb_range=0.1))(x)
    assert torch.isnan(y[0, 3, elbow]).all() and torch.isnan(y[0, 3, BODY.joint_names.index("Hand_L")]).all()
    assert not torch.isnan(y[0, 3, BODY.joint_names.index("Hand_R")]).any()
    assert not torch.isnan(y[1:]).any() and not torch.isnan(y[0, :3]).any()


def test_mirror_refuses_a_skeleton_with_an_unpaired_side():
    lopsided = Skeleton(("Hips", "Spine", "Hand_L"), (-1, 0, 1))
    with pytest.raises(ValueError, match="Hand_L.*no right partner"):
        mirror_index(lopsided)
    assert mirror_index(BODY)[BODY.joint_names.index("Foot_R")] == BODY.joint_names.index("Foot_L")


def test_settings_out_of_range_are_refused():
    for bad in (BodyAugment(stature_range=0.7), BodyAugment(mirror_prob=1.5), BodyAugment(joint_shift_m=-0.1)):
        with pytest.raises(ValueError):
            bad.check()


def _archive(tmp_path: Path) -> Path:
    """An archive of two 'studios' (folders a and b), b four times the size of a."""
    clips = []
    for k, (folder, seconds) in enumerate((("a", 3.0), ("b", 12.0))):
        for i, c in enumerate(generate_clips(2, seconds, 30.0, seed=k)):
            clips.append(c.replace(name=f"{folder}{i}", source=f"/data/{folder}/take{i}.bvh"))
    path = tmp_path / "corpus.npz"
    save_clips(path, clips, compact=True)
    return path


def test_compact_archive_round_trip(tmp_path):
    clips = generate_clips(3, 2.0, 30.0, seed=3)
    clips[1].positions[5:9, 4] = np.nan
    path = tmp_path / "c.npz"
    save_clips(path, clips, compact=True)
    back = load_clips(path)
    for a, b in zip(clips, back):
        assert a.name == b.name and a.fps == b.fps and a.skeleton == b.skeleton
        assert np.array_equal(np.isnan(a.positions), np.isnan(b.positions))
        assert np.nanmax(np.abs(a.positions - b.positions)) <= 0.0005 + 1e-6  # to the millimetre
    full = tmp_path / "f.npz"
    save_clips(full, clips)
    assert path.stat().st_size < full.stat().st_size / 3


def test_tempo_factors_add_faster_and_slower_training_clips(tmp_path):
    path = _archive(tmp_path)
    common = dict(source="archive", path=str(path), cache_dir=None, val_fraction=0, test_fraction=0)
    plain = MotionDataModule(**common)
    plain.setup("fit")
    tempo = MotionDataModule(**common, tempo_factors=[0.8, 1.25])
    tempo.setup("fit")
    frames = lambda dm: sum(c.num_frames for c in dm.clips["train"])  # noqa: E731
    assert frames(tempo) == pytest.approx(frames(plain) * (1 + 1 / 0.8 + 1 / 1.25), rel=0.01)
    assert all(c.fps == 30.0 for c in tempo.clips["train"])
    with pytest.raises(ValueError, match="tempo"):
        MotionDataModule(**common, tempo_factors=[10.0])


def test_source_weights_set_each_studios_share_of_the_batches(tmp_path):
    path = _archive(tmp_path)
    dm = MotionDataModule(
        source="archive",
        path=str(path),
        cache_dir=None,
        val_fraction=0,
        test_fraction=0,
        stride_s=0.1,
        source_weights={"*/a/*": 1.0, "*/b/*": 1.0},
    )
    dm.setup("fit")
    ds = dm.datasets["train"]
    clip_in_a = torch.tensor([c.source.startswith("/data/a/") for c in dm.clips["train"]])
    assert clip_in_a[ds.clip_index].float().mean() < 0.25  # a is the small studio
    torch.manual_seed(0)
    drawn = torch.cat([b["clip_index"] for b in DeviceBatches(ds, 64, torch.device("cpu"))])
    share_a = clip_in_a[drawn].float().mean().item()
    assert share_a == pytest.approx(0.5, abs=0.05)
    with pytest.raises(ValueError, match="positive"):
        MotionDataModule(source="archive", path=str(path), source_weights={"*/a/*": 0.0})
