"""Motion-DVAE's denoising test table (the paper's Table 1): for each noise level, each method's
MPJPE, root-relative MPJPE, joint acceleration and seconds per frame, under the ground truth's
acceleration. The module decides what to predict and times it; this keeps the cells."""

from __future__ import annotations

import torch
import torch.nn as nn

from mocapfix.evaluation.harness import TestTable
from mocapfix.evaluation.metrics import MPJPE, JointAcceleration

METHODS = ("noisy", "dvae_regression", "dvae_optimisation")
# the classical baseline: Gaussian smoothing in time at a few widths (frames); the table keeps
# each, and the best one per noise level is the bar the model has to clear
SMOOTH_FRAMES = (1.0, 2.0, 4.0)
SMOOTHERS = tuple(f"smooth{s:g}f" for s in SMOOTH_FRAMES)


class DenoiseTable(nn.Module):
    """Cells per (noise level i, method, "abs" | "rel" | "acc"), synced across processes by
    TestTable; seconds and frames per noise level for the seconds-per-frame column."""

    def __init__(self, sigmas: list[float], fps: float, methods: tuple[str, ...] = METHODS + SMOOTHERS):
        super().__init__()
        self.sigmas, self.methods = [float(s) for s in sigmas], methods
        cells = {
            (i, m, k): JointAcceleration(fps) if k == "acc" else MPJPE(root_relative=k == "rel")
            for i in range(len(self.sigmas))
            for m in methods
            for k in ("abs", "rel", "acc")
        }
        self.table = TestTable({**cells, "truth_acc": JointAcceleration(fps)})
        self.seconds = {(i, m): 0.0 for i in range(len(self.sigmas)) for m in methods}
        self.frames = {i: 0 for i in range(len(self.sigmas))}

    def update_truth(self, truth: torch.Tensor) -> None:
        # truth: (B, T, J, 3) clean windows, once per batch
        self.table.update("truth_acc", truth)

    def update(
        self, i: int, method: str, pred: torch.Tensor, truth: torch.Tensor, seconds: float | None = None
    ) -> None:
        # pred, truth: (B, T, J, 3) at noise level i; seconds: the time the method took on them
        pred = pred.float()
        self.table.update((i, method, "abs"), pred, truth)
        self.table.update((i, method, "rel"), pred, truth)
        self.table.update((i, method, "acc"), pred)
        if seconds is not None:
            self.seconds[(i, method)] += seconds
        if method == self.methods[0]:
            self.frames[i] += truth.shape[0] * truth.shape[1]

    def rows(self, key: str) -> tuple[list[dict], dict[str, float]] | None:
        """(rows for eval.json, scalars to log) with key "sigma_m" or "sigma_rad" naming the noise
        level; None if no window was scored."""
        cells = self.table.compute()
        if "truth_acc" not in cells:
            return None
        rows, scalars = [], {}
        for i, sigma in enumerate(self.sigmas):
            base = {"task": "noise", "part": "full", key: sigma}
            rows.append(
                {
                    **base,
                    "method": "ground_truth",
                    "mpjpe_mm": 0.0,
                    "mpjpe_rel_mm": 0.0,
                    "accel_ms2": round(cells["truth_acc"], 2),
                    "seconds_per_frame": None,
                }
            )
            for m in self.methods:
                timed = self.seconds[(i, m)] > 0
                spf = self.seconds[(i, m)] / max(1, self.frames[i]) if timed else None
                rows.append(
                    {
                        **base,
                        "method": m,
                        "mpjpe_mm": round(cells[(i, m, "abs")], 2),
                        "mpjpe_rel_mm": round(cells[(i, m, "rel")], 2),
                        "accel_ms2": round(cells[(i, m, "acc")], 2),
                        "seconds_per_frame": None if spf is None else float(f"{spf:.3g}"),
                    }
                )
                scalars[f"test/{key}{sigma}/{m}_mpjpe_mm"] = rows[-1]["mpjpe_mm"]
        return rows, scalars


def format_denoise_table(
    rows: list[dict], key: str, methods: tuple[str, ...] = ("ground_truth", *METHODS, *SMOOTHERS)
) -> str:
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
