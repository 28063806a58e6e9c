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
