"""Starting from a trained model: `fit --model.init_args.init_weights` and `mocapfix adapt`."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from mocapfix.apps.main import main
from mocapfix.core.skeleton import preset
from mocapfix.fix.fixers import load_fixer
from mocapfix.io.positions import write_positions
from mocapfix.io.synthetic import generate_clips
from mocapfix.pretrained import pretrained_path
from mocapfix.rig.mapping import onto_skeleton
from mocapfix.training.xmae_module import XMAEModule


@pytest.fixture(autouse=True)
def _run_in_tmp_path(tmp_path, monkeypatch):
    """adapt writes its logs (logs/adapt/) and data cache (.cache/mocapfix/) in the folder it runs in."""
    monkeypatch.chdir(tmp_path)


def _body21_takes(folder, n=6, seconds=4.0):
    """Synthetic takes on the shipped model's 21 joints, as positions files (another body than
    Bandai's actors: the synthetic generator's proportions)."""
    body = preset("body21")
    folder.mkdir(exist_ok=True)
    for i, clip in enumerate(generate_clips(n, seconds, 30.0, seed=11)):
        write_positions(folder / f"take{i}.npz", onto_skeleton(clip, body).positions, 30.0, body)
    return folder


def test_init_weights_starts_from_the_checkpoint_network():
    module = XMAEModule(init_weights="xmae-cpu-bandai", preset="paper")  # the checkpoint's sizes win
    shipped = torch.load(pretrained_path("xmae-cpu-bandai"), weights_only=True)
    assert module.sizes["enc_dim"] == shipped["model"]["config"]["enc_dim"] == 64
    assert module.fill_policy is not None  # the checkpoint's, until a validation measures one
    with pytest.raises(ValueError, match="not an XMAE"):
        XMAEModule(init_weights=str(pretrained_path("motion-dvae-bandai")))


def test_adapt_fine_tunes_and_fix_reads_the_result(tmp_path, capsys):
    folder = _body21_takes(tmp_path / "takes")
    out = tmp_path / "mine.ckpt"
    rc = main(["adapt", str(folder), "--model", "xmae-cpu-bandai", "--minutes", "0.15", "-o", str(out)])
    assert rc == 0, capsys.readouterr().err
    assert "adapted model" in capsys.readouterr().out
    adapted = torch.load(out, weights_only=True)
    shipped = torch.load(pretrained_path("xmae-cpu-bandai"), weights_only=True)
    assert adapted["global_step"] > 0
    moved = [
        (adapted["state_dict"][k].float() - v.float()).abs().max().item()
        for k, v in shipped["state_dict"].items()
        if k.startswith("net.")
    ]
    assert max(moved) > 0  # it trained
    # the adapted model fixes a take with a hole, and keeps every observed token
    take = np.load(folder / "take0.npz")["positions"].copy()
    take[40:55, 8] = np.nan
    write_positions(tmp_path / "holed.npz", take, 30.0, preset("body21"))
    assert main(["fix", str(tmp_path / "holed.npz"), "--ckpt", str(out)]) == 0
    fixed = np.load(tmp_path / "holed.fixed.npz")["positions"]
    assert np.isfinite(fixed).all() and np.array_equal(fixed[np.isfinite(take)], take[np.isfinite(take)])
    assert load_fixer(out).kind == "xmae"


def test_adapt_refuses_what_it_cannot_use(tmp_path, capsys):
    folder = _body21_takes(tmp_path / "takes", n=2)
    assert main(["adapt", str(folder), "--model", "motion-dvae-bandai", "--minutes", "0.1"]) == 1
    assert "XMAE" in capsys.readouterr().err
    assert main(["adapt", str(folder), "--model", "xmae-cpu-bandai", "--minutes", "-1"]) == 2
    assert main(["adapt", str(tmp_path / "nothing"), "--model", "xmae-cpu-bandai", "--minutes", "0.1"]) == 1
    err = capsys.readouterr().err
    assert "nothing" in err and "Traceback" not in err


def test_adapt_goes_on_with_the_checkpoint_objective(tmp_path, capsys):
    """A model trained on the holes fix meets (hole_ratio) adapts on holes, not on the paper's masking."""
    start = torch.load(pretrained_path("xmae-cpu-bandai"), weights_only=True)
    start["hyper_parameters"].update(hole_ratio=1.0, max_hole_s=0.5, mask_ratio=0.8)
    torch.save(start, tmp_path / "holes.ckpt")
    folder = _body21_takes(tmp_path / "takes", n=3)
    out = tmp_path / "mine.ckpt"
    rc = main(["adapt", str(folder), "--ckpt", str(tmp_path / "holes.ckpt"), "--minutes", "0.1", "-o", str(out)])
    assert rc == 0, capsys.readouterr().err
    hp = torch.load(out, weights_only=True)["hyper_parameters"]
    assert (hp["hole_ratio"], hp["max_hole_s"], hp["mask_ratio"]) == (1.0, 0.5, 0.8)
