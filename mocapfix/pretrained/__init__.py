"""Models shipped with mocapfix: weights only (no optimiser state), in the package, never
downloaded. `fix --model NAME` runs one, `mocapfix models` lists them; docs/models.md is each
one's model card (data, split, recipe, measured table, license).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

HERE = Path(__file__).resolve().parent


@dataclass(frozen=True)
class Pretrained:
    file: str  # beside this module
    summary: str  # one line for `mocapfix models`
    license: str


MODELS: dict[str, Pretrained] = {
    "xmae-cpu-bandai": Pretrained(
        "xmae_cpu_bandai.ckpt",
        "XMAE (cpu preset, 175k parameters) + fill policy; Bandai Namco, 21 joints, 30 fps; infill and displaced "
        "joints (--mode infill|both)",
        "CC BY-NC 4.0 (trained on Bandai Namco's motion dataset): non-commercial use only",
    ),
    "motion-dvae-bandai": Pretrained(
        "motion_dvae_bandai.ckpt",
        "Motion-DVAE denoiser (rotations state, width 256); Bandai Namco's 21-joint hierarchy, 30 fps; jitter "
        "on BVH takes (--mode denoise)",
        "CC BY-NC 4.0 (trained on Bandai Namco's motion dataset): non-commercial use only",
    ),
    "jitter-many": Pretrained(
        "jitter_many.ckpt",
        "jitter remover (a learned correction to a 6-Hz low-pass, 392k parameters); any rig that maps onto 21 "
        "joints, any frame rate >= 12 fps; jitter (--mode denoise)",
        "CC BY-NC 4.0 (trained on Bandai Namco's motion dataset, ReActIdle (MIT) and CMU (free)): "
        "non-commercial use only",
    ),
}


def pretrained_path(name: str) -> Path:
    """The checkpoint file of a shipped model; ValueError naming the shipped ones."""
    if name not in MODELS:
        raise ValueError(f"no shipped model {name!r} (shipped: {', '.join(MODELS)}; `mocapfix models` lists them)")
    return HERE / MODELS[name].file
