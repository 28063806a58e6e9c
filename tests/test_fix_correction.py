"""`fix` with a learned correction checkpoint (fix/correction.py, fixers.CorrectionFixer): each
hole of a take corrected with its context, and the correction filling only the holes where it
measured better than every classical fill on holes cut into the recording."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from cli_utils import run_mocapfix

from mocapfix.core.clip import Clip, MotionFileError
from mocapfix.core.skeleton import Skeleton
from mocapfix.data.corruption import training_holes
from mocapfix.fills.classical import classical_fills, hermite_infill
from mocapfix.fills.fill import made
from mocapfix.fix import measure_recordings
from mocapfix.fix.correction import corrected_take, hole_runs
from mocapfix.fix.fixer import FixOptions
from mocapfix.fix.fixers import CorrectionFixer, load_fixer
from mocapfix.io import read_motion
from mocapfix.io.positions import write_positions
from mocapfix.models.build import build_model
from mocapfix.models.checkpoint import save_checkpoint, weights_checkpoint
from mocapfix.models.correction import CorrectionConfig, base_fill

CHAIN = Skeleton(("root", "a", "b", "c"), (-1, 0, 1, 2))
GAPS = (0.1, 0.3, 0.5, 0.7, 0.9)


def _net(hidden: int = 32, base: str = "hermite", fps: float = 30.0):
    config = CorrectionConfig(4, fps, base, context_frames=5, hole_points=8, hidden=hidden, parents=CHAIN.parents)
    return build_model("correction", config).double()


def _shift(net, metres: float):
    """The network's correction a constant `metres` on every coordinate of a hole."""
    with torch.no_grad():
        net.linear.bias.fill_(metres / 0.01)  # it outputs centimetres
    return net


def _waves(B: int, T: int, seed: int, fps: float = 30.0, components: int = 1) -> torch.Tensor:
    """(B, T, 4, 3) float64: every coordinate a sum of `components` sinusoids of 1-2 Hz (random
    amplitude and phase): a motion whose Hermite fill errs the same way given the same context.
    Several components of their own frequencies per coordinate never repeat: no other place of a
    take shows what a hole hid (motion matching finds nothing there)."""
    g = torch.Generator().manual_seed(seed)
    t = torch.arange(T, dtype=torch.float64)[None, :, None, None] / fps
    out = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64).expand(B, T, 4, 3)
    for _ in range(components):
        shape = (B, 1, 1, 1) if components == 1 else (B, 1, 4, 3)
        freq = 1 + torch.rand(*shape, generator=g, dtype=torch.float64)
        amp = (0.05 + 0.2 * torch.rand(B, 1, 4, 3, generator=g, dtype=torch.float64)) / components
        phase = 2 * math.pi * torch.rand(B, 1, 4, 3, generator=g, dtype=torch.float64)
        out = out + amp * torch.sin(2 * math.pi * freq * t + phase)
    return out


def _holed(x: np.ndarray, holes: list[tuple[int, int]], joints=slice(None)) -> np.ndarray:
    x = x.copy()
    for s, e in holes:
        x[s:e, joints] = np.nan
    return x


def test_hole_runs_are_the_runs_of_frames_with_a_missing_token_up_to_the_longest():
    missing = np.zeros((20, 2), dtype=bool)
    missing[2:4, 0] = missing[3:6, 1] = True  # one run, 2..6
    missing[10:19, 0] = True  # 9 frames
    assert hole_runs(missing, 9) == [(2, 6), (10, 19)]
    assert hole_runs(missing, 8) == [(2, 6)]


def test_an_untrained_network_fills_each_hole_with_its_base_fill_and_keeps_observed_tokens():
    x = _waves(1, 90, seed=0)[0].numpy()
    holed = _holed(x, [(20, 35), (60, 64)], slice(1, 3))
    out, corrected = corrected_take(_net(), holed, 30.0, 30.0, 1.0)
    xt = torch.from_numpy(holed)[None]
    base = base_fill(_net().config, xt, torch.isfinite(xt).all(-1))[0].numpy()
    assert corrected == 2 and np.array_equal(out, base)
    observed = np.isfinite(holed).all(-1)
    assert np.array_equal(out[observed], holed[observed])


def test_only_the_holes_the_network_was_trained_for_and_the_asked_ones_are_corrected():
    x = _waves(1, 150, seed=1)[0].numpy()
    holed = _holed(x, [(20, 35), (60, 100)], slice(0, 2))  # 0.5 s and 1.33 s at 30 fps
    net = _shift(_net(), 0.01)
    xt = torch.from_numpy(holed)[None]
    base = base_fill(net.config, xt, torch.isfinite(xt).all(-1))[0].numpy()
    out, corrected = corrected_take(net, holed, 30.0, 30.0, max_hole_s=1.0)
    assert corrected == 1
    np.testing.assert_allclose(out[20:35, :2] - base[20:35, :2], 0.01, atol=1e-9)
    assert np.array_equal(out[60:100], base[60:100])  # longer than it was trained on: the base fill
    asked = np.zeros(150, dtype=bool)
    asked[70] = True
    out, corrected = corrected_take(net, holed, 30.0, 30.0, max_hole_s=2.0, asked=asked)
    assert corrected == 1 and np.array_equal(out[20:35], base[20:35])
    np.testing.assert_allclose(out[60:100, :2] - base[60:100, :2], 0.01, atol=1e-9)


def test_a_take_at_another_rate_is_corrected_at_the_networks_and_keeps_its_own_frames():
    x = _waves(1, 240, seed=2, fps=120.0)[0].numpy()  # 2 s at 120 fps; the network reads 30 fps
    holed = _holed(x, [(100, 160)], slice(2, 4))
    net = _shift(_net(), 0.01)
    out, corrected = corrected_take(net, holed, 120.0, 30.0, max_hole_s=1.0)
    xt = torch.from_numpy(holed)[None]
    base = base_fill(net.config, xt, torch.isfinite(xt).all(-1))[0].numpy()  # at 120 fps
    assert corrected == 1 and out.shape == x.shape
    np.testing.assert_allclose(out[100:160, 2:] - base[100:160, 2:], 0.01, atol=1e-9)
    observed = np.isfinite(holed).all(-1)
    assert np.array_equal(out[observed], holed[observed])


def _trained(steps: int = 120) -> torch.nn.Module:
    """A correction of the Hermite fill learned on sinusoid windows (the motion the takes below
    have)."""
    torch.manual_seed(0)
    net = _net().float()
    parts = torch.ones(1, 4, dtype=torch.bool)
    opt = torch.optim.Adam(net.parameters(), lr=3e-3)
    for step in range(steps):
        x = _waves(32, 36, seed=step, components=3).float()
        hole = training_holes(32, 36, parts, 27, None, x, margin=5)
        base = hermite_infill(torch.where(hole[..., None], torch.nan, x), ~hole)
        loss = ((net(base, hole) - x) ** 2).sum(-1)[hole].mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
    return net.eval()


def _takes(count: int, seconds: float = 20.0) -> tuple[list[Clip], list[np.ndarray]]:
    """Sinusoid takes at 30 fps with full-body holes of 0.5 s every 2 s: (holed clips, truths)."""
    clips, truths = [], []
    for k in range(count):
        x = _waves(1, int(30 * seconds), seed=1000 + k, components=3)[0].numpy().astype(np.float32)
        holes = [(s, s + 15) for s in range(40, len(x) - 40, 60)]
        clips.append(Clip(_holed(x, holes), 30.0, CHAIN, name=f"take{k}"))
        truths.append(x)
    return clips, truths


@pytest.fixture(scope="module")
def trained() -> torch.nn.Module:
    return _trained()


def test_fix_fills_with_a_correction_where_it_beats_every_classical_fill_on_the_recordings_own_holes(trained):
    clips, truths = _takes(4)
    fixer = CorrectionFixer(trained, CHAIN, 30.0, 36, 1.0, GAPS)
    measured = measure_recordings([[c] for c in clips], fixer)
    assert "full 0.5s correction" in measured[1]  # alone, or with another fill
    errors: dict[str, list[float]] = {"fix": []}
    for c, truth in zip(clips, truths):
        (out,), report = fixer.fix_clips([c], FixOptions("infill", measured=measured))
        assert sum(n for m, n in report.filled_by.items() if "correction" in m) == report.filled > 0
        hole = ~np.isfinite(c.positions).all(-1)
        errors["fix"] += np.linalg.norm(out.positions - truth, axis=-1)[hole].tolist()
        xt = torch.from_numpy(c.positions.astype(np.float64))[None]
        for name, fill in made(classical_fills(), xt, torch.isfinite(xt).all(-1), 30.0, CHAIN).items():
            errors.setdefault(name, []).extend(np.linalg.norm(fill[0].numpy() - truth, axis=-1)[hole].tolist())
    mean = {k: float(np.mean(v)) for k, v in errors.items()}
    best = min(v for k, v in mean.items() if k != "fix")
    assert mean["fix"] < 0.8 * best, mean


def test_a_correction_that_measures_worse_fills_no_hole_and_fix_says_so():
    clips, _ = _takes(4)
    fixer = CorrectionFixer(_shift(_net(), 0.05).float(), CHAIN, 30.0, 36, 1.0, GAPS)
    measured = measure_recordings([[c] for c in clips], fixer)
    assert "correction" not in measured[1].split(":", 1)[1]
    (out,), report = fixer.fix_clips([clips[0]], FixOptions("infill", measured=measured))
    assert not any("correction" in m for m in report.filled_by) and report.filled > 0
    assert np.isfinite(out.positions).all()


def test_a_correction_checkpoint_is_loaded_by_fix_and_fills_holes_only(tmp_path):
    net = _net().float()
    hparams = {"skeleton": CHAIN.to_dict(), "window_fps": 30.0, "window_frames": 36, "max_hole_s": 1.0}
    save_checkpoint(tmp_path / "c.ckpt", weights_checkpoint("correction", net, hparams))
    fixer = load_fixer(tmp_path / "c.ckpt")
    assert isinstance(fixer, CorrectionFixer) and fixer.max_hole_s == 1.0
    clips, _ = _takes(1, seconds=4.0)
    for mode in ("denoise", "both"):
        with pytest.raises(MotionFileError, match="fills holes") as e:
            fixer.fix_clips(clips, FixOptions(mode))
        assert "\n" not in str(e.value)
    with pytest.raises(ValueError, match="fp32"):
        load_fixer(tmp_path / "c.ckpt", precision="bf16")


def test_fix_a_folder_with_a_correction_checkpoint_says_which_holes_it_filled(trained, tmp_path, capsys):
    """The command a user runs after `fit --config correction_bvh`: the run's policy line names the
    correction where it won, each file's line counts what it filled, the outputs are written."""
    hparams = {"skeleton": CHAIN.to_dict(), "window_fps": 30.0, "window_frames": 36, "max_hole_s": 1.0}
    save_checkpoint(tmp_path / "c.ckpt", weights_checkpoint("correction", trained, hparams))
    clips, _ = _takes(4)
    for c in clips:
        write_positions(tmp_path / "takes" / f"{c.name}.npz", c.positions, c.fps, CHAIN)
    args = ["fix", tmp_path / "takes", "--ckpt", tmp_path / "c.ckpt", "--out-dir", tmp_path / "out"]
    rc, out, err = run_mocapfix(args, capsys)
    assert rc == 0, err
    assert "fill policy measured on the 4 files of this run" in out and "full 0.5s correction" in out
    assert out.count("filled by correction") == 4
    for c in clips:
        fixed = read_motion(tmp_path / "out" / f"{c.name}.npz")[0].positions
        assert np.isfinite(fixed).all()
        observed = np.isfinite(c.positions)
        assert np.array_equal(fixed[observed], c.positions[observed])
