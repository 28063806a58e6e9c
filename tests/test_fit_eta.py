"""How long a fit will take, on the console (training/fit_eta.py)."""

from __future__ import annotations

import re
from types import SimpleNamespace

from cli_utils import CONFIGS, SMALL_DATA, TINY, run_cli
from lightning.pytorch.callbacks import Timer

from mocapfix.training import fit_eta
from mocapfix.training.fit_eta import SETTLE_STEPS, TIMED_STEPS, FitETA, duration

LINE = re.compile(
    r"fit: ~(?P<left>[\d.]+) (?P<unit>s|min|h) to go \(ends about \d\d:\d\d\), step (?P<step>[\d,]+) of "
    r"(?P<total>[\d,]+): (?P<per_step>[\d.]+) s/step, validation (?P<val>\d+) s every (?P<every>[\d,]+) steps"
    r"(, the fill policy at the end ~(?P<policy>[\d.]+) (?P<policy_unit>s|min|h))?"
)


def _trainer(max_steps=2000, every=100, callbacks=()):
    return SimpleNamespace(
        global_step=0,
        max_steps=max_steps,
        estimated_stepping_batches=max_steps,
        callbacks=list(callbacks),
        enable_validation=every is not None,
        val_check_batch=every,
        check_val_every_n_epoch=None,
        accumulate_grad_batches=1,
        sanity_checking=False,
        is_global_zero=True,
        progress_bar_callback=None,  # nothing printed; the callback keeps its line
    )


def _run(monkeypatch, trainer, steps, seconds_per_step=0.5, validation_s=20.0):
    """Drive the callback through `steps` optimiser steps on a fake clock, with a validation of
    validation_s seconds every trainer.val_check_batch steps; -> the lines it said, in order."""
    clock = SimpleNamespace(now=0.0)
    monkeypatch.setattr(fit_eta.time, "perf_counter", lambda: clock.now)
    eta, lines = FitETA(), []
    eta.on_train_start(trainer, None)
    for step in range(trainer.global_step + 1, trainer.global_step + steps + 1):
        eta.on_train_batch_start(trainer, None, None, step)
        clock.now += seconds_per_step
        trainer.global_step = step
        eta.on_train_batch_end(trainer, None, None, None, step)
        if trainer.val_check_batch and step % trainer.val_check_batch == 0:
            eta.on_validation_start(trainer, None)
            clock.now += validation_s
            eta.on_validation_end(trainer, None)
        if eta.line and (not lines or lines[-1] != eta.line):
            lines.append(eta.line)
    eta.on_train_batch_start(trainer, None, None, steps + 1)  # the step after the last validation
    if eta.line != lines[-1]:
        lines.append(eta.line)
    return eta, lines


def test_the_estimate_is_the_steps_and_validations_left_at_their_measured_times(monkeypatch):
    eta, lines = _run(monkeypatch, _trainer(), steps=100)
    # after the first timed steps: the steps' time, the validations not timed yet
    first = SETTLE_STEPS + TIMED_STEPS
    assert lines[0].startswith(f"fit: {duration((2000 - first) * 0.5)} to go")
    assert f"step {first} of 2,000: 0.50 s/step, 20 validations not timed yet" in lines[0]
    # after the first validation: 1,900 steps of 0.5 s and 19 validations of 20 s
    assert eta.estimate_s == 1900 * 0.5 + 19 * 20.0
    assert lines[-1].startswith("fit: ~22 min to go") and "validation 20 s every 100 steps" in lines[-1]
    assert len(lines) == 2  # said again only after a validation


class _AfterTraining:
    def after_training(self, trainer, pl_module):
        return 120.0, "the fill policy at the end"


def test_what_a_callback_does_after_training_is_added(monkeypatch):
    trainer = _trainer(callbacks=[_AfterTraining()])
    trainer.lightning_module = None
    eta, lines = _run(monkeypatch, trainer, steps=100)
    assert eta.estimate_s == 1900 * 0.5 + 19 * 20.0 + 120.0
    assert lines[-1].endswith("validation 20 s every 100 steps, the fill policy at the end ~2 min")


def test_a_time_limit_that_comes_first_decides(monkeypatch):
    timer = Timer(duration="00:00:10:00")
    monkeypatch.setattr(timer, "time_remaining", lambda stage: 300.0)
    eta, lines = _run(monkeypatch, _trainer(callbacks=[timer]), steps=100)
    assert eta.estimate_s == 300.0 and "the time limit comes first" in lines[-1]


def test_without_validations_the_steps_alone(monkeypatch):
    eta, lines = _run(monkeypatch, _trainer(max_steps=200, every=None), steps=20)
    assert eta.estimate_s == (200 - SETTLE_STEPS - TIMED_STEPS) * 0.5 and "validation" not in lines[0]


def test_durations_read_as_a_person_says_them():
    assert [duration(s) for s in (0.2, 45, 89.6, 720, 5399, 9000)] == [
        "~1 s",
        "~45 s",
        "~90 s",
        "~12 min",
        "~90 min",
        "~2.5 h",
    ]


def _seconds(match, value="left", unit="unit") -> float:
    return float(match[value]) * {"s": 1, "min": 60, "h": 3600}[match[unit]]


def test_fit_says_how_long_it_will_take_before_half_of_it(tmp_path, capsys):
    """A real run: the line is on the console after the first validation (step 6 of 12), made of
    the run's own step and validation times and the fill policy's measurement at the end (xmae's
    calibrate_every_n_val 0, timed on a sample); a quiet run (no progress bar) prints none."""
    args = [
        "fit",
        "--config",
        CONFIGS / "xmae.yaml",
        *TINY,
        *SMALL_DATA,
        "--trainer.enable_model_summary",
        "false",
        "--trainer.logger",
        "false",
        "--model.init_args.calibration_windows",
        "4",
        "--trainer.max_steps",
        "12",
        "--trainer.val_check_interval",
        "6",
    ]
    capsys.readouterr()
    assert run_cli(args, tmp_path) == 0
    lines = [m for m in map(LINE.search, capsys.readouterr().err.splitlines()) if m]
    assert lines, "no ETA line"
    first = lines[0]
    assert first["step"] == "6" and first["total"] == "12" and first["every"] == "6"
    per_step, val_s = float(first["per_step"]), float(first["val"])
    assert per_step > 0 and first["policy"] is not None
    # 6 steps left, the validation at step 12 and the policy, at their measured times (as printed, rounded)
    expected = 6 * per_step + val_s + _seconds(first, "policy", "policy_unit")
    assert abs(_seconds(first) - expected) <= 2.0 + 0.05 * _seconds(first)
    capsys.readouterr()
    assert run_cli([*args, "--trainer.enable_progress_bar", "false"], tmp_path) == 0
    assert "fit: ~" not in capsys.readouterr().err
