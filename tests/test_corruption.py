import math

import numpy as np
import pytest
import roma
import torch

from mocapfix.core.kinematics import fk_axis_angle
from mocapfix.core.skeleton import preset
from mocapfix.data.corruption import (
    available,
    constant_displacement,
    gap_frames,
    gaussian_noise,
    infill_gap,
    mask_and_displace,
    random_z_rotation,
    rotate_z,
    rotation_noise,
    training_gaps,
    training_holes,
)
from mocapfix.models.xmae_inference import denormalize, kept_index, normalize
from mocapfix.training.xmae_input import xmae_training_input

B, T, J = 6, 50, 17
N = T * J


def gen(seed=0):
    return torch.Generator().manual_seed(seed)


def motion(seed=0, nan_frac=0.0):
    x = torch.randn(B, T, J, 3, generator=gen(seed), dtype=torch.float64)
    if nan_frac:
        drop = torch.rand(B, T, J, generator=gen(seed + 1)) < nan_frac
        x[drop] = float("nan")
    return x


def test_fixed_counts_and_displaced_subset():
    x = motion()
    c = mask_and_displace(x, 0.85, 0.05, generator=gen())
    K, D = round(0.15 * N), round(0.05 * N)
    assert c.observed.sum(dim=(1, 2)).tolist() == [K] * B
    assert c.displaced.sum(dim=(1, 2)).tolist() == [D] * B
    assert not (c.displaced & ~c.observed).any()
    # kept clean tokens untouched, masked tokens 0, displaced tokens moved
    clean = c.observed & ~c.displaced
    assert torch.equal(c.positions[clean], x[clean])
    assert (c.positions[~c.observed] == 0).all()
    assert ((c.positions - x)[c.displaced].norm(dim=-1) > 0).all()
    # the chosen tokens differ between samples (not one shared mask)
    assert not torch.equal(c.observed[0], c.observed[1])


def test_nan_tokens_never_observed_and_short_samples_keep_all():
    x = motion(nan_frac=0.3)
    x[0] = float("nan")
    x[1, :, :] = float("nan")
    x[1, 0, :5] = 1.0  # only 5 tokens of data in sample 1: fewer than K
    c = mask_and_displace(x, generator=gen(3))
    avail = available(x)
    assert not (c.observed & ~avail).any()
    assert not torch.isnan(c.positions).any()
    counts = c.observed.sum(dim=(1, 2))
    assert counts[0] == 0 and counts[1] == 5
    assert (counts[2:] == round(0.15 * N)).all()
    # displaced share of the kept tokens kept for the short sample: round(5 * D / K)
    assert c.displaced[1].sum() == round(5 * round(0.05 * N) / round(0.15 * N))
    assert c.displaced[0].sum() == 0


def test_bernoulli_mode_rates():
    x = torch.zeros(64, T, J, 3)
    c = mask_and_displace(x, 0.85, 0.05, fixed_kept_count=False, generator=gen())
    kept_rate = c.observed.float().mean().item()
    disp_rate = c.displaced.float().mean().item()
    assert abs(kept_rate - 0.15) < 0.01 and abs(disp_rate - 0.05) < 0.005
    assert c.observed.sum(dim=(1, 2)).unique().numel() > 1  # counts vary per sample
    assert not (c.displaced & ~c.observed).any()


def test_displacement_uniform_in_ball():
    R = 0.5
    x = torch.zeros(200, T, J, 3)
    c = mask_and_displace(x, 0.5, 0.5, max_displacement_m=R, generator=gen())
    off = c.positions[c.displaced]  # offsets from 0
    r = off.norm(dim=-1)
    assert r.max() <= R + 1e-6
    # uniform in a ball: E[r] = 3R/4, P(r < R/2) = 1/8, direction mean ~ 0
    assert abs(r.mean().item() - 0.75 * R) < 0.01 * R
    assert abs((r < R / 2).float().mean().item() - 0.125) < 0.01
    assert (off / r[:, None]).mean(dim=0).abs().max() < 0.02


def test_determinism_and_generator_use():
    x = motion(nan_frac=0.1)
    a = mask_and_displace(x, generator=gen(7))
    b = mask_and_displace(x, generator=gen(7))
    c = mask_and_displace(x, generator=gen(8))
    for u, v in zip(a, b):
        assert torch.equal(u, v)
    assert not torch.equal(a.observed, c.observed)
    # same seed, float32 batch: same tokens chosen (random draws do not depend on dtype)
    d = mask_and_displace(x.float(), generator=gen(7))
    assert torch.equal(a.observed, d.observed) and torch.equal(a.displaced, d.displaced)


def test_training_gaps_remove_whole_frames_and_keep_counts():
    x = motion()
    gaps = training_gaps(4000, T, 0.5, gen(1), x)  # (4000, T)
    has = gaps.any(dim=1)
    assert abs(has.float().mean().item() - 0.5) < 0.04
    length = gaps.sum(dim=1)[has]
    assert length.min() == 1 and length.max() == T - 2
    # one contiguous stretch per window: a single rising edge
    rises = (gaps[:, 1:] & ~gaps[:, :-1]).sum(dim=1) + gaps[:, 0]
    assert (rises[has] == 1).all()
    assert gaps[:, 0].any() and gaps[:, -1].any()  # anywhere, edges too

    c = mask_and_displace(x, generator=gen(2), gap_ratio=1.0)
    gaps = training_gaps(B, T, 1.0, gen(2), x)  # the same first draws
    assert not c.observed[gaps].any()  # every joint of a gap frame
    K = round(0.15 * N)
    left = (~gaps).sum(dim=1) * J  # tokens outside the gap
    assert c.observed.sum(dim=(1, 2)).tolist() == torch.clamp(left, max=K).tolist()
    # gap_ratio 0 draws nothing extra: the paper's corruption, token for token
    a, b = mask_and_displace(x, generator=gen(2)), mask_and_displace(x, generator=gen(2), gap_ratio=0.0)
    assert torch.equal(a.observed, b.observed) and torch.equal(a.positions, b.positions)


def test_training_holes_take_one_part_for_one_stretch_inside_the_window():
    x = motion()
    parts = torch.zeros(3, J, dtype=torch.bool)
    parts[0] = True  # the whole body
    parts[1, :4] = True
    parts[2, 10:12] = True
    holes = training_holes(3000, T, parts, 20, gen(3), x)  # (3000, T, J)
    frames = holes.any(dim=2)  # (3000, T)
    length = frames.sum(dim=1)
    assert length.min() == 1 and length.max() == 20  # every window has one, 1..max frames
    rises = (frames[:, 1:] & ~frames[:, :-1]).sum(dim=1) + frames[:, 0]
    assert (rises == 1).all()  # one contiguous stretch
    assert not frames[:, 0].any() and not frames[:, -1].any()  # observed data on both sides
    joints = holes.any(dim=1)  # (3000, J): which joints went missing
    which = (joints[:, None, :] == parts[None]).all(dim=2)  # (3000, 3): exactly one part's joints
    assert (which.sum(dim=1) == 1).all()
    share = which.float().mean(dim=0)
    assert (share - 1 / 3).abs().max() < 0.04  # parts drawn uniformly
    # a window too short for the longest hole still keeps a frame either side
    short = training_holes(500, 5, parts, 20, gen(4), x).any(dim=2)
    assert short.sum(dim=1).max() == 3 and not short[:, 0].any() and not short[:, -1].any()
    # margin: as many observed frames either side as asked, or as the window leaves around the hole
    wide = training_holes(3000, T, parts, T, gen(5), x, margin=6).any(dim=2)
    n = wide.sum(dim=1)
    before = wide.float().argmax(dim=1)
    after = T - before - n
    want = ((T - n) // 2).clamp(max=6)
    assert (before >= want).all() and (after >= want).all() and n.max() == T - 2


def test_hole_windows_observe_everything_but_the_hole():
    x = motion(nan_frac=0.05)
    parts = torch.ones(1, J, dtype=torch.bool)
    ti = xmae_training_input(x, 0.85, 0.05, 1.0, True, False, gen(5), 0.0, 1.0, parts, 10)
    c = ti.corrupted
    assert not c.displaced.any()  # no displaced token: only the hole is scored
    missing = available(x) & ~c.observed  # (B, T, J) the hole's tokens that have data
    frames = missing.any(dim=2)
    assert (frames.sum(dim=1) >= 1).all() and (frames.sum(dim=1) <= 10).all()
    assert (missing == (available(x) & frames[:, :, None])).all()  # every joint of a hole frame, nothing else
    assert ti.kept.shape == (B, N)  # the encoder reads whole windows (padding covers the rest)
    assert (~ti.padding).sum(dim=1).tolist() == c.observed.sum(dim=(1, 2)).tolist()
    # hole_ratio 0: the paper's corruption, token for token
    a = xmae_training_input(x, 0.85, 0.05, 1.0, True, False, gen(6))
    b = xmae_training_input(x, 0.85, 0.05, 1.0, True, False, gen(6), 0.0, 0.0, parts, 10)
    assert torch.equal(a.corrupted.observed, b.corrupted.observed) and torch.equal(a.kept, b.kept)
    with pytest.raises(ValueError, match="max_hole_frames"):
        xmae_training_input(x, 0.85, 0.05, 1.0, True, False, gen(6), 0.0, 0.5, None, 10)


def test_invalid_ratios():
    with pytest.raises(ValueError, match="gap_ratio"):
        mask_and_displace(motion(), gap_ratio=1.5)
    with pytest.raises(ValueError):
        mask_and_displace(motion(), 0.9, 0.2)


def test_kept_index():
    observed = torch.rand(4, 5, 3, generator=gen()) < 0.4
    observed[2] = False
    idx, pad = kept_index(observed)
    counts = observed.reshape(4, -1).sum(dim=1)
    assert idx.shape == (4, int(counts.max())) and idx.dtype == torch.long
    for b in range(4):
        expect = [t * 3 + j for t in range(5) for j in range(3) if observed[b, t, j]]
        n = len(expect)
        assert idx[b, :n].tolist() == expect
        assert not pad[b, :n].any() and pad[b, n:].all()
        assert (idx[b, n:] == 0).all()
    # gathering with the index returns the observed tokens in t-major, joint-fastest order
    x = torch.arange(4 * 5 * 3).reshape(4, 5 * 3)
    g = x.gather(1, idx)
    assert g[0, : counts[0]].tolist() == x[0][observed[0].reshape(-1)].tolist()
    idx0, pad0 = kept_index(torch.zeros(2, 3, 4, dtype=torch.bool))
    assert idx0.shape == (2, 0) and pad0.shape == (2, 0)


@pytest.mark.parametrize(
    "T_, fps, gap_s, start, stop",
    [(50, 50, 0.1, 23, 28), (50, 50, 0.3, 18, 33), (60, 60, 0.9, 3, 57), (30, 30, 0.4, 9, 21), (51, 50, 0.5, 13, 38)],
)
def test_gap_frames_centred(T_, fps, gap_s, start, stop):
    assert gap_frames(T_, fps, gap_s) == (start, stop)


def test_infill_gap_masks():
    x = motion(nan_frac=0.05)
    arm = [11, 12, 13]
    c = infill_gap(x, fps=50, gap_s=0.3, joints=arm)
    start, stop = gap_frames(T, 50, 0.3)
    expect = available(x).clone()
    expect[:, start:stop, arm] = False
    assert torch.equal(c.observed, expect)
    assert not c.displaced.any()
    assert torch.equal(c.positions[c.observed], x[c.observed])
    assert (c.positions[~c.observed] == 0).all() and not torch.isnan(c.positions).any()
    full = infill_gap(x, fps=50, gap_s=0.3)
    assert not full.observed[:, start:stop].any()
    assert torch.equal(full.observed[:, :start], available(x)[:, :start])
    with pytest.raises(ValueError):
        infill_gap(x, fps=50, gap_s=1.1)


def test_constant_displacement():
    x = motion(nan_frac=0.05)
    arm = [14, 15, 16]
    c = constant_displacement(x, 50, 0.5, arm, generator=gen(1))
    start, stop = gap_frames(T, 50, 0.5)
    assert torch.equal(c.observed, available(x))
    expect = torch.zeros(B, T, J, dtype=torch.bool)
    expect[:, start:stop, arm] = True
    assert torch.equal(c.displaced, expect & available(x))
    d = c.positions - torch.nan_to_num(x)
    for b in range(B):
        offs = d[b][c.displaced[b]]
        assert torch.allclose(offs, offs[0].expand_as(offs), atol=1e-12)  # one offset per sample
        assert 0.5 - 1e-9 <= offs[0].norm() <= 1.0 + 1e-9
    assert (d[~c.displaced] == 0).all()
    again = constant_displacement(x, 50, 0.5, arm, generator=gen(1))
    assert torch.equal(again.positions, c.positions)


def test_gaussian_noise():
    x = motion(nan_frac=0.1)
    c = gaussian_noise(x, 0.02, generator=gen())
    assert torch.equal(c.observed, available(x)) and torch.equal(c.displaced, c.observed)
    noise = (c.positions - x)[c.observed]
    assert abs(noise.std().item() - 0.02) < 0.001
    assert not torch.isnan(c.positions).any()
    assert torch.equal(gaussian_noise(x, 0.02, generator=gen()).positions, c.positions)


def test_rotation_noise_matches_fk():
    sk = preset("h36m17")
    rot = 0.3 * torch.randn(2, 10, sk.num_joints, 3, generator=gen(), dtype=torch.float64)
    trans = torch.randn(2, 10, 3, generator=gen(1), dtype=torch.float64)
    offsets = 0.2 * torch.randn(sk.num_joints, 3, generator=gen(2), dtype=torch.float64)
    noisy_rot, noisy_pos = rotation_noise(rot, trans, offsets, sk.parents, 0.1, generator=gen(3))
    assert torch.equal(noisy_rot[..., 0, :], rot[..., 0, :])  # root orientation untouched by default
    assert abs((noisy_rot - rot)[..., 1:, :].std().item() - 0.1) < 0.01
    assert torch.allclose(noisy_pos, fk_axis_angle(noisy_rot, trans, offsets, sk.parents))
    # independent check of one joint's position from rotation matrices
    R = roma.rotvec_to_rotmat(noisy_rot)
    j = 3  # RFoot: 0 -> 1 -> 2 -> 3
    p = (
        trans
        + (R[..., 0, :, :] @ offsets[1])
        + (R[..., 0, :, :] @ R[..., 1, :, :] @ offsets[2])
        + (R[..., 0, :, :] @ R[..., 1, :, :] @ R[..., 2, :, :] @ offsets[3])
    )
    assert torch.allclose(noisy_pos[..., j, :], p)
    only_arm, _ = rotation_noise(rot, trans, offsets, sk.parents, 0.1, generator=gen(3), joints=[11, 12])
    changed = (only_arm != rot).any(dim=-1).any(dim=(0, 1))
    assert changed.nonzero().flatten().tolist() == [11, 12]


def test_normalize_over_observed_tokens():
    x = motion(nan_frac=0.1) + torch.tensor([5.0, -3.0, 1.0], dtype=torch.float64)
    c = mask_and_displace(x, generator=gen())
    normed, offset = normalize(c.positions, c.observed)
    assert offset.shape == (B, 1, 1, 3) and (offset[..., 2] == 0).all()
    for b in range(B):
        obs = normed[b][c.observed[b]]
        assert torch.allclose(obs[:, :2].mean(dim=0), torch.zeros(2, dtype=torch.float64), atol=1e-12)
        # mean computed over observed tokens of the CORRUPTED input (displaced included)
        assert torch.allclose(offset[b, 0, 0, :2], c.positions[b][c.observed[b]][:, :2].mean(dim=0))
    assert torch.equal(normed[..., 2], c.positions[..., 2])
    assert torch.allclose(denormalize(normed, offset), c.positions)
    # NaN at unobserved tokens does not reach the mean; no observed token -> offset 0, no NaN
    obs = available(x)
    obs[0] = False
    normed_raw, off_raw = normalize(x, obs)
    assert not torch.isnan(off_raw).any() and (off_raw[0] == 0).all()
    assert torch.allclose(normed_raw[1][obs[1]][:, :2].mean(dim=0), torch.zeros(2, dtype=torch.float64), atol=1e-12)


def test_rotate_z():
    x = motion()
    rotated, angle = random_z_rotation(x, generator=gen())
    assert angle.shape == (B,) and (angle >= 0).all() and (angle < 2 * math.pi).all()
    assert torch.allclose(rotate_z(rotated, -angle), x)
    assert torch.equal(rotated[..., 2], x[..., 2])
    assert torch.allclose(rotated[..., :2].norm(dim=-1), x[..., :2].norm(dim=-1))
    quarter = rotate_z(torch.tensor([[1.0, 0.0, 2.0]]), torch.tensor([math.pi / 2]))
    assert torch.allclose(quarter, torch.tensor([[0.0, 1.0, 2.0]]), atol=1e-7)
    # numpy reference rotation on one sample
    c, s = np.cos(angle[2].item()), np.sin(angle[2].item())
    Rz = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    assert np.allclose(rotated[2].numpy(), x[2].numpy() @ Rz.T)


def test_cpu_generator_same_result_for_any_batch_device():
    # draws happen on the generator's device: a CPU generator is valid for any batch device
    x = motion()
    a = mask_and_displace(x, generator=gen(5))
    dev = "cuda" if torch.cuda.is_available() else "cpu"
    b = mask_and_displace(x.to(dev), generator=gen(5))
    assert torch.equal(a.observed, b.observed.cpu())
    assert torch.allclose(a.positions, b.positions.cpu())


@pytest.mark.gpu
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_mask_and_displace_on_cuda():
    x = motion(nan_frac=0.1).float().cuda()
    g = torch.Generator(device="cuda").manual_seed(0)
    c = mask_and_displace(x, generator=g)
    assert c.positions.is_cuda and c.observed.is_cuda and c.displaced.is_cuda
    assert (c.observed.sum(dim=(1, 2)) == round(0.15 * N)).all()
    assert (c.displaced.sum(dim=(1, 2)) == round(0.05 * N)).all()
    assert not (c.observed & ~available(x)).any() and not torch.isnan(c.positions).any()
    idx, pad = kept_index(c.observed)
    assert idx.is_cuda and not pad.any()
    normed, offset = normalize(c.positions, c.observed)
    rotated, angle = random_z_rotation(normed)
    assert torch.allclose(rotate_z(rotated, -angle), normed, atol=1e-5)
    h = infill_gap(x, 50, 0.3, [11, 12, 13])
    assert h.observed.is_cuda
