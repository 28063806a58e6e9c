"""How long a fit will take, said on the console early and again after each validation.

A CPU run of the paper's network is tens of minutes, and its validations a large part of them; the
progress bar counts an epoch's batches, not the run's steps, and leaves validations out. One line,
after the first few timed steps and again once each validation is over (the checkpoints it
writes included):

    fit: ~6 min to go (ends about 22:19), step 5 of 12: 3.29 s/step, validation 20 s every 5 steps,
    the fill policy at the end ~6 min

(`--config xmae --trainer.max_steps 12 --trainer.val_check_interval 5` on a busy 2-core CPU; it
ended at 22:20, the policy's measurement 6.2 min.)

From the run's own measurements: the optimiser steps' time without the validations (the first
SETTLE_STEPS left out: caches, allocations) and the last validation's, times the steps and
validations left, plus what a callback says it will do once training is over (`after_training`:
the fill policy of the final checkpoints, training/final_policy.py). A time limit
(trainer.max_time) that comes first decides the training part. Printed where the progress bar is
(trainer.enable_progress_bar false: a quiet run, nothing printed), by the first process only.
"""

from __future__ import annotations

import math
import sys
import time

import lightning as L
from lightning.pytorch.callbacks import Timer

SETTLE_STEPS = 3  # steps not timed: the first ones pay for allocations and warming caches
# the first line: after TIMED_STEPS timed steps, or after MIN_TIMED_STEPS of them where steps are slow
TIMED_STEPS = 10
MIN_TIMED_STEPS = 2
TIMED_S = 20.0


def duration(seconds: float) -> str:
    """~45 s, ~12 min, ~2.5 h."""
    if seconds < 90:
        return f"~{max(1, round(seconds))} s"
    if seconds < 90 * 60:
        return f"~{round(seconds / 60)} min"
    return f"~{seconds / 3600:.1f} h"


def steps_between_validations(trainer: L.Trainer) -> float | None:
    """Optimiser steps from one validation to the next as the Trainer schedules them; None: no
    validations, or validations by the clock (trainer.val_check_interval as a time)."""
    if not trainer.enable_validation or not trainer.val_check_batch:
        return None
    every = trainer.val_check_batch  # training batches
    if trainer.check_val_every_n_epoch is not None:  # within each k-th epoch
        per_epoch = trainer.num_training_batches
        if not math.isfinite(per_epoch) or per_epoch <= 0:
            return None
        checks = max(1, int(per_epoch // every)) if math.isfinite(every) else 1
        every = per_epoch * trainer.check_val_every_n_epoch / checks
    elif not math.isfinite(every):
        return None
    return every / max(1, trainer.accumulate_grad_batches)


class FitETA(L.Callback):
    def __init__(self) -> None:
        self._reset()

    def _reset(self) -> None:
        self._timed_from: tuple[int, float] | None = None  # (step, perf_counter) where timing began
        self._first_step = 0
        self._val_s = 0.0  # validation time since timing began
        self._last_val_s: float | None = None  # the last validation's, checkpoints included
        self._val_start: float | None = None
        self._val_over = False  # a validation ended: its time closes at the next step
        self._said = False
        self.line: str | None = None  # the last line printed (tests read it)
        self.estimate_s: float | None = None  # its time to go

    def on_train_start(self, trainer, pl_module) -> None:
        self._reset()
        self._first_step = trainer.global_step  # a resumed run starts at its checkpoint's step

    def on_train_batch_start(self, trainer, pl_module, batch, batch_idx) -> None:
        if self._val_over:  # the validation, and the checkpoints written after it, are over
            self._val_over = False
            now = time.perf_counter()
            self._last_val_s = now - self._val_start
            if self._timed_from is not None:
                self._val_s += self._last_val_s
            self._say(trainer)

    def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx) -> None:
        step = trainer.global_step
        if self._timed_from is None:
            if step >= self._first_step + SETTLE_STEPS:
                self._timed_from = (step, time.perf_counter())
            return
        if not self._said:
            timed, seconds = step - self._timed_from[0], self._train_seconds()
            if timed >= TIMED_STEPS or (timed >= MIN_TIMED_STEPS and seconds >= TIMED_S):
                self._say(trainer)

    def on_validation_start(self, trainer, pl_module) -> None:
        if not trainer.sanity_checking:
            self._val_start = time.perf_counter()

    def on_validation_end(self, trainer, pl_module) -> None:
        if not trainer.sanity_checking and self._val_start is not None:
            self._val_over = True

    def on_train_end(self, trainer, pl_module) -> None:
        self._val_over = False

    # --- the estimate ---

    def _train_seconds(self) -> float:
        return time.perf_counter() - self._timed_from[1] - self._val_s

    def estimate(self, trainer) -> tuple[float, str] | None:
        """(seconds to go, what they are made of) from what was measured so far; None: not yet."""
        if self._timed_from is None:
            return None
        step = trainer.global_step
        timed = step - self._timed_from[0]
        total = trainer.max_steps if trainer.max_steps and trainer.max_steps > 0 else trainer.estimated_stepping_batches
        if timed <= 0 or not math.isfinite(total):
            return None
        per_step = self._train_seconds() / timed
        left = max(0, int(total) - step)
        seconds = left * per_step
        parts = [f"step {step:,} of {int(total):,}: {per_step:.2f} s/step"]
        every = steps_between_validations(trainer)
        if every is not None:
            if trainer.check_val_every_n_epoch is None:  # exactly at the multiples of `every`
                validations = int(total // every) - int(step // every)
            else:
                validations = round(left / every)
            if self._last_val_s is not None:
                seconds += validations * self._last_val_s
                parts.append(f"validation {self._last_val_s:.0f} s every {every:,.0f} steps")
            elif validations:
                parts.append(f"{validations} validations not timed yet")
        timer = next((cb for cb in trainer.callbacks if isinstance(cb, Timer)), None)
        remaining = timer.time_remaining("train") if timer is not None else None
        if remaining is not None and remaining < seconds:
            seconds = remaining
            parts.append("the time limit comes first")
        for cb in trainer.callbacks:  # work a callback does once training is over (after_training)
            after = getattr(cb, "after_training", None)
            found = after(trainer, trainer.lightning_module) if callable(after) else None
            if found is not None:
                seconds += found[0]
                parts.append(f"{found[1]} {duration(found[0])}")
        return seconds, ", ".join(parts)

    def _say(self, trainer) -> None:
        found = self.estimate(trainer)
        if found is None:
            return
        self._said = True
        if not trainer.is_global_zero:
            return
        seconds, made_of = found
        ends = time.strftime("%H:%M", time.localtime(time.time() + seconds))
        self.line, self.estimate_s = f"fit: {duration(seconds)} to go (ends about {ends}), {made_of}", seconds
        bar = trainer.progress_bar_callback
        if bar is None:  # no progress bar: a quiet run
            return
        from lightning.pytorch.callbacks import TQDMProgressBar

        if isinstance(bar, TQDMProgressBar):
            bar.print(self.line, file=sys.stderr)  # above the bar, not through it
        else:
            print(self.line, file=sys.stderr)
