"""Untrusted checkpoints and runs (issue 45): a checkpoint names no code to run, `adapt` never
writes onto its inputs, and two runs of one experiment never share a run folder."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest
import torch
from cli_utils import CONFIGS, QUIET

from mocapfix.apps.main import main
from mocapfix.training.registry import MODULES

EVIL = "import pathlib\npathlib.Path({marker!r}).write_text('ran')\nclass Model:\n    pass\n"


def _checkpoint(path: Path, hyper_parameters) -> Path:
    torch.save({"hyper_parameters": hyper_parameters, "state_dict": {}}, path)
    return path


def _one_error_line(err: str, name) -> None:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and str(name) in lines[0] and "Traceback" not in err, err


@pytest.fixture
def evil_module(tmp_path, monkeypatch) -> Path:
    """evil.py beside the checkpoint, in the working folder and importable (as `python -m
    mocapfix` run there would find it); importing it writes the returned marker file."""
    marker = tmp_path / "marker"
    (tmp_path / "evil.py").write_text(EVIL.format(marker=str(marker)))
    monkeypatch.chdir(tmp_path)
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.delitem(sys.modules, "evil", raising=False)
    monkeypatch.delitem(sys.modules, "this", raising=False)  # `this` prints the Zen on import
    return marker


@pytest.mark.parametrize(
    "hyper_parameters",
    [
        {"_class_path": "evil.Model", "lr": 1.0},
        {"class_path": "evil.Model", "init_args": {}},  # jsonargparse's own key, without LightningCLI's
        {"_class_path": "this.Zen"},
        {"_class_path": "subprocess.Popen", "args": "true"},  # a real class, not mocapfix's
        {"_class_path": "mocapfix.models.xmae.XMAE"},  # mocapfix's, but not a training module
        {"_class_path": "mocapfix.data.datamodule.MotionDataModule"},
        {"_class_path": MODULES["xmae"], "skeleton": {"class_path": "evil.Model"}},  # one nested deeper
    ],
    ids=["evil", "bare-class-path", "zen", "popen", "network", "datamodule", "nested"],
)
@pytest.mark.parametrize("command", ["validate", "fit"])
def test_a_checkpoint_naming_a_class_runs_no_code_and_is_one_line(
    tmp_path, evil_module, capsys, hyper_parameters, command
):
    ckpt = _checkpoint(tmp_path / "model.ckpt", hyper_parameters)
    capsys.readouterr()
    rc = main([command, "--config", str(CONFIGS / "xmae.yaml"), *QUIET, "--ckpt_path", str(ckpt)])
    out = capsys.readouterr()
    assert not evil_module.exists() and "evil" not in sys.modules and "this" not in sys.modules
    assert "Beautiful is better than ugly" not in out.out + out.err
    assert rc == 2
    _one_error_line(out.err, ckpt)
    assert "not one of mocapfix's" in out.err and MODULES["xmae"] in out.err
    # fix reads checkpoints by the kind they name, and no kind is a module to import
    entry = {"kind": "evil.Model", "config": {}}
    torch.save({"hyper_parameters": hyper_parameters, "model": entry, "state_dict": {}}, tmp_path / "kind.ckpt")
    (tmp_path / "take.npz").write_bytes(b"")
    assert main(["fix", str(tmp_path / "take.npz"), "--ckpt", str(tmp_path / "kind.ckpt")]) != 0
    assert not evil_module.exists() and "evil" not in sys.modules


def test_the_registry_is_the_configs_model_classes_and_every_kind():
    import importlib

    import lightning as L
    import yaml

    from mocapfix.models.build import CONFIGS as KINDS

    configured = {yaml.safe_load(p.read_text())["model"]["class_path"] for p in (CONFIGS / "model").glob("*.yaml")}
    assert configured == set(MODULES.values()) and set(MODULES) == set(KINDS)
    for path in MODULES.values():
        module, name = path.rsplit(".", 1)
        assert issubclass(getattr(importlib.import_module(module), name), L.LightningModule)


def _adapt_start(tmp_path) -> Path:
    """A copy of the shipped XMAE at checkpoints/adapt/mine.ckpt: where adapt's default output for
    --ckpt mine.ckpt would land."""
    from mocapfix.pretrained import pretrained_path

    start = tmp_path / "checkpoints" / "adapt" / "mine.ckpt"
    start.parent.mkdir(parents=True)
    start.write_bytes(pretrained_path("xmae-cpu-bandai").read_bytes())
    return start


def test_adapt_never_writes_onto_its_input_checkpoint(tmp_path, monkeypatch, capsys):
    from mocapfix.apps import adapt

    monkeypatch.chdir(tmp_path)
    start = _adapt_start(tmp_path)
    before = start.read_bytes()
    (tmp_path / "link.ckpt").symlink_to(start)
    os.link(start, tmp_path / "hard.ckpt")
    takes = tmp_path / "takes"
    takes.mkdir()
    # -o onto the input, by its name, a relative name, a symbolic link or a hard link: one line, nothing written
    for out in (start, Path("checkpoints/adapt/mine.ckpt"), tmp_path / "link.ckpt", tmp_path / "hard.ckpt"):
        for ckpt in (start, Path("checkpoints/adapt/../adapt/mine.ckpt"), tmp_path / "hard.ckpt"):
            args = adapt.build_parser().parse_args([str(takes), "--ckpt", str(ckpt), "-o", str(out)])
            with pytest.raises(ValueError, match="is the checkpoint adapt starts from") as e:
                adapt.output_path(args, str(ckpt))
            assert str(out) in str(e.value) and "\n" not in str(e.value)
    capsys.readouterr()
    assert main(["adapt", str(takes), "--ckpt", str(start), "-o", str(tmp_path / "link.ckpt"), "--minutes", "1"]) == 1
    _one_error_line(capsys.readouterr().err, tmp_path / "link.ckpt")
    # the default output (checkpoints/adapt/<stem>.ckpt) would be the input: another name beside it
    for ckpt in (start, Path("checkpoints/adapt/mine.ckpt")):
        args = adapt.build_parser().parse_args([str(takes), "--ckpt", str(ckpt)])
        out = adapt.output_path(args, str(ckpt))
        assert out.parent.resolve() == start.parent and not out.exists() and out.suffix == ".ckpt"
        assert out.resolve() != start.resolve()
    assert start.read_bytes() == before and (tmp_path / "link.ckpt").is_symlink()


def test_adapt_from_a_checkpoint_at_its_default_output_writes_beside_it(tmp_path, monkeypatch, capsys):
    from test_adapt import _body21_takes

    monkeypatch.chdir(tmp_path)
    start = _adapt_start(tmp_path)
    before = start.read_bytes()
    takes = _body21_takes(tmp_path / "takes", n=2, seconds=3.0)
    assert main(["adapt", str(takes), "--ckpt", "checkpoints/adapt/mine.ckpt", "--minutes", "0.01"]) == 0
    assert start.read_bytes() == before
    out = capsys.readouterr().out
    (adapted,) = set(start.parent.glob("*.ckpt")) - {start}
    assert f"adapted model: {adapted.relative_to(tmp_path)}" in out
    assert torch.load(adapted, weights_only=True)["adapted_from"] == "checkpoints/adapt/mine.ckpt"


def _claim(roots: list[str], start, queue) -> None:
    from mocapfix.training.run_dirs import claim_version

    start.wait()
    queue.put(claim_version([Path(r) for r in roots]))


def test_runs_started_together_claim_distinct_folders(tmp_path):
    import multiprocessing

    from mocapfix.training.run_dirs import claim_version

    roots = [tmp_path / "logs" / "exp", tmp_path / "checkpoints" / "exp"]
    (roots[1] / "version_2").mkdir(parents=True)  # an earlier run's checkpoints, its logs deleted
    ctx = multiprocessing.get_context("fork")
    start, queue = ctx.Event(), ctx.Queue()
    workers = [ctx.Process(target=_claim, args=([str(r) for r in roots], start, queue)) for _ in range(4)]
    for w in workers:
        w.start()
    start.set()  # all at once
    claimed = sorted(queue.get(timeout=30) for _ in workers)
    for w in workers:
        w.join(timeout=30)
    assert claimed == [3, 4, 5, 6]  # each its own N, none the earlier run's
    assert claim_version(roots) == 7
    for n in [*claimed, 7]:
        assert all((r / f"version_{n}").is_dir() for r in roots)
    # a folder another process made meanwhile (here: before the next claim) is never taken
    (roots[0] / "version_8").mkdir()
    assert claim_version(roots) == 9 and not (roots[1] / "version_8").exists()


def test_a_fit_keeps_out_of_another_runs_folders(tmp_path, monkeypatch, capsys):
    """Another run of the experiment (started at the same time: its folder exists, its logs not
    yet) keeps its last.ckpt and config; this one writes its own, and last.ckpt leads to it."""
    from cli_utils import SMALL_DATA, TINY

    monkeypatch.chdir(tmp_path)
    runs = tmp_path / "checkpoints" / "e"
    (runs / "version_0").mkdir(parents=True)
    (runs / "version_0" / "last.ckpt").write_bytes(b"theirs")
    (tmp_path / "logs" / "e").mkdir(parents=True)
    args = ["fit", "--config", str(CONFIGS / "xmae.yaml"), *TINY, *SMALL_DATA, *QUIET, "--experiment", "e"]
    args += ["--trainer.max_steps", "1", "--trainer.val_check_interval", "1"]
    assert main([*args, "--model.init_args.calibration_windows", "0"]) == 0
    assert (runs / "version_0" / "last.ckpt").read_bytes() == b"theirs"
    assert torch.load(runs / "version_1" / "last.ckpt", weights_only=True)["global_step"] == 1
    assert (tmp_path / "logs" / "e" / "version_1" / "config.yaml").is_file()
    assert not (tmp_path / "logs" / "e" / "version_0").exists()
    # checkpoints/<experiment>/last.ckpt: the last written, what --ckpt_path last resumes
    assert (runs / "last.ckpt").resolve() == (runs / "version_1" / "last.ckpt").resolve()
    assert "checkpoints/e/version_1/last.ckpt" in capsys.readouterr().out


@pytest.mark.parametrize("content", [[1, 2], {"hyper_parameters": [1]}, {"hyper_parameters": {}, "state_dict": {}}])
def test_a_checkpoint_that_is_not_a_training_runs_is_one_line(tmp_path, monkeypatch, capsys, content):
    monkeypatch.chdir(tmp_path)
    torch.save(content, tmp_path / "odd.ckpt")
    capsys.readouterr()
    assert main(["test", "--config", str(CONFIGS / "xmae.yaml"), *QUIET, "--ckpt_path", "odd.ckpt"]) == 2
    _one_error_line(capsys.readouterr().err, "odd.ckpt")
