"""A checkpoint at the step reached when training is stopped from outside."""

from __future__ import annotations

import signal
import threading
from pathlib import Path

import lightning as L
from lightning.pytorch.trainer.states import TrainerFn
from lightning.pytorch.utilities.exceptions import SIGTERMException

from mocapfix.training.run_dirs import point_last


class CheckpointOnInterrupt(L.Callback):
    """Ctrl-C, or SIGTERM (a scheduler's time limit, a preempted machine), during `fit`: writes
    `path` (the experiment's last.ckpt) at the step reached, so `--ckpt_path last` goes on from
    there rather than from the last validation. Other exceptions write nothing: a failed setup
    would have no trained state to keep, only a good last.ckpt to overwrite. Under DDP the first
    process writes it alone (the strategies mocapfix configures keep whole weights on every
    process)."""

    def __init__(self, path: str | Path, link_from: str | Path | None = None):
        """link_from: the experiment's folder, whose last.ckpt then links to path (run_dirs.py)."""
        self.path = Path(path)
        self.link_from = Path(link_from) if link_from is not None else None

    def on_sanity_check_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self._own_sigterm(trainer)

    def on_train_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self._own_sigterm(trainer)

    @staticmethod
    def _own_sigterm(trainer: L.Trainer) -> None:
        """Under DDP, SIGTERM without a collective in the signal handler. Lightning's handler
        broadcasts the stop from inside the handler, which runs wherever the process happens to
        be: inside a gradient all-reduce or a metric sync that the other process has already
        left, the two collectives pair up wrong and a process waits for the gloo/NCCL timeout.
        This one forwards the signal to the other processes (as Lightning's does) and sets the
        flag; the training loop's own per-step broadcast carries it to every process at a point
        they all reach. Installed when the run starts (after Lightning registers its handlers)."""
        if trainer.world_size == 1 or threading.current_thread() is not threading.main_thread():
            return
        connector = trainer._signal_connector  # Lightning's; its teardown restores the handlers it saved

        def on_sigterm(signum, frame) -> None:
            launcher = trainer.strategy.launcher
            if not connector.received_sigterm and launcher is not None:
                launcher.kill(signum)
            connector.received_sigterm = True

        signal.signal(signal.SIGTERM, on_sigterm)

    def on_exception(self, trainer: L.Trainer, pl_module: L.LightningModule, exception: BaseException) -> None:
        # under DDP, after a SIGTERM, another process may stop first: this one's next collective
        # then fails ("connection closed by peer"), a RuntimeError that is the same stop
        stopped = isinstance(exception, (KeyboardInterrupt, SIGTERMException)) or (
            isinstance(exception, RuntimeError) and trainer.received_sigterm
        )
        if stopped and trainer.state.fn == TrainerFn.FITTING and trainer.global_step > 0:
            if trainer.world_size == 1:
                trainer.save_checkpoint(self.path)
            elif trainer.is_global_zero:
                # Under DDP, no collective here: trainer.save_checkpoint ends in a barrier, and the
                # other processes may be anywhere (in Lightning's SIGTERM broadcast, a gradient
                # all-reduce, their own on_exception): a barrier there waits for the gloo/NCCL
                # timeout. Without sharded state, the first process holds everything to save.
                checkpoint = trainer._checkpoint_connector.dump_checkpoint()
                trainer.strategy.checkpoint_io.save_checkpoint(checkpoint, self.path)
            if trainer.is_global_zero and self.link_from is not None and self.path.parent != self.link_from:
                point_last(self.link_from, self.path)
