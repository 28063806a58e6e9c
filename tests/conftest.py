"""Shared fixtures. The real data lives beside the repository (../shared/data), never inside it."""

from __future__ import annotations

import os
from pathlib import Path

# Under pytest-xdist each worker gets its share of the cores for torch, OpenMP and BLAS threads
# (set before either is imported): two workers of two threads each on two cores spin against each
# other: the suite took 469 s against 257 s with one thread each (2-core CPU).
if "PYTEST_XDIST_WORKER_COUNT" in os.environ:
    _threads = str(max(1, (os.cpu_count() or 1) // int(os.environ["PYTEST_XDIST_WORKER_COUNT"])))
    for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(_name, _threads)

import pytest  # noqa: E402

BANDAI_DIR = Path(__file__).resolve().parents[2] / "shared" / "data" / "bandai-namco"
CMU_DIR = Path(__file__).resolve().parents[2] / "shared" / "data" / "cmu-sample"


@pytest.fixture(scope="session")
def bandai_dir() -> Path:
    """The Bandai Namco BVH clips (384 files, cm, y up); tests that need them skip without them."""
    if not BANDAI_DIR.is_dir():
        pytest.skip(
            f"Bandai Namco data not found at {BANDAI_DIR} (expected ../shared/data/bandai-namco beside the repository)"
        )
    return BANDAI_DIR


@pytest.fixture(scope="session")
def bandai_files(bandai_dir: Path) -> list[Path]:
    """Every *.bvh under bandai_dir, sorted."""
    files = sorted(bandai_dir.rglob("*.bvh"))
    if not files:
        pytest.skip(f"no .bvh files under {bandai_dir}")
    return files


@pytest.fixture(scope="session")
def cmu_files() -> list[Path]:
    """The CMU sample's BVH takes (70, five subjects in folders 05-09, 120 fps, ASF units): a
    second studio, rig and frame rate; tests that need them skip without them."""
    files = sorted(CMU_DIR.rglob("*.bvh"))
    if not files:
        pytest.skip(f"CMU sample not found at {CMU_DIR} (expected ../shared/data/cmu-sample beside the repository)")
    return files


@pytest.fixture(scope="session")
def body21_takes(bandai_files) -> list:
    """Every 8th Bandai take of 2 s or more on the models' 21 joints: (T, 21, 3) float64 metres,
    z up, 30 fps."""
    import numpy as np

    from mocapfix.core.skeleton import preset
    from mocapfix.io import read_motion
    from mocapfix.rig.mapping import onto_skeleton

    takes = []
    for f in bandai_files[::8]:
        clip = read_motion(f)[0]
        if clip.duration_s >= 2.0:
            takes.append(onto_skeleton(clip, preset("body21")).positions.astype(np.float64))
    return takes


REPO = Path(__file__).resolve().parents[1]
# What runs write in the folder they run in; a test writes them under tmp_path (monkeypatch.chdir
# or explicit paths), never into the checkout
RUN_OUTPUTS = ("logs", "checkpoints", "mlruns", ".cache/mocapfix")


def _run_output_folders() -> dict[str, int]:
    """Every folder under the checkout's RUN_OUTPUTS with its modification time: a file made,
    removed or renamed in a folder changes the folder's time (files themselves are not read, so a
    checkout with many logs stays cheap to check)."""
    found = {}
    for name in RUN_OUTPUTS:
        for folder, _, _ in os.walk(REPO / name):
            found[folder] = os.stat(folder).st_mtime_ns
    return found


@pytest.fixture(autouse=True)
def _nothing_written_into_the_checkout():
    before = _run_output_folders()
    yield
    after = _run_output_folders()
    changed = sorted(f for f in before.keys() | after.keys() if before.get(f) != after.get(f))
    assert not changed, f"the test wrote into the checkout: {', '.join(changed)} (write under tmp_path)"
