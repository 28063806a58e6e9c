"""The one way a LightningModule puts a window figure into TensorBoard during validation."""

from __future__ import annotations

import lightning as L
import torch


def log_validation_figure(
    module: L.LightningModule,
    tag: str,
    truth: torch.Tensor,
    given: torch.Tensor,
    observed: torch.Tensor | None,
    output: torch.Tensor,
    fps: float,
    title: str,
) -> None:
    """truth, given, output: (T, J, 3); observed: (T, J) bool or None (all given).
    Logs every `figure_every_n_val`-th call (a module hyperparameter), when the logger can draw figures."""
    n_val = getattr(module, "_n_val", 0)
    module._n_val = n_val + 1
    experiment = getattr(module.logger, "experiment", None)
    if not hasattr(experiment, "add_figure") or n_val % max(1, module.hparams.figure_every_n_val):
        return
    from mocapfix.viz import window_figure

    def to_numpy(t):
        return t.detach().float().cpu().numpy()

    seen = to_numpy(observed) > 0 if observed is not None else ~torch.isnan(given[..., 0]).cpu().numpy()
    fig = window_figure(
        to_numpy(truth), to_numpy(given), seen, to_numpy(output), module.skeleton.limbs, fps, title=title
    )
    experiment.add_figure(tag, fig, module.global_step)
