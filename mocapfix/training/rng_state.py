"""torch's random number generator states in checkpoints, so a resumed run draws on where it stopped.

The training corruption (masks, displacement, noise) and the training loader's shuffling draw from
torch's global generators, which seed_everything resets at every start. Without the saved states a
resumed run replays the masks and batch order of the run's first steps.
"""

from __future__ import annotations

import lightning as L
import torch


class RNGStateInCheckpoint(L.Callback):
    """Saves the CPU and CUDA generator states with each checkpoint and restores them on resume.
    CUDA states restore only on a machine with as many GPUs (a GPU run resumed on a CPU keeps
    the CPU state only; the CPU draws nothing from the GPU's generators)."""

    def state_dict(self) -> dict:
        state = {"cpu": torch.get_rng_state()}
        if torch.cuda.is_available() and torch.cuda.is_initialized():
            state["cuda"] = torch.cuda.get_rng_state_all()  # one ByteTensor per device
        return state

    def load_state_dict(self, state_dict: dict) -> None:
        torch.set_rng_state(state_dict["cpu"])
        cuda = state_dict.get("cuda")
        if cuda is not None and torch.cuda.is_available() and len(cuda) == torch.cuda.device_count():
            torch.cuda.set_rng_state_all(cuda)
