"""The fill policy of the checkpoints a fit leaves, measured for their own weights.

A validation that measures the fill policy runs the network about 16 times over its windows
(evaluation/policy_fit.py): on a CPU, minutes of every validation for the paper's network. A
config can measure it at fewer validations (XMAEModule's calibrate_every_n_val); then, when training
ends, each of the run's final checkpoints, best and last, whose policy was not measured for its
weights at the validation that wrote it gets its policy now: its weights loaded into the network,
the policy measured on the val windows as a validation would, written into the file (as `mocapfix
validate --ckpt_path` does), the network's own weights put back. A run stopped by an interrupt
ends without it: `mocapfix validate --ckpt_path last` measures its last.ckpt. How long it will
take is in fit's console line (training/fit_eta.py reads after_training), from the validations'
own network pass (XMAEModule.fill_policy_seconds).
"""

from __future__ import annotations

import itertools
import logging
import math
import time
from collections.abc import Callable, Iterable
from pathlib import Path

import lightning as L
import torch

from mocapfix.models.checkpoint import load_checkpoint, network_weights, save_checkpoint, set_fill_policy

log = logging.getLogger(__name__)


class FinalFillPolicy(L.Callback):
    """On the module: policy_steps (the global steps whose weights a validation measured the policy
    for), measure_fill_policy(batches), fill_policy_seconds(windows) and fill_policy (XMAEModule)."""

    def __init__(self) -> None:
        self._windows = 0  # the val windows the measurement at the end reads

    # --- how long it will take (training/fit_eta.py says it) ---

    def on_train_start(self, trainer, pl_module) -> None:
        self._windows = 0
        batches = _val_batches(trainer) if _measures_at_the_end(trainer, pl_module) else None
        for batch in batches() if batches is not None else ():
            self._windows += len(batch["positions"])
            if self._windows >= pl_module.hparams.calibration_windows:
                break
        self._windows = min(self._windows, pl_module.hparams.calibration_windows)

    def after_training(self, trainer, pl_module) -> tuple[float, str] | None:
        """(about how many seconds the measurement at the end takes, what it is); None: none, or
        not timed yet. For one file: best and last are usually the same step's weights (two: twice
        as long)."""
        if not self._windows or not _measures_at_the_end(trainer, pl_module):
            return None
        seconds = pl_module.fill_policy_seconds(self._windows)
        return (seconds, "the fill policy at the end") if seconds is not None else None

    # --- the measurement ---

    def on_train_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        # on_train_end, not on_fit_end: the network is still on the training device
        if not trainer.is_global_zero or pl_module.hparams.get("calibration_windows", 0) <= 0:
            return
        files = _final_files(trainer)
        if not files:
            return
        batches = _val_batches(trainer)
        if batches is None:
            return
        measured = {}  # step -> policy: best and last are often the same step's weights
        for path in files:
            ckpt = load_checkpoint(path)
            step = ckpt.get("global_step")
            if step in pl_module.policy_steps:  # measured at the validation that wrote it
                continue
            start = time.perf_counter()
            if step not in measured:
                log.info("fill policy: measuring it for %s (step %s) on the val windows", path, step)
                measured[step] = _measure(trainer, pl_module, network_weights(ckpt, "net"), batches())
            policy = measured[step]
            if policy is None:
                continue
            set_fill_policy(ckpt, policy.to_dict())
            save_checkpoint(path, ckpt)
            if step == trainer.global_step:  # the module's own weights: its policy too
                pl_module.fill_policy = policy
            log.info(
                "fill policy: %d val windows, %.0f s, written into %s",
                policy.windows,
                time.perf_counter() - start,
                path,
            )


def _measures_at_the_end(trainer: L.Trainer, pl_module: L.LightningModule) -> bool:
    """Whether the final checkpoints will need their policy measured when training ends: some of
    the fit's validations do not measure it, and the run writes checkpoints."""
    hp = pl_module.hparams
    return (
        trainer.is_global_zero
        and hp.get("calibration_windows", 0) > 0
        and hp.get("calibrate_every_n_val", 1) != 1
        and bool(trainer.checkpoint_callbacks)
    )


def _final_files(trainer: L.Trainer) -> list[Path]:
    """The run's best and last checkpoint files, each once; only those in the run's own folder
    (a resumed run's best may still be an earlier run's file, which is that run's to keep)."""
    files: list[Path] = []
    for cb in trainer.checkpoint_callbacks:
        for name in (getattr(cb, "best_model_path", ""), getattr(cb, "last_model_path", "")):
            if not name or not cb.dirpath:
                continue
            path = Path(name)
            if path.is_file() and path.parent.resolve() == Path(cb.dirpath).resolve() and path not in files:
                files.append(path)
    return files


def _val_batches(trainer: L.Trainer) -> Callable[[], Iterable] | None:
    """The batches the fit's validations read (its val loader, or the data module's where no
    validation ran yet; as many batches as trainer.limit_val_batches lets them), each call afresh;
    None: the fit validates nothing (no policy either)."""
    if not trainer.enable_validation:
        return None
    loader, counts = trainer.val_dataloaders, trainer.num_val_batches
    if isinstance(loader, (list, tuple)):
        loader = loader[0] if loader else None
    if loader is None and trainer.datamodule is not None:  # no validation ran in this fit
        loader, limit = trainer.datamodule.val_dataloader(), trainer.limit_val_batches
        counts = [limit if isinstance(limit, int) else int(len(loader) * limit)]
    if loader is None:
        return None
    count = counts[0] if isinstance(counts, (list, tuple)) and counts else None
    if count is None or not math.isfinite(count):
        return lambda: loader
    return lambda: itertools.islice(loader, int(count))


def _measure(trainer: L.Trainer, pl_module: L.LightningModule, weights: dict, batches):
    """The policy of the network with weights (its own weights are put back after)."""
    net = pl_module.net
    own = {k: v.detach().clone() for k, v in net.state_dict().items()}
    was_training = pl_module.training
    pl_module.eval()
    try:
        net.load_state_dict({k: v.to(own[k].dtype) for k, v in weights.items()})
        with torch.no_grad(), trainer.precision_plugin.val_step_context():
            return pl_module.measure_fill_policy(batches)
    finally:
        net.load_state_dict(own)
        pl_module.train(was_training)
