"""The metric the best checkpoint is chosen by (`--monitor`) must be one the model logs."""

from __future__ import annotations

import lightning as L


class MonitorCheck(L.Callback):
    """Checks `monitor` against what the sanity-check validation logged, before any training:
    Lightning itself finds a misspelt name only at the end of the first validation (after
    val_check_interval steps), raises, and the run ends without a checkpoint."""

    def __init__(self, monitor: str):
        self.monitor = monitor

    def on_sanity_check_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        # only validation metrics exist by now (a training metric, train/loss, is not checked)
        logged = sorted(k for k in trainer.callback_metrics if k.startswith("val/"))
        if logged and self.monitor.startswith("val/") and self.monitor not in trainer.callback_metrics:
            raise ValueError(
                f"--monitor {self.monitor}: the model logs no such metric at validation; it logs {', '.join(logged)}"
            )
