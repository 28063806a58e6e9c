"""Matplotlib skeleton figures: a person sees what a model did to a window."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")  # no display: figures go to TensorBoard or files
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402


def window_figure(
    truth: np.ndarray,
    observed_input: np.ndarray,
    observed: np.ndarray,
    output: np.ndarray,
    limbs,
    fps: float,
    num_frames: int = 5,
    title: str = "",
):
    """truth, observed_input, output: (T, J, 3) metres; observed: (T, J) bool.
    Rows: ground truth / observed input (missing joints left out, displaced ones shown as given) /
    output. Columns: a few frames across the window, side view (x right, z up)."""
    T = truth.shape[0]
    observed = np.asarray(observed, dtype=bool)
    frames = np.linspace(0, T - 1, num_frames).round().astype(int)
    fig, axes = plt.subplots(3, num_frames, figsize=(2.2 * num_frames, 6.6), sharex="col", sharey=True)
    rows = (("ground truth", truth, None), ("observed input", observed_input, observed), ("output", output, None))
    zmin, zmax = np.nanmin(truth[..., 2]) - 0.1, np.nanmax(truth[..., 2]) + 0.1
    for r, (label, pos, obs) in enumerate(rows):
        for c, t in enumerate(frames):
            ax = axes[r, c]
            p = pos[t]
            cx = np.nanmean(truth[t, :, 0])
            for a, b in limbs:
                if obs is not None and not (obs[t, a] and obs[t, b]):
                    continue
                ax.plot([p[a, 0], p[b, 0]], [p[a, 2], p[b, 2]], "-", color=("k", "tab:orange", "tab:green")[r], lw=1.5)
            shown = np.ones(p.shape[0], bool) if obs is None else obs[t]
            ax.plot(p[shown, 0], p[shown, 2], ".", color="tab:red" if r == 1 else "tab:blue", ms=3)
            if r == 2:  # ground truth faint under the output, to see the error
                for a, b in limbs:
                    ax.plot(
                        [truth[t, a, 0], truth[t, b, 0]],
                        [truth[t, a, 2], truth[t, b, 2]],
                        "-",
                        color="0.8",
                        lw=1,
                        zorder=0,
                    )
            ax.set_xlim(cx - 1.0, cx + 1.0)
            ax.set_ylim(zmin, zmax)
            ax.set_aspect("equal")
            ax.tick_params(labelsize=6)
            if r == 0:
                ax.set_title(f"t = {t / fps:.2f} s", fontsize=8)
        axes[r, 0].set_ylabel(f"{label}\nz (m)", fontsize=8)
    if title:
        fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    return fig
