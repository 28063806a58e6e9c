"""Configs: packaged pieces and experiments, found by name, merged in order."""

from __future__ import annotations

import pytest
import yaml
from cli_utils import CONFIGS, run_cli

from mocapfix.apps.cli import CONFIG_DIR, expand_configs, packaged_configs
from mocapfix.apps.main import main


def print_config(args, tmp_path, capsys) -> dict:
    capsys.readouterr()
    with pytest.raises(SystemExit) as e:
        run_cli(["fit", *args, "--print_config"], tmp_path)
    assert e.value.code in (0, None)
    return yaml.safe_load(capsys.readouterr().out)


def test_the_checkout_configs_are_the_packaged_ones():
    assert CONFIGS.resolve() == CONFIG_DIR
    assert {"xmae", "xmae_cpu", "xmae_bvh", "motion_dvae", "motion_dvae_denoise"} <= set(packaged_configs())


@pytest.mark.parametrize(
    "name",
    [
        "xmae",
        "xmae_cpu",
        "xmae_bvh",
        "xmae_amass",
        "xmae_h36m",
        "correction_h36m",
        "correction_bvh",
        "motion_dvae",
        "motion_dvae_bvh",
        "motion_dvae_denoise_bvh",
    ],
)
def test_every_experiment_names_its_pieces_and_parses(name, tmp_path, capsys):
    text = yaml.safe_load((CONFIG_DIR / f"{name}.yaml").read_text())
    assert set(text["defaults"]) & {"data/synthetic", "data/bvh", "data/amass", "data/h36m"}
    assert "class_path" not in text.get("model", {})  # the model piece names the class
    cfg = print_config(["--config", name, "--data.path", "/nowhere"], tmp_path, capsys)
    assert cfg["experiment"] == name and cfg["model"]["class_path"].startswith("mocapfix.training.")
    assert cfg["trainer"]["check_val_every_n_epoch"] is None  # from the trainer piece


def test_an_experiment_holds_only_differences_and_they_win(tmp_path, capsys):
    cfg = print_config(["--config", "xmae_cpu", "--data.path", "/nowhere"], tmp_path, capsys)
    init = cfg["model"]["init_args"]
    assert init["preset"] == "cpu" and init["lr"] == 1.0e-3 and init["mask_ratio"] == 0.85  # experiment, piece
    assert cfg["trainer"]["accelerator"] == "cpu" and cfg["trainer"]["max_steps"] == 4500
    assert cfg["data"]["source"] == "bvh" and cfg["data"]["path"] == "/nowhere" and cfg["data"]["batch_size"] == 64
    # by name, by file in the checkout, and a later --config over an earlier one: the same merge
    by_file = print_config(["--config", CONFIGS / "xmae_cpu.yaml", "--data.path", "/nowhere"], tmp_path, capsys)
    assert by_file == cfg
    cpu_trainer = print_config(
        ["--config", "xmae_bvh", "--config", "trainer/cpu", "--data.path", "/x"], tmp_path, capsys
    )
    assert cpu_trainer["trainer"]["accelerator"] == "cpu" and cpu_trainer["trainer"]["precision"] == "32-true"


def test_a_users_own_experiment_builds_on_packaged_and_local_pieces(tmp_path, capsys):
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "fast.yaml").write_text("trainer:\n  max_steps: 7\n")
    (tmp_path / "mine" / "exp.yaml").write_text(
        "defaults: [data/synthetic, model/xmae, trainer/default, fast]\nexperiment: mine\n"
        "model:\n  init_args:\n    preset: cpu\n"
    )
    args = expand_configs(["--config", str(tmp_path / "mine" / "exp.yaml"), "--trainer.max_steps", "9"])
    configs = [args[i + 1] for i, a in enumerate(args) if a == "--config"]
    assert [c.split("/")[-1] for c in configs] == [
        "synthetic.yaml",
        "xmae.yaml",
        "default.yaml",
        "fast.yaml",
        "exp.yaml",
    ]
    assert args[-2:] == ["--trainer.max_steps", "9"]
    cfg = print_config(["--config", tmp_path / "mine" / "exp.yaml"], tmp_path, capsys)
    assert cfg["trainer"]["max_steps"] == 7 and cfg["model"]["init_args"]["preset"] == "cpu"


def test_an_unknown_config_is_one_line_naming_the_packaged_ones(tmp_path, capsys):
    rc = run_cli(["fit", "--config", "xmea"], tmp_path)
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "xmea: no such config file" in err[0] and "xmae_cpu" in err[0]
    (tmp_path / "bad.yaml").write_text("defaults: [no_such_piece]\n")
    assert run_cli(["fit", "--config", tmp_path / "bad.yaml"], tmp_path) == 2
    assert "no_such_piece: no such config file" in capsys.readouterr().err


def test_help_lists_the_packaged_configs(capsys):
    assert main(["--help"]) == 0 and "packaged configs: " in capsys.readouterr().out


def test_a_csv_logger_takes_the_experiment_name_and_no_figures(tmp_path, capsys):
    from cli_utils import QUIET, SMALL_DATA, TINY

    args = [
        "fit",
        "--config",
        "xmae",
        *TINY,
        *SMALL_DATA,
        *QUIET,
        "--experiment",
        "plain",
        "--logger",
        "csv",
        "--trainer.max_steps",
        "2",
        "--trainer.val_check_interval",
        "2",
        "--model.init_args.calibration_windows",
        "4",
    ]
    assert run_cli(args, tmp_path) == 0
    out = capsys.readouterr().out
    run = tmp_path / "logs" / "plain" / "version_0"
    assert "CSVLogger logs: logs/plain/version_0" in out and "TensorBoard" not in out
    assert (run / "metrics.csv").is_file() and "val/mpjpe_mm" in (run / "metrics.csv").read_text()
    assert not list(run.glob("events.out.tfevents*"))
    assert run_cli(["fit", "--config", "xmae", "--logger", "wandb", *QUIET], tmp_path) == 2
    assert "--logger must be one of tensorboard, csv, mlflow" in capsys.readouterr().err
