"""`mocapfix render` and `fix --render`: files that read back with the length and size asked, and
the filled tokens' colour in exactly the frames where tokens were filled."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
import torch
from PIL import Image

from mocapfix.apps.main import main
from mocapfix.core.render import FILLED
from mocapfix.io.positions import write_positions
from mocapfix.io.synthetic import generate_clips
from mocapfix.models.checkpoint import xmae_checkpoint
from mocapfix.models.xmae import XMAE

PANEL_PX = (384, 424)  # two recordings x two views at 2.4 in and 80 dpi, plus the time bar
HOLE_FRAMES = range(10, 20)


def _has(image: np.ndarray, rgb, tol: int = 40, pixels: int = 3) -> bool:
    """Whether at least `pixels` pixels of image (H, W, 3) are within tol of rgb (a GIF's palette
    may move a colour a little; antialiased edges are mixtures, the markers' cores are not)."""
    return int((np.abs(image[..., :3].astype(int) - np.array(rgb)).max(-1) <= tol).sum()) >= pixels


@pytest.fixture()
def recording(tmp_path):
    """1 s at 30 fps: the input lacks the left wrist in frames 10-19; the "fixed" file has them back
    and one observed token (the pelvis at frame 25) moved by 10 cm."""
    clip = generate_clips(1, 1.0, fps=30, seed=3)[0]
    truth = clip.positions
    wrist = clip.skeleton.joint_names.index("left_wrist")
    given = truth.copy()
    given[HOLE_FRAMES, wrist] = np.nan
    fixed = truth.copy()
    fixed[25, 0] += 0.1
    write_positions(tmp_path / "in.npz", given, 30.0, clip.skeleton)
    write_positions(tmp_path / "out.npz", fixed, 30.0, clip.skeleton)
    return tmp_path, clip


def test_render_gif_frames_size_and_filled_colour(recording, capsys):
    d, _ = recording
    assert main(["render", str(d / "in.npz"), str(d / "out.npz"), "-o", str(d / "r.gif")]) == 0
    im = Image.open(d / "r.gif")
    assert im.n_frames == 30 and im.size == PANEL_PX
    green = []
    for k in range(im.n_frames):
        im.seek(k)
        green.append(_has(np.asarray(im.convert("RGB")), FILLED))
    assert [k for k, g in enumerate(green) if g] == list(HOLE_FRAMES)


def test_render_png_filmstrip_and_span(recording):
    d, _ = recording
    assert main(["render", str(d / "in.npz"), str(d / "out.npz"), "-o", str(d / "s.png")]) == 0
    strip = np.asarray(Image.open(d / "s.png").convert("RGB"))
    assert strip.shape[:2] == (2 * PANEL_PX[1], 4 * PANEL_PX[0])  # 8 frames, 4 to a row
    assert _has(strip, FILLED)  # frames 12 and 17 are among the 8
    # a span before the hole: no filled token drawn; fewer frames than 8 -> one row
    args = ["render", str(d / "in.npz"), str(d / "out.npz"), "-o", str(d / "early.png"), "--duration", "0.2"]
    assert main([*args, "--fps", "10"]) == 0
    early = np.asarray(Image.open(d / "early.png").convert("RGB"))
    assert early.shape[:2] == (PANEL_PX[1], 4 * PANEL_PX[0]) and not _has(early, FILLED)


def test_render_errors_are_one_line(recording, tmp_path, capsys):
    d, clip = recording
    write_positions(d / "short.npz", clip.positions[:20], 30.0, clip.skeleton)
    assert main(["render", str(d / "in.npz"), str(d / "short.npz"), "-o", str(d / "x.gif")]) == 1
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "20 frames" in err and "in.npz" in err
    assert main(["render", str(d / "in.npz"), "-o", str(d / "x.avi")]) == 1
    assert ".gif, .mp4 or .png" in capsys.readouterr().err
    assert main(["render", str(d / "in.npz"), "-o", str(d / "x.gif"), "--start", "5"]) == 1
    assert "past the recording's end" in capsys.readouterr().err
    if shutil.which("ffmpeg") is None:
        assert main(["render", str(d / "in.npz"), "-o", str(d / "x.mp4")]) == 1
        assert "ffmpeg" in capsys.readouterr().err


def test_fix_render_writes_a_gif_beside_the_output(recording):
    d, clip = recording
    torch.manual_seed(0)
    sizes = dict(enc_dim=32, enc_depth=1, enc_mlp_dim=64, dec_dim=32, dec_depth=1, dec_mlp_dim=64, head_dim=16)
    net = XMAE(clip.skeleton.num_joints, 30, **sizes)
    torch.save(xmae_checkpoint(net, clip.skeleton, 30.0), d / "m.ckpt")
    assert main(["fix", str(d / "in.npz"), "--ckpt", str(d / "m.ckpt"), "--render"]) == 0
    im = Image.open(d / "in.fixed.gif")
    assert im.n_frames == 30 and im.size == PANEL_PX
    # the joints x time map: green (filled) only in the fixed row, at the left wrist's hole
    holes = np.asarray(Image.open(d / "in.fixed.holes.png").convert("RGB"))
    top, bottom = holes[: len(holes) // 2], holes[len(holes) // 2 :]
    assert _has(bottom, FILLED, pixels=20) and not _has(top, FILLED)


def test_a_long_file_name_fits_its_panel_with_its_start_and_end():
    from mocapfix.core.render import TITLE_CHARACTERS, _fitted

    assert _fitted("take.npz") == "take.npz"
    long = "dataset-2_walk_elderly_002_broken.npz"
    short = _fitted(long)
    assert len(short) == TITLE_CHARACTERS and short.startswith("dataset-2_walk") and short.endswith("_broken.npz")
