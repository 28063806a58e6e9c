"""BindData: the data module's DataSpec handed to the LightningModule before its setup.

Lightning runs the data module's setup, then the callbacks', then the module's: in between, this
callback calls module.bind_data(spec, stage), where the module builds its network for the data's
skeleton and window (or checks that a loaded one fits). The modules return it from
configure_callbacks(), so any Trainer (the CLI's, a test's, a script's) binds the data the same way.
BuiltFromData is that contract for a module whose network is built from the data alone.
"""

from __future__ import annotations

import lightning as L
from lightning.pytorch.callbacks import Callback

from mocapfix.core.skeleton import Skeleton
from mocapfix.data.spec import DataSpec


class BindData(Callback):
    def setup(self, trainer: L.Trainer, pl_module: L.LightningModule, stage: str) -> None:
        dm = trainer.datamodule
        if dm is not None and hasattr(dm, "spec"):
            pl_module.bind_data(dm.spec(), stage)


def require_same_window(hparams, data: DataSpec, built: str) -> None:
    """A network built for one skeleton and window (its hyperparameters: skeleton, window_fps,
    window_frames) must meet data of the same; else a ValueError that says both."""
    parents, frames, fps = tuple(hparams["skeleton"]["parents"]), hparams["window_frames"], hparams["window_fps"]
    if (tuple(data.skeleton.parents), data.window_frames) != (parents, frames) or abs(data.fps - fps) > 1e-6:
        raise ValueError(
            f"{built} {len(parents)} joints, {frames} frames at {fps} fps; the data gives "
            f"{data.skeleton.num_joints} joints, {data.window_frames} frames at {data.fps} fps"
        )


class BuiltFromData:
    """The binding of a LightningModule (mixed in before L.LightningModule) whose network is made
    by its _build() from the data's skeleton and window (hparams skeleton, window_fps,
    window_frames), or comes from a checkpoint (self.net set) and must fit the data; its skeleton
    is the one in its hyperparameters. (No class attribute `net` here: nn.Module keeps submodules
    where a class attribute would shadow them.)"""

    @property
    def skeleton(self) -> Skeleton:
        return Skeleton.from_dict(self.hparams.skeleton)

    def configure_callbacks(self):
        return [BindData()]

    def bind_data(self, data: DataSpec, stage: str) -> None:
        if self.net is None:
            self.hparams.update(skeleton=data.skeleton.to_dict(), window_fps=data.fps, window_frames=data.window_frames)
            self._build()
        else:
            require_same_window(self.hparams, data, "this model was built for")

    def setup(self, stage: str) -> None:
        if self.net is None:
            raise RuntimeError(
                f"{type(self).__name__} needs a data module (or a checkpoint) to know the skeleton and window"
            )
