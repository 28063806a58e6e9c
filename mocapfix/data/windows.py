"""Clips -> fixed-length windows: joint selection, splitting by file, caching (resampling: core/resample.py).

Everything here is numpy: it runs once per dataset (then comes from the cache), not per batch.
"""

from __future__ import annotations

import fnmatch
import hashlib
import json
import zlib
from pathlib import Path

import numpy as np
import torch

from mocapfix.core.clip import Clip, MotionFileError
from mocapfix.core.skeleton import Skeleton
from mocapfix.io.npz import load_npz


def complete_windows(batch: dict) -> torch.Tensor:
    """(B,) bool: windows with no missing value (NaN) in their positions or rotations."""
    ok = torch.isfinite(batch["positions"]).flatten(1).all(1)
    if "rotations" in batch:
        ok &= torch.isfinite(batch["rotations"]).flatten(1).all(1)
    return ok


def select(batch: dict, keep: torch.Tensor) -> dict:
    """The windows of a batch where keep (B,) is True; values that are not per window as they are."""
    return {k: v[keep] if torch.is_tensor(v) and v.shape[:1] == keep.shape else v for k, v in batch.items()}


def spread_complete_batches(dataset, max_windows: int = 4096, batch_size: int = 512):
    """Up to max_windows windows spread evenly over the dataset, in batches, complete windows only
    (for statistics over a dataset without reading all of it)."""
    n = len(dataset)
    idx = torch.linspace(0, n - 1, min(n, max_windows)).round().long().unique().tolist()
    for i in range(0, len(idx), batch_size):
        batch = dataset.__getitems__(idx[i : i + batch_size])
        batch = select(batch, complete_windows(batch))
        if len(batch["positions"]):
            yield batch


def window_starts(num_frames: int, window: int, stride: int) -> np.ndarray:
    """Start frames of every full window; none for a clip shorter than one window."""
    if num_frames < window:
        return np.zeros(0, dtype=np.int64)
    return np.arange(0, num_frames - window + 1, stride, dtype=np.int64)


def split_of(
    source: str, val_fraction: float, test_fraction: float, seed: int, patterns: dict[str, list[str]] | None = None
) -> str:
    """'train' | 'val' | 'test' for a file. Whole files go to one split, so no clip leaks.

    Patterns (fnmatch on the file name, then on the full path) win; otherwise a seeded hash of
    the file name decides, stable across machines and runs (crc32, not python's hash()).
    """
    forced = pattern_split(source, patterns)
    if forced is not None:
        return forced
    name = Path(source).name
    u = zlib.crc32(f"{seed}:{name}".encode()) / 2**32
    if u < test_fraction:
        return "test"
    if u < test_fraction + val_fraction:
        return "val"
    return "train"


def pattern_split(source: str, patterns: dict[str, list[str]] | None) -> str | None:
    """The split a file's name (or full path) is forced into by an fnmatch pattern, else None."""
    name = Path(source).name
    for split in ("test", "val", "train"):
        for pat in (patterns or {}).get(split, []) or []:
            if fnmatch.fnmatch(name, pat) or fnmatch.fnmatch(source, pat):
                return split
    return None


def split_groups(groups: list[str], val_fraction: float, test_fraction: float, seed: int) -> dict[str, str]:
    """Each group (a performer's or session's folder) -> 'train' | 'val' | 'test', whole groups to
    one split, so that val and test hold performers training never saw. With a handful of groups
    a hash of each would often leave a split empty: the groups are ranked by a seeded hash
    instead, and the first round(fraction * n) of them (at least one for a fraction above 0) are
    test, the next val; at least one is left to train on."""
    names = sorted(set(groups), key=lambda g: zlib.crc32(f"{seed}:{g}".encode()))
    n = len(names)
    n_test = max(1, round(test_fraction * n)) if test_fraction > 0 else 0
    n_val = max(1, round(val_fraction * n)) if val_fraction > 0 else 0
    if n_test + n_val >= n:
        raise ValueError(
            f"data.split_by folder: {n} folders cannot give a test ({n_test}), a val ({n_val}) and a "
            "training split; give more folders of performers, or split_by: file"
        )
    return {g: "test" if i < n_test else "val" if i < n_test + n_val else "train" for i, g in enumerate(names)}


# --- cache: parsed, joint-selected, resampled clips as one npz ---

# What the readers and _prepare make of a file: bump it when that changes (a reader fix, a new
# meta field), so caches written by older code are parsed again instead of served stale.
# 2: session 8 (BVH fps from the printed frame time, csv fps and times).
# 3: session 9 (AMASS betas stored per frame were flattened: another body).
# 4: units from the body (any metres per unit), absurd values as missing, helper roots left out.
# 5: body parts from the rig's structure (skeleton labels), units from the legs (CMU: "asf"),
#    excursions (jumps) as missing, root OFFSETs that hold the rest height.
CACHE_VERSION = 5


def cache_key(files: list[Path], options: dict) -> str:
    h = hashlib.sha1(json.dumps({**options, "cache_version": CACHE_VERSION}, sort_keys=True, default=str).encode())
    for f in files:
        st = f.stat()
        h.update(f"{f.resolve()}|{st.st_size}|{st.st_mtime_ns}".encode())
    return h.hexdigest()[:16]


def save_clips(path: Path, clips: list[Clip], compact: bool = False) -> None:
    """All clips of one dataset in one npz (same skeleton); written atomically.

    compact: positions only, to the millimetre, about a sixth of the size (to carry a corpus of
    hours of motion to another machine): each clip's positions in int16 mm about its own origin,
    stored as frame-to-frame steps (small numbers, which zlib packs well) and compressed; missing
    tokens as a bit mask. load_clips reads both kinds."""
    path.parent.mkdir(parents=True, exist_ok=True)
    lengths = np.array([c.num_frames for c in clips], dtype=np.int64)
    arrays = {
        "lengths": lengths,
        "fps": np.array([c.fps for c in clips], dtype=np.float64),
        "header": np.array(
            json.dumps(
                {
                    "skeleton": clips[0].skeleton.to_dict(),
                    "names": [c.name for c in clips],
                    "sources": [c.source for c in clips],
                    "meta": [c.meta for c in clips],
                },
                default=str,
            )
        ),
    }
    if compact:
        arrays.update(_compact_positions(clips))
    else:
        arrays["positions"] = np.concatenate([c.positions for c in clips])
        if all(c.has_rotations for c in clips):
            arrays["rotations"] = np.concatenate([c.rotations for c in clips])
            arrays["root_translation"] = np.concatenate([c.root_translation for c in clips])
            arrays["offsets"] = np.stack([c.offsets for c in clips])
    tmp = path.with_name(path.name + ".tmp.npz")
    (np.savez_compressed if compact else np.savez)(tmp, **arrays)
    tmp.replace(path)


def _compact_positions(clips: list[Clip]) -> dict[str, np.ndarray]:
    origins, mm, missing = [], [], []
    for c in clips:
        finite = c.positions[np.isfinite(c.positions).all(-1)]  # (n, 3)
        origin = np.round(finite.mean(0) if len(finite) else np.zeros(3), 3).astype(np.float64)
        rel = np.nan_to_num(np.round((c.positions - origin) * 1000.0))
        if np.abs(rel).max(initial=0) > 32767:
            raise ValueError(f"{c.source or c.name}: a joint over 32 m from the clip's centre cannot be stored compact")
        origins.append(origin)
        mm.append(rel.astype(np.int16))
        missing.append(np.isnan(c.positions).any(-1))  # (T, J)
    mm = np.concatenate(mm)  # (F, J, 3) int16
    # steps in int16 arithmetic: wrapping is exact, and the running sum on loading undoes it
    steps = np.diff(mm, axis=0, prepend=np.zeros_like(mm[:1]))
    return {
        "positions_mm_steps": steps,
        "missing_bits": np.packbits(np.concatenate(missing).reshape(-1)),
        "origins_m": np.stack(origins),
    }


def _expand_positions(z, lengths: np.ndarray) -> np.ndarray:
    steps = z["positions_mm_steps"]  # (F, J, 3) int16
    mm = np.cumsum(steps, axis=0, dtype=np.int16)
    clip_of_frame = np.repeat(np.arange(len(lengths)), lengths)
    positions = (mm.astype(np.float32) / 1000.0 + z["origins_m"][clip_of_frame, None, :]).astype(np.float32)
    missing = np.unpackbits(z["missing_bits"], count=steps.shape[0] * steps.shape[1]).astype(bool)
    positions[missing.reshape(steps.shape[:2])] = np.nan
    return positions


def load_clips(path: Path) -> list[Clip]:
    z = load_npz(Path(path))
    if not isinstance(z, np.lib.npyio.NpzFile) or not (
        {"header", "lengths", "fps"} <= set(z.files) and ("positions" in z.files or "positions_mm_steps" in z.files)
    ):
        raise MotionFileError(
            path,
            "not an archive of parsed clips (the .npz the data cache and "
            "`scripts/gpu_session.sh prepare` write: header, positions, lengths, fps)",
        )
    with z:
        header = json.loads(str(z["header"]))
        skeleton = Skeleton.from_dict(header["skeleton"])
        bounds = np.concatenate([[0], np.cumsum(z["lengths"])])
        has_rot = "rotations" in z
        positions = z["positions"] if "positions" in z else _expand_positions(z, z["lengths"])
        rot = z["rotations"] if has_rot else None
        root = z["root_translation"] if has_rot else None
        offsets = z["offsets"] if has_rot else None
        clips = []
        for i, (a, b) in enumerate(zip(bounds[:-1], bounds[1:])):
            clips.append(
                Clip(
                    positions[a:b],
                    float(z["fps"][i]),
                    skeleton,
                    header["names"][i],
                    header["sources"][i],
                    rotations=rot[a:b] if has_rot else None,
                    root_translation=root[a:b] if has_rot else None,
                    offsets=offsets[i] if has_rot else None,
                    meta=header["meta"][i],
                )
            )
    return clips
