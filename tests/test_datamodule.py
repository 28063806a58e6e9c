"""MotionDataModule: splits by file, windows, cache, resampling, errors."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest
import torch

from mocapfix.core.clip import Clip, MotionFileError
from mocapfix.core.resample import resample_clip
from mocapfix.core.skeleton import preset
from mocapfix.data.datamodule import MotionDataModule
from mocapfix.data.windows import split_groups, split_of
from mocapfix.io.positions import write_positions
from mocapfix.io.synthetic import generate_clips


def _positions_folder(tmp_path, n_files=12, seconds=3.0, fps=60.0):
    skel = preset("h36m17")
    rng = np.random.default_rng(0)
    for i in range(n_files):
        T = int(seconds * fps)
        pos = np.cumsum(rng.normal(0, 0.01, (T, 17, 3)), axis=0).astype(np.float32) + 1.0
        pos[T // 2 : T // 2 + 5, 3] = np.nan  # a missing joint: data, not an error
        write_positions(tmp_path / f"take_{i:02d}.npz", pos, fps, skel)
    return tmp_path


def test_split_by_file_no_leak_and_deterministic(tmp_path):
    folder = _positions_folder(tmp_path)
    dm = MotionDataModule(
        source="positions",
        path=str(folder),
        fps=30,
        window_s=1.0,
        stride_s=0.25,
        val_fraction=0.25,
        test_fraction=0.25,
        cache_dir=None,
        batch_size=4,
    )
    dm.setup("fit")
    sources = {s: {c.source for c in dm.clips[s]} for s in ("train", "val", "test")}
    assert sources["train"] and sources["val"] and sources["test"]
    assert (
        not (sources["train"] & sources["val"])
        and not (sources["train"] & sources["test"])
        and not (sources["val"] & sources["test"])
    )
    # the same files land in the same splits on every run
    dm2 = MotionDataModule(
        source="positions", path=str(folder), fps=30, val_fraction=0.25, test_fraction=0.25, cache_dir=None
    )
    dm2.setup("fit")
    assert {s: {c.source for c in dm2.clips[s]} for s in sources} == sources
    batch = next(iter(dm.train_dataloader()))
    assert batch["positions"].shape == (4, 30, 17, 3)
    assert batch["positions"].dtype == torch.float32


def test_split_by_folder_keeps_each_performer_in_one_split(tmp_path):
    """Folders are performers (CMU's subject folders): val and test hold people training never
    saw, whole; a pattern still forces a file; too few folders for three splits is one line."""
    for person in ("p1", "p2", "p3", "p4", "p5"):
        (tmp_path / person).mkdir()
        _positions_folder(tmp_path / person, n_files=3)
    dm = MotionDataModule(
        source="positions",
        path=str(tmp_path),
        fps=30,
        val_fraction=0.2,
        test_fraction=0.2,
        split_by="folder",
        cache_dir=None,
        train_patterns=["*/p3/take_00.npz"],
    )
    dm.setup("fit")
    where = {}  # folder -> the splits its files went to
    for split, clips in dm.clips.items():
        for c in clips:
            if not c.source.endswith("p3/take_00.npz"):
                where.setdefault(Path(c.source).parent.name, set()).add(split)
    assert all(len(s) == 1 for s in where.values()), where
    assert sorted(s for v in where.values() for s in v) == ["test", "train", "train", "train", "val"]
    assert any(c.source.endswith("p3/take_00.npz") for c in dm.clips["train"])
    with pytest.raises(ValueError, match="2 folders cannot give"):
        split_groups(["a", "b"], 0.2, 0.2, 0)


def test_patterns_override_hash():
    assert split_of("/data/S9_walk.npz", 0.0, 0.0, 0, {"test": ["S9_*"]}) == "test"
    assert split_of("/data/S1_walk.npz", 0.0, 0.0, 0, {"test": ["S9_*"]}) == "train"
    assert split_of("/data/x.npz", 0.0, 1.0, 0) == "test"


def test_windows_cover_clip_and_keep_nan(tmp_path):
    folder = _positions_folder(tmp_path, n_files=2)
    dm = MotionDataModule(
        source="positions",
        path=str(folder),
        fps=60,
        window_s=1.0,
        stride_s=0.5,
        val_fraction=0.0,
        test_fraction=0.0,
        cache_dir=None,
    )
    dm.setup("fit")
    ds = dm.datasets["train"]
    # 3 s at 60 fps, 1 s windows every 0.5 s -> starts 0, 30, ..., 120: 5 per file
    assert len(ds) == 10
    w = ds.__getitems__([0, 1])["positions"]
    clip = dm.clips["train"][0]
    np.testing.assert_array_equal(w[1].numpy(), clip.positions[30:90])
    assert torch.isnan(ds.positions).any(), "missing joints must stay NaN (data), not be dropped or zeroed"


def test_cache_second_run_skips_parsing(tmp_path, monkeypatch):
    folder = _positions_folder(tmp_path / "data")
    kw = dict(source="positions", path=str(folder), fps=30, cache_dir=str(tmp_path / "cache"))
    dm = MotionDataModule(**kw)
    clips = dm.load_clips()
    calls = []
    monkeypatch.setattr(MotionDataModule, "_read_all", lambda self: calls.append(1) or [])
    again = MotionDataModule(**kw).load_clips()
    assert not calls, "the second run must come from the cache"
    assert [c.name for c in again] == [c.name for c in clips]
    np.testing.assert_array_equal(again[3].positions, clips[3].positions)
    # a changed option is another cache entry, parsed again
    with pytest.raises(MotionFileError):
        MotionDataModule(**{**kw, "fps": 25}).load_clips()  # _read_all returns nothing now
    assert calls == [1]
    # and so is a cache written by code whose readers changed since
    import mocapfix.data.windows as windows

    monkeypatch.setattr(windows, "CACHE_VERSION", windows.CACHE_VERSION + 1)
    with pytest.raises(MotionFileError):
        MotionDataModule(**kw).load_clips()
    assert calls == [1, 1]


def test_resample_rotation_clip_keeps_bones_exact():
    clip = generate_clips(1, 2.0, 60.0, seed=3)[0]
    r = resample_clip(clip, 25.0)
    assert r.fps == 25.0 and r.num_frames == 50
    bone = lambda p, a, b: np.linalg.norm(p[:, a] - p[:, b], axis=-1)  # noqa: E731
    for a, b in [(0, 1), (4, 7), (16, 18)]:
        np.testing.assert_allclose(bone(r.positions, b, a), bone(clip.positions, b, a)[0], atol=1e-5)
    # the resampled frame at t = 1.0 s equals the source frame at t = 1.0 s
    np.testing.assert_allclose(r.positions[25], clip.positions[60], atol=1e-4)


def test_resample_positions_marks_neighbours_of_missing_as_missing():
    skel = preset("h36m17")
    pos = np.zeros((10, 17, 3), np.float32) + np.arange(10, dtype=np.float32)[:, None, None]
    pos[4, 0] = np.nan
    r = resample_clip(Clip(pos, 10.0, skel), 20.0)
    assert np.isnan(r.positions[7:10, 0]).all() and not np.isnan(r.positions[6, 0]).any()
    np.testing.assert_allclose(r.positions[3, 1], [1.5, 1.5, 1.5])


def test_synthetic_rotations_in_batches():
    dm = MotionDataModule(
        source="synthetic",
        synthetic_clips=10,
        synthetic_seconds=3.0,
        with_rotations=True,
        cache_dir=None,
        batch_size=3,
        val_fraction=0.2,
        test_fraction=0.2,
    )
    dm.setup("fit")
    b = next(iter(dm.train_dataloader()))
    assert b["rotations"].shape == (3, 30, 22, 3) and b["offsets"].shape == (3, 22, 3)
    assert b["root_translation"].shape == (3, 30, 3)


def test_unknown_source_is_a_clear_error():
    with pytest.raises(ValueError, match="unknown source type 'mocap'"):
        MotionDataModule(source="mocap", path="x")


@pytest.mark.slow  # minutes of CPU; `make test-all` runs it
def test_bandai_drop_root_cache_timing(bandai_dir, tmp_path):
    """All 384 clips, 1-second windows at 30 fps: parse, then from the cache."""
    kw = dict(source="bvh", path=str(bandai_dir), drop_joints=["joint_Root"], fps=30, cache_dir=str(tmp_path))
    t0 = time.perf_counter()
    dm = MotionDataModule(**kw)
    dm.setup("fit")
    first = time.perf_counter() - t0
    t0 = time.perf_counter()
    dm2 = MotionDataModule(**kw)
    dm2.setup("fit")
    cached = time.perf_counter() - t0
    print(f"bandai: parse {first:.1f} s, cache {cached:.2f} s")
    assert sum(len(v) for v in dm.clips.values()) == 384
    assert dm.skeleton.num_joints == 21 and "joint_Root" not in dm.skeleton.joint_names
    assert all(c.has_rotations for c in dm.clips["train"])
    assert len(dm2.datasets["train"]) == len(dm.datasets["train"]) > 1000
    assert cached < first


def test_archive_source_and_what_is_not_an_archive(tmp_path):
    """source: archive reads the cache's format (how parsed data travels to a machine without the
    raw files); anything else is one MotionFileError naming the file."""
    from mocapfix.data.windows import save_clips

    clips = generate_clips(3, 2.0, fps=30, seed=0)
    save_clips(tmp_path / "a.npz", clips)
    dm = MotionDataModule(
        source="archive",
        path=str(tmp_path / "a.npz"),
        cache_dir=None,
        fps=30,
        val_fraction=0.0,
        test_fraction=0.0,
        with_rotations=True,
    )
    dm.setup("fit")
    direct = MotionDataModule(
        source="synthetic",
        synthetic_clips=3,
        synthetic_seconds=2.0,
        cache_dir=None,
        fps=30,
        val_fraction=0.0,
        test_fraction=0.0,
        with_rotations=True,
    )
    direct.setup("fit")
    assert len(dm.datasets["train"]) == len(direct.datasets["train"]) > 0 and dm.has_rotations
    write_positions(tmp_path / "positions.npz", clips[0].positions, 30, clips[0].skeleton)
    (tmp_path / "text.csv").write_text("a,b\n1,2\n")
    for path, problem in (
        ("missing.npz", "no such archive file"),
        ("positions.npz", "not an archive of parsed clips"),
        ("text.csv", "not an npz file"),
    ):
        dm = MotionDataModule(source="archive", path=str(tmp_path / path), cache_dir=None)
        with pytest.raises(MotionFileError, match=problem) as e:
            dm.setup("fit")
        assert str(e.value).startswith(str(tmp_path / path))


def test_drop_joints_names_a_joint_of_the_data(tmp_path):
    """A drop_joints name that no file has (a typo) is an error, not a silent no-op."""
    c = generate_clips(1, 2.0, fps=30, seed=0)[0]
    write_positions(tmp_path / "a.npz", c.positions, 30, c.skeleton)
    kw = dict(source="positions", path=str(tmp_path), cache_dir=None, fps=30, val_fraction=0.0, test_fraction=0.0)
    dm = MotionDataModule(drop_joints=[c.skeleton.joint_names[-1]], **kw)
    dm.setup("fit")
    assert dm.skeleton.num_joints == c.skeleton.num_joints - 1
    with pytest.raises(MotionFileError, match=r"drop_joints not in any file's skeleton: \['Nope'\]"):
        MotionDataModule(drop_joints=["Nope"], **kw).setup("fit")
    with pytest.raises(MotionFileError, match="one tree") as e:  # the root: its children would be roots
        MotionDataModule(drop_joints=[c.skeleton.joint_names[0]], **kw).setup("fit")
    assert str(e.value).startswith(str(tmp_path / "a.npz"))


@pytest.mark.parametrize("val, test", [(-0.1, 0.1), (0.1, 1.5), (0.6, 0.6)])
def test_split_fractions_are_checked(val, test):
    with pytest.raises(ValueError, match="together at most 1"):
        MotionDataModule(val_fraction=val, test_fraction=test)
    MotionDataModule(val_fraction=0.0, test_fraction=1.0)  # every file to test: evaluation-only data


def test_a_file_at_the_wrong_scale_is_named(tmp_path):
    """A file in mm declared as metres would train a model in kilometres, silently."""
    c = generate_clips(2, 2.0, fps=30, seed=0)
    write_positions(tmp_path / "good.npz", c[0].positions, 30, c[0].skeleton)
    write_positions(tmp_path / "mm.npz", c[1].positions * 1000, 30, c[1].skeleton, unit="m")
    dm = MotionDataModule(source="positions", path=str(tmp_path), cache_dir=None, fps=30)
    with pytest.raises(MotionFileError, match="not a human body") as e:
        dm.setup("fit")
    assert str(e.value).startswith(str(tmp_path / "mm.npz"))


def test_parsing_a_folder_shows_progress(bandai_files, tmp_path, monkeypatch, caplog):
    import logging

    import mocapfix.data.datamodule as datamodule

    monkeypatch.setattr(datamodule, "PROGRESS_EVERY_S", 0.0)
    dm = MotionDataModule(source="bvh", path=[str(f) for f in bandai_files[:3]], fps=30, cache_dir=None)
    with caplog.at_level(logging.INFO, logger="mocapfix"):
        dm.setup("fit")
    lines = [r.getMessage() for r in caplog.records if r.getMessage().startswith("parsing:")]
    assert lines[0].startswith("parsing: 0 of 3 files") and len(lines) == 3
