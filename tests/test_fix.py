"""`mocapfix fix`: formats and layouts, modes, windows and blending, fps, errors, atomic writes, and a
small XMAE trained in the test against Lerp."""

from __future__ import annotations

import json
import os
import pickle

import numpy as np
import pytest
import torch
from cli_utils import CONFIGS, QUIET, TINY, run_cli, run_mocapfix

from mocapfix.apps.main import main
from mocapfix.core.clip import Clip, MotionFileError
from mocapfix.core.resample import model_frames, resample_frames
from mocapfix.core.skeleton import Skeleton, preset
from mocapfix.evaluation.recording import corrupt_recording
from mocapfix.fills.classical import lerp_infill
from mocapfix.fix import fix_clips, map_joints
from mocapfix.fix.fixers import load_fixer, resolve_precision
from mocapfix.fix.position_fixer import PositionFixer
from mocapfix.fix.windowing import blend_weights, window_layout, windows_for
from mocapfix.io import read_motion
from mocapfix.io.bvh import write_bvh
from mocapfix.io.h36m import H36M_KEEP
from mocapfix.io.positions import write_positions
from mocapfix.io.synthetic import generate_clips
from mocapfix.models.checkpoint import xmae_checkpoint
from mocapfix.models.xmae import XMAE

SMPL = preset("smpl22")
SMPL_REST = np.stack([np.zeros(22), np.linspace(-0.2, 0.2, 22), np.linspace(0.0, 1.7, 22)], axis=-1)  # (22, 3)
SIZES = dict(enc_dim=32, enc_depth=1, enc_mlp_dim=64, dec_dim=32, dec_depth=1, dec_mlp_dim=64, head_dim=16)


def _ckpt(path, skeleton=SMPL, fps=30.0, frames=30, seed=0):
    torch.manual_seed(seed)
    net = XMAE(skeleton.num_joints, frames, **SIZES)
    torch.save(xmae_checkpoint(net, skeleton, fps), path)
    return path


@pytest.fixture(scope="module")
def ckpt(tmp_path_factory):
    """A random-init tiny XMAE for smpl22 at 30 fps, 1 s windows, shaped like a training checkpoint."""
    return _ckpt(tmp_path_factory.mktemp("ckpt") / "tiny.ckpt")


@pytest.fixture(scope="module")
def motion():
    """Two people, 4 s at 30 fps (120 frames), smpl22, metres z up."""
    return np.stack([c.positions for c in generate_clips(2, 4.0, fps=30, seed=7)])  # (2, 120, 22, 3)


def fix(args, capsys) -> tuple[int, str, str]:
    return run_mocapfix(["fix", *args], capsys)


def _npz(path):
    with np.load(path) as z:
        return {k: z[k] for k in z.files}


class FnFixer(PositionFixer):
    """A Fixer whose estimate is fn(positions, observed): for properties that must hold whatever
    the model says."""

    kind = "test"

    def __init__(self, fn, skeleton=SMPL, fps=30.0, window=30):
        self.fn, self.skeleton, self.fps, self.window = fn, skeleton, fps, window
        self.calls = 0

    def estimate(self, positions, observed):
        self.calls += len(positions)
        return self.fn(positions, observed)


def lerp_fixer(**kw):
    return FnFixer(lambda p, o: lerp_infill(p, o).float(), **kw)


# --- the product path: formats, layouts, modes ---


def test_infill_keeps_observed_bit_identical_fills_the_rest_and_reports(tmp_path, ckpt, motion, capsys):
    pos = motion[0].copy()
    pos[40:55] = np.nan  # full skeleton, 0.5 s
    pos[70:80, SMPL.groups["left_arm"]] = np.nan
    write_positions(tmp_path / "take.npz", pos, 30, SMPL)
    rc, out, err = fix([tmp_path / "take.npz", "--ckpt", ckpt], capsys)
    assert rc == 0, err
    res = _npz(tmp_path / "take.fixed.npz")  # default output name, beside the input
    inp = _npz(tmp_path / "take.npz")
    seen = ~np.isnan(inp["positions"])
    assert res["positions"].shape == inp["positions"].shape
    assert np.array_equal(res["positions"][seen], inp["positions"][seen])  # bit for bit
    assert np.isfinite(res["positions"]).all()
    assert not np.array_equal(res["positions"][~seen], np.zeros_like(res["positions"][~seen]))
    assert list(res["joint_names"]) == list(SMPL.joint_names) and float(res["fps"]) == 30
    line = out.strip()
    assert line.count("\n") == 0
    n_missing = int(np.isnan(pos).any(-1).sum())
    for part in ("120 frames", "1 person", f"{n_missing} tokens filled", "limb sigma", "infill"):
        assert part in line, line
    assert line.endswith(" s") and "->" in line


def test_observed_tokens_bit_identical_in_centimetres_y_up(tmp_path, ckpt, motion, capsys):
    # a unit conversion there and back is not exact in float32: fix must copy the file's own numbers
    raw = (motion[0][..., [0, 2, 1]] * np.array([1, 1, -1]) * 100).astype(np.float32)  # z up -> y up, cm
    raw[30:45, 3:9] = np.nan
    np.savez(
        tmp_path / "cm.npz",
        positions=raw,
        fps=30.0,
        joint_names=np.array(SMPL.joint_names),
        parents=np.array(SMPL.parents),
        unit="cm",
        up_axis="y",
    )
    rc, _, err = fix([tmp_path / "cm.npz", "--ckpt", ckpt, "--out-dir", tmp_path / "out"], capsys)
    assert rc == 0, err
    res = _npz(tmp_path / "out" / "cm.npz")
    seen = ~np.isnan(raw)
    assert str(res["unit"]) == "cm" and str(res["up_axis"]) == "y"
    assert np.array_equal(res["positions"][seen], raw[seen]) and np.isfinite(res["positions"]).all()
    back = read_motion(tmp_path / "out" / "cm.npz")[0]
    assert np.abs(back.positions[:30] - read_motion(tmp_path / "cm.npz")[0].positions[:30]).max() == 0


def test_modes(tmp_path, ckpt, motion):
    fixer = load_fixer(ckpt)
    pos = motion[0].copy()
    pos[50:60, 4] = np.nan
    clip = Clip(pos, 30.0, SMPL, name="m", source="m")
    missing = np.isnan(pos).any(-1)
    infill, r_in = fix_clips([clip], fixer, "infill")
    denoise, r_de = fix_clips([clip], fixer, "denoise")
    both, r_bo = fix_clips([clip], fixer, "both")
    assert np.array_equal(infill[0].positions[~missing], pos[~missing])
    # denoise: every observed token replaced, missing ones stay missing
    assert np.isnan(denoise[0].positions[missing]).all()
    assert np.isfinite(denoise[0].positions[~missing]).all()
    assert (denoise[0].positions[~missing] != pos[~missing]).any(-1).mean() > 0.99
    # both: the denoised tokens, and the missing ones filled
    assert np.isfinite(both[0].positions).all()
    np.testing.assert_allclose(both[0].positions[~missing], denoise[0].positions[~missing], atol=1e-6)
    assert (r_in.filled, r_in.replaced) == (10, 0)
    assert (r_de.filled, r_de.replaced) == (0, missing.size - 10)
    assert (r_bo.filled, r_bo.replaced) == (10, missing.size - 10)


def test_multi_person_npz_and_csv_keep_their_layout(tmp_path, ckpt, motion, capsys):
    pos = motion.copy()
    pos[1, 20:40, 10:] = np.nan
    write_positions(tmp_path / "two.npz", pos, 30, SMPL)
    write_positions(tmp_path / "two.csv", pos, 30, SMPL, person_ids=["alice", "bob"], first_frame=100)
    rc, out, err = fix(
        [tmp_path / "two.npz", tmp_path / "two.csv", "--ckpt", ckpt, "--out-dir", tmp_path / "o"], capsys
    )
    assert rc == 0, err
    assert out.count("2 people") == 2
    res = _npz(tmp_path / "o" / "two.npz")
    assert res["positions"].shape == (2, 120, 22, 3) and np.isfinite(res["positions"]).all()
    assert np.array_equal(res["positions"][0], pos[0])  # the complete person is untouched
    lines = (tmp_path / "o" / "two.csv").read_text().splitlines()
    header = next(line for line in lines if not line.startswith("#"))
    assert header.startswith("person,frame,time,pelvis_x")
    rows = [line.split(",") for line in lines[lines.index(header) + 1 :]]
    assert {r[0] for r in rows} == {"alice", "bob"} and len(rows) == 240
    assert rows[0][1] == "100" and all(cell != "" for r in rows for cell in r)
    back = read_motion(tmp_path / "o" / "two.csv")
    assert [c.meta["person_id"] for c in back] == ["alice", "bob"]
    np.testing.assert_array_equal(back[0].positions, pos[0])


def test_every_window_of_every_person_in_one_batched_pass(motion):
    calls = []
    fixer = FnFixer(lambda p, o: (calls.append(len(p)), lerp_infill(p, o).float())[1])
    clips = [Clip(motion[i], 30.0, SMPL, name=f"p{i}", source="f", meta={"person_id": i}) for i in range(2)]
    _, report = fix_clips(clips, fixer, "both", batch_size=1000)
    starts, _ = window_layout(120, 30, 0.5)
    assert calls == [2 * len(starts)] and report.windows == 2 * len(starts)
    calls.clear()
    fix_clips(clips, fixer, "both", batch_size=5)
    assert calls == [5] * (2 * len(starts) // 5) + ([2 * len(starts) % 5] if 2 * len(starts) % 5 else [])


def test_infill_runs_only_windows_near_missing_tokens(motion):
    fixer = lerp_fixer()
    pos = motion[0].copy()
    clip = Clip(pos, 30.0, SMPL, name="c", source="c")
    _, report = fix_clips([clip], fixer, "infill")
    assert report.windows == 0 and fixer.calls == 0  # nothing missing: nothing to run
    pos[60, 5] = np.nan
    _, report = fix_clips([clip.replace(positions=pos)], fixer, "infill")
    assert report.windows == 1  # one window centred on frames 59-61 (the gap and its anchors)


def test_windows_centre_short_gaps_and_grid_long_ones():
    need = np.zeros(200, dtype=bool)
    need[50:54] = True  # short: one window, the gap in its middle
    starts, stride = windows_for(need, 30, 0.5)
    assert starts.tolist() == [37] and stride == 15
    need[3:5] = True  # near the clip start: clamped to 0
    assert windows_for(need, 30, 0.5)[0].tolist() == [0, 37]
    need[:] = False
    need[100:160] = True  # long: the grid, a quarter window of context
    starts = windows_for(need, 30, 0.5)[0]
    assert starts[0] == 93 and starts[-1] + 30 == 167 and (np.diff(starts) <= 15).all()
    assert windows_for(np.ones(200, dtype=bool), 30, 0.5)[0].tolist() == window_layout(200, 30, 0.5)[0].tolist()


@pytest.mark.parametrize("frames", [1, 2, 7, 29, 30, 31])
def test_inputs_shorter_than_a_window(tmp_path, ckpt, motion, capsys, frames):
    pos = motion[0, :frames].copy()
    if frames > 2:
        pos[frames // 2, :5] = np.nan
    write_positions(tmp_path / "short.npz", pos, 30, SMPL)
    rc, out, err = fix([tmp_path / "short.npz", "--ckpt", ckpt, "--mode", "both"], capsys)
    assert rc == 0, err
    res = _npz(tmp_path / "short.fixed.npz")["positions"]
    assert res.shape == pos.shape and np.isfinite(res).all()
    assert f"{frames} frames" in out


def test_fps_conversion_is_exact_on_linear_motion():
    # 60 fps input, model at 30 fps: frames resampled to the model and back; Lerp as the model
    # makes the whole path exact on motion linear in time, shared and in-between instants alike.
    T = 95
    t = np.arange(T) / 60.0
    pos = (SMPL_REST[None] + t[:, None, None] * np.array([0.8, -0.3, 0.1])).astype(np.float32)
    # Lerp stands in for the model: exact on linear motion as long as no window has a gap at its
    # edge (it holds the edge value there), so the gaps avoid model frames 0 and 14 (mod 15).
    pos[20:27, 3] = np.nan  # input frames 20-26 = model frames 10-13, and the odd ones between
    pos[61] = np.nan  # a whole frame at an instant the model's grid skips
    truth = (SMPL_REST[None] + t[:, None, None] * np.array([0.8, -0.3, 0.1])).astype(np.float32)
    clip = Clip(pos, 60.0, SMPL, name="c", source="c")
    for mode in ("infill", "both"):
        out, report = fix_clips([clip], lerp_fixer(), mode)
        assert out[0].fps == 60.0 and out[0].num_frames == T
        np.testing.assert_allclose(out[0].positions, truth, atol=2e-6)
    # a rate the model's does not divide (50 fps data, 30 fps model) keeps frames and stays close
    t50 = np.arange(120) / 50.0
    wave = (SMPL_REST[None] + 0.05 * np.sin(2 * np.pi * t50)[:, None, None]).astype(np.float32)
    out, _ = fix_clips([Clip(wave, 50.0, SMPL)], lerp_fixer(), "both")
    assert out[0].num_frames == 120 and np.isfinite(out[0].positions).all()
    # the last frame (2.38 s) lies past the model's last grid instant inside the clip (2.3667 s):
    # the grid's next frame is unobserved and this model (Lerp) holds there
    assert np.abs(out[0].positions - wave)[:-1].max() < 1e-3


def test_resample_frames_and_model_frames():
    x = np.arange(10, dtype=np.float64)[:, None]
    assert model_frames(10, 60.0, 30.0) == 6  # frames 0, 2, ..., 10 (the last past the end)
    y = resample_frames(x, 60.0, 30.0, 6)
    assert y[:5, 0].tolist() == [0, 2, 4, 6, 8] and np.isnan(y[5, 0])
    z = resample_frames(y[:5], 30.0, 60.0, 9)
    assert z[:, 0].tolist() == list(range(9))
    x[3] = np.nan
    w = resample_frames(x, 30.0, 45.0, 13)  # 2/3-frame steps: NaN only next to frame 3
    assert np.isnan(w[:, 0]).tolist() == [False] * 4 + [True, True] + [False] * 7  # frames 2.67 and 3.33


def test_blending_is_seamless():
    # Windows that disagree (each its own constant offset, as real windows do a little) must
    # not leave seams: acceleration at window borders no larger than inside windows. Without
    # overlap the same windows leave steps that the measure sees.
    clips = generate_clips(3, 12.0, fps=30, seed=5)

    def border_ratio(overlap):
        g = torch.Generator().manual_seed(0)
        fixer = FnFixer(lambda p, o: torch.nan_to_num(p) + 0.01 * torch.randn(len(p), 1, 1, 3, generator=g))
        ratios = []
        for c in clips:
            y = fix_clips([c], fixer, "both", overlap=overlap)[0][0].positions
            acc = np.zeros(len(y))
            acc[1:-1] = np.linalg.norm(y[:-2] - 2 * y[1:-1] + y[2:], axis=-1).mean(-1)
            border = np.zeros(len(y), dtype=bool)
            for s in window_layout(len(y), 30, overlap)[0]:
                for f in (s - 1, s, s + 29, s + 30):
                    if 1 <= f <= len(y) - 2:
                        border[f] = True
            inside = ~border
            inside[[0, -1]] = False
            ratios.append(acc[border].mean() / acc[inside].mean())
        return float(np.mean(ratios))

    assert border_ratio(0.5) <= 1.05  # the default overlap
    assert border_ratio(0.0) > 1.5  # the measure does see seams


def test_blend_weights_partition_unity():
    for W, S in ((30, 15), (30, 22), (50, 25), (30, 30)):
        w = blend_weights(W, S)
        assert w.min() > 0 and w.max() <= 1
        total = np.zeros(W * 4)
        for s in range(0, W * 3, S):
            total[s : s + W] += w
        assert np.allclose(total[W : 2 * W], 1.0)


def test_pass_through_joints_unchanged(tmp_path, ckpt, motion, capsys):
    # an input with joints the model does not know, in another order: mapped by name
    names = ("prop",) + SMPL.joint_names[::-1]
    order = list(range(22))[::-1]
    pos = np.concatenate([np.full((120, 1, 3), 0.5, dtype=np.float32), motion[0][:, order]], axis=1)
    pos[10:20, 0] = np.nan  # a gap in the unknown joint: filled along the skeleton (a root: its own spline)
    pos[50:60, 5] = np.nan  # a gap in a model joint is filled
    parents = [-1] + [0] * 22  # any tree: only names matter to the model
    write_positions(tmp_path / "x.npz", pos, 30, Skeleton(names, parents))
    rc, _, err = fix([tmp_path / "x.npz", "--ckpt", ckpt, "--mode", "both"], capsys)
    assert rc == 0, err
    res = _npz(tmp_path / "x.fixed.npz")
    assert list(res["joint_names"]) == list(names)
    seen = np.isfinite(pos[:, 0])
    np.testing.assert_array_equal(res["positions"][:, 0][seen], pos[:, 0][seen])
    np.testing.assert_allclose(res["positions"][10:20, 0], 0.5, atol=1e-6)
    assert np.isfinite(res["positions"][:, 1:]).all()


def test_map_joints_case_and_missing():
    sk = Skeleton(tuple(n.upper() for n in SMPL.joint_names), SMPL.parents)
    assert map_joints(sk, SMPL).tolist() == list(range(22))
    short = SMPL.subset([j for j in range(22) if SMPL.joint_names[j] not in ("left_wrist", "right_wrist")])
    with pytest.raises(MotionFileError, match="missing left_wrist, right_wrist"):
        map_joints(short, SMPL, "f.npz")


def test_nothing_observed_in_a_window_falls_back_to_lerp_and_says_so(ckpt, motion):
    pos = np.concatenate([motion[0], motion[1]])  # 240 frames
    pos[60:180] = np.nan  # a 4 s hole: windows with nothing in them
    pos[:, 20] = np.nan  # a joint never seen at all
    clip = Clip(pos, 30.0, SMPL, name="h", source="h")
    out, report = fix_clips([clip], load_fixer(ckpt), "both")
    y = out[0].positions
    # the joint never seen is left missing, not a body's guess written as data; the rest is filled
    assert np.isnan(y[:, 20]).all() and np.isfinite(np.delete(y, 20, axis=1)).all()
    lerp = lerp_infill(torch.from_numpy(pos)[None], torch.from_numpy(~np.isnan(pos).any(-1))[None])[0].numpy()
    np.testing.assert_allclose(y[100:140, :20], lerp[100:140, :20], atol=1e-5)  # deep inside the hole
    infill, infill_report = fix_clips([clip], load_fixer(ckpt), "infill")
    assert np.isnan(infill[0].positions[:, 20]).all() and np.isfinite(np.delete(infill[0].positions, 20, axis=1)).all()
    assert infill_report.filled == int(np.isnan(np.delete(pos, 20, axis=1)).any(-1).sum())  # not the lost joint's
    text = " ".join(report.notes)
    assert "no data within a window: linear interpolation" in text
    assert "never observed: left_wrist (left missing" in text


def test_bvh_input_writes_a_bvh_or_positions_npz(tmp_path, ckpt, capsys):
    clip = generate_clips(1, 2.0, fps=30, seed=1)[0]
    clip.meta.update(unit="cm", up_axis="y")
    write_bvh(tmp_path / "walk.bvh", clip)
    # by default a BVH (the model's positions put back on the file's skeleton: tests/test_ik.py)
    rc, out, err = fix([tmp_path / "walk.bvh", "--ckpt", ckpt, "--mode", "both"], capsys)
    assert rc == 0, err
    assert "walk.fixed.bvh" in out and "inverse kinematics" in out
    # or positions, on request
    rc, out, err = fix([tmp_path / "walk.bvh", "--ckpt", ckpt, "--mode", "both", "-o", tmp_path / "walk.npz"], capsys)
    assert rc == 0, err
    assert "walk.npz" in out and "a .bvh output (the default for a BVH input) keeps rotations" in out
    res = _npz(tmp_path / "walk.npz")
    assert str(res["unit"]) == "cm" and str(res["up_axis"]) == "y" and res["positions"].shape == (60, 22, 3)
    # a positions input cannot become a BVH
    write_positions(tmp_path / "p.npz", clip.positions, 30.0, clip.skeleton)
    rc, _, err = fix([tmp_path / "p.npz", "--ckpt", ckpt, "-o", tmp_path / "p.bvh"], capsys)
    assert rc == 1 and "needs a BVH input" in err and not (tmp_path / "p.bvh").exists()


def test_h36m_input_keeps_its_layout(tmp_path, capsys):
    ck = _ckpt(tmp_path / "h36m.ckpt", preset("h36m17"), fps=50.0, frames=50)
    rng = np.random.default_rng(0)
    tree = {
        "S9": {
            "Walking": (np.cumsum(rng.normal(0, 0.003, (80, 32, 3)), 0) + 1).astype(np.float32),
            "Eating": (np.cumsum(rng.normal(0, 0.003, (130, 32, 3)), 0) + 1).astype(np.float32),
        }
    }
    tree["S9"]["Walking"][10:20, 3] = np.nan
    np.savez(tmp_path / "data_3d_h36m.npz", positions_3d=np.array(tree, dtype=object))
    rc, out, err = fix([tmp_path / "data_3d_h36m.npz", "--ckpt", ck], capsys)
    assert rc == 0, err
    assert "2 sequences" in out and "210 frames" in out
    back = read_motion(tmp_path / "data_3d_h36m.fixed.npz", "h36m")
    assert [c.name for c in back] == ["S9/Eating", "S9/Walking"]
    assert [c.num_frames for c in back] == [130, 80] and all(np.isfinite(c.positions).all() for c in back)
    # the raw dataset's millimetres: too big a body as metres, read and written back in mm with --unit
    mm = {"S9": {a: x * 1000 for a, x in tree["S9"].items()}}
    (tmp_path / "mm").mkdir()
    np.savez(tmp_path / "mm" / "data_3d_h36m.npz", positions_3d=np.array(mm, dtype=object))
    rc, _, err = fix([tmp_path / "mm" / "data_3d_h36m.npz", "--ckpt", ck], capsys)
    assert rc == 1 and "not a human body" in err
    rc, _, err = fix([tmp_path / "mm" / "data_3d_h36m.npz", "--ckpt", ck, "--unit", "mm"], capsys)
    assert rc == 0, err
    with np.load(tmp_path / "mm" / "data_3d_h36m.fixed.npz", allow_pickle=True) as z:
        walking = z["positions_3d"].item()["S9"]["Walking"]
    given = mm["S9"]["Walking"][:, H36M_KEEP]  # (80, 17, 3) mm
    seen = np.isfinite(given)
    np.testing.assert_allclose(walking[seen], given[seen], rtol=1e-6)  # observed kept, in mm


def test_amass_input(tmp_path, capsys):
    pytest.importorskip("smplx", reason="AMASS needs the optional smplx extra (pip install mocapfix[smpl])")
    from test_amass import _amass, _model

    with open(tmp_path / "SMPLH_MALE.pkl", "wb") as f:
        pickle.dump(_model(52, 10, hands=True), f)
    _amass(tmp_path / "take_poses.npz", 45, 156, 10)
    ck = _ckpt(tmp_path / "smpl.ckpt")
    rc, out, err = fix(
        [tmp_path / "take_poses.npz", "--ckpt", ck, "--body-model", tmp_path / "SMPLH_MALE.pkl", "--mode", "both"],
        capsys,
    )
    assert rc == 0, err
    res = _npz(tmp_path / "take_poses.fixed.npz")
    assert res["positions"].shape[1:] == (22, 3) and np.isfinite(res["positions"]).all()
    assert "not rotations" in out


def test_json_report(tmp_path, ckpt, motion, capsys):
    write_positions(tmp_path / "a.npz", motion[0], 30, SMPL)
    rc, out, _ = fix([tmp_path / "a.npz", "--ckpt", ckpt, "--json", "--mode", "denoise"], capsys)
    assert rc == 0
    r = json.loads(out)
    assert r["frames"] == 120 and r["people"] == 1 and r["replaced"] == 120 * 22 and r["seconds"] > 0
    assert r["limb_sigma_after_mm"] is not None


# --- errors: one line per bad file, the others still processed ---


def test_bad_inputs_each_one_line_and_the_rest_still_run(tmp_path, ckpt, motion, capsys):
    good = write_positions(tmp_path / "good.npz", motion[0], 30, SMPL)
    write_positions(tmp_path / "whole.npz", motion[0], 30, SMPL)
    (tmp_path / "trunc.npz").write_bytes((tmp_path / "whole.npz").read_bytes()[:300])
    np.savez(tmp_path / "shape.npz", positions=np.zeros((10, 22, 2)), fps=30.0, joint_names=np.array(SMPL.joint_names))
    np.savez(
        tmp_path / "nofps.npz",
        positions=motion[0],
        joint_names=np.array(SMPL.joint_names),
        parents=np.array(SMPL.parents),
    )
    two = motion.copy()
    two[1] = np.nan
    write_positions(tmp_path / "nanperson.npz", two, 30, SMPL)
    legs = [0, 1, 2, 3, 4, 5, 6]  # Human3.6M's hip and legs: under half of the model's joints
    write_positions(tmp_path / "h36m.npz", motion[0][:, [0, 2, 5, 8, 1, 4, 7]], 30, preset("h36m17").subset(legs))
    (tmp_path / "text.csv").write_text("hello\n")
    write_positions(tmp_path / "mm_as_m.npz", motion[0] * 1000, 30, SMPL, unit="m")  # mm numbers said to be m
    bad = {
        "missing.npz": "no such file",
        "trunc.npz": "not a readable npz",
        "shape.npz": "(frames, joints, 3)",
        "nofps.npz": "fps",
        "nanperson.npz": "person 1: no data",
        "h36m.npz": "missing spine1, spine2, spine3, left_foot",
        "text.csv": "columns",
        "mm_as_m.npz": "m long (median), read as m: not a human body",
    }
    args = [tmp_path / n for n in bad] + [good]
    rc, out, err = fix([*args, "--ckpt", ckpt], capsys)
    assert rc == 1
    # errors only: a body of 1750 m is also a warning where it is read, and the checkpoint has no fill policy
    lines = [ln for ln in err.strip().splitlines() if ln.startswith("error:")]
    assert len(lines) == len(bad), err
    for line, (name, words) in zip(lines, bad.items()):
        assert line.startswith(f"error: {tmp_path / name}: ") and words in line, line
    assert "Traceback" not in err
    assert (tmp_path / "good.fixed.npz").exists() and out.count("\n") == 1
    assert not any((tmp_path / n.replace(".", ".fixed.")).exists() for n in bad)
    # fps given on the command line reads the file that lacks it; the unit, the file in mm
    rc, _, err = fix([tmp_path / "nofps.npz", "--ckpt", ckpt, "--fps", "30"], capsys)
    assert rc == 0, err
    rc, _, err = fix([tmp_path / "mm_as_m.npz", "--ckpt", ckpt, "--unit", "mm"], capsys)
    assert rc == 0, err


@pytest.mark.parametrize("kind", ["garbage", "plain_dict", "pickled_object", "other_model", "missing", "bad_weights"])
def test_not_a_mocapfix_checkpoint(tmp_path, motion, capsys, kind):
    write_positions(tmp_path / "a.npz", motion[0], 30, SMPL)
    path = tmp_path / "x.ckpt"
    if kind == "garbage":
        path.write_bytes(b"PK\x03\x04 not really a zip")
    elif kind == "plain_dict":
        torch.save({"weights": torch.zeros(3)}, path)
    elif kind == "pickled_object":
        torch.save({"hyper_parameters": {"x": Skeleton}, "state_dict": {}}, path)
    elif kind == "other_model":
        torch.save({"hyper_parameters": {"lr": 1.0}, "state_dict": {"model.w": torch.zeros(2)}}, path)
    elif kind == "bad_weights":
        ck = xmae_checkpoint(XMAE(22, 30, **SIZES), SMPL, 30.0)
        ck["model"]["config"]["enc_dim"] = 64
        torch.save(ck, path)
    rc, out, err = fix([tmp_path / "a.npz", "--ckpt", path], capsys)
    assert rc == 1 and out == ""
    assert err.count("\n") == 1 and err.startswith(f"error: {path}: ") and "Traceback" not in err
    words = {"missing": "no such checkpoint", "bad_weights": "weights do not fit"}.get(
        kind, "not a mocapfix checkpoint"
    )
    assert words in err
    assert not (tmp_path / "a.fixed.npz").exists()


def test_checkpoint_of_another_skeleton_maps_by_body_part_or_names_the_missing_joints(tmp_path, motion, capsys):
    ck = _ckpt(tmp_path / "h.ckpt", preset("h36m17"), fps=50.0, frames=50)
    write_positions(tmp_path / "a.npz", motion[0], 30, SMPL)  # SMPL's names onto Human3.6M's joints
    rc, _, err = fix([tmp_path / "a.npz", "--ckpt", ck], capsys)
    assert rc == 0, err
    # a recording without the wrists: the model estimates them and does not write them
    no_wrists = [j for j in range(22) if "wrist" not in SMPL.joint_names[j]]
    write_positions(tmp_path / "b.npz", motion[0][:, no_wrists], 30, SMPL.subset(no_wrists))
    rc, out, err = fix([tmp_path / "b.npz", "--ckpt", ck], capsys)
    assert rc == 0 and "model joints not in the recording: LWrist, RWrist (estimated, not written)" in out, err
    assert _npz(tmp_path / "b.fixed.npz")["positions"].shape == (120, 20, 3)
    # fewer than half of the model's joints: not this model's kind of skeleton, an error naming them
    legs = [j for j in range(22) if any(w in SMPL.joint_names[j] for w in ("pelvis", "hip", "knee", "ankle"))]
    write_positions(tmp_path / "c.npz", motion[0][:, legs], 30, SMPL.subset(legs))
    rc, _, err = fix([tmp_path / "c.npz", "--ckpt", ck], capsys)
    assert rc == 1 and "skeleton does not match the model's (h36m17, 17 joints): missing Spine" in err


def test_never_overwrites_input_or_existing_output(tmp_path, ckpt, motion, capsys):
    write_positions(tmp_path / "a.npz", motion[0], 30, SMPL)
    before = (tmp_path / "a.npz").read_bytes()
    rc, _, err = fix([tmp_path / "a.npz", "--ckpt", ckpt, "-o", tmp_path / "a.npz", "--force"], capsys)
    assert rc == 1 and "is the input" in err and (tmp_path / "a.npz").read_bytes() == before
    (tmp_path / "a.fixed.npz").write_bytes(b"keep me")
    rc, _, err = fix([tmp_path / "a.npz", "--ckpt", ckpt], capsys)
    assert rc == 1 and "exists (use --force" in err and (tmp_path / "a.fixed.npz").read_bytes() == b"keep me"
    rc, _, err = fix([tmp_path / "a.npz", "--ckpt", ckpt, "--force"], capsys)
    assert rc == 0 and (tmp_path / "a.fixed.npz").read_bytes() != b"keep me"
    with pytest.raises(SystemExit) as e:  # -o with several inputs is a usage error
        main(["fix", str(tmp_path / "a.npz"), str(tmp_path / "a.npz"), "--ckpt", str(ckpt), "-o", "x.npz"])
    assert e.value.code == 2


def test_folder_input_skips_earlier_outputs(tmp_path, ckpt, motion, capsys):
    (tmp_path / "in" / "sub").mkdir(parents=True)
    write_positions(tmp_path / "in" / "a.npz", motion[0], 30, SMPL)
    write_positions(tmp_path / "in" / "sub" / "b.csv", motion[1], 30, SMPL)
    write_positions(tmp_path / "in" / "a.fixed.npz", motion[0], 30, SMPL)
    rc, out, err = fix([tmp_path / "in", "--ckpt", ckpt, "--out-dir", tmp_path / "out"], capsys)
    assert rc == 0, err
    assert out.count("\n") == 2
    assert (tmp_path / "out" / "a.npz").exists() and (tmp_path / "out" / "sub" / "b.csv").exists()


def test_interrupted_run_leaves_no_output(tmp_path, ckpt, motion, monkeypatch, capsys):
    write_positions(tmp_path / "a.npz", motion[0], 30, SMPL)

    def interrupted(f, **arrays):
        f.write(b"half a file")
        raise KeyboardInterrupt

    monkeypatch.setattr(np, "savez_compressed", interrupted)
    rc, _, err = fix([tmp_path / "a.npz", "--ckpt", ckpt, "--mode", "both"], capsys)
    assert rc == 130 and "interrupted" in err
    assert sorted(os.listdir(tmp_path)) == ["a.npz"]  # no output, no temporary file


def test_progress_bar_on_a_terminal_and_lines_otherwise():
    import io

    from mocapfix.apps.fix_one import Progress

    class Tty(io.StringIO):
        def isatty(self):
            return True

    tty, log = Tty(), io.StringIO()
    for stream in (tty, log):
        p = Progress("take.npz", True, stream)
        for done in range(1, 101):
            p(done, 100)
    assert tty.getvalue().count("\r") == 100 and tty.getvalue().endswith("100% (100/100 windows)\n")
    assert log.getvalue().count("\n") == 11  # the first batch, then one line per 10%
    quiet = io.StringIO()
    Progress("x", False, quiet)(5, 10)
    assert quiet.getvalue() == ""


# --- a small XMAE trained here, against Lerp ---

TRAIN = [
    "fit",
    "--config",
    CONFIGS / "xmae.yaml",
    *TINY,
    *QUIET,
    "--trainer.logger",
    "false",
    "--data.synthetic_clips",
    "24",
    "--data.synthetic_seconds",
    "10",
    "--data.cache_dir",
    "null",
    "--data.fps",
    "10",
    "--data.stride_s",
    "0.1",
    "--data.val_fraction",
    "0.1",
    "--data.test_fraction",
    "0",
    "--data.batch_size",
    "32",
    "--trainer.limit_val_batches",
    "0",
    "--trainer.val_check_interval",
    "null",
    "--trainer.check_val_every_n_epoch",
    "1000",
    "--model.init_args.lr",
    "3e-3",
    "--model.init_args.warmup_steps",
    "50",
]


def _train(tmp_path, steps: int):
    assert run_cli([*TRAIN, "--experiment", "fix", "--trainer.max_steps", str(steps)], tmp_path) == 0
    return tmp_path / "checkpoints" / "fix" / "last.ckpt"


def _evaluate(ckpt, tmp_path, capsys) -> dict:
    """Fix corrupted held-out clips through the CLI (--mode both) -> errors in mm and limb sigma."""
    clips = generate_clips(4, 10.0, fps=30, seed=1234)  # other seed than training
    rng = np.random.default_rng(0)
    truth = np.stack([c.positions for c in clips])
    bad, gap, disp = zip(*(corrupt_recording(c.positions, 30.0, SMPL.groups, rng) for c in clips))
    bad, gap, disp = np.stack(bad), np.stack(gap), np.stack(disp)
    write_positions(tmp_path / "bad.npz", bad, 30, SMPL)
    rc, out, err = fix([tmp_path / "bad.npz", "--ckpt", ckpt, "--mode", "both", "--json"], capsys)
    assert rc == 0, err
    fixed = _npz(tmp_path / "bad.fixed.npz")["positions"]
    lerp = lerp_infill(torch.from_numpy(bad), torch.from_numpy(~gap)).numpy()
    corrupted = gap | disp
    err_fix, err_lerp = (1000 * np.linalg.norm(p - truth, axis=-1) for p in (fixed, lerp))
    return {
        "fixed": fixed,
        "report": json.loads(out),
        "fix_mm": err_fix[corrupted].mean(),
        "lerp_mm": err_lerp[corrupted].mean(),
        "fix_disp_mm": err_fix[disp].mean(),
        "lerp_disp_mm": err_lerp[disp].mean(),
        "fix_gap_mm": err_fix[gap].mean(),
        "lerp_gap_mm": err_lerp[gap].mean(),
    }


@pytest.mark.slow  # a minute of CPU; `make test-all` runs it
def test_trained_xmae_checkpoint_sanity(tmp_path, capsys):
    """A briefly trained XMAE straight from `fit`: the Lightning checkpoint loads, nothing NaN
    comes out, displaced tokens are pulled back and limbs are steadier than in the input."""
    ckpt = _train(tmp_path, 150)
    r = _evaluate(ckpt, tmp_path, capsys)
    assert np.isfinite(r["fixed"]).all()
    assert r["fix_disp_mm"] < 0.5 * r["lerp_disp_mm"]
    assert r["report"]["limb_sigma_after_mm"] < r["report"]["limb_sigma_before_mm"]


@pytest.mark.slow
def test_trained_xmae_beats_lerp(tmp_path, capsys):
    """The issue's bar: gaps of 0.1-0.9 s and 2% displaced tokens; the fixed output's MPJPE on the
    corrupted tokens below Lerp's, nothing NaN, limb sigma below the corrupted input's."""
    ckpt = _train(tmp_path, 3000)
    r = _evaluate(ckpt, tmp_path, capsys)
    assert np.isfinite(r["fixed"]).all()
    assert r["fix_mm"] < r["lerp_mm"], {k: v for k, v in r.items() if k.endswith("mm")}
    assert r["report"]["limb_sigma_after_mm"] < r["report"]["limb_sigma_before_mm"]
    # and a real model's windows blend without seams (clips at the model's 10 fps: borders are frames)
    fixer = load_fixer(ckpt)
    ratios = []
    for c in generate_clips(3, 20.0, fps=10, seed=5):
        y = fix_clips([c], fixer, "both")[0][0].positions
        acc = np.zeros(len(y))
        acc[1:-1] = np.linalg.norm(y[:-2] - 2 * y[1:-1] + y[2:], axis=-1).mean(-1)
        border = np.zeros(len(y), dtype=bool)
        for s in window_layout(len(y), fixer.window, 0.5)[0]:
            for f in (s - 1, s, s + fixer.window - 1, s + fixer.window):
                if 1 <= f <= len(y) - 2:
                    border[f] = True
        inside = ~border
        inside[[0, -1]] = False
        ratios.append(acc[border].mean() / acc[inside].mean())
    assert np.mean(ratios) <= 1.1, ratios


def test_bf16_precision_stays_close_to_fp32_and_keeps_observed_tokens(ckpt, motion):
    pos = motion[0].copy()
    pos[50:60, 4] = np.nan
    clip = Clip(pos, 30.0, SMPL, name="m", source="m")
    fp32 = fix_clips([clip], load_fixer(ckpt, precision="fp32"), "both")[0][0].positions
    bf16_fixer = load_fixer(ckpt, precision="bf16")
    assert bf16_fixer.precision == "bf16"
    bf16 = fix_clips([clip], bf16_fixer, "both")[0][0].positions
    assert not np.array_equal(bf16, fp32)  # the bf16 path really ran
    assert np.abs(bf16 - fp32).mean() < 2e-3  # metres; coordinates stay fp32 at the network's ends
    infill = fix_clips([clip], bf16_fixer, "infill")[0][0].positions
    seen = ~np.isnan(pos).any(-1)
    assert np.array_equal(infill[seen], pos[seen]) and np.isfinite(infill).all()


def test_precision_auto_and_bad_values():
    assert resolve_precision("fp32", torch.device("cpu")) == "fp32"
    assert resolve_precision("auto", torch.device("cpu")) in ("fp32", "bf16")
    with pytest.raises(ValueError):
        resolve_precision("fp16", torch.device("cpu"))


def test_wrong_command_lines_are_usage_errors(tmp_path, ckpt, motion, capsys):
    """--out-dir naming a file and a non-positive --fps are the command line's fault (exit 2, one
    message), not an error per input file (exit 1, repeated)."""
    write_positions(tmp_path / "a.npz", motion[0], 30, SMPL)
    (tmp_path / "afile").write_text("x")
    for extra, message in (
        (["--out-dir", tmp_path / "afile"], "is a file, not a folder"),
        (["--fps", "0"], "--fps: must be 1 to 10000 frames per second"),
        (["--fps", "nan"], "--fps: must be 1 to 10000 frames per second"),
    ):
        with pytest.raises(SystemExit) as e:
            main(["fix", str(tmp_path / "a.npz"), "--ckpt", str(ckpt), *map(str, extra)])
        err = capsys.readouterr().err
        assert e.value.code == 2 and message in err and "a.npz" not in err


def test_an_error_about_another_file_names_the_input_too(tmp_path):
    from mocapfix.apps.fix_one import _one_line
    from mocapfix.core.clip import MotionFileError

    models = MotionFileError(tmp_path / "models", "no SMPLH model for gender 'robot'")
    assert (
        _one_line(tmp_path / "a.npz", models)
        == f"{tmp_path / 'a.npz'}: {tmp_path / 'models'}: no SMPLH model for gender 'robot'"
    )
    own = MotionFileError(tmp_path / "a.npz", "no betas (body shape)")
    assert _one_line(tmp_path / "a.npz", own) == f"{tmp_path / 'a.npz'}: no betas (body shape)"
    assert _one_line(tmp_path / "a.npz", ValueError("bad")) == f"{tmp_path / 'a.npz'}: ValueError: bad"


def test_sigterm_stops_fix_with_one_line_exit_143_and_no_temp_files(tmp_path, ckpt):
    """A scheduler's SIGTERM mid-run: the outputs written so far are whole, no hidden temporary
    file is left, one line says so, and the exit code is 143."""
    import os
    import signal
    import subprocess
    import sys
    import time

    clips = generate_clips(24, 30.0, fps=30, seed=3)
    for i, c in enumerate(clips):
        pos = c.positions.copy()
        pos[::7, 5] = np.nan
        write_positions(tmp_path / f"take{i:02d}.npz", pos, 30, SMPL)
    env = dict(os.environ, OMP_NUM_THREADS="1")
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "mocapfix",
            "fix",
            str(tmp_path),
            "--ckpt",
            str(ckpt),
            "--out-dir",
            str(tmp_path / "out"),
            "--progress",
            "never",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    first = proc.stdout.readline()  # the first file is done: the run is under way
    assert "->" in first, proc.stderr.read()
    time.sleep(0.05)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 143, err
    assert "stopped by SIGTERM" in err and "Traceback" not in err
    outputs = sorted(p.name for p in (tmp_path / "out").iterdir())
    assert outputs and not any(n.startswith(".") for n in outputs) and len(outputs) < 24
    for name in outputs:  # every file there is whole
        assert np.isfinite(read_motion(tmp_path / "out" / name)[0].positions).all()


def test_a_hermite_correcting_model_starts_from_the_whole_takes_hermite_fill(tmp_path):
    """fill_kind hermite: fix hands the network the take's Hermite fill (whole take, the take's
    frame rate); with its output layer zeroed the model answers exactly that fill, not the
    fill of its 1-s windows."""
    from mocapfix.fills.classical import hermite_infill
    from mocapfix.fix.measure import model_fill
    from mocapfix.io.synthetic import generate_clips
    from mocapfix.models.xmae import XMAE
    from mocapfix.rig.mapping import onto_skeleton

    body = preset("body21")
    take = onto_skeleton(generate_clips(1, 6.0, 30.0, seed=4)[0], body).positions.astype(np.float64)
    holed = take.copy()
    holed[80:106] = np.nan  # 0.87 s of the whole body: a 1-s window holds almost no context
    net = XMAE(
        21, 30, enc_dim=32, enc_depth=1, dec_dim=32, dec_depth=1, head_dim=16, fill_input=True, fill_kind="hermite"
    )
    torch.nn.init.zeros_(net.head.weight)
    torch.nn.init.zeros_(net.head.bias)
    torch.save(xmae_checkpoint(net, body, 30.0), tmp_path / "h.ckpt")
    out = model_fill(load_fixer(tmp_path / "h.ckpt"), overlap=0.5, batch_size=16)(holed.astype(np.float32), 30.0)
    x = torch.from_numpy(holed)[None]
    hermite = hermite_infill(x, ~torch.isnan(x).any(-1))[0].numpy()
    assert np.abs(out[80:106] - hermite[80:106]).max() < 1e-4
    assert (
        np.abs(hermite[80:106] - take[80:106]).mean()
        < np.abs(lerp_infill(x, ~torch.isnan(x).any(-1))[0].numpy()[80:106] - take[80:106]).mean()
    )


def test_the_model_asked_for_some_holes_runs_their_windows_only_and_fills_them_as_for_all(tmp_path):
    """The model's fill a policy is measured with, asked for one hole of a take: the windows that
    hole needs run (the far hole's do not: Lerp there), and that hole comes out as when every
    hole of the take is filled (its windows the same: the holes are far apart)."""
    from mocapfix.fix.measure import model_fill
    from mocapfix.pretrained import pretrained_path
    from mocapfix.rig.mapping import onto_skeleton

    body = preset("body21")
    take = onto_skeleton(generate_clips(1, 12.0, 30.0, seed=5)[0], body).positions.astype(np.float32)
    holed = take.copy()
    holed[40:55, body.groups["left_arm"]] = np.nan
    holed[250:270] = np.nan
    fill = model_fill(load_fixer(pretrained_path("xmae-cpu-bandai")), overlap=0.5, batch_size=16)
    asked = np.zeros(len(take), dtype=bool)
    asked[250:270] = True
    every, some = fill(holed, 30.0), fill(holed, 30.0, asked)
    np.testing.assert_allclose(some[250:270], every[250:270], atol=1e-5)
    x = torch.from_numpy(holed.astype(np.float64))[None]
    np.testing.assert_allclose(some[40:55], lerp_infill(x, ~torch.isnan(x).any(-1))[0].numpy()[40:55])
    assert np.abs(every[40:55] - some[40:55]).max() > 1e-3
    # two takes at once (their windows in the same batches) get what each gets alone
    other = np.zeros(len(take), dtype=bool)
    other[40:55] = True
    both = fill.takes([holed, holed], 30.0, [asked, other])
    np.testing.assert_allclose(both[0], some, atol=1e-5)
    np.testing.assert_allclose(both[1], fill(holed, 30.0, other), atol=1e-5)


def test_the_model_runs_only_for_the_holes_its_policy_gives_it():
    """A policy that fills every hole with the limb fill: no window of the model runs and the holes
    are the limb fill's; one that gives the model the arm's holes: its windows run for those, and
    the leg's hole is still the limb fill's."""
    from mocapfix.fills.classical import limb_infill
    from mocapfix.fills.holes import PARTS
    from mocapfix.fills.policy import FillPolicy
    from mocapfix.pretrained import pretrained_path
    from mocapfix.rig.mapping import onto_skeleton

    body = preset("body21")
    take = onto_skeleton(generate_clips(1, 12.0, 30.0, seed=6)[0], body)
    holed = take.positions.copy()
    holed[40:55, body.groups["left_arm"]] = np.nan
    holed[250:265, body.groups["left_leg"]] = np.nan
    clip = take.replace(positions=holed)
    fixer = load_fixer(pretrained_path("xmae-cpu-bandai"))
    gaps = [0.1, 0.5, 0.9]
    x = torch.from_numpy(holed.astype(np.float64))[None]
    limb = limb_infill(x, ~torch.isnan(x).any(-1), body.parents)[0].numpy()

    def fixed(model_error: dict[str, float]):
        tables = {p: {"limb": [10.0] * 3, "xmae": [model_error.get(p, 100.0)] * 3} for p in PARTS}
        policy = FillPolicy(gaps, tables, None, 1, [], ("limb", 0.95))
        (out,), report = fix_clips([clip], fixer, "infill", measured=(policy, "a policy made up"))
        return out.positions, report

    out, report = fixed({})
    assert report.windows == 0
    np.testing.assert_allclose(out[40:55], limb[40:55], atol=1e-5)
    out, report = fixed({"arm": 1.0})
    assert report.windows > 0
    assert np.abs(out[40:55] - limb[40:55]).max() > 1e-3
    np.testing.assert_allclose(out[250:265], limb[250:265], atol=1e-5)
