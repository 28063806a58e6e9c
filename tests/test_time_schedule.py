"""The cosine's end moved to where the run's time limit stops it (training/time_schedule.py)."""

from __future__ import annotations

from types import SimpleNamespace

import torch
from lightning.pytorch.callbacks import Timer

from mocapfix.training import time_schedule
from mocapfix.training.schedules import WarmupCosine
from mocapfix.training.time_schedule import MIN_TIMED_STEPS, SETTLE_STEPS, TIMED_S, TIMED_STEPS, FitScheduleToTime


def _run(monkeypatch, remaining_s, planned_steps=10_000, first_step=0, seconds_per_step=0.1, steps=200, schedule=None):
    """Drive the callback through `steps` optimiser steps on a fake clock; -> the schedule (a new
    one planned for planned_steps, or the one given: a resumed run's)."""
    schedule = schedule or WarmupCosine(10, planned_steps)
    opt = torch.optim.SGD([torch.nn.Parameter(torch.zeros(1))], lr=1.0)
    timer = Timer(duration="00:01:00:00")
    monkeypatch.setattr(timer, "time_remaining", lambda stage: remaining_s)
    trainer = SimpleNamespace(
        callbacks=[timer],
        global_step=first_step,
        lr_scheduler_configs=[SimpleNamespace(scheduler=torch.optim.lr_scheduler.LambdaLR(opt, schedule))],
    )
    clock = SimpleNamespace(now=0.0)
    monkeypatch.setattr(time_schedule.time, "perf_counter", lambda: clock.now)
    callback = FitScheduleToTime()
    callback.on_train_start(trainer, None)
    for step in range(first_step + 1, first_step + steps + 1):
        trainer.global_step, clock.now = step, step * seconds_per_step
        callback.on_train_batch_end(trainer, None, None, None, step)
    return schedule


def test_the_cosine_ends_where_the_time_left_runs_out(monkeypatch):
    # timed over 100 steps at 0.1 s a step; then 50 s left: 0.9 * 500 more steps
    schedule = _run(monkeypatch, remaining_s=50.0)
    measured_at = SETTLE_STEPS + TIMED_STEPS
    assert schedule.total_steps == measured_at + int(0.9 * 50.0 / 0.1)
    assert schedule(schedule.total_steps) == 0.0 < schedule(schedule.total_steps - 50)
    # a resumed run times its own steps, from its checkpoint's step on
    resumed = _run(monkeypatch, remaining_s=50.0, first_step=5_000, planned_steps=20_000)
    assert resumed.total_steps == 5_000 + measured_at + 450
    # slow steps: timed for TIMED_S seconds (at least MIN_TIMED_STEPS steps), not 100 steps
    slow = _run(monkeypatch, remaining_s=600.0, seconds_per_step=2.0, steps=40)
    timed = max(MIN_TIMED_STEPS, int(TIMED_S / 2.0))
    assert slow.total_steps == SETTLE_STEPS + timed + int(0.9 * 600.0 / 2.0)


def test_a_step_limit_that_comes_first_and_no_time_limit_leave_the_plan(monkeypatch):
    assert _run(monkeypatch, remaining_s=3_600.0, planned_steps=1_000).total_steps == 1_000  # steps end it first
    assert _run(monkeypatch, remaining_s=None).total_steps == 10_000  # no max_time
    # no time left: the cosine ends where the steps were timed
    assert _run(monkeypatch, remaining_s=0.0).total_steps == SETTLE_STEPS + TIMED_STEPS


def test_a_resume_with_more_time_re_plans_from_the_planned_end(monkeypatch):
    first = _run(monkeypatch, remaining_s=50.0)  # the first run's end moved before step 600
    assert first.total_steps < 600 and first.planned_steps == 10_000
    schedule = WarmupCosine(10, 10_000)
    schedule.total_steps = first.total_steps  # what the checkpoint carries to the resumed run
    resumed_at = first.total_steps
    _run(monkeypatch, 200.0, first_step=resumed_at, steps=SETTLE_STEPS + TIMED_STEPS, schedule=schedule)
    assert schedule.total_steps == resumed_at + SETTLE_STEPS + TIMED_STEPS + int(0.9 * 200.0 / 0.1)


def test_the_moved_end_is_in_the_checkpoint():
    opt = torch.optim.SGD([torch.nn.Parameter(torch.zeros(1))], lr=1.0)
    saved = torch.optim.lr_scheduler.LambdaLR(opt, WarmupCosine(10, 10_000))
    saved.lr_lambdas[0].total_steps = 560
    resumed = torch.optim.lr_scheduler.LambdaLR(opt, WarmupCosine(10, 10_000))
    resumed.load_state_dict(saved.state_dict())
    assert resumed.lr_lambdas[0].total_steps == 560 and resumed.lr_lambdas[0].planned_steps == 10_000
