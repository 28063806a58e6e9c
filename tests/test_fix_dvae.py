"""`mocapfix fix` with Motion-DVAE checkpoints: the denoising stage on the positions state (positions
windows, as XMAE) and on the rotations state (a Bandai BVH in, a BVH in the input's hierarchy
out), the same estimate as the denoising module's, exact rotation windowing, and the errors.
Checkpoints are tiny untrained denoising modules built here (seconds, no training)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from cli_utils import run_mocapfix
from scipy.spatial.transform import Rotation, Slerp

from mocapfix.apps.main import main
from mocapfix.core.clip import MotionFileError
from mocapfix.core.kinematics import fk_axis_angle
from mocapfix.core.resample import resample_motion
from mocapfix.core.skeleton import preset
from mocapfix.fix import fix_clips
from mocapfix.fix.fixers import DVAEFixer, load_fixer
from mocapfix.fix.rotations import RotationFixer
from mocapfix.io import read_motion
from mocapfix.io.bvh import read_bvh
from mocapfix.io.positions import write_positions
from mocapfix.io.synthetic import generate_clips
from mocapfix.models.checkpoint import model_kind, read_checkpoint
from mocapfix.models.dvae_inference import Observation
from mocapfix.training.denoise_module import DVAEDenoiseModule
from mocapfix.training.dvae_module import MotionDVAEModule

SMPL = preset("smpl22")
BANDAI_FILE = "dataset-1_walk-left_active_001.bvh"  # 90 frames at 30 fps
REPO = Path(__file__).resolve().parents[1]


def _modules(skeleton, state: str, fps=30.0, frames=30, seed=0, **denoise):
    """A tiny prior and the denoising module built on it (untrained: fix's plumbing, not its quality)."""
    torch.manual_seed(seed)
    prior = MotionDVAEModule(
        state=state,
        latent_dim=4,
        lstm_hidden=16,
        mlp_hidden=16,
        norm_groups=4,
        skeleton=skeleton.to_dict(),
        window_fps=fps,
        window_frames=frames,
    )
    hp = {k: v for k, v in prior.hparams.items() if not k.startswith("_")}
    denoiser = DVAEDenoiseModule(prior_hparams=hp, noise="rotation" if state == "rotations" else "position", **denoise)
    with torch.no_grad():  # a standardisation that is not the identity, so fix must use the stored one
        denoiser.net.x_mean.normal_(0.0, 0.05)
        denoiser.net.x_std.uniform_(0.5, 1.5)
        for p in denoiser.noise_pred.parameters():  # zero-initialised last layer: make eq. 18 see something
            p.add_(0.01 * torch.randn_like(p))
    return prior, denoiser


def _save(path, module) -> Path:
    """What Lightning saves, minus the training state: plain hyperparameters, the weights and
    what the module's on_save_checkpoint adds (the model's kind and config)."""
    ckpt = {"hyper_parameters": dict(module.hparams), "state_dict": module.state_dict()}
    module.on_save_checkpoint(ckpt)
    torch.save(ckpt, path)
    return path


def fix(args, capsys) -> tuple[int, str, str]:
    return run_mocapfix(["fix", *args], capsys)


@pytest.fixture(scope="module")
def bandai_file(bandai_files) -> Path:
    return {f.name: f for f in bandai_files}[BANDAI_FILE]


@pytest.fixture(scope="module")
def bandai_skeleton(bandai_file):
    """The skeleton the Bandai configs train on: joint_Root dropped, Hips the root."""
    return read_bvh(bandai_file, drop_joints=["joint_Root"])[0].skeleton


@pytest.fixture(scope="module")
def positions_ckpt(tmp_path_factory):
    return _save(tmp_path_factory.mktemp("dvae") / "pos.ckpt", _modules(SMPL, "positions")[1])


@pytest.fixture(scope="module")
def rotations_ckpt(tmp_path_factory, bandai_skeleton):
    return _save(tmp_path_factory.mktemp("dvae") / "rot.ckpt", _modules(bandai_skeleton, "rotations")[1])


# --- checkpoints ---


def test_model_kind_tells_the_denoising_stage_from_the_prior_and_refuses_the_prior(tmp_path):
    prior, denoiser = _modules(SMPL, "positions")
    dn = _save(tmp_path / "dn.ckpt", denoiser)
    assert model_kind(read_checkpoint(dn)) == "motion-dvae"
    fixer = load_fixer(dn)
    assert isinstance(fixer, DVAEFixer) and fixer.kind == "motion-dvae" and fixer.state == "positions"
    assert (fixer.skeleton.joint_names, fixer.fps, fixer.window) == (SMPL.joint_names, 30.0, 30)
    pr = _save(tmp_path / "prior.ckpt", prior)
    assert model_kind(read_checkpoint(pr)) == "motion-dvae-prior"
    with pytest.raises(MotionFileError, match="prior checkpoint; fix needs the denoising stage") as e:
        load_fixer(pr)
    assert "\n" not in str(e.value) and str(pr) in str(e.value)


def test_checkpoints_missing_what_rebuilds_the_nets_are_one_line_errors(tmp_path):
    _, denoiser = _modules(SMPL, "positions")
    ckpt = {"hyper_parameters": dict(denoiser.hparams), "state_dict": denoiser.state_dict()}
    for drop, match in (("prior_hparams", "lacks prior_hparams"), ("noise_lambda", "lacks noise_lambda")):
        hp = {k: v for k, v in ckpt["hyper_parameters"].items() if k != drop}
        torch.save({**ckpt, "hyper_parameters": hp}, tmp_path / "x.ckpt")
        with pytest.raises(MotionFileError, match=match) as e:
            load_fixer(tmp_path / "x.ckpt")
        assert "\n" not in str(e.value)
    hp = dict(ckpt["hyper_parameters"], prior_hparams={**ckpt["hyper_parameters"]["prior_hparams"], "lstm_hidden": 8})
    torch.save({**ckpt, "hyper_parameters": hp}, tmp_path / "x.ckpt")
    with pytest.raises(MotionFileError, match="weights do not fit"):
        load_fixer(tmp_path / "x.ckpt")


# --- the estimate is the denoising module's ---


@pytest.mark.parametrize("estimate", ["decoder", "fusion"])
def test_positions_fixer_is_the_denoising_modules_regression_estimate(tmp_path, estimate):
    _, denoiser = _modules(SMPL, "positions", noise_lambda=5.0, estimate=estimate)
    fixer = load_fixer(_save(tmp_path / "dn.ckpt", denoiser))
    assert fixer.fusion == (estimate == "fusion")
    clips = generate_clips(3, 1.0, fps=30, seed=3)
    pos = torch.stack([torch.from_numpy(c.positions[:30]) for c in clips])  # (3, 30, 22, 3)
    denoiser.eval()
    with torch.no_grad():
        want = denoiser.estimate(Observation(pos, None, None, None))
    got = fixer.estimate(pos, torch.ones(pos.shape[:-1], dtype=torch.bool))
    torch.testing.assert_close(got, want.float())
    # missing tokens: Lerp before the model; eq. 18 fuses only where there is an observation
    obs = torch.ones(pos.shape[:-1], dtype=torch.bool)
    obs[:, 10:14, 5] = False
    holed = pos.clone()
    holed[~obs] = float("nan")
    out = fixer.estimate(holed, obs)
    assert out.shape == pos.shape and torch.isfinite(out).all()


def test_rotations_fixer_is_the_denoising_modules_decoder_motion(bandai_file, bandai_skeleton, tmp_path):
    _, denoiser = _modules(bandai_skeleton, "rotations")
    fixer = load_fixer(_save(tmp_path / "rot.ckpt", denoiser))
    assert fixer.state == "rotations"
    c = read_bvh(bandai_file, drop_joints=["joint_Root"])[0]
    rot = torch.from_numpy(np.stack([c.rotations[0:30], c.rotations[20:50]]))  # (2, 30, 21, 3)
    root = torch.from_numpy(np.stack([c.root_translation[0:30], c.root_translation[20:50]]))
    offs = torch.from_numpy(np.stack([c.offsets, c.offsets]))
    est_rot, est_root = fixer.estimate_rotations(rot, root, offs)
    assert est_rot.shape == rot.shape and est_root.shape == root.shape
    denoiser.eval()
    with torch.no_grad():
        want = denoiser.estimate(
            Observation(fk_axis_angle(rot, root, offs[:, None], bandai_skeleton.parents), rot, root, offs)
        )
    # FK of the fixer's world-frame rotations is the module's estimate (decoder output, Gaussian setting)
    torch.testing.assert_close(
        fk_axis_angle(est_rot, est_root, offs[:, None], bandai_skeleton.parents), want, atol=1e-4, rtol=0
    )


# --- windows of rotations ---


class IdentityRotationFixer(RotationFixer):
    """Gives its input back: windowing, resampling and blending must then give the clip back."""

    kind, state, notes = "identity", "rotations", []

    def __init__(self, skeleton, fps=30.0, window=30):
        self.skeleton, self.fps, self.window = skeleton, fps, window
        self.lengths = []

    def estimate_rotations(self, rotations, root_translation, offsets):
        self.lengths.append(rotations.shape[1])
        return rotations.clone(), root_translation.clone()


@pytest.mark.parametrize("rate,frames", [(1, None), (2, None), (1, 17)])
def test_rotation_windows_resampling_and_blending_give_an_identity_model_the_clip_back(
    bandai_file, bandai_skeleton, rate, frames
):
    c = read_bvh(bandai_file, drop_joints=["joint_Root"])[0]
    if frames is not None:  # shorter than a window: too short to judge, kept as it is
        c = c.replace(
            positions=c.positions[:frames], rotations=c.rotations[:frames], root_translation=c.root_translation[:frames]
        )
    # the model at the clip's rate (30.00003 fps: Frame Time 0.0333333), or twice it: slerp there and back
    fixer = IdentityRotationFixer(bandai_skeleton, fps=rate * c.fps)
    assert frames is None or frames < fixer.window
    (out,), report = fix_clips([c], fixer, "denoise", overlap=0.5)
    if frames is not None:
        assert out is c and fixer.lengths == [] and report.windows == 0 and report.replaced == 0
        assert any(n.endswith("observed tokens kept, not judged") for n in report.notes)
        return
    assert report.windows > 0 and report.replaced == c.num_frames * c.skeleton.num_joints
    assert out.positions.shape == c.positions.shape and out.rotations.shape == c.rotations.shape
    np.testing.assert_allclose(out.positions, c.positions, atol=5e-5)  # float32 rotations down a 21-joint chain
    np.testing.assert_allclose(out.root_translation, c.root_translation, atol=1e-6)


def test_resample_motion_is_slerp():
    rng = np.random.default_rng(0)
    rot = rng.normal(size=(5, 2, 3)).astype(np.float32)
    root = rng.normal(size=(5, 3)).astype(np.float32)
    r2, t2 = resample_motion(rot, root, 30.0, 60.0, 9)
    assert np.array_equal(r2[::2], rot) and np.array_equal(t2[::2], root)  # shared instants: exact copies
    for j in range(2):
        want = Slerp(np.arange(5), Rotation.from_rotvec(rot[:, j]))(np.arange(9) / 2).as_matrix()
        np.testing.assert_allclose(Rotation.from_rotvec(r2[:, j]).as_matrix(), want, atol=1e-5)
    np.testing.assert_allclose(t2[1::2], (root[:-1] + root[1:]) / 2, atol=1e-6)


# --- the product path ---


def test_fix_positions_npz_with_a_positions_state_dvae(tmp_path, positions_ckpt, capsys):
    pos = generate_clips(1, 4.0, fps=30, seed=7)[0].positions.copy()  # (120, 22, 3)
    pos[40:55] = np.nan
    pos[70:80, SMPL.groups["left_arm"]] = np.nan
    write_positions(tmp_path / "take.npz", pos, 30, SMPL)
    seen = ~np.isnan(pos)
    for mode in ("infill", "denoise", "both"):
        rc, out, err = fix(
            [tmp_path / "take.npz", "--ckpt", positions_ckpt, "--mode", mode, "-o", tmp_path / f"{mode}.npz"], capsys
        )
        assert rc == 0, err
        with np.load(tmp_path / f"{mode}.npz") as z:
            res, names = z["positions"], list(z["joint_names"])
        assert res.shape == pos.shape and names == list(SMPL.joint_names)
        assert np.isfinite(res[seen if mode == "denoise" else np.ones_like(seen)]).all()
        if mode == "infill":
            assert np.array_equal(res[seen], pos[seen])
        else:
            assert not np.allclose(res[seen], pos[seen])
        assert f"({mode}, motion-dvae)" in out and out.count("\n") == 1


def test_fix_bandai_bvh_with_a_rotations_state_dvae_writes_the_inputs_hierarchy(
    tmp_path, bandai_file, rotations_ckpt, capsys
):
    rc, out, err = fix([bandai_file, "--ckpt", rotations_ckpt, "--mode", "denoise", "--out-dir", tmp_path], capsys)
    assert rc == 0, err
    target = tmp_path / bandai_file.name  # BVH stays BVH
    assert f"-> {target}:" in out and "(denoise, motion-dvae)" in out and "positions" not in out.split(";", 1)[-1]
    # every joint of the file, joint_Root too (the reader leaves the helper root out unasked)
    whole = [read_bvh(bandai_file)[0].meta["dropped_root"], *read_bvh(bandai_file)[0].skeleton.joint_names]
    inp = read_bvh(bandai_file, keep_joints=whole)[0]
    # the input's unit and up axis: guessing them from an untrained model's poses could go either way
    res = read_bvh(target, unit=inp.meta["unit"], up_axis=inp.meta["up_axis"], keep_joints=whole)[0]
    # the input's hierarchy, text for text: joints (joint_Root too), offsets, channels, End Sites
    assert target.read_text().split("MOTION")[0] == bandai_file.read_text().split("MOTION")[0]
    assert (res.skeleton.joint_names, res.skeleton.parents) == (inp.skeleton.joint_names, inp.skeleton.parents)
    assert res.num_frames == inp.num_frames and res.fps == pytest.approx(inp.fps)
    assert np.isfinite(res.positions).all() and not np.allclose(res.positions, inp.positions, atol=1e-3)
    np.testing.assert_allclose(res.positions[:, 0], inp.positions[:, 0], atol=1e-5)  # joint_Root stays put
    # what is written is a pose: bone lengths are the input's in every frame
    bone = lambda p: np.linalg.norm(p[:, 2:] - p[:, np.array(inp.skeleton.parents[2:])], axis=-1)  # noqa: E731
    np.testing.assert_allclose(bone(res.positions), bone(inp.positions), atol=1e-4)
    # re-read as the model reads it: rotations, and their FK is the file's positions
    again = read_bvh(target, drop_joints=["joint_Root"])[0]
    assert again.has_rotations

    # positions instead, on request: the input's body joints (the helper joint_Root is left out)
    rc, out, err = fix([bandai_file, "--ckpt", rotations_ckpt, "--mode", "both", "-o", tmp_path / "w.npz"], capsys)
    assert rc == 0, err
    assert "positions .npz/.csv: a .bvh output (the default for a BVH input) keeps rotations" in out
    back = read_motion(tmp_path / "w.npz")[0]
    assert back.skeleton.joint_names == inp.skeleton.joint_names[1:] and np.isfinite(back.positions).all()
    np.testing.assert_allclose(back.positions, res.positions[:, 1:], atol=1e-4)  # the same motion as the BVH
    # infill: rotation data has no missing token; the output is the input's motion
    rc, out, err = fix([bandai_file, "--ckpt", rotations_ckpt, "-o", tmp_path / "same.bvh"], capsys)
    assert rc == 0, err
    assert "nothing to fill" in out
    np.testing.assert_allclose(
        read_bvh(tmp_path / "same.bvh", keep_joints=whole)[0].positions, inp.positions, atol=1e-4
    )


def test_wrong_inputs_for_a_dvae_are_one_line_errors(tmp_path, bandai_file, positions_ckpt, rotations_ckpt, capsys):
    pos = generate_clips(1, 2.0, fps=30, seed=1)[0].positions
    write_positions(tmp_path / "smpl.npz", pos, 30, SMPL)
    # a checkpoint of another skeleton: SMPL without its collars has nothing to play Bandai
    # Namco's Shoulder_L/R (the rest maps by body part), and a rotations model needs every joint
    no_collars = [j for j in range(22) if "collar" not in SMPL.joint_names[j]]
    write_positions(tmp_path / "smpl20.npz", pos[:, no_collars], 30, SMPL.subset(no_collars))
    rc, out, err = fix([tmp_path / "smpl20.npz", "--ckpt", rotations_ckpt, "--mode", "denoise"], capsys)
    assert rc == 1 and out == "" and err.count("\n") == 1 and "skeleton does not match the model's" in err, err
    # a positions model estimates the joints a recording lacks (Bandai has two spine joints for
    # SMPL's three: spine3 is left) and does not write them
    rc, out, err = fix(
        [bandai_file, "--ckpt", positions_ckpt, "--mode", "denoise", "--out-dir", tmp_path / "o"], capsys
    )
    assert rc == 0 and "model joints not in the recording: spine3" in out, err
    # a rotations-state model on a positions file of its joints: it needs rotations
    c = read_bvh(bandai_file, drop_joints=["joint_Root"])[0]
    write_positions(tmp_path / "bandai_pos.npz", c.positions, 30, c.skeleton)
    rc, out, err = fix(
        [tmp_path / "bandai_pos.npz", "--ckpt", rotations_ckpt, "--mode", "denoise", "--out-dir", tmp_path / "o"],
        capsys,
    )
    assert rc == 1 and err.count("\n") == 1 and "needs joint rotations; this input has none" in err, err
    # a BVH output for a positions model stays refused
    rc, out, err = fix([tmp_path / "smpl.npz", "--ckpt", positions_ckpt, "-o", tmp_path / "x.bvh"], capsys)
    assert rc == 1 and "cannot write x.bvh" in err


def test_python_m_mocapfix_fix_with_a_dvae_checkpoint(tmp_path, bandai_file, rotations_ckpt):
    env = {**os.environ, "PYTHONPATH": str(REPO), "OMP_NUM_THREADS": "1"}
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "mocapfix",
            "fix",
            str(bandai_file),
            "--ckpt",
            str(rotations_ckpt),
            "--mode",
            "denoise",
            "--out-dir",
            str(tmp_path),
            "--json",
        ],
        capture_output=True,
        text=True,
        cwd=REPO,
        timeout=300,
        env=env,
    )
    assert proc.returncode == 0, proc.stderr
    rec = json.loads(proc.stdout)
    assert rec["model"] == "motion-dvae" and rec["output"].endswith(".bvh") and rec["replaced"] > 0
    assert read_bvh(rec["output"])[0].skeleton.joint_names == read_bvh(bandai_file)[0].skeleton.joint_names


def test_bf16_is_refused_for_a_dvae_checkpoint(positions_ckpt, capsys):

    capsys.readouterr()
    assert main(["fix", str(positions_ckpt), "--ckpt", str(positions_ckpt), "--precision", "bf16"]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "bf16" in err
