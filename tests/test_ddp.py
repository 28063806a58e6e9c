"""Two CPU processes (DDP over gloo), as `--trainer.devices 2 --trainer.strategy ddp` runs them:
fit works, and a test table is a property of the data, not of how it was split: the same with 1
process and 2, and with another eval_batch_size (test corruption is seeded per window, no window
is counted twice). Run through `python -m mocapfix` in a subprocess: DDP starts its second
process by running the same command again."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest
import torch.distributed
from cli_utils import REPO, SMALL_DATA, TINY

pytestmark = [
    pytest.mark.skipif(not torch.distributed.is_available(), reason="torch without distributed"),
    pytest.mark.skipif(sys.platform == "win32", reason="gloo DDP test: Linux/macOS"),
]

DATA = [a for a in SMALL_DATA]  # 12 synthetic clips of 3 s: 9 test windows, uneven over 2 processes
QUIET = ["--trainer.enable_progress_bar", "false", "--trainer.enable_model_summary", "false"]
# the displacement and noise rows draw random numbers: they are the ones a batch-seeded test moved
TABLE = ["--model.init_args.eval_gaps_s", "[0.3]", "--model.init_args.eval_noise_sigmas_m", "[0.05]"]


def mocapfix(args: list, cwd, devices: int) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(REPO), OMP_NUM_THREADS="1", MOCAPFIX_TRACEBACK="1")
    ddp = ["--trainer.devices", str(devices)] + (["--trainer.strategy", "ddp"] if devices > 1 else [])
    cmd = [sys.executable, "-m", "mocapfix", *map(str, args), "--trainer.accelerator", "cpu", *ddp]
    run = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-3000:]
    return run


def eval_rows(run: subprocess.CompletedProcess, cwd) -> dict:
    path = next(line.split(": ", 1)[1] for line in run.stdout.splitlines() if line.startswith("eval.json: "))
    rows = json.loads((cwd / path).read_text())
    return {(r["task"], r["part"], r.get("gap_s"), r.get("sigma_m"), r["method"]): r["mpjpe_mm"] for r in rows}


@pytest.mark.slow  # minutes of CPU; `make test-all` runs it
def test_two_process_fit_and_test_give_the_one_process_table(tmp_path):
    common = ["--config", "xmae", *TINY, *DATA, *QUIET, *TABLE, "--model.init_args.calibration_windows", "0"]
    mocapfix(
        ["fit", *common, "--experiment", "ddp", "--trainer.max_steps", "2", "--trainer.val_check_interval", "1"],
        tmp_path,
        devices=2,
    )
    ckpt = tmp_path / "checkpoints" / "ddp" / "last.ckpt"
    assert ckpt.exists()
    test = ["test", *common, "--experiment", "ddp_test", "--ckpt_path", ckpt]
    one = eval_rows(mocapfix([*test, "--data.eval_batch_size", "8"], tmp_path, devices=1), tmp_path)
    two = eval_rows(mocapfix([*test, "--data.eval_batch_size", "3"], tmp_path, devices=2), tmp_path)
    assert one.keys() == two.keys() and any(k[0] == "displacement" for k in one)
    for key, value in one.items():
        assert two[key] == pytest.approx(value, abs=0.02), key  # eval.json rounds to 0.01 mm

    # predict: every window once, in the split's order, whichever process predicted it

    paths = []
    for devices in (1, 2):
        run = mocapfix(["predict", *common, "--experiment", f"pred{devices}", "--ckpt_path", ckpt], tmp_path, devices)
        assert run.returncode == 0
        paths.append(next((tmp_path / "logs" / f"pred{devices}").rglob("predictions.npz")))
    a, b = (np.load(p)["positions"] for p in paths)
    assert a.shape == b.shape and a.shape[0] == 9
    np.testing.assert_allclose(a, b, atol=1e-5, equal_nan=True)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_sigterm_ends_a_two_process_fit_with_a_checkpoint(tmp_path):
    """SIGTERM (a scheduler's time limit) to a 2-process fit: every process ends within 30 s,
    exit 143, last.ckpt at the step reached (not the hang until the gloo timeout it once was)."""
    import signal
    import time

    import torch

    env = dict(os.environ, PYTHONPATH=str(REPO), OMP_NUM_THREADS="1")
    args = ["--config", "xmae", *TINY, *DATA, *QUIET, "--model.init_args.calibration_windows", "0"]
    args += ["--experiment", "term", "--trainer.max_steps", "100000", "--trainer.val_check_interval", "4"]
    ddp = ["--trainer.accelerator", "cpu", "--trainer.devices", "2", "--trainer.strategy", "ddp"]
    proc = subprocess.Popen(
        [sys.executable, "-m", "mocapfix", "fit", *args, *ddp],
        cwd=tmp_path,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    last = tmp_path / "checkpoints" / "term" / "last.ckpt"
    deadline = time.time() + 240
    while not last.exists() and proc.poll() is None and time.time() < deadline:
        time.sleep(0.5)
    assert last.exists(), proc.stderr.read()[-3000:] if proc.poll() is not None else "no checkpoint in 240 s"
    time.sleep(2.0)  # training on past the first validation
    proc.send_signal(signal.SIGTERM)
    t0 = time.time()
    try:
        rc = proc.wait(timeout=30)
    except subprocess.TimeoutExpired:
        rc = None
    finally:
        if proc.poll() is None:
            proc.kill()
    err = proc.stderr.read()
    assert rc is not None, "still running 30 s after SIGTERM:\n" + err[-4000:]
    assert rc == 143 and "stopped by SIGTERM" in err, err[-3000:]
    stopped_s = time.time() - t0
    print(f"2-process fit stopped {stopped_s:.1f} s after SIGTERM")
    assert stopped_s < 30
    step = torch.load(last, map_location="cpu", weights_only=True)["global_step"]
    assert step > 4  # the step reached, past the validation's checkpoint
    # and no process of the run is left
    time.sleep(1.0)
    left = []
    for pid in os.listdir("/proc"):
        try:
            if pid.isdigit() and os.readlink(f"/proc/{pid}/cwd") == str(tmp_path):
                left.append(pid)
        except OSError:
            pass
    assert not left, left
