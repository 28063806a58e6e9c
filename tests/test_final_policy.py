"""The fill policy of a fit's final checkpoints, measured when training ends where the validations
did not measure it (XMAEModule's calibrate_every_n_val, training/final_policy.py)."""

from __future__ import annotations

import pytest
import torch
from cli_utils import CONFIGS, QUIET, SMALL_DATA, TINY, run_cli

from mocapfix.training.xmae_module import XMAEModule

FIT = [
    "fit",
    "--config",
    CONFIGS / "xmae.yaml",  # calibrate_every_n_val: 0, the 2-core CPU setting
    *TINY,
    *SMALL_DATA,
    *QUIET,
    "--experiment",
    "f",
    "--model.init_args.calibration_windows",
    "8",
    "--trainer.max_steps",
    "6",
    "--trainer.val_check_interval",
    "3",
]


def _load(path):
    return torch.load(path, map_location="cpu", weights_only=True)


def test_the_final_checkpoints_get_the_policy_a_validation_would_measure(tmp_path, capsys):
    assert run_cli(FIT, tmp_path) == 0
    run = tmp_path / "checkpoints" / "f" / "version_0"
    last = _load(run / "last.ckpt")
    assert last["global_step"] == 6
    for path in run.glob("*.ckpt"):  # best and last: each its own weights' policy
        policy = _load(path)["fill_policy"]
        assert policy["windows"] == 8 and set(policy["error_mm"]) == {"full", "arm", "leg"}
    # the same numbers as `validate` measures for those weights (the calibrate step of docs/fix.md)
    bare = tmp_path / "bare.ckpt"
    torch.save({k: v for k, v in last.items() if k != "fill_policy"}, bare)
    validate = ["validate", *FIT[1:-4], "--ckpt_path", bare]
    assert run_cli(validate, tmp_path) == 0
    measured = _load(bare)["fill_policy"]
    assert measured["windows"] == last["fill_policy"]["windows"]
    assert measured["replace_threshold_m"] == pytest.approx(last["fill_policy"]["replace_threshold_m"], rel=1e-5)
    for part, methods in measured["error_mm"].items():
        for method, errors in methods.items():
            assert errors == pytest.approx(last["fill_policy"]["error_mm"][part][method], rel=1e-5), (part, method)
    capsys.readouterr()


def test_every_validation_measures_it_with_calibrate_every_n_val_1(tmp_path, capsys):
    """The setting's other end (the GPU configs' default): the validation that wrote the checkpoint
    measured its policy, and nothing is measured again when training ends."""
    fit = [*FIT, "--model.init_args.calibrate_every_n_val", "1", "--trainer.max_steps", "3"]
    capsys.readouterr()
    assert run_cli(fit, tmp_path) == 0
    assert "fill policy: measuring" not in capsys.readouterr().err
    assert _load(tmp_path / "checkpoints" / "f" / "last.ckpt")["fill_policy"]["windows"] == 8


def test_calibrate_every_n_val_is_a_count():
    with pytest.raises(ValueError, match="calibrate_every_n_val"):
        XMAEModule(calibrate_every_n_val=-1)
