"""`python -m mocapfix predict`: the model's output on the data module's predict windows, to a file."""

from __future__ import annotations

from pathlib import Path

import lightning as L
import numpy as np
import torch
from lightning.pytorch.callbacks import BasePredictionWriter

from mocapfix.io.files import atomic_write


class WritePredictions(BasePredictionWriter):
    """Writes every predicted window to predictions.npz in the run's log folder: `positions`
    (N, T, J, 3) metres z up, NaN where the model gave nothing, with `fps`, `joint_names` and
    `parents`. (Whole recordings in their own files and layouts: `mocapfix fix`.)"""

    def __init__(self):
        super().__init__(write_interval="epoch")
        self.path: Path | None = None

    def write_on_epoch_end(self, trainer: L.Trainer, pl_module: L.LightningModule, predictions, batch_indices):
        if predictions and isinstance(predictions[0], list):  # one list per predict dataloader
            predictions = [p for per_loader in predictions for p in per_loader]
            batch_indices = [b for per_loader in batch_indices for b in per_loader]
        positions = torch.cat([p.float().cpu() for p in predictions]) if predictions else None  # (n, T, J, 3)
        if trainer.world_size > 1:  # every process's windows, back in the split's order
            index = torch.as_tensor(list(_flat(batch_indices)), dtype=torch.long)  # (n,) the windows predicted here
            parts = [None] * trainer.world_size
            torch.distributed.all_gather_object(parts, (index, positions))
            parts = [(i, p) for i, p in parts if p is not None]
            if not parts:
                return
            index, positions = torch.cat([i for i, _ in parts]), torch.cat([p for _, p in parts])
            positions = positions[torch.argsort(index)]
        if not trainer.is_global_zero or positions is None:
            return
        positions = positions.numpy()  # (N, T, J, 3)
        skeleton = trainer.datamodule.skeleton
        log_dir = trainer.logger.log_dir if trainer.logger and trainer.logger.log_dir else trainer.default_root_dir
        self.path = Path(log_dir) / "predictions.npz"
        atomic_write(
            self.path,
            lambda f: np.savez_compressed(
                f,
                positions=positions,
                fps=np.float64(trainer.datamodule.hparams.fps),
                joint_names=np.array(skeleton.joint_names),
                parents=np.array(skeleton.parents),
            ),
        )


def _flat(nested):
    """The ints of batch_indices, however Lightning nested them (per dataloader, per batch)."""
    for x in nested:
        if isinstance(x, (list, tuple)):
            yield from _flat(x)
        else:
            yield int(x)
