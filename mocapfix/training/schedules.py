"""Schedules stepped per optimiser step: the learning rate's and the KL weight's."""

from __future__ import annotations

import math


def warmup_cosine(step: int, warmup_steps: int, total_steps: int) -> float:
    """Multiplier of the peak lr: linear warm-up from 0, then cosine decay to 0 at total_steps."""
    if step < warmup_steps:
        return (step + 1) / warmup_steps
    progress = min(1.0, (step - warmup_steps) / max(1, total_steps - warmup_steps))
    return 0.5 * (1.0 + math.cos(math.pi * progress))


class WarmupCosine:
    """warmup_cosine as LambdaLR's lr_lambda. An object, not a partial: LambdaLR saves an object's
    attributes in the checkpoint, so an end moved during a run (training/time_schedule.py) is
    what a resumed run goes on with. planned_steps keeps the end the run was configured with."""

    def __init__(self, warmup_steps: int, total_steps: int):
        self.warmup_steps, self.total_steps, self.planned_steps = warmup_steps, total_steps, total_steps

    def __call__(self, step: int) -> float:
        return warmup_cosine(step, self.warmup_steps, self.total_steps)


def adamw_warmup_cosine(module, lr: float, weight_decay: float, warmup_steps: int, total_steps: int | None) -> dict:
    """A LightningModule's configure_optimizers: AdamW, its lr warmed up then decayed by cosine per
    step (total_steps None: the Trainer's estimated number of optimiser steps)."""
    import torch

    opt = torch.optim.AdamW(module.parameters(), lr=lr, weight_decay=weight_decay)
    total = total_steps or int(module.trainer.estimated_stepping_batches)
    sched = torch.optim.lr_scheduler.LambdaLR(opt, WarmupCosine(warmup_steps, total))
    return {"optimizer": opt, "lr_scheduler": {"scheduler": sched, "interval": "step"}}


def kl_anneal_weight(step: int, anneal_steps: int) -> float:
    """Linear KL annealing: 0 at step 0, 1 from anneal_steps on (1 throughout when anneal_steps <= 0)."""
    return 1.0 if anneal_steps <= 0 else min(1.0, step / anneal_steps)


def anneal_steps_of(trainer, steps: int | None, epochs: float) -> int:
    """The annealing length in optimiser steps: `steps` when given, else `epochs` epochs of the trainer."""
    if steps is not None:
        return int(steps)
    per_epoch = trainer.num_training_batches / max(1, trainer.accumulate_grad_batches)
    return int(round(epochs * per_epoch)) if per_epoch != float("inf") else 0
