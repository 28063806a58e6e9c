"""The GPU fast paths (issue 6) keep their meaning on the CPU: device-resident batches, a kept
count known without reading the data, torch.compile behind a flag (bf16 vs fp32: test_xmae_model.py)."""

from __future__ import annotations

import shutil

import pytest
import torch
from cli_utils import CONFIGS, QUIET, SMALL_DATA, TINY, run_cli

from mocapfix.data.corruption import kept_count, mask_and_displace
from mocapfix.data.datamodule import DeviceBatches, WindowDataset
from mocapfix.io.synthetic import generate_clips
from mocapfix.models.xmae import XMAE
from mocapfix.models.xmae_inference import kept_index
from mocapfix.training.xmae_module import XMAEModule


def test_kept_index_with_a_given_count_matches_the_data_count():
    g = torch.Generator().manual_seed(0)
    x = torch.randn(5, 10, 6, 3, generator=g)
    x[1, 1:] = float("nan")  # sample 1 is short of data: 6 tokens, fewer than K = 9 to keep
    c = mask_and_displace(x, 0.85, 0.05, generator=g)
    K = kept_count(10 * 6, 0.85)
    idx, pad = kept_index(c.observed, K)
    idx_ref, pad_ref = kept_index(c.observed)
    assert idx.shape == (5, K) and K == idx_ref.shape[1]
    assert torch.equal(idx, idx_ref) and torch.equal(pad, pad_ref)
    assert pad[1].any() and not pad[0].any()  # the short sample is padded, the others are not


def test_padding_with_no_real_token_is_elementwise_and_safe():
    # a sample with nothing observed attends to one zero slot instead of producing NaN
    torch.manual_seed(0)
    net = XMAE(
        4, 5, enc_dim=32, enc_depth=1, enc_mlp_dim=64, dec_dim=32, dec_depth=1, dec_mlp_dim=64, head_dim=16
    ).eval()
    tokens = torch.randn(2, 20, 3)
    kept = torch.tensor([[0, 3, 7], [0, 0, 0]])
    padding = torch.tensor([[False, False, False], [True, True, True]])
    out = net(tokens, kept, padding)
    assert torch.isfinite(out).all()
    # the real sample's output does not depend on whether the batch has a padded neighbour
    torch.testing.assert_close(out[:1], net(tokens[:1], kept[:1], None), atol=1e-5, rtol=1e-5)


def _windows(n_clips=6, seconds=2.0):
    ds = WindowDataset(generate_clips(n_clips, seconds, fps=30, seed=0), window=30, stride=10)
    ds.positions[:, 0, 0] = torch.arange(len(ds.positions), dtype=torch.float32)  # frame number
    return ds


def _identity(batch) -> list[tuple]:
    # a window is known by its first frame's number (planted in the first joint's x by _windows)
    return [int(f) for f in batch["positions"][:, 0, 0, 0]]


def test_device_batches_cover_every_window_once_and_split_ranks():
    ds = _windows()
    everything = set(_identity(ds.__getitems__(list(range(len(ds))))))
    assert len(everything) == len(ds)
    per_rank = []
    for rank in range(2):
        batches = DeviceBatches(_windows(), batch_size=4, device=torch.device("cpu"), rank=rank, world_size=2)
        batches.set_epoch(3)
        got = list(batches)
        assert len(got) == len(batches) == (len(ds) // 2) // 4
        assert all(b["positions"].shape == (4, 30, 22, 3) for b in got)
        per_rank.append([w for b in got for w in _identity(b)])
    # the same permutation on both ranks, disjoint shares, no window twice, all real windows
    assert not set(per_rank[0]) & set(per_rank[1])
    for ids in per_rank:
        assert len(set(ids)) == len(ids) and set(ids) <= everything
    full = DeviceBatches(_windows(), batch_size=1, device=torch.device("cpu"))
    assert {w for b in full for w in _identity(b)} == everything


def test_device_batches_epochs_differ_and_repeat():
    b = DeviceBatches(_windows(), batch_size=4, device=torch.device("cpu"))
    first = [x["positions"] for x in b]
    again = [x["positions"] for x in b]  # same epoch number: the same order (resume continues it)
    b.set_epoch(1)
    other = [x["positions"] for x in b]
    assert all(torch.equal(a, c) for a, c in zip(first, again))
    assert not all(torch.equal(a, c) for a, c in zip(first, other))


def test_device_batches_short_dataset_gives_one_short_batch():
    ds = _windows(n_clips=1, seconds=1.5)
    b = DeviceBatches(ds, batch_size=64, device=torch.device("cpu"))
    got = list(b)
    assert len(b) == 1 and len(got) == 1 and got[0]["positions"].shape[0] == len(ds)


def test_fit_with_batches_on_device(tmp_path):
    rc = run_cli(
        [
            "fit",
            "--config",
            CONFIGS / "xmae.yaml",
            *TINY,
            *SMALL_DATA,
            *QUIET,
            "--data.batches_on_device",
            "true",
            "--trainer.fast_dev_run",
            "2",
        ],
        tmp_path,
    )
    assert rc == 0


def test_compile_mode_is_checked():
    with pytest.raises(ValueError, match="compile_mode"):
        XMAEModule(compile_model=True, compile_mode="fast")


def test_compile_flag_keeps_checkpoint_names():
    skel = generate_clips(1, 1.0, fps=10, seed=0)[0].skeleton.to_dict()
    kwargs = dict(
        enc_dim=32,
        enc_depth=1,
        enc_mlp_dim=64,
        dec_dim=32,
        dec_depth=1,
        dec_mlp_dim=64,
        head_dim=16,
        skeleton=skel,
        window_fps=10.0,
        window_frames=10,
    )
    eager, compiled = XMAEModule(**kwargs), XMAEModule(compile_model=True, **kwargs)
    assert list(eager.state_dict()) == list(compiled.state_dict())
    compiled.load_state_dict(eager.state_dict())  # a checkpoint of either loads into the other


@pytest.mark.slow
@pytest.mark.skipif(not (shutil.which("cc") or shutil.which("gcc")), reason="torch.compile on CPU needs a C compiler")
@pytest.mark.parametrize("mode", ["default", "reduce-overhead"])
def test_compiled_training_step_matches_eager(mode):
    """torch.compile (inductor on the CPU: needs a C compiler) gives the eager loss and gradients;
    "reduce-overhead" (CUDA graphs on a GPU) leaves the CPU path working."""
    skel = generate_clips(1, 1.0, fps=10, seed=0)[0].skeleton.to_dict()
    kwargs = dict(
        enc_dim=32,
        enc_depth=1,
        enc_mlp_dim=64,
        dec_dim=32,
        dec_depth=1,
        dec_mlp_dim=64,
        head_dim=16,
        skeleton=skel,
        window_fps=10.0,
        window_frames=10,
        rotate_augment=False,
    )
    eager, compiled = XMAEModule(**kwargs), XMAEModule(compile_model=True, compile_mode=mode, **kwargs)
    compiled.load_state_dict(eager.state_dict())
    x = torch.from_numpy(generate_clips(4, 1.0, fps=10, seed=1)[0].positions[:10])[None].repeat(4, 1, 1, 1)
    losses = []
    for m in (eager, compiled):
        loss, *_ = m._corrupt_and_predict(x, torch.Generator().manual_seed(0))
        loss.backward()
        losses.append((loss.detach(), m.net.embed.weight.grad.clone()))
    torch.testing.assert_close(losses[0][0], losses[1][0], atol=1e-5, rtol=1e-4)
    torch.testing.assert_close(losses[0][1], losses[1][1], atol=1e-5, rtol=1e-3)


CUDA = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")


@pytest.mark.gpu
@CUDA
def test_cuda_graph_training_steps_match_eager():
    """compile_mode reduce-overhead on a GPU: the network's forward and backward replayed as CUDA
    graphs give the eager loss and gradients, step after step (each step's graph outputs reuse
    the last step's memory: a stale reference would show here)."""
    skel = generate_clips(1, 1.0, fps=10, seed=0)[0].skeleton.to_dict()
    kwargs = dict(
        enc_dim=32,
        enc_depth=1,
        enc_mlp_dim=64,
        dec_dim=32,
        dec_depth=1,
        dec_mlp_dim=64,
        head_dim=16,
        skeleton=skel,
        window_fps=10.0,
        window_frames=10,
        rotate_augment=False,
    )
    eager = XMAEModule(**kwargs).cuda()
    graphed = XMAEModule(compile_model=True, compile_mode="reduce-overhead", **kwargs).cuda()
    graphed.load_state_dict(eager.state_dict())
    x = torch.from_numpy(generate_clips(4, 1.0, fps=10, seed=1)[0].positions[:10])[None].repeat(4, 1, 1, 1).cuda()
    precision = torch.get_float32_matmul_precision()
    torch.set_float32_matmul_precision("highest")  # no TF32: compare like with like
    try:
        for step in range(3):
            results = []
            for m in (eager, graphed):
                m.zero_grad()
                if m is graphed:
                    torch.compiler.cudagraph_mark_step_begin()  # as XMAEModule.training_step does
                loss, *_ = m._corrupt_and_predict(x, torch.Generator().manual_seed(step))
                loss.backward()
                results.append((loss.detach(), m.net.embed.weight.grad.clone()))
            torch.testing.assert_close(results[0][0], results[1][0], atol=1e-5, rtol=1e-4)
            torch.testing.assert_close(results[0][1], results[1][1], atol=1e-5, rtol=1e-3)
    finally:
        torch.set_float32_matmul_precision(precision)


@pytest.mark.gpu
@CUDA
def test_cuda_graph_fit_validates_and_resumes(tmp_path):
    """The whole loop with compile_mode reduce-overhead: bf16, data on the device, validation (a
    second graph, other shapes, its figure kept past the next batch) and a resume from last.ckpt."""
    common = [
        "fit",
        "--config",
        CONFIGS / "xmae.yaml",
        *TINY,
        *SMALL_DATA,
        *QUIET,
        "--experiment",
        "graphs",
        "--trainer.accelerator",
        "gpu",
        "--trainer.precision",
        "bf16-mixed",
        "--data.batches_on_device",
        "true",
        "--model.init_args.compile_model",
        "true",
        "--model.init_args.compile_mode",
        "reduce-overhead",
        "--trainer.val_check_interval",
        "2",
        "--checkpoint_every_n_steps",
        "2",
    ]
    assert run_cli([*common, "--trainer.max_steps", "4"], tmp_path) == 0
    assert run_cli([*common, "--trainer.max_steps", "6", "--ckpt_path", "last"], tmp_path) == 0
    ckpt = torch.load(tmp_path / "checkpoints" / "graphs" / "last.ckpt", map_location="cpu", weights_only=True)
    assert ckpt["global_step"] == 6 and ckpt["hyper_parameters"]["compile_mode"] == "reduce-overhead"
    assert all(torch.isfinite(v).all() for v in ckpt["state_dict"].values() if v.is_floating_point())
