"""XMAE network: sizes, masking semantics, variable observed counts."""

from __future__ import annotations

import pytest
import torch

from mocapfix.models.xmae import XMAE
from mocapfix.models.xmae_inference import kept_index


def test_paper_size_parameter_count():
    # Table 1 sizes; the paper says 5.6 M (smpl22 at 1 s / 60 fps: 5,588,611)
    n = sum(p.numel() for p in XMAE(22, 60).parameters())
    assert n == 5_588_611


def _tiny(decoder="cross"):
    torch.manual_seed(0)
    return (
        XMAE(
            5,
            6,
            enc_dim=32,
            enc_depth=2,
            enc_mlp_dim=64,
            dec_dim=32,
            dec_depth=2,
            dec_mlp_dim=64,
            head_dim=16,
            decoder=decoder,
        )
        .double()
        .eval()
    )


@pytest.mark.parametrize("decoder", ["cross", "mae"])
def test_variable_observed_count_matches_per_sample_loop(decoder):
    """Padded batch with different observed counts == each sample run alone without padding."""
    net = _tiny(decoder)
    B, T, J = 4, 6, 5
    g = torch.Generator().manual_seed(1)
    x = torch.randn(B, T * J, 3, generator=g, dtype=torch.float64)
    observed = torch.rand(B, T * J, generator=g) < torch.tensor([0.1, 0.3, 0.6, 0.9])[:, None]
    kept, pad = kept_index(observed.view(B, T, J))
    assert pad.any(), "the test needs samples of different observed counts"
    batched = net(x, kept, pad)
    for b in range(B):
        idx = observed[b].nonzero()[:, 0][None]
        single = net(x[b : b + 1], idx)
        torch.testing.assert_close(batched[b], single[0], atol=1e-10, rtol=1e-10)


def test_shared_first_decoder_self_attention_is_the_per_sample_decoder():
    """decode runs the first block's self-attention once for the batch (the queries are the same
    for every sample): output and gradients equal every block run on the whole batch."""
    net = _tiny()
    B, T, J = 3, 6, 5
    g = torch.Generator().manual_seed(2)
    x = torch.randn(B, T * J, 3, generator=g, dtype=torch.float64)
    kept, pad = kept_index(torch.rand(B, T, J, generator=g) < torch.tensor([0.2, 0.5, 0.8])[:, None, None])

    def per_sample_decoder():  # the Transformer decoder as written: every block on (B, N, Dd)
        memory = net.encode(x, kept, pad)
        q = net.enc_to_dec(net.mask_token + net._positions(net.enc_pos_joint, net.enc_pos_time)).expand(B, -1, -1)
        for blk in net.decoder:
            q = blk(q, memory, memory_padding=pad)
        return net.head(net.dec_norm(q)) * net.position_unit_m

    outputs, grads = [], []
    for run in (lambda: net(x, kept, pad), per_sample_decoder):
        net.zero_grad()
        y = run()
        (y * torch.linspace(-1, 1, y.numel(), dtype=y.dtype).view_as(y)).sum().backward()
        outputs.append(y.detach())
        grads.append(torch.cat([p.grad.flatten() for p in net.decoder[0].parameters()]))
    torch.testing.assert_close(outputs[0], outputs[1], atol=1e-10, rtol=1e-10)
    torch.testing.assert_close(grads[0], grads[1], atol=1e-10, rtol=1e-8)


def test_masked_token_values_are_never_read():
    net = _tiny()
    x = torch.randn(2, 30, 3, dtype=torch.float64)
    observed = torch.zeros(2, 30, dtype=torch.bool)
    observed[:, ::3] = True
    kept, pad = kept_index(observed.view(2, 6, 5))
    y1 = net(x, kept, pad)
    x2 = x.clone()
    x2[~observed] = 1e6
    torch.testing.assert_close(net(x2, kept, pad), y1)


def test_cross_decoder_queries_do_not_depend_on_mask_count():
    """The decoder input is the same mask-token sequence whatever is observed (no train/test gap):
    with identical encoded memory, the output is identical."""
    net = _tiny()
    memory = torch.randn(1, 7, 32, dtype=torch.float64)
    kept_a = torch.arange(7)[None]
    kept_b = torch.arange(7)[None] + 10
    torch.testing.assert_close(net.decode(memory, kept_a, None), net.decode(memory, kept_b, None))


def test_no_observed_token_gives_finite_output():
    net = _tiny()
    observed = torch.zeros(2, 6, 5, dtype=torch.bool)
    observed[1, 0, 0] = True
    kept, pad = kept_index(observed)
    out = net(torch.zeros(2, 30, 3, dtype=torch.float64), kept, pad)
    assert torch.isfinite(out).all()


def test_bf16_autocast_close_to_fp32():
    """The bf16 path (GPU training) stays close to fp32 on CPU."""
    torch.manual_seed(0)
    net = XMAE(22, 30, enc_dim=64, enc_depth=2, enc_mlp_dim=128, dec_dim=64, dec_depth=1, dec_mlp_dim=128).eval()
    x = torch.randn(4, 660, 3) * 0.5
    kept = torch.rand(4, 660).argsort(1)[:, :100]
    ref = net(x, kept)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        low = net(x, kept).float()
    assert (low - ref).abs().mean() < 0.02 * ref.abs().mean() + 1e-3


def test_bf16_autocast_keeps_coordinates_in_full_precision():
    """Coordinates enter and leave the network in fp32 under autocast: bf16 would round a 1.5 m
    coordinate to 6 mm steps (15 units of 0.1 m), and 1 mm would be invisible to the model."""
    torch.manual_seed(0)
    net = XMAE(22, 30, enc_dim=64, enc_depth=1, enc_mlp_dim=128, dec_dim=64, dec_depth=1, dec_mlp_dim=128).eval()
    x = torch.full((1, 660, 3), 1.5)
    moved = x.clone()
    moved[0, 0, 0] += 0.001
    kept = torch.arange(660)[None]
    with torch.autocast("cpu", dtype=torch.bfloat16):
        a, b = net.encode(x, kept, None), net.encode(moved, kept, None)
        out = net(x, kept)
    assert not torch.equal(a, b)
    assert out.dtype == torch.float32


def test_fill_input_starts_at_the_fill_and_learns_a_correction():
    """fill_input (not in the paper): the untrained network answers the Lerp fill exactly (its
    correction head starts at zero), and one optimiser step moves it off."""
    from mocapfix.fills.classical import lerp_infill
    from mocapfix.models.xmae_inference import xmae_reconstruct

    torch.manual_seed(0)
    net = XMAE(
        5,
        6,
        enc_dim=32,
        enc_depth=1,
        enc_mlp_dim=64,
        dec_dim=32,
        dec_depth=1,
        dec_mlp_dim=64,
        head_dim=16,
        fill_input=True,
    )
    g = torch.Generator().manual_seed(2)
    x = torch.randn(3, 6, 5, 3, generator=g)
    observed = torch.rand(3, 6, 5, generator=g) < 0.6
    torch.testing.assert_close(xmae_reconstruct(net, x, observed), lerp_infill(x, observed), atol=1e-5, rtol=0)
    opt = torch.optim.SGD(net.parameters(), lr=0.1)
    (xmae_reconstruct(net, x, observed) - x).pow(2).mean().backward()
    opt.step()
    assert (xmae_reconstruct(net, x, observed) - lerp_infill(x, observed)).abs().max() > 1e-4
    kept, pad = kept_index(observed)
    with pytest.raises(ValueError, match="fill_input"):
        net(x.reshape(3, 30, 3), kept, pad)  # built with fill_input: a fill is needed
    with pytest.raises(ValueError, match="cross"):
        XMAE(5, 6, decoder="mae", fill_input=True)
