import numpy as np
import pytest
import torch

from mocapfix.data.corruption import infill_gap
from mocapfix.fills.classical import lerp_infill


def np_lerp(x, observed):
    """Per-joint np.interp reference (np.interp holds the edge values outside the observed range)."""
    B, T, J, _ = x.shape
    out = np.empty_like(x)
    seen = observed.any(axis=1)  # (B, J)
    for b in range(B):
        for j in range(J):
            if not seen[b, j]:
                continue
            ts = np.nonzero(observed[b, :, j])[0]
            for k in range(3):
                out[b, :, j, k] = np.interp(np.arange(T), ts, x[b, ts, j, k])
        for j in range(J):
            if not seen[b, j]:
                out[b, :, j] = out[b][:, seen[b]].mean(axis=1) if seen[b].any() else 0.0
    return out


def test_lerp_matches_np_interp_on_random_masks():
    rng = np.random.default_rng(0)
    B, T, J = 5, 40, 6
    x = rng.normal(size=(B, T, J, 3))
    observed = rng.random((B, T, J)) < 0.3
    observed[0, :, 2] = False  # a joint never observed: body mean
    observed[1, :, 0] = False
    observed[1, 7, 0] = True  # a single observation: held everywhere
    observed[2] = False  # nothing observed: zeros
    x[~observed] = np.nan  # values at unobserved tokens must not matter
    out = lerp_infill(torch.from_numpy(x), torch.from_numpy(observed))
    ref = np_lerp(x, observed)
    assert not torch.isnan(out).any()
    np.testing.assert_allclose(out.numpy(), ref, rtol=1e-12, atol=1e-12)
    assert (out[2] == 0).all()
    assert torch.allclose(out[1, :, 0], torch.from_numpy(x[1, 7, 0]).expand(T, 3))
    # observed tokens bit-identical
    obs = torch.from_numpy(observed)
    assert torch.equal(out[obs], torch.from_numpy(x)[obs])


def test_lerp_exact_on_linear_motion_and_border_gaps():
    T = 30
    tt = torch.arange(T, dtype=torch.float32)
    x = torch.stack([0.1 * tt, -0.2 * tt, torch.ones(T)], dim=-1)[None, :, None, :].repeat(2, 1, 3, 1)  # (2, T, 3, 3)
    c = infill_gap(x, fps=30, gap_s=0.5)
    out = lerp_infill(c.positions, c.observed)
    assert torch.allclose(out, x, atol=1e-6)  # linear motion: lerp is exact inside the window
    observed = torch.ones(2, T, 3, dtype=torch.bool)
    observed[:, :5] = False
    observed[:, -4:] = False
    out = lerp_infill(x, observed)
    assert torch.equal(out[:, :5], x[:, 5:6].expand(2, 5, 3, 3))  # held first observed value
    assert torch.equal(out[:, -4:], x[:, -5:-4].expand(2, 4, 3, 3))  # held last observed value


def test_lerp_float32_and_observed_nan_treated_as_missing():
    rng = np.random.default_rng(1)
    x = torch.from_numpy(rng.normal(size=(2, 20, 4, 3)).astype(np.float32))
    observed = torch.from_numpy(rng.random((2, 20, 4)) < 0.5)
    observed[:, 0] = True
    observed[:, -1] = True
    x[0, 0, 0] = float("nan")  # marked observed but NaN: filled from the neighbours
    out = lerp_infill(x, observed)
    assert out.dtype == torch.float32 and not torch.isnan(out).any()
    eff = observed.clone()
    eff[0, 0, 0] = False
    ref = np_lerp(x.double().numpy(), eff.numpy())
    np.testing.assert_allclose(out.numpy(), ref, rtol=1e-5, atol=1e-5)


def test_lerp_at_the_missing_tokens_only_is_the_whole_take_lerp_bit_for_bit():
    """On the CPU, a window whose every joint is observed somewhere is filled at its missing
    tokens only (_lerp_missing); a joint never observed sends it down the whole-window path.
    Both give the same bits: the same windows with a never-observed joint appended (which the
    other joints' fills do not read) come out identical on the joints they share."""
    rng = np.random.default_rng(3)
    for trial in range(60):
        B, T, J = int(rng.integers(1, 4)), int(rng.integers(2, 50)), int(rng.integers(1, 7))
        dtype = torch.float64 if trial % 2 else torch.float32
        x = torch.from_numpy(rng.normal(size=(B, T, J, 3))).to(dtype)
        observed = torch.from_numpy(rng.random((B, T, J)) < rng.uniform(0.2, 0.9))
        observed[:, 0] |= ~observed.any(dim=1)  # every joint observed somewhere: the sparse path
        x[torch.from_numpy(rng.random((B, T, J)) < 0.05)] = float("nan")  # NaN under "observed" too
        extra = torch.cat([x, torch.full((B, T, 1, 3), float("nan"), dtype=dtype)], dim=2)
        whole = lerp_infill(extra, torch.cat([observed, torch.zeros(B, T, 1, dtype=torch.bool)], dim=2))
        sparse = lerp_infill(x, observed)
        assert torch.equal(sparse.nan_to_num(7.0), whole[:, :, :J].nan_to_num(7.0)), trial


def test_each_tokens_observed_neighbours_are_the_nearest_observed_frames_of_its_joint():
    """_observed_neighbours: the last observed frame at or before each token (-1: none) and the
    first at or after it (T: none), against a loop over the frames."""
    from mocapfix.fills.classical import _observed_neighbours

    rng = np.random.default_rng(5)
    for trial in range(20):
        B, T, J = int(rng.integers(1, 3)), int(rng.integers(1, 30)), int(rng.integers(1, 4))
        B, T, J = (2, 1, 3) if trial == 0 else (B, T, J)  # one frame: reversed views of it must not reach torch
        obs = rng.random((B, T, J)) < rng.uniform(0.0, 1.0)
        t, prev, nxt = _observed_neighbours(torch.from_numpy(obs))
        for b, f, j in np.ndindex(B, T, J):
            seen = np.flatnonzero(obs[b, :, j])
            assert prev[b, f, j] == max(seen[seen <= f], default=-1) and t[b, f, j] == f
            assert nxt[b, f, j] == min(seen[seen >= f], default=T)


def test_the_hermite_at_the_missing_tokens_only_is_the_whole_take_cubic_bit_for_bit():
    """On the CPU the Hermite's cubic is computed at the tokens inside a gap only
    (_hermite_missing); a device computes it at every token and keeps those (_hermite_everywhere):
    the same bits, NaN under "observed", gaps at the borders and joints never seen included."""
    from mocapfix.fills.classical import _hermite_everywhere, _hermite_missing, _lerp, _observed_neighbours

    rng = np.random.default_rng(4)
    for trial in range(60):
        B, T, J = int(rng.integers(1, 4)), int(rng.integers(2, 60)), int(rng.integers(1, 7))
        dtype = torch.float64 if trial % 2 else torch.float32
        x = torch.from_numpy(rng.normal(size=(B, T, J, 3)).cumsum(1)).to(dtype)
        observed = torch.from_numpy(rng.random((B, T, J)) < rng.uniform(0.2, 0.95))
        x[torch.from_numpy(rng.random((B, T, J)) < 0.05)] = float("nan")
        obs = observed & ~torch.isnan(x).any(-1)
        t, prev, nxt = _observed_neighbours(obs)
        lerp = _lerp(x, obs, t, prev, nxt)
        sparse, whole = _hermite_missing(x, obs, lerp, prev, nxt), _hermite_everywhere(lerp, obs, t, prev, nxt)
        assert torch.equal(sparse.nan_to_num(7.0), whole.nan_to_num(7.0)), trial


@pytest.mark.gpu
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_lerp_on_cuda():
    rng = np.random.default_rng(2)
    x = rng.normal(size=(3, 25, 5, 3))
    observed = rng.random((3, 25, 5)) < 0.4
    out = lerp_infill(torch.from_numpy(x).cuda(), torch.from_numpy(observed).cuda())
    np.testing.assert_allclose(out.cpu().numpy(), np_lerp(x, observed), rtol=1e-10, atol=1e-10)


def test_gaussian_smooth_keeps_constants_and_lines_and_cuts_jitter():
    from mocapfix.fills.classical import gaussian_smooth

    T = 30
    t = torch.arange(T, dtype=torch.float64)
    const = torch.full((1, T, 2, 3), 0.7, dtype=torch.float64)
    torch.testing.assert_close(gaussian_smooth(const, 2.0), const)  # the ends too: renormalised kernel
    line = (0.01 * t)[None, :, None, None].expand(1, T, 2, 3)
    inner = slice(6, T - 6)  # the kernel (radius 6) inside the window: symmetric, a line stays
    torch.testing.assert_close(gaussian_smooth(line, 2.0)[:, inner], line[:, inner])
    g = torch.Generator().manual_seed(0)
    noise = 0.01 * torch.randn(4, T, 5, 3, generator=g, dtype=torch.float64)
    assert gaussian_smooth(noise, 2.0).std() < 0.4 * noise.std()  # white noise: about 1/sqrt(2 sqrt(pi) 2)


def test_hermite_continues_the_motion_and_keeps_the_contract():
    """A joint moving on a cubic: the Hermite fill, from each end's velocity, follows it through
    a gap much closer than Lerp; observed tokens bit-identical, border gaps held, nothing NaN."""
    from mocapfix.fills.classical import hermite_infill

    T = 40
    t = torch.arange(T, dtype=torch.float64) / 30.0
    path = torch.stack([t**3 - t, 0.5 * t**2, torch.sin(2 * t)], dim=-1)  # (T, 3)
    positions = path[None, :, None, :].repeat(1, 1, 2, 1)  # (1, T, 2, 3)
    observed = torch.ones(1, T, 2, dtype=torch.bool)
    observed[0, 12:24, 0] = False  # a 0.4-s gap
    observed[0, :5, 1] = False  # a gap at the start: held
    holed = torch.where(observed[..., None], positions, torch.nan)
    out = hermite_infill(holed, observed)
    assert torch.equal(out[observed], positions[observed]) and not torch.isnan(out).any()
    gap = ~observed[0, :, 0]
    err = (out[0, gap, 0] - path[gap]).norm(dim=-1).mean()
    lerp = (lerp_infill(holed, observed)[0, gap, 0] - path[gap]).norm(dim=-1).mean()
    assert err < 0.2 * lerp
    assert torch.equal(out[0, :5, 1], positions[0, 5, 1].expand(5, 3))


@pytest.mark.parametrize("name", ["spline", "pchip", "hermite", "limb"])
def test_a_classical_fill_asked_for_a_few_holes_fills_them_as_over_the_whole_take(name):
    """Asked for some holes, a classical fill fills crops around them (CROP_FRAMES each side):
    at the asked tokens the same as filling the whole take (the take's other holes, near and far,
    included; bones that stretch as tracked keypoints' do), within 0.01 mm (a spline's reach beyond
    the crop: 4e-3 mm here), and Lerp at the holes not asked for."""
    from mocapfix.core.skeleton import preset
    from mocapfix.fills.classical import Classical, lerp_infill
    from mocapfix.io.synthetic import generate_clips
    from mocapfix.rig.mapping import onto_skeleton

    body = preset("body21")
    clip = onto_skeleton(generate_clips(1, 20.0, 30.0, seed=3)[0], body)
    rng = np.random.default_rng(1)
    x = torch.from_numpy(clip.positions.astype(np.float64) + rng.normal(0, 0.01, clip.positions.shape))[None]
    observed = torch.ones(x.shape[:3], dtype=torch.bool)
    for start in rng.integers(5, 580, 30):  # the take's own holes, some next to the asked ones
        observed[0, start : start + rng.integers(2, 20), rng.integers(0, body.num_joints, 3)] = False
    asked = torch.zeros_like(observed)
    for start, joints in ((100, [5, 6, 7]), (118, [5, 6, 7]), (400, list(range(body.num_joints)))):
        observed[0, start : start + 15, joints] = False
        asked[0, start : start + 15, joints] = True
    x = x.masked_fill(~observed[..., None], float("nan"))
    whole = Classical(name).fill(x, observed, 30.0, body)[name]
    cropped = Classical(name).fill(x, observed, 30.0, body, asked)[name]
    assert (cropped - whole).norm(dim=-1)[asked].max() < 1e-5
    others = ~observed & ~asked
    assert torch.equal(cropped[others], lerp_infill(x, observed)[others])
    assert torch.equal(cropped[observed], x[observed])
