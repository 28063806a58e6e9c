"""Motion file readers: every format comes in as a list of Clips (metres, z up, NaN = missing).

read_motion(path, source) is the one entry point; list_motion_files finds the files of a folder.
Readers are imported inside the functions: AMASS pulls in torch and smplx, which reading a BVH
file should not pay for.
"""

from __future__ import annotations

import argparse
import inspect
import logging
import os
from pathlib import Path

import numpy as np

from mocapfix.core.clip import MAX_FPS, MIN_FPS, Clip, MotionFileError, check_frame_rate, shown

log = logging.getLogger(__name__)
SOURCES = ("auto", "bvh", "positions", "keypoints", "h36m", "amass")


def frame_rate(text: str) -> float:
    """--fps: a wrong command line (exit 2), not a failure of every file read with it."""
    try:
        fps = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not MIN_FPS <= fps <= MAX_FPS:
        raise argparse.ArgumentTypeError(f"must be {MIN_FPS:g} to {MAX_FPS:g} frames per second, got {text}")
    return fps


def add_read_arguments(parser, fps: bool = True) -> None:
    """The reader options every file-taking command shares (inspect, fix, render): an argparse
    parser. fps=False leaves --fps to the command (render: the animation's frame rate)."""
    parser.add_argument("--source", default="auto", choices=SOURCES)
    parser.add_argument(
        "--unit",
        default="auto",
        help="the file's unit: m, cm, mm, inch or metres per file unit (0.0564); auto: from the body",
    )
    parser.add_argument(
        "--up-axis", default="auto", help="override the file's up axis: z, y, -y (y down: a camera's axes), -z"
    )
    if fps:
        parser.add_argument("--fps", type=frame_rate, default=None, help="frame rate for files that lack one")
    parser.add_argument("--body-model", default=None, help="SMPL-H model file or folder (AMASS)")
    parser.add_argument(
        "--layout",
        default=None,
        help="a keypoint array's joint order (io/layouts.py): h36m17, coco17, mediapipe33, smpl24, openpose25, "
        "kinect20, kinect25, azure32; default: told from the joint count where one layout has it",
    )
    parser.add_argument(
        "--min-confidence",
        type=float,
        default=0.0,
        help="keypoints with a 4th column: a joint at or below this confidence in a frame is missing there",
    )


def read_options(args, fps: bool = True) -> dict:
    """What add_read_arguments parsed (--source aside), as read_motion's keyword arguments."""
    options = {"unit": args.unit, "up_axis": args.up_axis, "body_model_path": args.body_model}
    options.update(layout=args.layout, min_confidence=args.min_confidence)
    return {**options, "fps": args.fps} if fps else options


_EXTENSIONS = {
    "bvh": (".bvh",),
    "positions": (".npz", ".csv"),
    # .json (Azure Kinect's, MediaPipe's) and .txt (UTKinect / MSR Action3D skeletons): not in auto's walks
    "keypoints": (".npy", ".npz", ".skeleton", ".skl", ".json", ".txt"),
    "h36m": (".npz", ".txt"),  # .txt: the exponential-map files of the motion-prediction papers
    "amass": (".npz",),
    "auto": (".bvh", ".csv", ".npz", ".npy", ".skeleton", ".skl"),
}
# AMASS folders keep each subject's betas in shape.npz beside the motions: not a motion.
_NOT_MOTION = {"shape.npz"}


def _reader(source: str):
    if source == "bvh":
        from mocapfix.io.bvh import read_bvh

        return read_bvh
    if source == "positions":
        return _read_positions
    if source == "keypoints":
        return _read_keypoints
    if source == "h36m":
        return _read_h36m
    from mocapfix.io.amass import read_amass

    return read_amass


def _read_positions(
    path, unit="auto", up_axis="auto", fps=None, groups=None, min_confidence: float = 0.0
) -> list[Clip]:
    """A positions file (.npz, .csv: io/positions.py), or an Azure Kinect body-tracking CSV
    (timestamp;body_idx;... : io/azure_kinect_csv.py), told apart by its header."""
    from mocapfix.io.azure_kinect_csv import is_azure_kinect_csv, read_azure_kinect_csv
    from mocapfix.io.positions import read_positions

    if Path(path).suffix.lower() == ".csv" and is_azure_kinect_csv(path):
        return read_azure_kinect_csv(path, min_confidence, unit, fps, groups)
    return read_positions(path, unit, up_axis, fps, groups, min_confidence)


def _read_keypoints(
    path, layout=None, min_confidence: float = 0.0, unit="auto", up_axis="auto", fps=None, groups=None
) -> list[Clip]:
    """Keypoints as trackers hand them over: an array in a published layout (.npy/.npz,
    io/keypoints.py), Kinect v2 skeleton text (.skeleton, io/kinect_skeleton.py), a Kinect body
    log (.skl, io/kinect_log.py), Azure Kinect body tracking or MediaPipe's world landmarks (.json,
    io/azure_kinect.py, io/mediapipe_json.py) or the action datasets' Kinect v1 skeleton text
    (.txt, io/kinect_text.py)."""
    suffix = Path(path).suffix.lower()
    if suffix == ".txt":
        from mocapfix.io.kinect_text import read_kinect_text

        return read_kinect_text(path, unit, up_axis, fps, groups)
    if suffix == ".skeleton":
        from mocapfix.io.kinect_skeleton import read_kinect_skeleton

        return read_kinect_skeleton(path, min_confidence, unit, up_axis, fps, groups)
    if suffix == ".json":
        from mocapfix.io.azure_kinect import is_azure_kinect, read_azure_kinect
        from mocapfix.io.mediapipe_json import read_mediapipe_json
        from mocapfix.io.untrusted import read_json

        data = read_json(path, "JSON keypoints")
        if is_azure_kinect(data):
            return read_azure_kinect(path, unit, fps, groups, data)
        return read_mediapipe_json(path, data, min_confidence, unit, fps, groups)
    if suffix == ".skl":
        from mocapfix.io.kinect_log import read_kinect_log

        return read_kinect_log(path, min_confidence, unit, up_axis, fps, groups)
    from mocapfix.io.keypoints import read_keypoints

    return read_keypoints(path, layout, min_confidence, unit, up_axis, fps, groups)


def _read_h36m(path, unit: str = "auto", groups=None) -> list[Clip]:
    """Human3.6M either way it is published: VideoPose3D's positions (.npz, io/h36m.py) or one
    sequence's exponential maps (.txt, io/h36m_expmap.py)."""
    if Path(path).suffix.lower() == ".txt":
        from mocapfix.io.h36m_expmap import read_h36m_expmap

        return read_h36m_expmap(path, groups)
    from mocapfix.io.h36m import read_h36m

    return read_h36m(path, unit, groups)


def detect_source(path) -> str:
    """Format of a file from its extension and, for .npz, its keys (without loading the arrays)."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".bvh":
        return "bvh"
    if suffix == ".csv":
        return "positions"
    if suffix in (".npy", ".skeleton", ".skl", ".json"):  # keypoint arrays; Kinect text, logs; JSON (Azure, MediaPipe)
        return "keypoints"
    if suffix == ".txt":  # named alone: a folder's .txt files are listed only for --source h36m / keypoints
        return _text_source(path)
    if suffix == ".npz":
        from mocapfix.io.npz import listed_keys, load_npz

        with load_npz(path) as data:
            keys = set(data.files)
        if "positions_3d" in keys:
            return "h36m"
        if {"poses", "trans"} <= keys:
            return "amass"
        if "positions" in keys and keys & {"joint_names", "parents"}:
            return "positions"
        from mocapfix.io.keypoints import array_key

        if array_key(keys) is not None:  # no names, no tree: a published layout's
            return "keypoints"
        raise MotionFileError(
            path,
            f"npz with unknown keys ({listed_keys(list(keys))}); expected positions (positions file or "
            "keypoints), keypoints3d / keypoints / reconstruction (keypoints), positions_3d (Human3.6M) "
            "or poses+trans (AMASS)",
        )
    raise MotionFileError(
        path,
        f"unknown file type {suffix or '(no extension)'!r}; "
        "known: .bvh, .csv, .npz, .npy, .skeleton, .skl, .json, .txt",
    )


def _text_source(path: Path) -> str:
    """A .txt file's source by its first line: comma-separated exponential maps (Human3.6M) or a
    Kinect skeleton's whitespace-separated numbers (UTKinect-Action3D, MSR Action3D)."""
    from mocapfix.io.kinect_text import kinect_text_kind
    from mocapfix.io.untrusted import open_regular

    with open_regular(path, "text file") as f:
        first = f.read(64 << 10).decode("utf-8", errors="replace").lstrip().split("\n", 1)[0]
    if not first.strip():
        raise MotionFileError(path, "empty file")
    if "," in first:
        return "h36m"
    if kinect_text_kind(first) is not None:
        return "keypoints"
    raise MotionFileError(
        path,
        f"a .txt file with {len(first.split())} value(s) on its first line: neither Human3.6M exponential maps "
        "(99, comma-separated) nor a Kinect skeleton (UTKinect-Action3D 61, MSR Action3D 4)",
    )


def read_motion(path, source: str = "auto", **options) -> list[Clip]:
    """One motion file -> its clips (one per person, or per sequence for Human3.6M).

    source: "auto" (by extension and npz keys), "bvh", "positions", "keypoints", "h36m" or "amass".
    options go to the reader when it takes them (unit, up_axis, fps, groups, body_model_path,
    gender, layout, min_confidence); the others are dropped, so one set of options serves a folder of mixed files."""
    path = Path(path)
    if source not in SOURCES:
        raise MotionFileError(path, f"unknown source type {source!r}; known: {', '.join(SOURCES)}")
    if not path.exists():
        raise MotionFileError(path, "no such file")
    if path.is_dir():
        raise MotionFileError(path, "is a folder, not a motion file")
    if source == "auto":
        source = detect_source(path)
    reader = _reader(source)
    accepted = inspect.signature(reader).parameters
    # A file's numbers can be anything (1e308, inf): the readers make such values missing and say
    # so; numpy's overflow warnings on the way would be lines of noise before that one message.
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        clips = reader(path, **{k: v for k, v in options.items() if k in accepted})
        return [_checked(c) for c in clips]


def _checked(clip: Clip) -> Clip:
    """What every reader's clip goes through: absurd values made missing (io/absurd.py), the
    body's stature in meta, and a warning when that is not a human height (a wrong unit)."""
    from mocapfix.io.absurd import drop_absurd
    from mocapfix.io.conventions import stature_m, stature_warning
    from mocapfix.rig.structure import body_structure

    check_frame_rate(clip.source or clip.name, clip.fps)
    names, parents = clip.skeleton.joint_names, clip.skeleton.parents
    if not clip.skeleton.labels:  # the BVH reader placed them already (it needs them for the unit)
        structure = body_structure(parents, clip.positions, names, source=clip.source or clip.name)
        if structure is not None:
            clip = clip.replace(skeleton=clip.skeleton.with_labels(structure.labels))
    stature = stature_m(clip.positions, names, parents, clip.skeleton.labels)
    # The warning weighs what drop_absurd makes missing for being out of reach against what was
    # seen before it: a reader's non-finite values (a BVH's NaN channels, the way to mark a joint
    # missing) count in absurd_tokens but were never seen, and no unit would bring them in reach.
    seen = int((~clip.missing_mask()).sum())
    out_of_reach = clip.meta.get("out_of_reach_tokens", 0)
    clip = drop_absurd(clip, stature)
    clip.meta["stature_m"] = stature
    warning = stature_warning(stature, clip.meta, clip.source or clip.name)
    lost = clip.meta.get("out_of_reach_tokens", 0) - out_of_reach
    if seen and lost >= 0.5 * seen:  # data never silently becomes a hole
        warning = (
            f"{shown(clip.source or clip.name)}: {100 * lost / seen:.0f} % of the observed joint positions are "
            f"beyond any body's reach at unit {clip.meta.get('unit', '?')} and were read as missing: "
            "a wrong unit (--unit) or not a body?"
        )
    if warning:
        clip.meta["warning"] = warning
        log.warning("warning: %s", warning)
    return clip


# A folder of takes holds thousands of files (AMASS: about 18,000 with its folders). A walk that
# meets more entries than this is not in one (`--library ~`, a whole disk): it stops and says so.
MAX_FOLDER_ENTRIES = 100_000


def list_motion_files(path, source: str = "auto", on_error=None, max_entries: int = MAX_FOLDER_ENTRIES) -> list[Path]:
    """A file -> [it]; a folder -> its motion files for `source` (recursive, sorted, by extension).
    A subfolder that cannot be read is a MotionFileError, or on_error(that error) and the walk
    goes on (fix and inspect report it and run the other files).

    The walk is bounded: links to folders are not followed (a link cycle cannot trap it; a
    `warning:` line counts them and names the first, so a folder of linked folders is not taken
    for one without takes), only regular files are listed (a FIFO or a link to a device is not a
    take), a file system root is refused at once, and a folder with more than max_entries files
    and folders below it is a MotionFileError as soon as the walk has counted them."""
    path = Path(path)
    if source not in SOURCES:
        raise MotionFileError(path, f"unknown source type {source!r}; known: {', '.join(SOURCES)}")
    if not path.is_dir():
        if os.path.lexists(path):  # a file, or something that is not one: its reader says which
            return [path]
        raise MotionFileError(path, "no such file or folder")
    real = path.resolve()
    if real == Path(real.anchor):
        raise MotionFileError(path, "the file system root is not a folder of takes: name the folder that holds them")
    exts = _EXTENSIONS[source]

    def unreadable(e: OSError):  # rglob would skip such a folder without a word
        error = MotionFileError(e.filename or path, f"cannot read this folder ({e.strerror or type(e).__name__})")
        if on_error is None:
            raise error
        on_error(error)

    found, seen, linked = [], 0, []
    for root, folders, names in os.walk(path, onerror=unreadable):  # followlinks=False: no cycles
        seen += len(folders) + len(names)
        if seen > max_entries:
            raise MotionFileError(
                path,
                f"more than {max_entries:,} files and folders below this folder, not a folder of takes: "
                "name the folder that holds them",
            )
        found.extend(Path(root) / name for name in names)
        linked.extend(p for p in (Path(root) / name for name in folders) if p.is_symlink())
    if linked:
        log.warning(
            "warning: %s: links to folders are not followed, %d here (%s%s): "
            "give a linked folder itself to read its takes",
            shown(path),
            len(linked),
            shown(min(linked)),
            ", ..." if len(linked) > 1 else "",
        )
    return sorted(
        p
        for p in found
        if p.suffix.lower() in exts and p.name.lower() not in _NOT_MOTION and not p.name.startswith(".") and p.is_file()
    )
