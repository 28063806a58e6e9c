"""BindData: the data module's DataSpec handed to the LightningModule before its setup.

Lightning runs the data module's setup, then the callbacks', then the module's: in between, this
callback calls module.bind_data(spec, stage), where the module builds its network for the data's
skeleton and window (or checks that a loaded one fits). The modules return it from
configure_callbacks(), so any Trainer (the CLI's, a test's, a script's) binds the data the same way.
"""

from __future__ import annotations

import lightning as L
from lightning.pytorch.callbacks import Callback


class BindData(Callback):
    def setup(self, trainer: L.Trainer, pl_module: L.LightningModule, stage: str) -> None:
        dm = trainer.datamodule
        if dm is not None and hasattr(dm, "spec"):
            pl_module.bind_data(dm.spec(), stage)
