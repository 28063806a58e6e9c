"""Experiment tracking: each fit's hyperparameters beside its results, so that runs can be
compared and sorted (TensorBoard's HPARAMS tab: `tensorboard --logdir logs/<experiment>`).

- `run_hparams`: a fit's settings as one flat dict of plain values, named as on the command line:
  `model` (the LightningModule's class), `model.<setting>` (its constructor's settings; XMAE's
  network sizes as its preset resolves them), `data.<setting>` (the data module's), `trainer.*`
  (max_steps, precision, ...) and `seed`. Lists become one string ("0.9, 0.999"); the skeleton
  (the data's, not a setting) and the data loading knobs (workers, cache) are left out.
- `RunSummary`, a callback: the hparams session at the start of a fit (TensorBoard loggers), then
  after each validation the run's results as scalars, under hparams/ (every logger):
    hparams/best_val_mpjpe_mm  the lowest val/mpjpe_mm so far
    hparams/best_val_loss      the lowest val/loss so far
    hparams/val_vs_spline      val/gap_vs_spline at the validation of the lowest val/mpjpe_mm: the
                               model's MPJPE on the validation's gap over the cubic spline's on the
                               same holes (XMAE; below 1 the model beats the spline)
  Nothing is written before the first validation: no placeholder value (Lightning's hp_metric = -1
  is off, make_logger), so every point of these cards is a measurement. The best values travel in
  checkpoints: a resumed fit goes on from them.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping
from typing import Any

import lightning as L
from lightning.pytorch.loggers import TensorBoardLogger

# the scalars RunSummary logs: name -> (what it follows, how)
METRICS = {
    "hparams/best_val_mpjpe_mm": "val/mpjpe_mm",
    "hparams/best_val_loss": "val/loss",
    "hparams/val_vs_spline": "val/gap_vs_spline",
}
# settings that change how fast data arrives, not what a run learns
NOT_HYPERPARAMETERS = {"num_workers", "pin_memory", "persistent_workers", "batches_on_device", "cache_dir", "skeleton"}


def _plain(prefix: str, value: Any, out: dict) -> None:
    """value -> out[prefix...]: numbers, strings, booleans and None as they are, lists of those as
    one string, mappings flattened with dots; anything else left out."""
    if isinstance(value, Mapping):
        for k, v in value.items():
            if not str(k).startswith("_") and k not in NOT_HYPERPARAMETERS:
                _plain(f"{prefix}.{k}", v, out)
    elif value is None or isinstance(value, (bool, int, float, str)):
        out[prefix] = value
    elif isinstance(value, (list, tuple)) and all(isinstance(v, (bool, int, float, str)) for v in value):
        out[prefix] = ", ".join(str(v) for v in value)


def run_hparams(trainer: L.Trainer, module: L.LightningModule, seed: int | None = None) -> dict[str, Any]:
    """The fit's settings, flat (see the module's docstring)."""
    out: dict[str, Any] = {"model": type(module).__name__}
    tracked = getattr(module, "tracked_hparams", None)
    _plain("model", tracked() if callable(tracked) else dict(module.hparams), out)
    datamodule = getattr(trainer, "datamodule", None)
    if datamodule is not None:
        _plain("data", dict(datamodule.hparams), out)
    _plain(
        "trainer",
        {
            "max_steps": trainer.max_steps,
            "max_epochs": trainer.max_epochs if (trainer.max_epochs or 0) >= 0 else None,  # -1: no limit
            "precision": str(trainer.precision),
            "accumulate_grad_batches": trainer.accumulate_grad_batches,
            "gradient_clip_val": trainer.gradient_clip_val,
            "val_check_interval": trainer.val_check_interval,
            "world_size": trainer.world_size,
        },
        out,
    )
    out["seed"] = seed
    return out


def hparams_summaries(params: Mapping[str, Any], status: str | None = None) -> list:
    """TensorBoard's hparams plugin records (Summary protos) for one run: the session's start (its
    settings), or with `status` ("STATUS_SUCCESS", "STATUS_FAILURE": api_pb2.Status) its end.

    No experiment record (torch.utils.tensorboard.summary.hparams and Lightning's log_hyperparams
    write one): without it TensorBoard builds the experiment from the runs' sessions, lists first
    the settings that differ between the runs in view (its table shows five at a time), and takes
    the metrics from the runs' scalars (hparams/* among them) rather than a -1 placeholder."""
    from tensorboard.compat.proto.summary_pb2 import Summary, SummaryMetadata
    from tensorboard.plugins.hparams import api_pb2, metadata, plugin_data_pb2

    def summary(tag: str, **data) -> Summary:
        content = plugin_data_pb2.HParamsPluginData(version=metadata.PLUGIN_DATA_VERSION, **data)
        plugin = SummaryMetadata.PluginData(plugin_name=metadata.PLUGIN_NAME, content=content.SerializeToString())
        return Summary(value=[Summary.Value(tag=tag, metadata=SummaryMetadata(plugin_data=plugin))])

    if status is not None:
        end = plugin_data_pb2.SessionEndInfo(status=api_pb2.Status.Value(status), end_time_secs=time.time())
        return [summary(metadata.SESSION_END_INFO_TAG, session_end_info=end)]
    start = plugin_data_pb2.SessionStartInfo(start_time_secs=time.time())
    for name, value in params.items():
        if isinstance(value, bool):  # before int: a bool is one
            start.hparams[name].bool_value = value
        elif isinstance(value, (int, float)):
            start.hparams[name].number_value = value
        elif isinstance(value, str):
            start.hparams[name].string_value = value
    return [summary(metadata.SESSION_START_INFO_TAG, session_start_info=start)]


class StepsTensorBoardLogger(TensorBoardLogger):
    """TensorBoard without Lightning's "epoch" card, the first one a user met: these schedules
    count steps (validation every N steps), and epochs of windows compare nothing between runs."""

    def log_metrics(self, metrics: Mapping[str, float], step: int | None = None) -> None:
        super().log_metrics({k: v for k, v in metrics.items() if k != "epoch"}, step)


def _tensorboard_writers(trainer: L.Trainer) -> list:
    return [lg.experiment._get_file_writer() for lg in trainer.loggers if isinstance(lg, TensorBoardLogger)]


class RunSummary(L.Callback):
    """The run's hyperparameters (TensorBoard's hparams session) and its best validation results
    (hparams/ scalars, every logger); see the module's docstring."""

    def __init__(self, seed: int | None = None):
        self.seed = seed
        self.best: dict[str, float] = {}

    # only a fit's: validate, test and predict runs keep the state a checkpoint brings, and log nothing

    def on_fit_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if not trainer.is_global_zero:
            return
        params = run_hparams(trainer, pl_module, self.seed)
        for writer in _tensorboard_writers(trainer):
            for s in hparams_summaries(params):
                writer.add_summary(s)

    def _end(self, trainer: L.Trainer, status: str) -> None:
        if trainer.is_global_zero and trainer.state.fn == "fit":
            for writer in _tensorboard_writers(trainer):
                writer.add_summary(hparams_summaries({}, status)[0])
                writer.flush()

    def on_fit_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self._end(trainer, "STATUS_SUCCESS")

    def on_exception(self, trainer: L.Trainer, pl_module: L.LightningModule, exception: BaseException) -> None:
        from lightning.pytorch.utilities.exceptions import SIGTERMException

        # A run stopped on purpose (Ctrl-C, SIGTERM) ends without a status: it has not failed,
        # and its last.ckpt resumes it (TensorBoard's statuses have nothing between).
        if not isinstance(exception, (KeyboardInterrupt, SIGTERMException)):
            self._end(trainer, "STATUS_FAILURE")

    def on_validation_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        # after the epoch's metrics are in callback_metrics (on_validation_epoch_end comes before)
        if trainer.sanity_checking or trainer.state.fn != "fit":
            return
        seen = {k: float(v) for k, v in trainer.callback_metrics.items() if k in METRICS.values()}
        seen = {k: v for k, v in seen.items() if math.isfinite(v)}
        mpjpe = seen.get("val/mpjpe_mm")
        if mpjpe is not None and mpjpe < self.best.get("hparams/best_val_mpjpe_mm", math.inf):
            self.best["hparams/best_val_mpjpe_mm"] = mpjpe
            if "val/gap_vs_spline" in seen:
                self.best["hparams/val_vs_spline"] = seen["val/gap_vs_spline"]
        loss = seen.get("val/loss")
        if loss is not None and loss < self.best.get("hparams/best_val_loss", math.inf):
            self.best["hparams/best_val_loss"] = loss
        if self.best:
            for logger in trainer.loggers:
                logger.log_metrics(dict(self.best), step=trainer.global_step)

    def state_dict(self) -> dict:
        return {"best": dict(self.best)}

    def load_state_dict(self, state_dict: dict) -> None:
        self.best = dict(state_dict.get("best", {}))
