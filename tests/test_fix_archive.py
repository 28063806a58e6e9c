"""`mocapfix fix` over many files: worker processes, shards, resuming a killed run."""

from __future__ import annotations

import inspect
from pathlib import Path

import numpy as np
import pytest

from mocapfix.apps import fix_run
from mocapfix.apps.fix_run import parse_shard, shard_of
from mocapfix.apps.main import main
from mocapfix.evaluation.recording import random_holes, with_holes
from mocapfix.io import read_motion


def test_shards_are_disjoint_and_together_the_whole_run():
    files = list(range(11))
    parts = [shard_of(files, (i, 3)) for i in range(3)]
    assert sorted(sum(parts, [])) == files and not set(parts[0]) & set(parts[1])
    assert parse_shard("2/3") == (2, 3)
    for bad in ("3/3", "-1/2", "1", "a/b"):
        with pytest.raises(ValueError, match="--shard"):
            parse_shard(bad)


@pytest.fixture(scope="module")
def takes(tmp_path_factory, bandai_files) -> Path:
    """Four Bandai takes with holes, as positions .npz."""
    folder = tmp_path_factory.mktemp("archive")
    for i, f in enumerate(bandai_files[:4]):
        clip = read_motion(f)[0]
        x = with_holes(clip.positions, random_holes(*clip.positions.shape[:2], clip.fps, seed=i, count=3, hole_s=0.4))
        names, parents = np.array(clip.skeleton.joint_names), np.array(clip.skeleton.parents)
        np.savez(folder / f"{f.stem}.npz", positions=x, fps=np.float64(clip.fps), joint_names=names, parents=parents)
    return folder


def _outputs(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if not p.name.startswith(".")}


def _fix(takes: Path, out: Path, *extra) -> int:
    return main(["fix", str(takes), "--model", "xmae-cpu-bandai", "--out-dir", str(out), *map(str, extra)])


def test_workers_shards_and_resume_write_what_one_process_writes(takes, tmp_path, capsys):
    assert _fix(takes, tmp_path / "one", "--jobs", "1") == 0
    reference = _outputs(tmp_path / "one")
    assert len(reference) == 4
    assert "fix: 4 fixed, 0 failed, 0 skipped" in capsys.readouterr().err

    assert _fix(takes, tmp_path / "two", "--jobs", "2") == 0
    assert _outputs(tmp_path / "two") == reference
    assert "(2 workers)" in capsys.readouterr().err

    for i in (0, 1):
        assert _fix(takes, tmp_path / "shards", "--jobs", "1", "--shard", f"{i}/2") == 0
    assert _outputs(tmp_path / "shards") == reference

    # a killed run: two outputs whole, one left half-written under its hidden temporary name
    resumed = tmp_path / "resumed"
    resumed.mkdir()
    names = sorted(reference)
    for name in names[:2]:
        (resumed / name).write_bytes(reference[name])
    stale = resumed / f".{Path(names[2]).stem}.12345.partial.npz"
    stale.write_bytes(b"half")
    (resumed / f".{names[2]}.lock").write_bytes(b"")  # a killed run leaves its (unlocked) lock file too
    capsys.readouterr()
    assert _fix(takes, resumed, "--jobs", "1", "--resume") == 0
    assert _outputs(resumed) == reference and not stale.exists()
    err = capsys.readouterr().err
    assert "fix: 2 fixed, 0 failed, 2 skipped" in err
    # without --resume an existing output is still an error, never overwritten
    assert _fix(takes, resumed, "--jobs", "1") == 1
    assert "exists (use --force" in capsys.readouterr().err and _outputs(resumed) == reference


def test_the_run_objects_reach_each_worker_once(tmp_path, monkeypatch):
    """The motion library and the measured policy are written once for a run, whatever the number
    of files and measured takes, and a worker reads each once and keeps it (its search's caches
    with it): handed in every task, each file rebuilt them."""
    assert list(inspect.signature(fix_run.measure_take).parameters)[fix_run.LIBRARY_IN_JOB] == "library"
    shelf = fix_run._Shelf(tmp_path)
    library, policy = {"takes": np.arange(6.0)}, ("policy", "note")
    jobs = shelf.jobs([(k, 30.0, "skeleton", (0.5,), None, {}, library, k, {}) for k in range(5)])
    assert len(list(tmp_path.iterdir())) == 1
    assert all(job[fix_run.LIBRARY_IN_JOB] == jobs[0][fix_run.LIBRARY_IN_JOB] for job in jobs)
    assert [job[:6] + job[7:] for job in jobs] == [(k, 30.0, "skeleton", (0.5,), None, {}, k, {}) for k in range(5)]
    settings = fix_run.RunSettings(*[None] * 13, policy, library)
    shelved = shelf.settings(settings)
    assert shelved.library == jobs[0][fix_run.LIBRARY_IN_JOB] and len(list(tmp_path.iterdir())) == 2
    monkeypatch.setattr(fix_run, "_WORKER", {})  # a fresh worker
    read = fix_run._shelved(shelved.library)
    assert read["takes"].tolist() == library["takes"].tolist() and read is not library
    assert fix_run._shelved(shelved.library) is read  # the same object the second time: read once
    assert fix_run._shelved(shelved.measured) == policy and fix_run._shelved(None) is None


def test_a_fix_run_keeps_numpys_blas_on_one_thread(takes, tmp_path, monkeypatch):
    from threadpoolctl import threadpool_info

    def blas_threads():
        return [lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"]

    seen = []

    def fix_one(*args, **kwargs):
        seen.extend(blas_threads())
        return real(*args, **kwargs)

    real = fix_run.fix_one
    monkeypatch.setattr(fix_run, "fix_one", fix_one)
    before = blas_threads()
    assert _fix(takes, tmp_path / "out", "--jobs", "1") == 0
    assert seen and set(seen) == {1}
    assert blas_threads() == before  # as they were: the run leaves nothing set behind it


def test_the_measurement_and_the_files_search_one_library(takes, tmp_path, monkeypatch):
    """A run's takes make one motion library, which the policy's measurement and every file
    search: the measurement's own copy of it was its search's frames built twice in every worker."""
    from mocapfix.fills.motion_matching import MotionLibrary

    made = []
    real = MotionLibrary.__init__

    def init(self, *args, **kwargs):
        made.append(self)
        real(self, *args, **kwargs)

    monkeypatch.setattr(MotionLibrary, "__init__", init)
    assert _fix(takes, tmp_path / "out", "--jobs", "1") == 0
    assert len(made) == 1 and len(made[0].keys) == 4


def test_a_long_take_is_fixed_in_pieces_with_context(bandai_files, monkeypatch):
    """A take longer than a piece and its margins goes through fix piece by piece (memory bounded
    by a piece): every hole filled, every observed token kept, the counts those of the take."""
    from mocapfix.fix import fix_clips, pieces
    from mocapfix.fix.fixers import load_fixer
    from mocapfix.pretrained import pretrained_path

    clip = max((read_motion(f)[0] for f in bandai_files[:20]), key=lambda c: c.num_frames)
    monkeypatch.setattr(pieces, "PIECE_S", 1.0)
    monkeypatch.setattr(pieces, "PIECE_MARGIN_S", 0.5)
    assert clip.duration_s > 2.0
    x = clip.positions.copy()
    hand = clip.skeleton.index("Hand_L")
    x[20:30, hand] = np.nan  # across the first cut (frame 30) too: x[25:35]
    x[25:35, hand] = np.nan
    take = clip.replace(positions=x, rotations=None, root_translation=None, offsets=None)
    (out,), report = fix_clips([take], load_fixer(pretrained_path("xmae-cpu-bandai")), "infill")
    assert any(n.startswith("fixed in ") and "pieces" in n for n in report.notes)
    observed = np.isfinite(x).all(-1)
    assert np.array_equal(out.positions[observed], x[observed]) and np.isfinite(out.positions).all()
    assert report.filled == 15 and sum(report.filled_by.values()) <= 15
    assert np.linalg.norm(out.positions[20:35, hand] - clip.positions[20:35, hand], axis=-1).mean() < 0.1
