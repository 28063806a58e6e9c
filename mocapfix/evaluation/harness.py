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


def format_denoise_table(rows: list[dict], key: str, methods: tuple[str, ...]) -> str:
    """Motion-DVAE's Table 1 layout: one line per method, MPJPE / root-relative MPJPE / joint
    acceleration per noise level, and seconds per frame. key: "sigma_rad" or "sigma_m"."""
    sigmas = sorted({r[key] for r in rows})
    unit = "rad" if key == "sigma_rad" else "m"
    lines = [
        f"Motion-DVAE denoising, Gaussian noise sigma ({unit}): " + " ".join(f"{s:g}" for s in sigmas),
        f"{'method':20s} {'MPJPE mm':>26s} {'rel. mm':>26s} {'accel m/s^2':>26s} {'s/frame':>12s}",
    ]
    for m in methods:
        sub = {r[key]: r for r in rows if r["method"] == m}
        cols = [" ".join(f"{sub[s][c]:8.1f}" for s in sigmas) for c in ("mpjpe_mm", "mpjpe_rel_mm", "accel_ms2")]
        spf = [sub[s]["seconds_per_frame"] for s in sigmas if sub[s]["seconds_per_frame"] is not None]
        lines.append(
            f"{m:20s} {cols[0]:>26s} {cols[1]:>26s} {cols[2]:>26s} "
            f"{(f'{sum(spf) / len(spf):.2e}' if spf else '-'):>12s}"
        )
    return "\n".join(lines)
