"""The end of every LightningModule's `test`: the table's scalars logged, the table printed,
eval.json written in the run's log folder, and the table as text and a plot in TensorBoard."""

from __future__ import annotations

from pathlib import Path

import lightning as L

from mocapfix.evaluation.tasks import write_eval_json
from mocapfix.training.figures import log_test_figures


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
    log_test_figures(module, rows, text)
    logger = module.logger
    log_dir = Path(logger.log_dir if logger is not None and logger.log_dir else module.trainer.default_root_dir)
    return write_eval_json(log_dir / "eval.json", rows)
