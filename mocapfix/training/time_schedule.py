"""The learning-rate schedule's end moved to where a run's time limit will stop it.

A run given `--trainer.max_time` (a lent GPU's 10-minute call) stops on time,
usually before the step count its cosine was planned for, and then stops with the learning rate
still high: the weights it keeps are a noisy mid-schedule state. After a short measurement of
its own step rate, the run moves the cosine's end to the step it can reach in the time left, so
the rate reaches zero when the clock does. A step limit that comes first still decides.
"""

from __future__ import annotations

import time

import lightning as L
from lightning.pytorch.callbacks import Timer

from mocapfix.training.schedules import WarmupCosine

# Steps skipped before timing (compiling, caches warming up), then steps timed: TIMED_STEPS, or
# at least MIN_TIMED_STEPS over TIMED_S seconds where steps are slow.
SETTLE_STEPS = 10
TIMED_STEPS = 100
MIN_TIMED_STEPS = 10
TIMED_S = 15.0
# Time kept for what the timed steps did not see: validations, checkpoints, the last save.
MARGIN = 0.9


class FitScheduleToTime(L.Callback):
    """Once per run (and again after a resume): time a few optimiser steps, then set every
    WarmupCosine of the run's schedulers to end at the step the remaining time reaches (never
    later than it was planned, never inside the warm-up). A resume re-plans from the planned end:
    given more time than the last run, its rate rises again and ends on the new time."""

    def __init__(self) -> None:
        self._first_timed_step = 0
        self._start: tuple[int, float] | None = None  # (global step, perf_counter) when timing began
        self._done = False

    def on_train_start(self, trainer, pl_module) -> None:
        # a resumed run starts at its checkpoint's step
        self._first_timed_step, self._start, self._done = trainer.global_step + SETTLE_STEPS, None, False

    def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx) -> None:
        if self._done:
            return
        timer = next((cb for cb in trainer.callbacks if isinstance(cb, Timer)), None)
        remaining = timer.time_remaining("train") if timer is not None else None
        if remaining is None:  # no time limit: the planned schedule stands
            self._done = True
            return
        step = trainer.global_step
        if self._start is None:
            if step >= self._first_timed_step:
                self._start = (step, time.perf_counter())
            return
        timed_steps, timed_s = step - self._start[0], time.perf_counter() - self._start[1]
        if timed_steps < TIMED_STEPS and (timed_steps < MIN_TIMED_STEPS or timed_s < TIMED_S):
            return
        seconds_per_step = timed_s / timed_steps
        reachable = step + int(MARGIN * remaining / seconds_per_step)
        for config in trainer.lr_scheduler_configs:
            for schedule in getattr(config.scheduler, "lr_lambdas", []):
                if isinstance(schedule, WarmupCosine):
                    # from the planned end, not the last run's: a resumed run given more time goes further
                    schedule.total_steps = min(schedule.planned_steps, max(reachable, schedule.warmup_steps + 1))
        self._done = True
