"""What a person reads on the console: every command's --help ends with an example."""

from __future__ import annotations

import pytest

from mocapfix.apps.main import main

COMMANDS = ["fit", "validate", "test", "predict", "fix", "inspect", "adapt", "render", "demo", "models", "docs"]


@pytest.mark.parametrize("command", COMMANDS)
def test_every_commands_help_names_an_example(command, capsys):
    with pytest.raises(SystemExit) as done:
        main([command, "--help"])
    assert done.value.code in (0, None)
    out = capsys.readouterr().out
    assert f"example: mocapfix {command}" in " ".join(out.split()), out[-400:]


def test_top_level_help_names_an_example(capsys):
    assert main(["--help"]) == 0
    assert "example: mocapfix " in capsys.readouterr().out


# What `fit` printed before apps/console.py, none of which a user can act on
NOISE = (
    "Tip:",  # litlogger / litmodels advertisements
    "litlogger",
    "TPU available",
    "GPU available: False",
    "LeafSpec",  # torch's pytree deprecation, from Lightning's own code
    "smaller than the logging interval",
    "does not have many workers",
)


def test_fit_console_has_no_lightning_noise(tmp_path, capsys, monkeypatch):
    import logging
    import warnings

    import lightning.pytorch.trainer.connectors.data_connector as data_connector
    from cli_utils import CONFIGS, SMALL_DATA, TINY, run_cli

    from mocapfix.apps import console

    # as on a machine with many cores, where Lightning asks for data loader workers
    monkeypatch.setattr(data_connector, "suggested_max_num_workers", lambda *a: 8)
    dropped = []  # what the console's filters left out: the noise was there to leave out
    keep = console._Drop.filter
    monkeypatch.setattr(
        console._Drop, "filter", lambda self, r: keep(self, r) or dropped.append(r.getMessage()) or False
    )
    lines = []

    class Collect(logging.Handler):
        def emit(self, record):
            lines.append(record.getMessage())

    handler = Collect(logging.INFO)
    loggers = [logging.getLogger(n) for n in ("lightning.pytorch", "lightning.fabric")]
    for lg in loggers:
        lg.addHandler(handler)
    args = ["fit", "--config", CONFIGS / "xmae.yaml", *TINY, *SMALL_DATA, "--experiment", "quiet"]
    args += ["--trainer.max_steps", "2", "--trainer.val_check_interval", "2", "--trainer.log_every_n_steps", "50"]
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")  # every warning, however often it was shown before
            assert run_cli(args, tmp_path) == 0
    finally:
        for lg in loggers:
            lg.removeHandler(handler)
    out, err = capsys.readouterr()
    shown = "\n".join([out, err, *lines, *(str(w.message) for w in caught)])
    for noise in NOISE:
        assert noise not in shown, f"{noise!r} on the console:\n{shown[-3000:]}"
    assert any("Tip:" in m for m in dropped) and any("TPU available" in m for m in dropped)
    # what a user needs stays: the seed, the metrics, where logs and checkpoints went
    assert any(m.startswith("Seed set to") for m in lines)
    assert "val/mpjpe_mm" in err + out
    assert "TensorBoard logs: logs/quiet/version_0" in out and "checkpoints: best" in out
