"""build_model: a network from its kind and config.

A model's config is data (XMAEConfig, DVAEConfig, JitterConfig, CorrectionConfig: plain values), saved in
every checkpoint as checkpoint["model"] = {"kind": ..., "config": {...}} (models/checkpoint.py). Training,
resume, `fix`, the benchmarks and the tests all build networks through build_model (nanoGPT's model_args
habit), so a checkpoint says what it holds: nothing guesses a model from the names of its weights, and
renaming an attribute cannot break `fix`.
"""

from __future__ import annotations

from dataclasses import asdict, fields

import torch.nn as nn

from mocapfix.models.correction import CorrectionConfig, CorrectionNet
from mocapfix.models.dvae import DVAEConfig, MotionDVAE
from mocapfix.models.dvae_state import state_dim, velocity_mask
from mocapfix.models.jitter import JitterConfig, JitterNet
from mocapfix.models.xmae import XMAE, XMAEConfig

# kind -> its config class. A Motion-DVAE prior and its denoising stage share the network; the
# denoising stage adds its own predictors (training/denoise_module.py), built from the same config.
CONFIGS: dict[str, type] = {
    "xmae": XMAEConfig,
    "motion-dvae-prior": DVAEConfig,
    "motion-dvae": DVAEConfig,
    "jitter": JitterConfig,
    "correction": CorrectionConfig,
}


def model_config(kind: str, values: dict):
    """kind and plain values -> the kind's config; ValueError naming what does not fit."""
    if kind not in CONFIGS:
        raise ValueError(f"unknown model kind {kind!r} (known: {', '.join(CONFIGS)})")
    cls = CONFIGS[kind]
    names = {f.name for f in fields(cls)}
    unknown = sorted(set(values) - names)
    if unknown:
        raise ValueError(f"{kind} config: unknown setting(s) {', '.join(unknown)}")
    try:
        return cls(**values)
    except TypeError as e:  # a required value (num_joints, ...) missing
        raise ValueError(f"{kind} config: {e}") from None


def build_model(kind: str, config) -> nn.Module:
    """config: the kind's config dataclass or its plain values -> the untrained network."""
    if isinstance(config, dict):
        config = model_config(kind, config)
    if isinstance(config, XMAEConfig):
        return XMAE(**asdict(config))
    if isinstance(config, JitterConfig):
        return JitterNet(config)
    if isinstance(config, CorrectionConfig):
        return CorrectionNet(config)
    if isinstance(config, DVAEConfig):
        velocity = None if config.encoder_velocities else velocity_mask(config.state, config.num_joints)
        return MotionDVAE(
            state_dim(config.state, config.num_joints),
            config.latent_dim,
            config.lstm_hidden,
            config.mlp_hidden,
            config.norm_groups,
            velocity,
        )
    raise ValueError(f"not a model config: {type(config).__name__}")
