"""The test harness every LightningModule's `test` uses: a table of metrics accumulated over the
test batches, and its publication (logged scalars, the printed table, eval.json in the run's log
folder). The modules say what to predict; this file keeps the bookkeeping, so the three test
tables (XMAE's paper tables, the Motion-DVAE prior's reconstruction, the denoiser's noise table)
are counted, synced across processes and written the same way.
"""

from __future__ import annotations

from pathlib import Path

import lightning as L
import torch.nn as nn
from torchmetrics import Metric

from mocapfix.evaluation.tasks import write_eval_json


class TestTable(nn.Module):
    """One torchmetric per table cell (any hashable key, e.g. (task, method, "abs")). torchmetrics
    syncs each across processes at compute(); being an nn.Module, the table follows the
    LightningModule to its device."""

    def __init__(self, cells: dict[tuple, Metric]):
        super().__init__()
        self.keys = list(cells)
        self.index = {k: str(i) for i, k in enumerate(self.keys)}  # ModuleDict keys must be strings
        self.metrics = nn.ModuleDict({self.index[k]: m for k, m in cells.items()})

    def update(self, cell: tuple, *args, **kwargs) -> None:
        self.metrics[self.index[cell]].update(*args, **kwargs)

    def updated(self, cell: tuple) -> bool:
        return bool(self.metrics[self.index[cell]].update_called)

    def compute(self) -> dict[tuple, float]:
        """cell -> value, for the cells that saw data."""
        return {k: float(self.metrics[self.index[k]].compute()) for k in self.keys if self.updated(k)}


def publish(
    module: L.LightningModule, rows: list[dict], scalars: dict[str, float], text: str | None = None
) -> Path | None:
    """The end of a test: `scalars` logged (Lightning reduces them across processes), `text`
    printed and `rows` written to eval.json in the run's log folder by the first process.
    Returns eval.json's path (None on other processes)."""
    for name, value in scalars.items():
        module.log(name, value, sync_dist=True)
    if not module.trainer.is_global_zero:
        return None
    if text:
        print("\n" + text)
    logger = module.logger
    log_dir = Path(logger.log_dir if logger is not None and logger.log_dir else module.trainer.default_root_dir)
    return write_eval_json(log_dir / "eval.json", rows)
