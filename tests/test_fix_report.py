"""What `fix` tells about a file is about that file (issue 46): on a rig without some of the
model's joints (a DAZ/Poser figure has no toes; body21 has) the report counts the tokens of the
file's own joints that were written, measures the limbs between two joints the file has (before
and after on the same limbs), and names no fill of a joint the file lacks; a model that cannot
take a rig says which shipped model can."""

from __future__ import annotations

import re

import numpy as np
import pytest
import torch
from test_rig_exports import daz_poser, export

from mocapfix.apps.main import main
from mocapfix.core.clip import Clip
from mocapfix.evaluation.metrics import LimbSigma
from mocapfix.fix import fix_file, load_fixer
from mocapfix.io import read_motion
from mocapfix.io.bvh import read_bvh
from mocapfix.io.positions import write_positions
from mocapfix.pretrained import MODELS, pretrained_path
from mocapfix.rig.mapping import match_joints


@pytest.fixture(scope="module")
def take(bandai_files) -> Clip:
    """A Bandai take, 4 s, on its 21 joints (joint_Root left out: Hips carries the motion)."""
    clip = read_bvh({f.name: f for f in bandai_files}["dataset-1_walk_active_001.bvh"], drop_joints=["joint_Root"])[0]
    return clip.replace(
        positions=clip.positions[:120], rotations=clip.rotations[:120], root_translation=clip.root_translation[:120]
    )


@pytest.fixture(scope="module")
def xmae():
    return load_fixer(pretrained_path("xmae-cpu-bandai"))


def own_limb_sigma(clip: Clip, positions: np.ndarray, model) -> float:
    """Limb sigma (mm) over the model's limbs between two joints the clip's rig has."""
    found = match_joints(clip.skeleton, model)
    limbs = [(found.get(model.joint_names[a]), found.get(model.joint_names[b])) for a, b in model.limbs]
    limbs = [(a, b) for a, b in limbs if a is not None and b is not None]
    metric = LimbSigma(limbs)
    metric.update(torch.from_numpy(positions)[None])
    return float(metric.compute())


@pytest.mark.parametrize("mode", ["infill", "both"])
def test_a_clean_take_on_a_rig_without_toes_is_reported_unchanged(tmp_path, take, xmae, mode):
    """A clean DAZ take fix leaves as it was: nothing filled, replaced or measured of the toes the
    model estimates for it (before: "limb sigma 0.00 -> 5.03 mm", "filled by lerp+limb 240")."""
    path = export(take, daz_poser(toes=False), tmp_path / "daz.bvh")
    fixed = fix_file(path, xmae, mode)
    report = fixed.report
    assert "Toes_L" in xmae.skeleton.joint_names and "lToe" not in read_motion(path)[0].skeleton.joint_names
    assert (report.filled, report.replaced, report.filled_by) == (0, 0, {}), report
    assert report.limb_sigma_after_mm == pytest.approx(report.limb_sigma_before_mm, abs=1e-6)
    assert not any(n.startswith(("filled by", "fill policy measured")) for n in report.notes), report.notes


@pytest.mark.parametrize("ext", [".npz", ".csv"])
def test_positions_with_fewer_joints_than_the_model_count_what_was_written(tmp_path, take, xmae, ext):
    """A positions file of the rig without toes, with a hole in the left hand: the report's
    filled is the hole (each of its tokens by the method named in filled_by), and its limb sigma
    is over the file's own limbs, before and after."""
    [rig] = read_motion(export(take, daz_poser(toes=False), tmp_path / "daz.bvh"))
    positions = rig.positions.copy()
    hand = rig.skeleton.joint_names.index("lHand")
    positions[40:56, hand] = np.nan  # 16 tokens
    path = write_positions(tmp_path / f"daz{ext}", positions, rig.fps, rig.skeleton)
    [clip] = read_motion(path)
    fixed = fix_file(path, xmae, "infill")
    report, out = fixed.report, fixed.clips[0].positions
    written = int((np.isnan(clip.positions).any(-1) & np.isfinite(out).all(-1)).sum())
    assert report.filled == written == 16, report
    assert sum(report.filled_by.values()) == 16, report.filled_by
    assert report.replaced == 0
    assert report.limb_sigma_before_mm == pytest.approx(own_limb_sigma(clip, clip.positions, xmae.skeleton), rel=1e-5)
    assert report.limb_sigma_after_mm == pytest.approx(own_limb_sigma(clip, out, xmae.skeleton), rel=1e-5)


def split_rig() -> list:
    """A DAZ figure (toes too) whose legs hang from a joint above the hips ("Root"), as some
    exports hang them from a world or pelvis bone beside the spine."""
    rows = [("Root", None, "Hips"), ("hip", "Root", (0, 0, 0))]
    for name, parent, plays in daz_poser(toes=True)[1:]:
        rows.append((name, "Root" if name.endswith("Thigh") else parent, plays))
    return rows


def named_models(message: str) -> list[str]:
    return re.findall(r"--model ([\w-]+)", message)


def test_a_rotation_model_that_cannot_take_a_rig_names_the_shipped_models_that_can(tmp_path, take, capsys):
    """motion-dvae-bandai fixes the rotations of its joints as one tree; with the hips mapped to
    the rig's `hip` (--joint-map) the legs hang from the rig's Root beside it: one line naming
    the file and the shipped models that take the rig (each of which then does), not "keeping
    these joints leaves 3 roots"."""
    path = export(take, split_rig(), tmp_path / "split.bvh")
    joint_map = tmp_path / "map.yaml"
    joint_map.write_text("hip: Hips\n")
    args = [str(path), "--joint-map", str(joint_map), "--out-dir", str(tmp_path / "out"), "--force"]
    capsys.readouterr()
    assert main(["fix", *args, "--model", "motion-dvae-bandai", "--mode", "denoise"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"error: {path}: ") and "roots" not in err, err
    assert named_models(err) == ["jitter-many", "xmae-cpu-bandai"], err
    for model in named_models(err):
        assert main(["fix", *args, "--model", model]) == 0, capsys.readouterr().err


def test_a_model_that_needs_joints_a_rig_lacks_names_the_one_that_estimates_them(tmp_path, take, capsys):
    path = export(take, daz_poser(toes=False), tmp_path / "daz.bvh")
    capsys.readouterr()
    args = ["fix", str(path), "--mode", "denoise", "--out-dir", str(tmp_path / "out")]
    assert main([*args, "--model", "motion-dvae-bandai"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "missing Toes_L, Toes_R" in err, err
    assert named_models(err) == ["xmae-cpu-bandai"] and set(named_models(err)) <= set(MODELS), err
    # the jitter remover places the joints a rig lacks from the rest (rig/stand_ins.py), writes none
    assert main([*args, "--model", "jitter-many"]) == 0, capsys.readouterr().err
    out = capsys.readouterr().out
    assert "model joints not in the recording: Toes_L, Toes_R (placed from the rest, not written)" in out
