"""models/checkpoint.py: the one owner of what a checkpoint holds (read, write, shrink)."""

from __future__ import annotations

import ast
import sys
from pathlib import Path

import pytest
import torch

from mocapfix.core.clip import MotionFileError
from mocapfix.core.skeleton import preset
from mocapfix.models.build import build_model
from mocapfix.models.checkpoint import (
    load_checkpoint,
    model_kind,
    network_weights,
    read_checkpoint,
    save_checkpoint,
    set_fill_policy,
    weights_checkpoint,
    window_settings,
    xmae_checkpoint,
    xmae_config,
)
from mocapfix.models.xmae import XMAE

REPO = Path(__file__).resolve().parents[1]
OLD = REPO / "tests" / "data" / "old_checkpoints"
SIZES = dict(enc_dim=16, enc_depth=1, enc_mlp_dim=32, dec_dim=16, dec_depth=1, dec_mlp_dim=32, head_dim=8)


def test_a_written_checkpoint_reads_back_into_the_same_network(tmp_path):
    skeleton = preset("smpl22")
    net = XMAE(skeleton.num_joints, 12, **SIZES)
    ckpt = xmae_checkpoint(net, skeleton, 30.0)
    set_fill_policy(ckpt, {"gaps_s": [0.5]})
    save_checkpoint(tmp_path / "m.ckpt", ckpt)
    back = read_checkpoint(tmp_path / "m.ckpt")
    assert model_kind(back) == "xmae" and back["fill_policy"] == {"gaps_s": [0.5]}
    skel, fps, frames = window_settings(tmp_path / "m.ckpt", back["hyper_parameters"])
    assert skel.joint_names == skeleton.joint_names and (fps, frames) == (30.0, 12)
    again = build_model("xmae", xmae_config(tmp_path / "m.ckpt", back))
    again.load_state_dict(network_weights(back, "net"))
    for (k, a), b in zip(net.state_dict().items(), again.state_dict().values()):
        assert torch.equal(a, b), k


def test_extra_keys_and_hyperparameters_of_a_weights_only_checkpoint():
    net = XMAE(22, 12, **SIZES)
    ckpt = weights_checkpoint("xmae", net, {"lr": 1e-4}, global_step=3, adapted_from="x.ckpt")
    assert list(ckpt) == ["hyper_parameters", "model", "state_dict", "global_step", "adapted_from"]
    assert ckpt["model"]["config"]["enc_dim"] == 16 and all(k.startswith("net.") for k in ckpt["state_dict"])


def test_files_that_are_not_checkpoints_are_one_line_naming_the_file(tmp_path):
    (tmp_path / "text.ckpt").write_text("not a checkpoint")
    torch.save({"weights": torch.zeros(2)}, tmp_path / "bare.ckpt")
    for name, problem in (
        ("missing.ckpt", "no such checkpoint file"),
        ("text.ckpt", "not a mocapfix checkpoint"),
        ("bare.ckpt", "no hyper_parameters and state_dict"),
    ):
        with pytest.raises(MotionFileError, match=problem) as e:
            read_checkpoint(tmp_path / name)
        assert str(e.value).startswith(str(tmp_path / name)) and "\n" not in str(e.value)
    assert load_checkpoint(tmp_path / "bare.ckpt").keys() == {"weights"}  # plain values, unvalidated


def test_old_checkpoints_are_told_by_their_weights_and_their_xmae_rebuilt():
    """Checkpoints from before they named their model (commit 4ceef7a)."""
    xmae = read_checkpoint(OLD / "xmae-4ceef7a.ckpt")
    assert "model" not in xmae and model_kind(xmae) == "xmae"
    net = build_model("xmae", xmae_config(OLD / "xmae-4ceef7a.ckpt", xmae))
    net.load_state_dict(network_weights(xmae, "net"))
    assert model_kind(read_checkpoint(OLD / "motion_dvae_denoise-4ceef7a.ckpt")) == "motion-dvae"


def test_shrink_checkpoint_keeps_weights_and_hparams(tmp_path):
    sys.path.insert(0, str(REPO / "scripts"))
    try:
        from shrink_checkpoint import main
    finally:
        sys.path.remove(str(REPO / "scripts"))
    full = {
        "hyper_parameters": {"lr": 1e-4},
        "global_step": 7,
        "optimizer_states": [{"state": {}}],
        "state_dict": {"w": torch.randn(3, 3), "n": torch.tensor(5)},
    }
    torch.save(full, tmp_path / "full.ckpt")
    for flag, dtype in (([], torch.bfloat16), (["--fp32"], torch.float32)):
        assert main([*flag, str(tmp_path / "full.ckpt"), str(tmp_path / "small.ckpt")]) == 0
        small = torch.load(tmp_path / "small.ckpt", weights_only=True)
        assert "optimizer_states" not in small and small["hyper_parameters"] == {"lr": 1e-4}
        assert small["state_dict"]["w"].dtype == dtype and small["state_dict"]["n"].dtype == torch.int64
        torch.testing.assert_close(small["state_dict"]["w"].float(), full["state_dict"]["w"], atol=1e-2, rtol=1e-2)
    # an XMAE checkpoint from before checkpoints named their model: the entry added, the policy kept
    assert main(["--fp32", str(OLD / "xmae-4ceef7a.ckpt"), str(tmp_path / "x.ckpt")]) == 0
    small = torch.load(tmp_path / "x.ckpt", weights_only=True)
    assert small["model"]["kind"] == "xmae" and small["model"]["config"]["enc_dim"] == 32
    assert "fill_policy" in small and "optimizer_states" not in small
    build_model("xmae", small["model"]["config"]).load_state_dict(network_weights(small, "net"))


def test_only_the_checkpoint_module_loads_and_saves_checkpoints():
    """torch.load / torch.save appear in mocapfix/, bench/ and scripts/ only in models/checkpoint.py:
    the layout of the file has one owner."""
    owner = REPO / "mocapfix" / "models" / "checkpoint.py"
    found = []
    for folder in ("mocapfix", "bench", "scripts"):
        for path in sorted((REPO / folder).rglob("*.py")):
            if path == owner:
                continue
            for node in ast.walk(ast.parse(path.read_text(), str(path))):
                if (
                    isinstance(node, ast.Attribute)
                    and node.attr in ("load", "save")
                    and isinstance(node.value, ast.Name)
                    and node.value.id == "torch"
                ):
                    found.append(f"{path.relative_to(REPO)}:{node.lineno} torch.{node.attr}")
    assert not found, "checkpoints read or written outside models/checkpoint.py: " + ", ".join(found)
