"""DataSpec: what a model learns of the data it is set up for.

The data module answers it (MotionDataModule.spec(), after its setup) and the BindData callback
(training/bind_data.py) hands it to the LightningModule, which builds its network for that
skeleton and window: no module reads the trainer's data module itself, and a test or a script can
set a module up from a DataSpec of its own making.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from mocapfix.core.skeleton import Skeleton
from mocapfix.data.windows import complete_windows


@dataclass(frozen=True)
class DataSpec:
    skeleton: Skeleton
    fps: float  # frames per second of the windows
    window_frames: int  # frames per window
    source: str  # the data module's source (bvh, positions, synthetic, ...), for messages
    rotations: bool  # the windows carry joint rotations (data.with_rotations, and every clip has them)
    windows: dict = field(default_factory=dict, repr=False)  # split -> WindowDataset (statistics, checks)

    def complete_windows(self, split: str) -> int:
        """How many of the split's windows miss nothing (Motion-DVAE learns from and is scored on
        those only)."""
        ds = self.windows.get(split)
        if ds is None:
            return 0
        return sum(
            int(complete_windows(ds.__getitems__(list(range(i, min(i + 4096, len(ds)))))).sum())
            for i in range(0, len(ds), 4096)
        )
