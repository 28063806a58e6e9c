"""Real recordings read at their true size and orientation (issue 17): units from the body,
robust up axis, absurd values as missing data, helper roots found from the data, and files that
contribute nothing named."""

from __future__ import annotations

import json
import logging

import numpy as np
import pytest
import torch
from cli_utils import CONFIGS, QUIET, TINY, run_cli

from mocapfix.apps.inspect import inspect_files
from mocapfix.core.clip import MotionFileError
from mocapfix.core.skeleton import PRESETS
from mocapfix.fix.output import write_output
from mocapfix.io import list_motion_files, read_motion
from mocapfix.io.bvh import read_bvh, write_bvh
from mocapfix.io.conventions import parse_unit, resolve_unit
from mocapfix.io.positions import read_positions


def _bandai(bandai_files, i=3, frames=None):
    clip = read_bvh(bandai_files[i])[0]
    return (
        clip
        if frames is None
        else clip.replace(
            positions=clip.positions[:frames],
            rotations=clip.rotations[:frames],
            root_translation=clip.root_translation[:frames],
        )
    )


def _hip_height(clip) -> float:
    return float(np.nanmean(clip.positions[:, clip.skeleton.index("Hips"), 2]))


@pytest.mark.parametrize("unit", ["0.0564", "0.037", "mm", "inch"])
@pytest.mark.parametrize("up", ["y", "z"])
def test_bandai_in_other_units_and_axes_reads_at_its_size(bandai_files, tmp_path, unit, up):
    clip = _bandai(bandai_files)
    f = tmp_path / "converted.bvh"
    write_bvh(f, clip.replace(meta={**clip.meta, "unit": unit, "up_axis": up}))
    back = read_bvh(f)[0]
    assert back.meta["up_axis"] == up
    assert back.meta["unit_source"].startswith("auto")
    assert _hip_height(back) == pytest.approx(_hip_height(clip), rel=0.05)
    if unit in ("mm", "inch"):  # named units are found exactly
        assert back.meta["unit"] == unit
        np.testing.assert_allclose(back.positions, clip.positions, atol=1e-4)
    # fix writes back in the input's own unit: the numbers of the file, not metres
    out = tmp_path / "fixed.npz"
    write_output(out, [back], [back])
    [again] = read_positions(out)
    assert again.meta["unit"] == back.meta["unit"] and again.meta["unit_source"] == "file"
    np.testing.assert_allclose(again.positions, back.positions, atol=1e-5)
    with np.load(out) as data:
        raw = data["positions"]
    assert np.nanmax(np.abs(raw)) == pytest.approx(
        np.nanmax(np.abs(back.positions)) / parse_unit(back.meta["unit"]).metres, rel=1e-4
    )


def test_any_number_of_metres_is_a_unit(bandai_files, tmp_path, capsys):
    clip = _bandai(bandai_files)
    f = tmp_path / "odd.bvh"
    write_bvh(f, clip.replace(meta={**clip.meta, "unit": "0.0564"}))
    back = read_motion(f, unit="0.0564")[0]
    assert back.meta["unit"] == "0.0564" and back.meta["unit_source"] == "option"
    np.testing.assert_allclose(back.positions, clip.positions, atol=1e-4)
    assert parse_unit(0.0564).metres == 0.0564 and parse_unit("Inches").name == "inch"
    with pytest.raises(MotionFileError, match="unknown unit 'furlong'"):
        parse_unit("furlong", "x.bvh")
    with pytest.raises(MotionFileError, match="positive number"):
        parse_unit("-2", "x.bvh")


def test_a_wrong_explicit_unit_is_a_warning_naming_the_file_and_the_setting(bandai_files, caplog):
    with caplog.at_level(logging.WARNING, logger="mocapfix"):
        clip = read_motion(bandai_files[3], unit="inch")[0]  # the file is in cm: a 4.2 m giant
    assert clip.meta["stature_m"] > 2.2
    assert str(bandai_files[3]) in clip.meta["warning"] and "--unit" in clip.meta["warning"]
    assert any("tall" in r.getMessage() for r in caplog.records)
    assert "warning" not in read_motion(bandai_files[3])[0].meta


def test_named_units_win_within_a_quarter_of_the_estimate():
    # a 1.5 m person in cm stays in cm (not scaled to the standard adult); the leg is 0.72 m
    names, parents = ["Hips", "LeftUpLeg", "LeftLeg", "LeftFoot"], [-1, 0, 1, 2]
    pos = np.array([[[0, 0, 80], [10, 0, 78], [10, 0, 42], [10, 0, 6]]], dtype=np.float64)
    assert resolve_unit("x", "auto", None, pos, names, parents).name == "cm"
    odd = resolve_unit("x", "auto", None, pos * 0.01 / 0.1, names, parents)  # decimetres: no named unit near
    assert odd.name not in ("cm", "inch", "m", "mm", "asf") and odd.metres == pytest.approx(0.1 * 0.82 / 0.72, rel=1e-3)
    # the CMU database's ASF unit (1/0.45 inch) is a named one: a CMU subject reads at it exactly
    assert resolve_unit("x", "auto", None, pos * 0.01 / 0.0564, names, parents).name == "asf"


def _with_absurd_values(clip, path, up):
    """Write the clip as BVH (z up) and put 1e30 into frame 5 and inf into frame 9 of the root's
    vertical channel, the way a broken export does."""
    write_bvh(path, clip.replace(meta={**clip.meta, "up_axis": up}))
    lines = path.read_text().splitlines()
    first = lines.index(next(ln for ln in lines if ln.startswith("Frame Time"))) + 1
    vertical = "xyz".index(up)
    for frame, value in ((5, "1e30"), (9, "inf")):
        row = lines[first + frame].split()
        row[vertical] = value
        lines[first + frame] = " ".join(row)
    path.write_text("\n".join(lines) + "\n")


def test_absurd_values_are_missing_and_cannot_turn_the_body_over(bandai_files, tmp_path):
    clip = _bandai(bandai_files, frames=60)
    f = tmp_path / "glitch.bvh"
    _with_absurd_values(clip, f, "z")
    back = read_motion(f)[0]
    assert back.meta["up_axis"] == "z" and back.meta["unit"] == "cm"
    J = back.skeleton.num_joints
    assert back.meta["absurd_tokens"] == 2 * J  # both frames, every joint
    assert back.missing_mask()[[5, 9]].all() and back.missing_mask().sum() == 2 * J
    seen = np.delete(np.arange(60), [5, 9])
    np.testing.assert_allclose(back.positions[seen], clip.positions[seen], atol=1e-4)
    assert _hip_height(back) == pytest.approx(_hip_height(clip), rel=0.01)


def test_one_absurd_joint_in_a_positions_file(tmp_path):
    from test_positions import _motion

    pos = np.repeat(_motion(P=1)[0], 10, axis=0)  # (60, 17, 3) m
    pos[7, 13] = 1e30
    pos[20, 3, 2] = 40.0  # a foot 40 m up: no body does that
    f = tmp_path / "x.npz"
    np.savez(f, positions=pos, fps=30, joint_names=np.array(PRESETS["h36m17"].joint_names))
    [clip] = read_motion(f)
    assert clip.meta["absurd_tokens"] == 2 and clip.missing_mask().sum() == 2
    assert clip.missing_mask()[7, 13] and clip.missing_mask()[20, 3]


def test_inspect_counts_absurd_values_and_shows_how_the_unit_was_found(bandai_files, tmp_path, capsys):
    _with_absurd_values(_bandai(bandai_files, frames=60), tmp_path / "glitch.bvh", "y")
    clip = _bandai(bandai_files, frames=60)
    write_bvh(tmp_path / "odd.bvh", clip.replace(meta={**clip.meta, "unit": "0.1"}))
    assert inspect_files([str(tmp_path)], as_json=True) == 0
    rows = {r["file"].rsplit("/", 1)[-1]: r for r in map(json.loads, capsys.readouterr().out.splitlines())}
    assert rows["glitch.bvh"]["absurd_tokens"] == 2 * 21 and rows["glitch.bvh"]["up_axis"] == "y"
    assert rows["odd.bvh"]["unit_source"].startswith("auto: from the body")
    assert 1.5 < rows["odd.bvh"]["stature_m"] < 1.9 and rows["odd.bvh"]["absurd_tokens"] == 0
    assert inspect_files([str(tmp_path)]) == 0
    table = capsys.readouterr().out
    assert "stature m" in table and "absurd" in table and "2 files" not in table.split("unit ")[0]
    assert "glitch.bvh: 42 absurd joint positions" in table
    assert inspect_files([str(bandai_files[3])]) == 0
    assert "'joint_Root' left out (a helper joint" in capsys.readouterr().out


def test_fit_on_a_folder_with_absurd_values_stays_finite_and_fix_fills_them(bandai_files, tmp_path):
    data = tmp_path / "takes"
    data.mkdir()
    for i, name in enumerate(["a", "b", "c"]):
        _with_absurd_values(_bandai(bandai_files, i=3 + 40 * i, frames=90), data / f"{name}.bvh", "y")
    assert (
        run_cli(
            [
                "fit",
                "--config",
                CONFIGS / "xmae_bvh.yaml",
                *TINY,
                *QUIET,
                "--data.path",
                data,
                "--data.cache_dir",
                "null",
                "--data.batches_on_device",
                "false",
                "--data.batch_size",
                "8",
                "--data.eval_batch_size",
                "8",
                "--data.val_fraction",
                "0",
                "--data.test_fraction",
                "0",
                "--data.val_patterns",
                '["b.bvh"]',
                "--data.test_patterns",
                '["c.bvh"]',
                "--trainer.precision",
                "32",
                "--trainer.max_steps",
                "4",
                "--trainer.val_check_interval",
                "2",
                "--experiment",
                "glitch",
            ],
            tmp_path,
        )
        == 0
    )
    ckpt = tmp_path / "checkpoints" / "glitch" / "last.ckpt"
    state = torch.load(ckpt, map_location="cpu", weights_only=True)["state_dict"]
    assert all(torch.isfinite(v).all() for v in state.values() if v.is_floating_point())

    from mocapfix.apps.fix_cli import main as fix_main

    assert (
        fix_main([str(data / "a.bvh"), "--ckpt", str(ckpt), "--out-dir", str(tmp_path / "out"), "--progress", "never"])
        == 0
    )
    # absurd root channels leave the file without exact rotations, yet a BVH comes back (inverse
    # kinematics from the file's own pose)
    [fixed] = read_motion(tmp_path / "out" / "a.bvh")
    assert not fixed.missing_mask().any()  # the absurd frames were filled
    pos = fixed.positions
    centre = np.median(pos.reshape(-1, 3), axis=0)
    assert np.abs(pos - centre).max() < 5.0  # metres: nothing beyond the body's range


def test_helper_root_found_from_the_data_not_by_name(bandai_files, tmp_path):
    # the README's BVH command on a folder whose root helper has another name, and one without it
    clip = _bandai(bandai_files, frames=40)
    f = tmp_path / "other.bvh"
    write_bvh(f, clip)  # Hips is the root here: nothing to drop
    back = read_bvh(f)[0]
    assert "dropped_root" not in back.meta and back.skeleton.joint_names[0] == "Hips"
    text = bandai_files[3].read_text().replace("joint_Root", "Reference")
    g = tmp_path / "renamed.bvh"
    g.write_text(text)
    renamed = read_bvh(g)[0]
    assert renamed.meta["dropped_root"] == "Reference" and renamed.has_rotations
    kept = read_bvh(g, keep_joints=[n for n in ["Reference", *clip.skeleton.joint_names]])[0]
    assert kept.skeleton.joint_names[0] == "Reference"


def test_files_that_contribute_nothing_are_named(bandai_files, tmp_path, caplog):
    from mocapfix.data.datamodule import MotionDataModule

    data = tmp_path / "takes"
    data.mkdir()
    for i, frames in enumerate([90, 90, 20]):
        clip = _bandai(bandai_files, i=3 + i, frames=frames)
        write_bvh(data / f"t{i}.bvh", clip)
    dm = MotionDataModule(source="bvh", path=str(data), cache_dir=None, val_fraction=0, test_fraction=0)
    with caplog.at_level(logging.WARNING, logger="mocapfix"):
        dm.setup("fit")
    lines = [r.getMessage() for r in caplog.records if "contributes nothing" in r.getMessage()]
    assert len(lines) == 1 and "t2.bvh" in lines[0] and "shorter than one window (20 frames" in lines[0]


def test_unreadable_folder_says_so(tmp_path, monkeypatch):
    import os

    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "x.bvh").write_text("HIERARCHY\n")
    real = os.scandir

    def scandir(path="."):
        if str(path).endswith("sub"):
            raise PermissionError(13, "Permission denied", str(path))
        return real(path)

    monkeypatch.setattr(os, "scandir", scandir)
    with pytest.raises(MotionFileError, match=r"sub: cannot read this folder \(Permission denied\)"):
        list_motion_files(tmp_path)


def test_ckpt_path_last_without_a_last_ckpt_is_one_line(tmp_path, capsys):
    rc = run_cli(
        ["test", "--config", CONFIGS / "xmae.yaml", *QUIET, "--experiment", "typo", "--ckpt_path", "last"], tmp_path
    )
    err = capsys.readouterr().err
    assert rc == 2 and "checkpoints/typo/last.ckpt: no such checkpoint" in err and "Traceback" not in err
