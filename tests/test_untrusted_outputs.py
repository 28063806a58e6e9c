"""What `mocapfix fix` and `mocapfix render` write, and the processes they run, when the folders
and names around them are not to be trusted (issue 45): no link followed, no two inputs of a run
into one output, no input of the run overwritten, no partial file, no temporary file left for
good, no worker outliving its run, no traceback when the reader of stdout goes away."""

from __future__ import annotations

import errno
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch
from cli_utils import run_mocapfix

from mocapfix.apps.main import main
from mocapfix.core.clip import MotionFileError
from mocapfix.core.skeleton import preset
from mocapfix.io.files import claimed
from mocapfix.io.positions import write_positions
from mocapfix.io.synthetic import generate_clips
from mocapfix.models.checkpoint import xmae_checkpoint
from mocapfix.models.xmae import XMAE

SMPL = preset("smpl22")
SIZES = dict(enc_dim=32, enc_depth=1, enc_mlp_dim=64, dec_dim=32, dec_depth=1, dec_mlp_dim=64, head_dim=16)


@pytest.fixture(scope="module")
def ckpt(tmp_path_factory) -> Path:
    """A random-init tiny XMAE for smpl22 at 30 fps, 1 s windows: fast, and what it writes does not matter here."""
    torch.manual_seed(0)
    path = tmp_path_factory.mktemp("ckpt") / "tiny.ckpt"
    torch.save(xmae_checkpoint(XMAE(SMPL.num_joints, 30, **SIZES), SMPL, 30.0), path)
    return path


def take(path: Path, seconds: float = 1.0, seed: int = 0) -> Path:
    """A smpl22 take with a hole, as a positions .npz (or .csv by path's suffix)."""
    x = generate_clips(1, seconds, fps=30, seed=seed)[0].positions.copy()  # (T, 22, 3)
    x[10:20, 5] = np.nan
    path.parent.mkdir(parents=True, exist_ok=True)
    write_positions(path, x, 30, SMPL)
    return path


def fix(args, capsys) -> tuple[int, str, str]:
    return run_mocapfix(["fix", *args], capsys)


def one_line(err: str, *names) -> None:
    """err is one error line naming names (after the note the tiny checkpoint gets: it has no fill policy)."""
    err = "".join(line for line in err.splitlines(keepends=True) if not line.startswith("note: "))
    assert err.count("\n") == 1 and err.startswith("error: ") and "Traceback" not in err, err
    for name in names:
        assert str(name) in err, (name, err)


def files_in(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


# --- 1. links beside an output are never followed ---


def test_a_planted_lock_link_is_not_followed(tmp_path, ckpt, capsys):
    src = take(tmp_path / "in" / "a.npz")
    victim = tmp_path / "elsewhere" / "f"
    victim.parent.mkdir()
    (tmp_path / "in" / ".a.fixed.npz.lock").symlink_to(victim)
    rc, _, err = fix([src, "--ckpt", ckpt], capsys)
    assert rc == 1 and not victim.exists() and not (tmp_path / "in" / "a.fixed.npz").exists()
    one_line(err, ".a.fixed.npz.lock")
    assert "link" in err
    # the same through the library call, and a lock that is a folder or a FIFO
    (tmp_path / "in" / ".b.npz.lock").mkdir()
    os.mkfifo(tmp_path / "in" / ".c.npz.lock")
    for name in ("a.fixed.npz", "b.npz", "c.npz"):
        with pytest.raises(MotionFileError, match="lock"):
            with claimed(tmp_path / "in" / name):
                pass
    assert not victim.exists()


@pytest.mark.parametrize("force", [False, True])
@pytest.mark.parametrize("dangling", [False, True])
def test_an_output_that_is_a_link_is_neither_written_through_nor_replaced(tmp_path, ckpt, capsys, force, dangling):
    src = take(tmp_path / "a.npz")
    victim = tmp_path / "elsewhere.npz"
    if not dangling:
        victim.write_bytes(b"keep me")
    link = tmp_path / "out.npz"
    link.symlink_to(victim)
    rc, _, err = fix([src, "--ckpt", ckpt, "-o", link, *(["--force"] if force else [])], capsys)
    assert rc == 1 and link.is_symlink()
    assert (victim.read_bytes() == b"keep me") if not dangling else not victim.exists()
    one_line(err, link)
    assert "link" in err


# --- 2. two inputs into one output: refused before any work ---


@pytest.mark.parametrize("force", [False, True])
def test_two_inputs_into_one_output_are_refused_before_any_work(tmp_path, ckpt, capsys, force):
    a, b = take(tmp_path / "A" / "x.npz", seed=1), take(tmp_path / "B" / "x.npz", seed=2)
    take(tmp_path / "A" / "y.npz", seed=3)  # an input without a collision is not fixed either
    out = tmp_path / "out"
    args = [tmp_path / "A", tmp_path / "B", "--ckpt", ckpt, "--out-dir", out, "--jobs", "2"]
    rc, stdout, err = fix([*args, *(["--force"] if force else [])], capsys)
    assert rc == 1 and stdout == ""
    one_line(err, a, b, out / "x.npz")
    assert not out.exists() or files_in(out) == []


def test_the_same_input_twice_is_fixed_once(tmp_path, ckpt, capsys):
    a = take(tmp_path / "in" / "a.npz")
    rc, stdout, err = fix([tmp_path / "in", a, "--ckpt", ckpt, "--out-dir", tmp_path / "out"], capsys)
    assert rc == 0, err
    assert stdout.count("\n") == 1 and files_in(tmp_path / "out") == ["a.npz"]


# --- 3. --force never touches an input of the run ---


def test_force_never_overwrites_another_input_of_the_run(tmp_path, ckpt, capsys):
    a = take(tmp_path / "A" / "sub" / "x.npz", seed=1)
    b = take(tmp_path / "O" / "sub" / "x.npz", seed=2)
    before = b.read_bytes()
    # A's take goes to O/sub/x.npz: another input of the same run (which itself goes to O/x.npz)
    rc, _, err = fix([tmp_path / "A", b, "--ckpt", ckpt, "--out-dir", tmp_path / "O", "--force"], capsys)
    assert rc == 1 and b.read_bytes() == before
    one_line(err, a, b)
    assert "input" in err
    assert files_in(tmp_path / "O") == ["sub"] and files_in(tmp_path / "O" / "sub") == ["x.npz"]  # no work done


def test_force_never_replaces_a_hard_link_of_an_input(tmp_path, ckpt, capsys):
    a, b = take(tmp_path / "in" / "a.npz", seed=1), take(tmp_path / "in" / "b.npz", seed=2)
    (tmp_path / "out").mkdir()
    os.link(b, tmp_path / "out" / "a.npz")  # out/a.npz is b.npz under another name
    rc, _, err = fix([tmp_path / "in", "--ckpt", ckpt, "--out-dir", tmp_path / "out", "--force"], capsys)
    assert rc == 1 and os.path.samefile(b, tmp_path / "out" / "a.npz")
    one_line(err, a, b)
    assert not (tmp_path / "out" / "b.npz").exists()  # refused before any work


# --- 4, 5. renders: never over an existing file, never partial ---


def test_fix_render_never_overwrites_an_existing_gif(tmp_path, ckpt, capsys):
    src = take(tmp_path / "a.npz")
    (tmp_path / "a.fixed.gif").write_bytes(b"keep me")
    rc, _, err = fix([src, "--ckpt", ckpt, "--render"], capsys)
    assert rc == 1 and (tmp_path / "a.fixed.gif").read_bytes() == b"keep me"
    one_line(err, tmp_path / "a.fixed.gif")
    assert "exists" in err
    assert files_in(tmp_path) == ["a.fixed.gif", "a.npz"]  # nothing written: not the output, not the map
    rc, _, err = fix([src, "--ckpt", ckpt, "--render", "--force"], capsys)
    assert rc == 0, err
    assert (tmp_path / "a.fixed.gif").read_bytes()[:3] == b"GIF"


def _full_disk(monkeypatch):
    """Pillow's GIF writer writes some bytes, then the disk is full."""
    from PIL import Image

    def save(self, fp, *args, **kwargs):
        with open(fp, "wb") as f:
            f.write(b"GIF89a" + b"\0" * 1000)
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(Image.Image, "save", save)


def test_render_onto_a_full_disk_leaves_nothing_and_names_the_output(tmp_path, capsys, monkeypatch):
    src = take(tmp_path / "a.npz")
    out = tmp_path / "r.gif"
    _full_disk(monkeypatch)
    capsys.readouterr()
    assert main(["render", str(src), "-o", str(out)]) == 1
    one_line(capsys.readouterr().err, out)
    assert files_in(tmp_path) == ["a.npz"]
    monkeypatch.undo()
    assert main(["render", str(src), "-o", str(out)]) == 0 and out.read_bytes()[:3] == b"GIF"
    whole = out.read_bytes()
    _full_disk(monkeypatch)  # a failed render over an existing one leaves it as it was
    assert main(["render", str(src), "-o", str(out)]) == 1 and out.read_bytes() == whole
    assert files_in(tmp_path) == ["a.npz", "r.gif"]


def test_fix_render_onto_a_full_disk_writes_nothing_and_a_rerun_works(tmp_path, ckpt, capsys, monkeypatch):
    src = take(tmp_path / "a.npz")
    _full_disk(monkeypatch)
    rc, _, err = fix([src, "--ckpt", ckpt, "--render"], capsys)
    assert rc == 1 and files_in(tmp_path) == ["a.npz"]  # the output and its pictures together, or none
    one_line(err, tmp_path / "a.fixed.gif")
    assert "No space left" in err
    monkeypatch.undo()
    rc, _, err = fix([src, "--ckpt", ckpt, "--render"], capsys)
    assert rc == 0, err
    assert files_in(tmp_path) == ["a.fixed.gif", "a.fixed.holes.png", "a.fixed.npz", "a.npz"]


# --- 6. a folder as the output ---


@pytest.mark.parametrize("force", [False, True])
def test_a_folder_as_the_output_is_one_line(tmp_path, ckpt, capsys, force):
    src = take(tmp_path / "a.npz")
    (tmp_path / "d.npz").mkdir()
    rc, _, err = fix([src, "--ckpt", ckpt, "-o", tmp_path / "d.npz", *(["--force"] if force else [])], capsys)
    assert rc == 1 and (tmp_path / "d.npz").is_dir()
    one_line(err, tmp_path / "d.npz")
    assert "folder" in err and "IsADirectoryError" not in err


# --- 7. a killed run's temporary files ---


@pytest.mark.parametrize("output_exists", [False, True])
def test_resume_removes_a_killed_runs_temporary_files(tmp_path, ckpt, capsys, output_exists):
    src = take(tmp_path / "in" / "a.npz")
    out = tmp_path / "out"
    out.mkdir()
    if output_exists:
        assert fix([src, "--ckpt", ckpt, "--out-dir", out], capsys)[0] == 0
    # what a SIGKILL leaves: the temporary files of the output and its picture, and their locks
    stale = [
        ".a.npz.k3j2x9.tmp",
        "..a.npz.m1n2o3.tmp.npz.q8w7e6.tmp",
        ".a.gif.zz11.tmp.gif",
        ".a.npz.lock",
        ".a.gif.lock",
    ]
    for name in stale:
        (out / name).write_bytes(b"half")
    keep = out / ".a.npz.notes"  # a hidden file that is not ours
    keep.write_bytes(b"mine")
    rc, _, err = fix([src, "--ckpt", ckpt, "--out-dir", out, "--resume", "--render"], capsys)
    assert rc == 0, err
    left = files_in(out)
    assert not set(stale) & set(left) and ".a.npz.notes" in left, left


# --- 8. workers die with their parent ---


def _children(pid: int) -> set[int]:
    """Every process under pid: its children, theirs (the fork server's workers), ..."""
    found = set()
    for task in Path(f"/proc/{pid}/task").glob("*"):
        try:
            found |= {int(c) for c in (task / "children").read_text().split()}
        except OSError:
            pass
    return found.union(*(_children(c) for c in found))


def _command(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().decode()
    except OSError:
        return ""


def still_alive_after_kill(proc: subprocess.Popen, workers: set[int]) -> set[int]:
    """Kill proc as `kill -9` would; the workers still alive 5 s later."""
    proc.kill()
    proc.wait()
    deadline = time.monotonic() + 5.0
    while any(_alive(w) for w in workers) and time.monotonic() < deadline:
        time.sleep(0.02)
    return {w for w in workers if _alive(w)}


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return False
    return state not in ("Z", "X")


POOL = """
import os, time
from concurrent.futures import ProcessPoolExecutor
from mocapfix.apps.processes import die_with_run, worker_context

if __name__ == "__main__":
    pool = ProcessPoolExecutor(2, worker_context([]), die_with_run, (os.getpid(),))
    futures = [pool.submit(time.sleep, 0.2) for _ in range(4)]  # both workers up and working
    for f in futures:
        f.result()
    print("up", flush=True)
    time.sleep(60)
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="/proc is Linux's")
def test_pool_workers_die_with_their_parent(tmp_path):
    """The mechanism fix's workers start with (apps/processes.py), in a pool without torch: fast."""
    script = tmp_path / "pool.py"
    script.write_text(POOL)
    proc = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
    workers: set[int] = set()
    try:
        assert proc.stdout.readline() == b"up\n"  # both workers have started and worked
        workers = {w for w in _children(proc.pid) if "resource_tracker" not in _command(w)}
        assert len(workers) == 3  # the fork server and the two workers it forked
        assert not still_alive_after_kill(proc, workers)
        assert proc.stdout.read() == b""  # and the caller's pipe is closed: nothing holds it open
    finally:
        for w in workers:
            if _alive(w):
                os.kill(w, signal.SIGKILL)
        proc.kill()
        proc.wait()
        proc.stdout.close()


WORKER = "import sys; from mocapfix.apps.processes import die_with_run as d; d(int(sys.argv[1])); print('alive')"


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="/proc is Linux's")
def test_a_worker_belongs_to_the_run_or_to_a_process_the_run_started():
    """A worker's parent is the run (spawned) or the run's fork server; one whose parent is neither
    (its run gone before it armed the signal, it was reparented) ends at once."""
    stranger = subprocess.Popen(["sleep", "30"])
    try:
        for run, lives in [(os.getpid(), True), (os.getppid(), True), (stranger.pid, False)]:
            done = subprocess.run([sys.executable, "-c", WORKER, str(run)], capture_output=True, text=True, timeout=60)
            assert (done.returncode, done.stdout) == ((0, "alive\n") if lives else (1, "")), (run, done)
    finally:
        stranger.kill()
        stranger.wait()


@pytest.mark.slow  # three processes that load torch: half a minute on 2 busy cores
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="/proc and PR_SET_PDEATHSIG are Linux's")
def test_workers_die_with_their_parent(tmp_path, ckpt):
    for i in range(8):
        take(tmp_path / "in" / f"t{i}.npz", seconds=20.0, seed=i)
    env = dict(os.environ, OMP_NUM_THREADS="1")
    proc = subprocess.Popen(
        [sys.executable, "-m", "mocapfix", "fix", str(tmp_path / "in"), "--ckpt", str(ckpt)]
        + ["--out-dir", str(tmp_path / "out"), "--jobs", "2", "--progress", "never"],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        env=env,
    )
    workers: set[int] = set()
    try:
        assert b"->" in proc.stdout.readline()  # a worker has fixed a file: both are up
        workers = {w for w in _children(proc.pid) if "resource_tracker" not in _command(w)}
        assert len(workers) == 3  # the fork server and the two workers it forked
        assert not still_alive_after_kill(proc, workers)
    finally:  # whatever happened, nothing of this run is left running
        for w in workers | (_children(proc.pid) if proc.poll() is None else set()):
            if _alive(w):
                os.kill(w, signal.SIGKILL)
        proc.kill()
        proc.wait()
        proc.stdout.close()


# --- 9. a closed stdout ---


def _closed_pipe() -> int:
    """The write end of a pipe whose reader is gone: every write to it fails with EPIPE."""
    read, write = os.pipe()
    os.close(read)
    return write


def test_a_closed_stdout_is_a_quiet_exit():
    """`mocapfix docs | head -0`: no traceback, no "Exception ignored" at the interpreter's exit."""
    write = _closed_pipe()
    try:
        done = subprocess.run([sys.executable, "-m", "mocapfix", "docs"], stdout=write, stderr=subprocess.PIPE)
    finally:
        os.close(write)
    assert done.stderr == b"" and done.returncode == 0


@pytest.mark.slow  # a process that loads torch: ten seconds on 2 busy cores
def test_a_closed_stdout_stops_the_printing_not_the_run(tmp_path, ckpt):
    for i in range(4):
        take(tmp_path / "in" / f"t{i}.npz", seed=i)
    env = dict(os.environ, OMP_NUM_THREADS="1")
    proc = subprocess.Popen(
        [sys.executable, "-m", "mocapfix", "fix", str(tmp_path / "in"), "--ckpt", str(ckpt)]
        + ["--out-dir", str(tmp_path / "out"), "--jobs", "1", "--progress", "never"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        env=env,
    )
    assert b"->" in proc.stdout.readline()  # `| head -1`: one line read, then the pipe closed
    proc.stdout.close()
    err = proc.stderr.read().decode()
    proc.wait(timeout=60)
    assert "Traceback" not in err and "BrokenPipe" not in err, err
    assert proc.returncode == 0, err
    assert files_in(tmp_path / "out") == [f"t{i}.npz" for i in range(4)]


def test_a_closed_stdout_in_process_keeps_fixing(tmp_path, ckpt, monkeypatch, capsys):
    """The same without a subprocess: a stdout whose reader went away."""

    class Gone:
        def write(self, text):
            raise BrokenPipeError(errno.EPIPE, "Broken pipe")

        def flush(self):
            raise BrokenPipeError(errno.EPIPE, "Broken pipe")

    for i in range(2):
        take(tmp_path / "in" / f"t{i}.npz", seed=i)
    monkeypatch.setattr(sys, "stdout", Gone())
    rc = main(["fix", str(tmp_path / "in"), "--ckpt", str(ckpt), "--out-dir", str(tmp_path / "out")])
    assert rc == 0 and files_in(tmp_path / "out") == ["t0.npz", "t1.npz"]


# --- 10. no numpy warning lines around an answer ---


def test_render_of_an_input_with_no_observed_token_beside_its_fix_is_quiet(tmp_path, capsys):
    """The input's every token missing, the fixed file's there: drawn, without a numpy warning
    (All-NaN slice) and the traceback that followed it."""
    import warnings

    x = generate_clips(1, 1.0, fps=30, seed=0)[0].positions  # (30, 22, 3)
    write_positions(tmp_path / "in.npz", np.full_like(x, np.nan), 30, SMPL)
    write_positions(tmp_path / "fixed.npz", x, 30, SMPL)
    capsys.readouterr()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        rc = main(["render", str(tmp_path / "in.npz"), str(tmp_path / "fixed.npz"), "-o", str(tmp_path / "r.gif")])
    assert rc == 0 and not caught and capsys.readouterr().err == ""
    rc = main(["render", str(tmp_path / "in.npz"), "-o", str(tmp_path / "alone.gif")])  # nothing to draw
    assert rc == 1 and not (tmp_path / "alone.gif").exists()
    one_line(capsys.readouterr().err, tmp_path / "in.npz")


def test_a_take_too_short_to_judge_is_fixed_without_a_warning_line(tmp_path, bandai_files, capsys):
    """jitter-many on a 1-frame take: the report line, and no library warning line on stderr."""
    import warnings

    src = next(f for f in bandai_files if f.name == "dataset-1_bow_active_001.bvh")
    head, motion = src.read_text().split("MOTION", 1)
    lines = motion.strip().splitlines()
    short = tmp_path / "short.bvh"
    short.write_text(f"{head}MOTION\nFrames: 1\n{lines[1]}\n{lines[2]}\n")
    capsys.readouterr()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        rc = main(["fix", str(short), "--model", "jitter-many", "-o", str(tmp_path / "out.bvh")])
    out = capsys.readouterr()
    assert rc == 0 and out.out.count("\n") == 1 and out.err == ""
    assert not [w for w in caught if "compute" in str(w.message)], [str(w.message) for w in caught]
