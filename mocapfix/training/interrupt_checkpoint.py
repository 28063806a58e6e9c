"""A checkpoint at the step reached when training is stopped from outside."""

from __future__ import annotations

from pathlib import Path

import lightning as L
from lightning.pytorch.trainer.states import TrainerFn
from lightning.pytorch.utilities.exceptions import SIGTERMException


class CheckpointOnInterrupt(L.Callback):
    """Ctrl-C, or SIGTERM (a scheduler's time limit, a preempted machine), during `fit`: writes
    `path` (the experiment's last.ckpt) at the step reached, so `--ckpt_path last` goes on from
    there rather than from the last validation. Other exceptions write nothing: a failed setup
    would have no trained state to keep, only a good last.ckpt to overwrite."""

    def __init__(self, path: str | Path):
        self.path = Path(path)

    def on_exception(self, trainer: L.Trainer, pl_module: L.LightningModule, exception: BaseException) -> None:
        if (
            isinstance(exception, (KeyboardInterrupt, SIGTERMException))
            and trainer.state.fn == TrainerFn.FITTING
            and trainer.global_step > 0
        ):
            trainer.save_checkpoint(self.path)
