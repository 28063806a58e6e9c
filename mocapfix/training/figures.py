"""The one way a LightningModule puts figures into its logger: the validation windows, and the
test table's error against gap length. Only where the logger draws figures (TensorBoard)."""

from __future__ import annotations

import lightning as L
import numpy as np
import torch

FIGURE_WINDOWS = 3  # windows in the validation figure


def _experiment(module: L.LightningModule):
    experiment = getattr(module.logger, "experiment", None)
    return experiment if hasattr(experiment, "add_figure") else None


def log_validation_figure(
    module: L.LightningModule,
    tag: str,
    truth: torch.Tensor,
    given: torch.Tensor,
    observed: torch.Tensor | None,
    output: torch.Tensor,
    title: str,
) -> None:
    """truth, given, output: (B, T, J, 3) the first validation batch's windows (the first
    FIGURE_WINDOWS drawn); observed: (B, T, J) bool or None (all given).
    Logs every `figure_every_n_val`-th call (a module hyperparameter)."""
    n_val = getattr(module, "_n_val", 0)
    module._n_val = n_val + 1
    experiment = _experiment(module)
    if experiment is None or n_val % max(1, module.hparams.figure_every_n_val):
        return
    from mocapfix.core.viz import window_figure

    def to_numpy(t):
        return t[:FIGURE_WINDOWS].detach().float().cpu().numpy()

    seen = to_numpy(observed) > 0 if observed is not None else ~np.isnan(to_numpy(given)[..., 0])
    fig = window_figure(to_numpy(truth), to_numpy(given), seen, to_numpy(output), module.skeleton.limbs, title=title)
    experiment.add_figure(tag, fig, module.global_step)


def log_test_figures(module: L.LightningModule, rows: list[dict], text: str | None) -> None:
    """The test table as text, and its infill rows as MPJPE against gap length (when it has any)."""
    experiment = _experiment(module)
    if experiment is None:
        return
    if text:
        experiment.add_text("test/table", "    " + text.replace("\n", "\n    "), module.global_step)  # markdown code
    if any(r.get("task") == "infill" for r in rows):
        from mocapfix.core.viz import gap_error_figure

        fig = gap_error_figure(rows, f"test: MPJPE by gap length, step {module.global_step}")
        experiment.add_figure("test/mpjpe_by_gap", fig, module.global_step)
