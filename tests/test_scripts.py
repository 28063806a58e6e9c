"""The tools in scripts/, what a checkout's user runs beside the package: build the training corpus
(run here on four takes), shrink a checkpoint for shipping (tests/test_checkpoint.py), drive a
lent GPU (gpu_session.sh: it needs the GPU; here, that it parses and names scripts that exist)."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def test_build_corpus_puts_each_performer_in_a_folder_and_keeps_check_subjects_out(tmp_path, bandai_files, cmu_files):
    import shutil

    from mocapfix.data.windows import load_clips

    idle, cmu = tmp_path / "reactidle" / "acted", tmp_path / "cmu"
    idle.mkdir(parents=True)
    cmu.mkdir()
    shutil.copy(bandai_files[0], idle / "000_acted.bvh")  # person 000
    shutil.copy(bandai_files[1], idle / "007_acted.bvh")  # person 007
    shutil.copy(cmu_files[0], cmu / "35_01.bvh")  # a subject to train on
    shutil.copy(cmu_files[1], cmu / "05_01.bvh")  # the stranger benchmark's: never trained on
    out = tmp_path / "corpus.npz"
    env = dict(os.environ, PYTHONPATH=str(REPO), OMP_NUM_THREADS="1")
    args = ["--reactidle", tmp_path / "reactidle", "--cmu", cmu, "--out", out, "--cache-dir", tmp_path / "cache"]
    run = subprocess.run(
        [sys.executable, str(REPO / "scripts" / "build_corpus.py"), *map(str, args)],
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert run.returncode == 0, run.stderr[-3000:]
    clips = load_clips(out)
    assert sorted(c.source for c in clips) == [
        "corpus/cmu35/35_01.bvh",
        "corpus/reactidle000/000_acted.bvh",
        "corpus/reactidle007/007_acted.bvh",
    ]
    assert all(c.skeleton.num_joints == 21 and c.fps == 30.0 for c in clips)


def test_the_gpu_session_parses_and_names_scripts_that_exist():
    script = REPO / "scripts" / "gpu_session.sh"
    subprocess.run(["bash", "-n", str(script)], check=True)
    named = set(re.findall(r"(?<!/)\b((?:bench|scripts)/\w+\.(?:py|sh))", script.read_text()))
    assert {"bench/fix_bandai.py", "scripts/shrink_checkpoint.py", "scripts/build_corpus.py"} <= named
    assert not [name for name in sorted(named) if not (REPO / name).is_file()]
