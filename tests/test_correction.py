"""The learned correction to a classical fill (models/correction.py, training/correction_module.py)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch
from cli_utils import CONFIGS, QUIET, run_cli

from mocapfix.data.augment import mirrored
from mocapfix.data.corruption import training_holes
from mocapfix.fills.classical import CLASSICAL, hermite_infill
from mocapfix.fix.fixer import FixOptions
from mocapfix.fix.fixers import CorrectionFixer, load_fixer
from mocapfix.io import read_motion
from mocapfix.models.build import build_model
from mocapfix.models.checkpoint import checkpoint_entry
from mocapfix.models.correction import CorrectionConfig, base_fill, correction_fill, longest_run
from mocapfix.training.ridge_bank import bucket_lengths, fit_bank


def _config(**changes) -> CorrectionConfig:
    values = dict(num_joints=4, fps=30.0, context_frames=5, hole_points=8, hidden=64, depth=2, heading_joints=(1, 2))
    values.update(changes)
    return CorrectionConfig(**values)


def _waves(B: int, T: int, J: int, seed: int) -> torch.Tensor:
    """(B, T, J, 3) float64: every coordinate a sinusoid of 1-2 Hz at 30 fps (random amplitude and
    phase per window and joint): a motion whose Hermite fill errs the same way given its context."""
    g = torch.Generator().manual_seed(seed)
    t = torch.arange(T, dtype=torch.float64)[None, :, None, None] / 30.0
    freq = 1 + torch.rand(B, 1, 1, 1, generator=g, dtype=torch.float64)
    amp = 0.05 + 0.2 * torch.rand(B, 1, J, 3, generator=g, dtype=torch.float64)
    phase = 2 * math.pi * torch.rand(B, 1, J, 3, generator=g, dtype=torch.float64)
    return amp * torch.sin(2 * math.pi * freq * t + phase) + torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)


def test_longest_run_finds_each_windows_longest_stretch_of_missing_frames():
    hole = torch.zeros(3, 12, 2, dtype=torch.bool)
    hole[0, 2:4, 0] = hole[0, 6:11, 1] = True  # two runs: the second is longer
    hole[1, 0:3, :] = True
    start, length = longest_run(hole)
    assert start[:2].tolist() == [6, 0] and length.tolist() == [5, 3, 0]


def test_an_untrained_network_is_its_base_fill_and_leaves_observed_tokens():
    x = _waves(4, 30, 4, seed=0)
    observed = torch.ones(4, 30, 4, dtype=torch.bool)
    observed[:, 10:20, :2] = False
    for base in ("hermite", "limb"):
        net = build_model("correction", _config(base=base, parents=(-1, 0, 1, 2))).double()
        out = correction_fill(net, torch.where(observed[..., None], x, torch.nan), observed)
        assert torch.equal(out, base_fill(net.config, torch.where(observed[..., None], x, torch.nan), observed))
        assert torch.equal(out[observed], x[observed])


def test_the_correction_turns_and_moves_with_the_body():
    """Turned about z and moved, a window gets its correction turned and moved the same: the
    network reads every hole in one heading and place."""
    torch.manual_seed(0)
    net = build_model("correction", _config()).double()
    for layer in (net.out, net.linear):
        torch.nn.init.normal_(layer.weight, std=0.01)
    x = _waves(3, 30, 4, seed=1)
    hole = torch.zeros(3, 30, 4, dtype=torch.bool)
    hole[:, 12:20, 3] = True
    a = 0.7
    turn = torch.tensor([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]], dtype=torch.float64)
    moved = x @ turn.T + torch.tensor([2.0, -1.0, 0.0], dtype=torch.float64)
    delta = net(x, hole) - x
    delta_moved = net(moved, hole) - moved
    assert delta.abs().max() > 1e-3  # a correction was made
    assert torch.allclose(delta_moved, delta @ turn.T, atol=1e-9)
    assert (delta[~hole] == 0).all()


def test_a_correction_its_features_predict_is_learned():
    """On sinusoids the Hermite fill's error over a hole follows from the motion around it: 300
    steps take more than half of it off on windows it never saw."""
    torch.manual_seed(0)
    net = build_model("correction", _config())
    parts = torch.tensor([[True] * 4, [False, False, True, True]])
    opt = torch.optim.Adam(net.parameters(), lr=3e-3)
    x_test = _waves(256, 30, 4, seed=99).float()
    hole_test = training_holes(256, 30, parts, 15, torch.Generator().manual_seed(5), x_test, margin=5)

    def errors(x, hole):
        observed = ~hole
        base = hermite_infill(torch.where(observed[..., None], x, torch.nan), observed)
        out = net(base, hole)
        return ((out - x) ** 2).sum(-1)[hole].mean(), ((base - x) ** 2).sum(-1)[hole].mean()

    for step in range(300):
        x = _waves(64, 30, 4, seed=step).float()
        loss, _ = errors(x, training_holes(64, 30, parts, 15, None, x, margin=5))
        opt.zero_grad()
        loss.backward()
        opt.step()
    with torch.no_grad():
        corrected, base = errors(x_test, hole_test)
    assert corrected < 0.5 * base


def _banked(**changes) -> CorrectionConfig:
    """A network with a linear bank: the whole body and joints 2-3 (a limb), 3 ranges of 1-15 frames."""
    return _config(length_buckets=3, max_hole_frames=15, part_groups=((0, 1, 2, 3), (2, 3)), **changes)


def test_each_hole_finds_its_maps_in_the_bank_by_part_and_length():
    net = build_model("correction", _banked())
    hole = torch.zeros(4, 30, 4, dtype=torch.bool)
    hole[0, 5:6] = True  # the whole body, 1 frame: first range
    hole[1, 5:15, 2:] = True  # the limb, 10 frames: 6-10, the second
    hole[2, 5:20, 2:] = True  # 15 frames: the last
    hole[3, 5:10, 1:] = True  # joints 1-3: no part group
    x = _waves(4, 30, 4, seed=0).float()
    group, bucket = net.cells(net.features(x, hole))
    assert group.tolist() == [0, 1, 1, -1] and bucket[:3].tolist() == [0, 1, 2]
    assert [bucket_lengths(b, 3, 15) for b in range(3)] == [(1, 5), (6, 10), (11, 15)]


def test_a_bank_of_zeros_changes_nothing_and_a_fitted_one_survives_a_checkpoint(tmp_path):
    x = _waves(8, 30, 4, seed=1).float()
    hole = training_holes(8, 30, torch.tensor([[True] * 4]), 12, torch.Generator().manual_seed(0), x, margin=5)
    base = hermite_infill(torch.where(~hole[..., None], x, torch.nan), ~hole)
    plain, banked = build_model("correction", _config()), build_model("correction", _banked())
    banked.load_state_dict({**banked.state_dict(), **plain.state_dict()})
    assert torch.equal(plain(base, hole), banked(base, hole))
    with torch.no_grad():
        banked.bank_0.normal_(0, 0.01)
        banked.bank_fitted.fill_(True)  # a resumed run does not fit it again (on_train_start)
    values = checkpoint_entry("correction", banked.config)["config"]  # as a checkpoint stores it
    values["part_groups"] = [list(g) for g in values["part_groups"]]  # lists after a round trip
    again = build_model("correction", values)
    again.load_state_dict(banked.state_dict())
    assert torch.equal(again(base, hole), banked(base, hole)) and not torch.equal(banked(base, hole), base)
    assert bool(again.bank_fitted)


def test_the_bank_fitted_in_closed_form_takes_most_of_the_fills_error_off_new_windows():
    """On sinusoids the Hermite's error is a function of the context a linear map of each kind
    of hole learns: fitted on 8 batches (each window its own take, every 5th held out to choose a
    strength), it takes over half of it off windows it never saw, for the whole body and the
    limb, short holes and long ones."""
    torch.manual_seed(0)
    net = build_model("correction", _banked())
    lines = fit_bank(
        net,
        lambda: iter([(_waves(128, 30, 4, seed=s).float(), torch.arange(128)) for s in range(4)]),
        batches=8,
        strengths=(1e-6, 1e-3),
        floor_m=0.002,
    )
    assert bool(net.bank_fitted) and len(lines) == 2 and "full body" in lines[0] and "joints 2,3" in lines[1]
    x = _waves(256, 30, 4, seed=99).float()
    for part in (torch.tensor([[True] * 4]), torch.tensor([[False, False, True, True]])):
        for shortest, longest in ((6, 10), (11, 15)):
            hole = training_holes(256, 30, part, longest, torch.Generator().manual_seed(3), x, 5, shortest)
            base = hermite_infill(torch.where(~hole[..., None], x, torch.nan), ~hole)
            with torch.no_grad():
                out = net(base, hole)
            assert ((out - x) ** 2).sum(-1)[hole].mean() < 0.5 * ((base - x) ** 2).sum(-1)[hole].mean()


def test_a_mirrored_window_swaps_each_joint_with_its_partner_across_a_vertical_plane():
    x = _waves(2, 10, 4, seed=3)
    y = mirrored(x, [0, 2, 1, 3])
    assert torch.equal(y[:, :, 1, 0], -x[:, :, 2, 0]) and torch.equal(y[:, :, 2, 1:], x[:, :, 1, 1:])
    assert torch.equal(mirrored(y, [0, 2, 1, 3]), x)


def test_training_holes_take_lengths_between_the_shortest_and_the_longest():
    x = torch.zeros(512, 40, 2, 3)
    hole = training_holes(512, 40, torch.tensor([[True, True]]), 12, torch.Generator().manual_seed(0), x, 3, 7)
    lengths = hole.any(-1).sum(1)
    assert lengths.min() == 7 and lengths.max() == 12


def _expmap_folder(root, seconds: float = 6.0) -> None:
    """S1 (train) and S9 (test) folders of exponential-map takes: the rest pose walking, its joints
    swinging (sinusoids of 1-2 Hz on every joint's map)."""
    rng = np.random.default_rng(0)
    T = int(50 * seconds)
    t = np.arange(T)[:, None] / 50.0
    for subject, takes in (("S1", 3), ("S9", 1)):
        for k in range(takes):
            ch = np.zeros((T, 99))
            ch[:, 2] = 8.0  # forward, mm a frame
            ch[:, 6:] = 0.3 * np.sin(2 * np.pi * (1 + rng.random(93)) * t + 2 * np.pi * rng.random(93))
            path = root / subject / f"walking_{k + 1}.txt"
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text("\n".join(",".join(f"{v:.6f}" for v in row) for row in ch) + "\n")


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """configs/correction_h36m.yaml for a few steps on generated Human3.6M takes, then `test`."""
    tmp = tmp_path_factory.mktemp("correction")
    _expmap_folder(tmp / "h36m")
    common = [*QUIET, "--data.path", tmp / "h36m", "--data.cache_dir", "null", "--experiment", "c"]
    common += ["--data.batch_size", "8", "--model.init_args.hidden", "32"]
    common += ["--model.init_args.length_buckets", "0"]  # the bank has its own test (below): fit_correction_bvh
    args = ["fit", "--config", CONFIGS / "correction_h36m.yaml", *common, "--trainer.max_steps", "3"]
    assert run_cli([*args, "--trainer.val_check_interval", "3", "--trainer.limit_val_batches", "1"], tmp) == 0
    ckpt = tmp / "checkpoints" / "c" / "last.ckpt"
    assert run_cli(["test", "--config", CONFIGS / "correction_h36m.yaml", *common, "--ckpt_path", ckpt], tmp) == 0
    return ckpt


def test_fit_and_test_print_the_papers_infilling_table_with_every_classical_fill(trained):
    ckpt = torch.load(trained, map_location="cpu", weights_only=True)
    assert ckpt["model"]["kind"] == "correction" and ckpt["model"]["config"]["fps"] == 50.0
    [table] = (trained.parents[2] / "logs" / "c").glob("version_*/eval.json")
    rows = json.loads(table.read_text())
    assert {r["method"] for r in rows} == {"correction", *CLASSICAL}
    gaps = (0.1, 0.3, 0.5, 0.7, 0.9)
    assert {(r["part"], r["gap_s"]) for r in rows} == {(p, g) for p in ("full", "arm", "leg") for g in gaps}
    cell = {r["method"]: r["mpjpe_rel_mm"] for r in rows if (r["part"], r["gap_s"]) == ("full", 0.5)}
    assert cell["lerp"] > cell["hermite"] > 0


def test_fix_fills_holes_with_a_trained_correction_checkpoint(trained, tmp_path):
    """The checkpoint `fit` writes is what `fix --ckpt` loads: its skeleton, rate, longest hole
    and gaps; a take's holes come back filled, its observed tokens as read."""
    fixer = load_fixer(trained)
    assert isinstance(fixer, CorrectionFixer) and fixer.fps == 50.0 and fixer.max_hole_s == 1.0
    assert fixer.policy.gaps_s == [0.1, 0.3, 0.5, 0.7, 0.9]
    (take,) = read_motion(trained.parents[2] / "h36m" / "S9" / "walking_1.txt")
    x = take.positions.copy()
    x[100:125, :] = np.nan
    x[200:210, 11:14] = np.nan
    holed = take.replace(positions=x)
    (out,), report = fixer.fix_clips([holed], FixOptions("infill"))
    assert np.isfinite(out.positions).all() and report.filled == int(np.isnan(x).any(-1).sum())
    assert np.array_equal(out.positions[~np.isnan(x)], x[~np.isnan(x)])


def test_fit_correction_bvh_fits_its_linear_bank_before_the_first_step_and_fix_reads_it(bandai_files, tmp_path, capsys):
    """configs/correction_bvh.yaml on six Bandai takes (one of them val; small: full-body
    holes in two ranges of lengths): the bank's maps are fitted in closed form and said, the
    checkpoint holds them, and `fix --ckpt` fills with it."""
    folder = tmp_path / "takes"
    folder.mkdir()
    for f in bandai_files[:6]:
        (folder / f.name).symlink_to(f)
    val = bandai_files[5].name
    args = ["fit", "--config", CONFIGS / "correction_bvh.yaml", *QUIET, "--data.path", folder]
    args += ["--data.cache_dir", "null", "--data.batch_size", "16", "--data.val_patterns", f"[{val}]"]
    args += ["--data.test_fraction", "0", "--model.init_args.hidden", "16", "--model.init_args.bank_batches", "2"]
    args += ["--model.init_args.hole_parts", "[full]", "--model.init_args.length_buckets", "2"]
    args += ["--model.init_args.context_frames", "4", "--model.init_args.hole_points", "4"]
    args += ["--trainer.max_steps", "1", "--trainer.limit_val_batches", "1", "--experiment", "c"]
    assert run_cli(args, tmp_path) == 0
    err = capsys.readouterr().err
    assert err.count("linear bank") == 1 and "full body" in err and "16-30 frames" in err
    ckpt = torch.load(tmp_path / "checkpoints" / "c" / "last.ckpt", weights_only=True)
    state = ckpt["state_dict"]
    assert bool(state["net.bank_fitted"]) and state["net.bank_0"].abs().sum() > 0
    fixer = load_fixer(tmp_path / "checkpoints" / "c" / "last.ckpt")
    assert isinstance(fixer, CorrectionFixer) and fixer.net.config.length_buckets == 2
    take = read_motion(bandai_files[5])[0]
    holed = take.positions.copy()
    holed[40:55] = np.nan
    (out,), report = fixer.fix_clips([take.replace(positions=holed)], FixOptions("infill"))
    assert np.isfinite(out.positions).all() and report.filled > 0
