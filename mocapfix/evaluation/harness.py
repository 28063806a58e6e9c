"""The test harness every LightningModule's `test` uses: a table of metrics accumulated over the
test batches. The modules say what to predict; this keeps the cells, so the three test tables
(XMAE's paper tables, the Motion-DVAE prior's reconstruction, the denoiser's noise table) are
counted and synced across processes the same way (training/test_report.py publishes them).
"""

from __future__ import annotations

import torch.nn as nn
from torchmetrics import Metric

from mocapfix.evaluation.metrics import MPJPE


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


def mpjpe_table(task_keys, methods) -> TestTable:
    """The paper tables' cells: (task key, method, "abs" | "rel") -> MPJPE, global and root-relative."""
    return TestTable(
        {(k, m, rel): MPJPE(root_relative=rel == "rel") for k in task_keys for m in methods for rel in ("abs", "rel")}
    )


def abs_and_rel(cells: dict[tuple, float]) -> dict[tuple[str, str], tuple[float, float]]:
    """mpjpe_table(...).compute() -> (task key, method) -> (global, root-relative), table_rows' input."""
    return {(key, m): (cells[(key, m, "abs")], cells[(key, m, "rel")]) for key, m, rel in cells if rel == "abs"}
