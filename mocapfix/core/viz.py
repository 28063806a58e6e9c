"""Matplotlib figures for TensorBoard: what a model did to a few windows, and a test table's
error against gap length."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")  # no display: figures go to TensorBoard or files
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

VIEWS = {"front": (0, 2), "side": (1, 2)}  # (horizontal, vertical) axes of z-up positions
ONION = (0.25, 0.5, 0.75)  # where in the window the drawn frames are; the last is solid


def window_figure(
    truth: np.ndarray,
    given: np.ndarray,
    observed: np.ndarray,
    output: np.ndarray,
    limbs,
    title: str = "",
):
    """truth, given, output: (N, T, J, 3) metres, z up; observed: (N, T, J) bool (one window may
    come as (T, J, 3) / (T, J)). Rows: ground truth / input (missing joints left out, displaced
    ones drawn where given) / output over the truth in grey. Columns: each window from the front
    (x, z) and the side (y, z), three frames across it, the earlier ones faint."""
    truth, given, output = (np.asarray(a, dtype=np.float64) for a in (truth, given, output))
    observed = np.asarray(observed, dtype=bool)
    if truth.ndim == 3:
        truth, given, observed, output = truth[None], given[None], observed[None], output[None]
    N, T = truth.shape[:2]
    frames = [min(T - 1, int(round(f * (T - 1)))) for f in ONION]
    fig, axes = plt.subplots(3, 2 * N, figsize=(2.0 * 2 * N, 6.0), squeeze=False)
    rows = (
        ("ground truth", truth, None, "k"),
        ("input", given, observed, "tab:orange"),
        ("output", output, None, "tab:green"),
    )
    for n in range(N):
        z = truth[n, ..., 2]
        zlim = (np.nanmin(z) - 0.1, np.nanmax(z) + 0.1)
        for v, (view, (h, vert)) in enumerate(VIEWS.items()):
            col = 2 * n + v
            centre = np.nanmean(truth[n, frames[-1], :, h])
            for r, (label, pos, obs, colour) in enumerate(rows):
                ax = axes[r, col]
                for k, t in enumerate(frames):
                    alpha = (k + 1) / len(frames)
                    p = pos[n, t]
                    if r == 2:  # the truth under the output, to see the error
                        q = truth[n, t]
                        for a, b in limbs:
                            ax.plot([q[a, h], q[b, h]], [q[a, vert], q[b, vert]], "-", color="0.85", lw=1, zorder=0)
                    for a, b in limbs:
                        if obs is not None and not (obs[n, t, a] and obs[n, t, b]):
                            continue
                        ax.plot([p[a, h], p[b, h]], [p[a, vert], p[b, vert]], "-", color=colour, lw=1.2, alpha=alpha)
                    shown = np.ones(p.shape[0], bool) if obs is None else obs[n, t]
                    ax.plot(p[shown, h], p[shown, vert], ".", color="tab:blue", ms=2, alpha=alpha)
                ax.set_xlim(centre - 1.0, centre + 1.0)
                ax.set_ylim(*zlim)
                ax.set_aspect("equal")
                ax.set_xticks([])
                ax.set_yticks([])
                if r == 0:
                    ax.set_title(f"window {n + 1}, {view}", fontsize=8)
                if col == 0:
                    ax.set_ylabel(label, fontsize=8)
    if title:
        fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    return fig


def gap_error_figure(rows: list[dict], title: str = ""):
    """A test table's infill rows (evaluation/tasks.py table_rows: task "infill", part, gap_s,
    method, mpjpe_mm) as MPJPE against gap length, one panel per body part, one line per method."""
    infill = [r for r in rows if r.get("task") == "infill" and "gap_s" in r]
    parts = sorted({r["part"] for r in infill}, key=lambda p: (p != "full", p))
    fig, axes = plt.subplots(1, max(1, len(parts)), figsize=(3.2 * max(1, len(parts)), 3.0), squeeze=False)
    for ax, part in zip(axes[0], parts):
        for method in sorted({r["method"] for r in infill if r["part"] == part}):
            pts = sorted((r["gap_s"], r["mpjpe_mm"]) for r in infill if r["part"] == part and r["method"] == method)
            ax.plot(*zip(*pts), "o-", ms=3, lw=1.2, label=method)
        ax.set_title(part, fontsize=9)
        ax.set_xlabel("gap (s)", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3)
    axes[0, 0].set_ylabel("MPJPE (mm)", fontsize=8)
    axes[0, 0].legend(fontsize=6)
    if title:
        fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    return fig
