"""A motion library kept in a file between runs (`fix --library TAKES --library-index FILE`).

Reading a library is most of what `--library` costs a run that fixes one take: parsing up to
LIBRARY_S of BVH or keypoint files and putting each take on the model's joints (about 2 CPU-s for
Bandai's first 10 minutes on this project's 2-core machine, against 0.01 s to load them from
here). The file keeps the takes as the search starts from them (float32, the model's joints, each
at its own fps) with the keys that hide a take from its own search; the searched copies (mirror
image, tempos) are made again on first use (MotionLibrary.frames: a fraction of a second), so the
file is a tenth of their size and serves takes of any rate.

The file is trusted with nothing: a signature of the takes' files (resolved path, size,
modification time) and of everything their reading depends on (the model's joints, --source, the
read options, --joint-map, LIBRARY_S) decides whether it is this library; any other file, a
changed take or another model, and the library is read again from the takes and the file
rewritten. It is read without pickle (io/npz.py) and checked array by array.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np

from mocapfix.core.clip import MotionFileError, check_frame_rate
from mocapfix.core.skeleton import Skeleton
from mocapfix.data.augment import mirror_of
from mocapfix.fills.motion_matching import LIBRARY_S, MotionLibrary, torso_of
from mocapfix.io.files import atomic_write
from mocapfix.io.npz import load_npz, npz_array

INDEX_FORMAT = 1  # bumped whenever what is saved, or how a take is read onto the joints, changes


def library_signature(files: list[Path], skeleton: Skeleton, settings: dict) -> str:
    """What a library index must have been made from: these files as they are now (resolved path,
    size, modification time in ns), the model's joints and the reading's settings (JSON-able:
    source, read options, joint map) -> a hex digest. A file that cannot be stat'ed counts as
    changed (it is read, and its error reported, as without an index)."""
    listed = []
    for f in files:
        try:
            st = Path(f).stat()
            listed.append([str(Path(f).resolve()), st.st_size, st.st_mtime_ns])
        except OSError:
            listed.append([str(f), -1, -1])
    what = {
        "format": INDEX_FORMAT,
        "library_s": LIBRARY_S,
        "joints": list(skeleton.joint_names),
        "parents": [int(p) for p in skeleton.parents],
        "settings": settings,
        "files": listed,
    }
    return hashlib.sha256(json.dumps(what, sort_keys=True, default=str).encode()).hexdigest()


def save_library(path: Path, library: MotionLibrary, signature: str, files_read: int, files_unread: int) -> None:
    """The library's takes (at least one) and keys into `path` (atomically: a run stopped while
    writing leaves the previous file or none)."""
    arrays = {
        "format": np.int64(INDEX_FORMAT),
        "signature": np.array(signature),
        "positions": np.concatenate([x for x, _ in library.takes]).astype(np.float32),  # (N, J, 3)
        "lengths": np.array([len(x) for x, _ in library.takes], dtype=np.int64),
        "fps": np.array([fps for _, fps in library.takes], dtype=np.float64),
        "key_files": np.array([str(k[0]) for k in library.keys], dtype=str),
        "key_clips": np.array([int(k[1]) for k in library.keys], dtype=np.int64),
        "files_read": np.int64(files_read),
        "files_unread": np.int64(files_unread),
    }
    atomic_write(Path(path), lambda f: np.savez(f, **arrays))


def load_library(path: Path, signature: str, skeleton: Skeleton) -> tuple[MotionLibrary, int, int] | None:
    """The library saved in `path` -> (it, files read, files not read when it was made); None
    where there is no file, or it was made from other takes or settings (`signature`). A file
    that is not a library index, or is damaged, is a MotionFileError naming it."""
    path = Path(path)
    if not path.exists():
        return None
    with load_npz(path, "library index") as data:
        missing = {"format", "signature", "positions", "lengths", "fps", "key_files", "key_clips"} - set(data.files)
        if missing:
            raise MotionFileError(path, f"not a mocapfix library index (no {', '.join(sorted(missing))})")
        arrays = {key: npz_array(path, data, key) for key in data.files}

    def whole(key: str) -> int | None:  # a scalar whole number, else None
        a = arrays.get(key)
        return int(a) if a is not None and a.shape == () and np.issubdtype(a.dtype, np.integer) else None

    made_as = whole("format")
    if made_as is None or arrays["signature"].shape != () or arrays["signature"].dtype.kind != "U":
        raise MotionFileError(path, "not a mocapfix library index (its format or signature is not one)")
    if made_as != INDEX_FORMAT or str(arrays["signature"]) != signature:
        return None  # another version's, or made from other takes or settings: made again
    positions, lengths, fps = arrays["positions"], arrays["lengths"], arrays["fps"]
    J = len(skeleton.joint_names)
    if positions.dtype != np.float32 or positions.ndim != 3 or positions.shape[1:] != (J, 3):
        raise MotionFileError(path, f"positions {positions.dtype} {positions.shape}, expected float32 (N, {J}, 3)")
    if np.isinf(positions).any():
        raise MotionFileError(path, "positions hold infinite values")
    if lengths.ndim != 1 or not len(lengths) or not np.issubdtype(lengths.dtype, np.integer) or (lengths < 1).any():
        raise MotionFileError(path, "lengths are not one or more positive whole numbers of frames")
    if lengths.sum() != len(positions):
        raise MotionFileError(path, f"lengths add up to {lengths.sum()} frames, positions hold {len(positions)}")
    K = len(lengths)
    kinds = {"fps": ("f", "frame rates"), "key_files": ("U", "file names"), "key_clips": ("i", "whole numbers")}
    for name, (kind, what) in kinds.items():
        if arrays[name].shape != (K,) or arrays[name].dtype.kind != kind:
            a = arrays[name]
            raise MotionFileError(path, f"{name} is {a.dtype} {a.shape}, expected {K} {what}, one per take")
    for rate in fps:
        check_frame_rate(path, rate)
    ends = np.cumsum(lengths)
    takes = [(positions[e - n : e], float(rate)) for e, n, rate in zip(ends, lengths, fps)]
    keys = [(str(f), int(c)) for f, c in zip(arrays["key_files"], arrays["key_clips"])]
    library = MotionLibrary(takes, keys, mirror_of(skeleton), torso_of(skeleton))
    return library, whole("files_read") or 0, whole("files_unread") or 0
