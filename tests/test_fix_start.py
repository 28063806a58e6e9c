"""What `fix` costs before it fixes anything: the modules it imports. torchmetrics and roma (which
imports torch._dynamo) each add over a second of CPU to every run's start, matplotlib a third;
a run on position files without --render needs none of them."""

from __future__ import annotations

import subprocess
import sys

import numpy as np

from mocapfix.core.skeleton import preset


def test_fix_on_a_positions_file_imports_neither_torchmetrics_nor_roma_nor_matplotlib(tmp_path):
    body = preset("body21")
    rng = np.random.default_rng(0)
    x = (rng.normal(0, 0.01, (90, body.num_joints, 3)).cumsum(0) + [0, 0, 1.0]).astype(np.float32)
    x[30:40, 5] = np.nan
    np.savez(tmp_path / "take.npz", positions=x, fps=30.0, joint_names=np.array(body.joint_names),
             parents=np.array(body.parents))  # fmt: skip
    code = (
        "import sys\n"
        "from mocapfix.apps.main import main\n"
        f"code = main(['fix', {str(tmp_path / 'take.npz')!r}, '--model', 'xmae-cpu-bandai', '-o', "
        f"{str(tmp_path / 'out.npz')!r}, '--progress', 'never'])\n"
        "print(code, *(name in sys.modules for name in ('torchmetrics', 'roma', 'matplotlib')))\n"
    )
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert run.stdout.split()[-4:] == ["0", "False", "False", "False"], run.stdout + run.stderr
    assert (tmp_path / "out.npz").exists()
