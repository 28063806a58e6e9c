"""What a checkpoint holds: the one place that reads, writes and shrinks mocapfix's checkpoint files.

A checkpoint is a dict of plain values, loaded with torch.load(weights_only=True): a file handed
over by someone else can never run code here.

    hyper_parameters  the training module's settings (a table); every model's include its window:
                      skeleton (Skeleton.to_dict), window_fps, window_frames
    model             {"kind": ..., "config": {...}}: what build_model rebuilds (models/build.py)
    state_dict        the weights, each under its sub-network's prefix ("net.", and for the
                      Motion-DVAE denoising stage "x0_pred.", "noise_pred.", "codec.")
    fill_policy       the fill policy's plain values, when one was measured (optional)
    ...               Lightning's training state (optimizer_states, loops, callbacks): training
                      resumes from it; shrink_checkpoint drops it

Checkpoints from before `model` existed (commit 4ceef7a and earlier) are told by their weights
(model_kind) and their network rebuilt from their hyperparameters (xmae_config).
Plain torch, no Lightning: training, fix, adapt and the tools share it.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import torch

from mocapfix.core.clip import MotionFileError
from mocapfix.core.skeleton import Skeleton
from mocapfix.io.files import atomic_write
from mocapfix.models.build import model_config
from mocapfix.models.xmae import XMAEConfig

HYPER_PARAMETERS, MODEL, STATE_DICT, FILL_POLICY = "hyper_parameters", "model", "state_dict", "fill_policy"
# What a shipped checkpoint keeps: enough for fix, evaluation and adapt, not to resume training.
SHIPPED = (HYPER_PARAMETERS, MODEL, FILL_POLICY, "global_step", "epoch", "pytorch-lightning_version")


# --- reading ---


def load_checkpoint(path) -> dict:
    """Whatever a checkpoint file holds, loaded with weights_only=True (plain values only).
    MotionFileError naming the file when it is no such file or not plain values."""
    path = Path(path)
    if not path.is_file():
        raise MotionFileError(path, "no such checkpoint file" if not path.exists() else "is not a file")
    try:
        return torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # not a zip/pickle, truncated, or objects that are not plain values
        text = " ".join(str(e).split())
        reason = (
            "holds objects that are not plain values"
            if "weights_only" in text.lower() or "unpickl" in text.lower()
            else f"not a PyTorch checkpoint ({type(e).__name__})"
        )
        raise MotionFileError(path, f"not a mocapfix checkpoint: {reason}") from None


def read_checkpoint(path) -> dict:
    """A mocapfix checkpoint (load_checkpoint) with a hyper_parameters and a state_dict table.
    Anything else is a MotionFileError."""
    ckpt = load_checkpoint(path)
    if (
        not isinstance(ckpt, dict)
        or not isinstance(ckpt.get(HYPER_PARAMETERS), dict)
        or not isinstance(ckpt.get(STATE_DICT), dict)
    ):
        raise MotionFileError(path, "not a mocapfix checkpoint: no hyper_parameters and state_dict")
    return ckpt


def is_training_state(ckpt) -> bool:
    """Whether a loaded checkpoint is a training run's own (Lightning's state beside the weights),
    the kind `fit --ckpt_path` resumes from; adapt's and shrunk files are weights only."""
    return isinstance(ckpt, dict) and "pytorch-lightning_version" in ckpt and isinstance(ckpt.get(STATE_DICT), dict)


def model_kind(ckpt: dict) -> str | None:
    """Which model a checkpoint holds: the kind it names (models/build.py); for checkpoints from
    before they named it, the keys their training module saved. None if unknown."""
    if isinstance(ckpt.get(MODEL), dict):
        return named_kind(ckpt)
    hparams, state_dict = ckpt[HYPER_PARAMETERS], ckpt[STATE_DICT]
    if "net.enc_pos_joint" in state_dict and "enc_dim" in hparams:  # training/xmae_module.py
        return "xmae"
    if any(k.startswith("net.gen.") for k in state_dict):  # MotionDVAE weights
        if any(k.startswith("x0_pred.") for k in state_dict):  # training/denoise_module.py
            return "motion-dvae"
        if "latent_dim" in hparams:  # training/dvae_module.py: the prior alone
            return "motion-dvae-prior"
    return None


def named_kind(ckpt: dict) -> str | None:
    """The kind a checkpoint names under "model"; None for one from before checkpoints named theirs."""
    entry = ckpt.get(MODEL)
    kind = entry.get("kind") if isinstance(entry, dict) else None
    return kind if isinstance(kind, str) else None


def hyperparameters(ckpt: dict) -> dict:
    """The training module's settings the checkpoint was saved with."""
    return ckpt[HYPER_PARAMETERS]


def window_settings(path, hparams: dict) -> tuple[Skeleton, float, int]:
    """hyperparameters (a checkpoint's, or a Motion-DVAE denoiser's prior_hparams) -> the model's
    skeleton, frame rate and window length; MotionFileError naming the file when they are not there."""
    missing = [k for k in ("skeleton", "window_fps", "window_frames") if hparams.get(k) is None]
    if missing:
        raise MotionFileError(path, f"checkpoint lacks {', '.join(missing)} (saved before training set it up?)")
    try:
        skeleton = Skeleton.from_dict(hparams["skeleton"])
        fps, frames = float(hparams["window_fps"]), int(hparams["window_frames"])
    except (KeyError, TypeError, ValueError) as e:
        raise MotionFileError(path, f"checkpoint's skeleton or window is malformed ({e})") from None
    if not (fps > 0 and frames > 0):
        raise MotionFileError(path, f"checkpoint's window is {frames} frames at {fps} fps")
    return skeleton, fps, frames


def network_weights(ckpt: dict, prefix: str = "net") -> dict:
    """The weights of one sub-network, named as its own state_dict names them (prefix taken off)."""
    start = prefix + "."
    return {k[len(start) :]: v for k, v in ckpt[STATE_DICT].items() if k.startswith(start)}


def stored_config(path, ckpt: dict) -> dict | None:
    """The network config a checkpoint stores under "model" (plain values); None for one written
    before checkpoints held it. MotionFileError naming the file when the entry is malformed."""
    if MODEL not in ckpt:
        return None
    entry = ckpt[MODEL]
    if not (isinstance(entry, dict) and isinstance(entry.get("config"), dict)):
        raise MotionFileError(path, "the checkpoint's model entry is malformed (no kind and config)")
    return entry["config"]


def xmae_config(path, ckpt: dict) -> dict:
    """An XMAE checkpoint's network config as plain values: its model entry, or, written before
    checkpoints held one, rebuilt from the sizes that were then hyperparameters."""
    if MODEL in ckpt:
        return stored_config(path, ckpt)
    hparams = ckpt[HYPER_PARAMETERS]
    skeleton, _, frames = window_settings(path, hparams)
    sizes = (f.name for f in dataclasses.fields(XMAEConfig) if f.name not in ("num_joints", "num_frames"))
    config = {k: hparams[k] for k in sizes if hparams.get(k) is not None}
    return {**config, "num_joints": skeleton.num_joints, "num_frames": frames}


def fill_policy_values(ckpt: dict) -> dict | None:
    """The fill policy's plain values (fills' FillPolicy.from_dict reads them); None when the
    checkpoint has none (the model everywhere, until `mocapfix validate --ckpt_path` adds one)."""
    return ckpt.get(FILL_POLICY)


# --- writing ---


def checkpoint_entry(kind: str, config) -> dict:
    """What a checkpoint stores under "model": plain values (weights_only loading reads them)."""
    return {"kind": kind, "config": dataclasses.asdict(config)}


def name_model(ckpt: dict, kind: str, config) -> None:
    """Write the model's kind and config into a checkpoint (the LightningModules' on_save_checkpoint)."""
    ckpt[MODEL] = checkpoint_entry(kind, config)


def set_fill_policy(ckpt: dict, values: dict | None) -> None:
    """Write a fill policy's plain values (FillPolicy.to_dict) into a checkpoint; None writes nothing."""
    if values is not None:
        ckpt[FILL_POLICY] = values


def weights_checkpoint(kind: str, net: torch.nn.Module, hparams: dict, **extra) -> dict:
    """The smallest checkpoint of a network that fix and adapt read: the settings, the model's kind
    and config, the weights under "net."; extra keys (global_step, a fill policy's values, ...) as given."""
    weights = {f"net.{k}": v.detach().cpu() for k, v in net.state_dict().items()}
    ckpt = {HYPER_PARAMETERS: dict(hparams), MODEL: checkpoint_entry(kind, net.config), STATE_DICT: weights}
    return {**ckpt, **extra}


def xmae_checkpoint(net, skeleton: Skeleton, fps: float) -> dict:
    """The smallest checkpoint load_fixer reads for an XMAE (what XMAEModule saves, minus the
    training state): for benchmarks and tests that need a model without training one."""
    return weights_checkpoint("xmae", net, _window(skeleton, fps, net.num_frames))


def jitter_checkpoint(net, skeleton: Skeleton, fps: float) -> dict:
    """The smallest checkpoint load_fixer reads for a jitter remover (as xmae_checkpoint)."""
    return weights_checkpoint("jitter", net, _window(skeleton, fps, net.config.num_frames))


def _window(skeleton: Skeleton, fps: float, frames: int) -> dict:
    return {"skeleton": skeleton.to_dict(), "window_fps": float(fps), "window_frames": int(frames)}


def save_checkpoint(path, ckpt: dict) -> None:
    """Write a checkpoint whole or not at all (a temporary file beside it, renamed over it: never
    written through a link)."""
    atomic_write(Path(path), lambda f: torch.save(ckpt, f))


def shrink_checkpoint(path, ckpt: dict, fp32: bool = False) -> dict:
    """A training checkpoint -> a weights-only copy small enough to ship or to bring back from a
    lent GPU: SHIPPED kept, the optimiser and loop states dropped, floating-point weights in
    bfloat16 (fp32=True keeps float32: Motion-DVAE runs in fp32). fix and evaluation read it;
    training cannot resume from it. An XMAE checkpoint from before checkpoints named their model
    gets the entry. path: the file it was read from, for messages."""
    small = {k: ckpt[k] for k in SHIPPED if k in ckpt}
    if MODEL not in small and model_kind(ckpt) == "xmae":
        try:
            small[MODEL] = checkpoint_entry("xmae", model_config("xmae", xmae_config(path, ckpt)))
        except ValueError:  # MotionFileError too: sizes that build no XMAE, copied as they are
            pass
    small[STATE_DICT] = {
        k: v.to(torch.bfloat16) if v.is_floating_point() and not fp32 else v for k, v in ckpt[STATE_DICT].items()
    }
    return small
