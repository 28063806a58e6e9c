"""Recordings drawn side by side, to judge by eye what `fix` did: an animation (GIF, or MP4 where
ffmpeg is on the PATH) or a filmstrip PNG.

One column per recording (the input first, then fixed versions of it), one row per view: front
(x right, z up) and side (y right, z up), each centred on the body at every frame, so depth
errors that a single view hides show in the other. In a fixed recording a token that was
missing in the input and has a value now is drawn in FILLED's colour, an observed token that
was changed in REPLACED's; the input's missing joints are left out. A time bar under the views
marks the frames where the input has a hole and where a token was replaced, with a cursor.
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # no display: files only
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib import animation  # noqa: E402
from matplotlib.collections import LineCollection  # noqa: E402

from mocapfix.core.clip import Clip  # noqa: E402

# Colours that survive a GIF's palette and read apart: RGB 0-255.
BONE, OBSERVED = (70, 70, 70), (31, 119, 180)
FILLED, REPLACED = (0, 200, 0), (255, 140, 0)
HOLE_BAR = (220, 40, 40)
VIEWS = {"front": (0, 2), "side": (1, 2)}  # (horizontal, vertical) axes of z-up positions
HALF_WIDTH_M = 0.9  # the panel shows the body's centre +- this, horizontally
STRIP_COLUMNS = 4  # a filmstrip's frames per row
TITLE_CHARACTERS = 34  # what a panel's width holds at its title's font size


def _rgb(c: tuple[int, int, int]) -> tuple[float, float, float]:
    return tuple(v / 255 for v in c)


@dataclass
class Track:
    """One recording as drawn: positions (T, J, 3) metres z up on the input's frames, and per
    token whether it was filled or replaced against the input (both False for the input)."""

    name: str
    positions: np.ndarray
    filled: np.ndarray  # (T, J) bool
    replaced: np.ndarray  # (T, J) bool


def tracks_for(input_clip: Clip, fixed: list[tuple[str, Clip]]) -> list[Track]:
    """The input and its fixed versions, on the input's joints (matched by name) and frames.
    A fixed recording must have the input's frame count and fps (what fix writes)."""
    x = input_clip.positions
    seen = np.isfinite(x).all(-1)  # (T, J)
    none = np.zeros_like(seen)
    tracks = [Track(input_clip.name or "input", x, none, none)]
    names = input_clip.skeleton.joint_names
    for label, c in fixed:
        if c.num_frames != input_clip.num_frames or abs(c.fps - input_clip.fps) > 1e-6:
            raise ValueError(
                f"{label}: {c.num_frames} frames at {c.fps:g} fps, the input has {input_clip.num_frames} at "
                f"{input_clip.fps:g}: render compares a recording with fix's output of it"
            )
        index = {n: j for j, n in enumerate(c.skeleton.joint_names)}
        y = np.full_like(x, np.nan)
        for j, n in enumerate(names):
            if n in index:
                y[:, j] = c.positions[:, index[n]]
        has = np.isfinite(y).all(-1)
        changed = seen & has & (np.abs(y - x).max(-1, initial=0.0) > 1e-6)
        tracks.append(Track(label, y, ~seen & has, changed))
    return tracks


def _span(num_frames: int, fps: float, start_s: float, duration_s: float | None, out_fps: float) -> np.ndarray:
    """The input frames drawn: from start_s for duration_s (to the end if None), at out_fps."""
    end = num_frames / fps if duration_s is None else min(start_s + duration_s, num_frames / fps)  # never past it
    t = np.arange(start_s, end, 1.0 / out_fps)
    frames = np.unique(np.round(t * fps).astype(np.int64))
    frames = frames[(frames >= 0) & (frames < num_frames)]
    if len(frames) == 0:
        raise ValueError(f"--start {start_s:g} s is past the recording's end ({num_frames / fps:.2f} s)")
    return frames


def _fitted(name: str, most: int = TITLE_CHARACTERS) -> str:
    """A panel's title within its width: a long file name keeps its start and its end."""
    if len(name) <= most:
        return name
    tail = (most - 1) // 2
    return name[: most - 1 - tail] + "…" + name[-tail:]


class _Scene:
    """The figure and its artists, redrawn per frame (set_frame)."""

    def __init__(self, tracks: list[Track], limbs, fps: float, frames: np.ndarray, panel_in: float = 2.4):
        self.tracks, self.limbs, self.fps, self.frames = tracks, list(limbs), fps, frames
        cols, rows = len(tracks), len(VIEWS)
        self.fig = plt.figure(figsize=(panel_in * cols, panel_in * rows + 0.5), dpi=80)
        grid = self.fig.add_gridspec(rows + 1, cols, height_ratios=[panel_in] * rows + [0.35])
        # the heights shown: the input's; where the input has none (every token missing), a fixed one's
        heights = next((z[np.isfinite(z)] for z in (t.positions[..., 2] for t in tracks) if np.isfinite(z).any()), None)
        if heights is None:  # render() draws nothing then; a scene by itself gets a unit's room
            heights = np.zeros(1)
        self.zmin, self.zmax = heights.min() - 0.05, heights.max() + 0.15
        self.axes, self.bones, self.points = [], [], []
        for r, view in enumerate(VIEWS):
            for c, tr in enumerate(tracks):
                ax = self.fig.add_subplot(grid[r, c])
                ax.set_aspect("equal")
                ax.set_xticks([])
                ax.set_yticks([])
                if r == 0:
                    ax.set_title(_fitted(tr.name), fontsize=8)
                if c == 0:
                    ax.set_ylabel(view, fontsize=8)
                self.axes.append((ax, view, tr))
                self.bones.append(ax.add_collection(LineCollection([], colors=[_rgb(BONE)], linewidths=1.5)))
                # observed, filled, replaced: markers without antialiasing keep their exact colour
                self.points.append(
                    [
                        ax.plot([], [], "o", color=_rgb(col), ms=4, mew=0, antialiased=False, zorder=3)[0]
                        for col in (OBSERVED, FILLED, REPLACED)
                    ]
                )
        self.bar = self.fig.add_subplot(grid[rows, :])
        self._draw_bar()

    def _draw_bar(self) -> None:
        """Holes in the input (any joint missing) and replaced tokens along the drawn span."""
        t = self.frames / self.fps
        holes = ~np.isfinite(self.tracks[0].positions[self.frames]).all(-1).all(-1)  # (F,)
        replaced = np.zeros(len(self.frames), dtype=bool)
        for tr in self.tracks[1:]:
            replaced |= tr.replaced[self.frames].any(-1)
        step = 1.0 / self.fps
        for mask, colour, y in ((holes, HOLE_BAR, 0.5), (replaced, REPLACED, 0.0)):
            for ti in t[mask]:
                self.bar.axvspan(ti, ti + step, ymin=y, ymax=y + 0.5, color=_rgb(colour), lw=0)
        self.bar.set_xlim(t[0], t[-1] + step)
        self.bar.set_ylim(0, 1)
        self.bar.set_yticks([])
        self.bar.tick_params(labelsize=6)
        self.bar.set_xlabel("s (red: input holes, orange: replaced)", fontsize=7)
        self.cursor = self.bar.axvline(t[0], color="k", lw=1)

    def set_frame(self, f: int) -> list:
        # the body's centre: the input's, else (a frame with every joint missing) the first fixed one's
        have = [tr.positions[f][np.isfinite(tr.positions[f]).all(-1)] for tr in self.tracks]
        centre = next((p.mean(0) for p in have if len(p)), np.zeros(3))
        limbs = np.array(self.limbs).reshape(-1, 2)
        for (ax, view, tr), bones, points in zip(self.axes, self.bones, self.points):
            h, v = VIEWS[view]
            p = tr.positions[f]
            ends = p[limbs][..., [h, v]]  # (L, 2 ends, 2)
            bones.set_segments(ends[np.isfinite(ends).all((1, 2))])
            has = np.isfinite(p).all(-1)
            kinds = (has & ~tr.filled[f] & ~tr.replaced[f], has & tr.filled[f], has & tr.replaced[f])
            for mask, artist in zip(kinds, points):
                artist.set_data(p[mask, h], p[mask, v])
            ax.set_xlim(centre[h] - HALF_WIDTH_M, centre[h] + HALF_WIDTH_M)
            ax.set_ylim(self.zmin, self.zmax)
        self.cursor.set_xdata([f / self.fps, f / self.fps])
        return [*self.bones, *(a for group in self.points for a in group), self.cursor]


def render(
    tracks: list[Track],
    limbs,
    fps: float,
    out: Path,
    start_s: float = 0.0,
    duration_s: float | None = None,
    out_fps: float | None = None,
    strip_frames: int = 8,
    write_to: Path | None = None,
) -> Path:
    """Draw tracks (tracks_for) to out: .gif (Pillow), .mp4 (ffmpeg, which must be on the PATH) or
    .png (a filmstrip: strip_frames frames across the span, one column each, recordings and
    views as rows). out_fps: the animation's frame rate (default: the recording's, at most 30).
    write_to: the file actually written, with out's extension (a temporary file beside out that
    the caller moves into place: io/files.py staged); messages name out."""
    out = Path(out)
    written = Path(write_to) if write_to is not None else out
    suffix = out.suffix.lower()
    if suffix not in (".gif", ".mp4", ".png"):
        raise ValueError(f"{out}: render writes .gif, .mp4 or .png")
    if suffix == ".mp4" and shutil.which("ffmpeg") is None:
        raise ValueError(f"{out}: .mp4 needs ffmpeg on the PATH (not found); write a .gif instead")
    out_fps = float(out_fps or min(fps, 30.0))
    frames = _span(len(tracks[0].positions), fps, start_s, duration_s, out_fps)
    if not any(np.isfinite(t.positions[frames]).any() for t in tracks):
        raise ValueError("no joint is observed in any frame drawn: nothing to draw")
    written.parent.mkdir(parents=True, exist_ok=True)
    if suffix == ".png":
        _filmstrip(tracks, limbs, fps, frames, written, strip_frames)
        return out
    scene = _Scene(tracks, limbs, fps, frames)
    scene.fig.tight_layout()
    writer = animation.PillowWriter(fps=out_fps) if suffix == ".gif" else animation.FFMpegWriter(fps=out_fps)
    try:
        with writer.saving(scene.fig, str(written), dpi=scene.fig.dpi):
            for f in frames:
                scene.set_frame(int(f))
                writer.grab_frame()
    finally:  # a failed write (a full disk) must not leave the figure open either
        plt.close(scene.fig)
    return out


def _filmstrip(tracks: list[Track], limbs, fps: float, frames: np.ndarray, out: Path, n: int) -> Path:
    """One image: the scene at n frames across the span, STRIP_COLUMNS scenes to a row."""
    picks = frames[np.unique(np.linspace(0, len(frames) - 1, min(n, len(frames))).round().astype(int))]
    scene, images = _Scene(tracks, limbs, fps, frames), []
    title = scene.fig.suptitle(" ", fontsize=8)  # laid out with a title, then its text per frame
    scene.fig.tight_layout()
    for f in picks:
        scene.set_frame(int(f))
        title.set_text(f"t = {f / fps:.2f} s")
        scene.fig.canvas.draw()
        images.append(np.array(scene.fig.canvas.buffer_rgba())[..., :3])  # a copy: the buffer is reused
    plt.close(scene.fig)
    blank = np.full_like(images[0], 255)
    images += [blank] * (-len(images) % STRIP_COLUMNS)
    rows = [np.concatenate(images[i : i + STRIP_COLUMNS], axis=1) for i in range(0, len(images), STRIP_COLUMNS)]
    plt.imsave(out, np.concatenate(rows, axis=0), format="png")
    return out


def holes_map(tracks: list[Track], joint_names, fps: float, out: Path, write_to: Path | None = None) -> Path:
    """A PNG of which joints were missing when: one row of joints x time per recording (the input,
    then each fixed one), missing tokens dark; in a fixed recording filled tokens in FILLED's
    colour and replaced ones in REPLACED's, so a glance says what fix did to which joint when.
    write_to: the file actually written (a temporary file beside out, see render)."""
    T, J = tracks[0].positions.shape[:2]
    fig, axes = plt.subplots(len(tracks), 1, figsize=(8, 0.5 + 0.12 * J * len(tracks)), squeeze=False, dpi=80)
    for ax, tr in zip(axes[:, 0], tracks):
        image = np.ones((J, T, 3))
        image[~np.isfinite(tr.positions).all(-1).T] = 0.2
        image[tr.filled.T] = _rgb(FILLED)
        image[tr.replaced.T] = _rgb(REPLACED)
        ax.imshow(image, aspect="auto", interpolation="nearest", extent=(0, T / fps, J - 0.5, -0.5))
        ax.set_yticks(range(J))
        ax.set_yticklabels(joint_names, fontsize=5)
        ax.set_title(f"{tr.name}: missing (dark), filled (green), replaced (orange)", fontsize=8)
        ax.tick_params(axis="x", labelsize=6)
    axes[-1, 0].set_xlabel("s", fontsize=7)
    fig.tight_layout()
    try:
        fig.savefig(write_to if write_to is not None else out, format="png")
    finally:
        plt.close(fig)
    return out
