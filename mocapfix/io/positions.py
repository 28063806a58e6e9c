"""Plain joint positions (.npz, .csv): the way tracking systems hand their output over.

Both layouts carry the same things: positions of J joints over T frames for P people, the
frame rate, the skeleton (parents and/or joint names), the unit and the up axis. Missing
joints are NaN (npz) or empty cells (csv). docs/data-formats.md shows examples.

npz: keys
    positions   (T, J, 3) or (P, T, J, 3) numbers           required
    fps         scalar > 0                                   required (or the reader's fps=)
    parents     (J,) ints, parents[0] == -1, parent < child  parents and/or joint_names
    joint_names (J,) strings                                 (names alone must match a preset)
    unit        "m" | "cm" | "mm"                            optional (guessed from bone lengths)
    up_axis     "z" | "y" | "-y" | "-z"                      optional, default "z" ("-y": y down)

csv: optional "# key=value" comment lines, then a header row, then one row per person and frame
    # fps=30 unit=m up_axis=z
    # parents=-1,0,1,2
    person,frame,time,Hip_x,Hip_y,Hip_z,RHip_x,RHip_y,RHip_z,...
    0,0,0,0.01,0.02,0.93,...
  - comment keys: fps, unit, up_axis (or up), parents (comma-separated ints, no spaces).
  - person (optional): any label; one clip per distinct label. Without it, one person.
  - frame (optional): integer frame number; frames with no row are missing. Without it the
    rows of each person are consecutive frames.
  - time (optional): seconds; gives fps when no "# fps=" line does (frames counted over the
    time they took, _fps_from_times); kept per frame (meta "times") and written back as read.
  - joint columns: <joint>_x, <joint>_y, <joint>_z, consecutive, in skeleton order; the
    joint names are the header's prefixes. An empty cell or "nan" is missing; a joint with
    any missing coordinate is missing. `<joint>.x` (Azure Kinect's CSV recorders) reads the same.
    A 4th column per joint, <joint>_visibility (or _confidence, _score: CONFIDENCE_WORDS; every
    joint or none), is its confidence: at or below min_confidence the joint is missing in that
    row (MediaPipe landmark dumps); it is written back as read.

Readers return Clips in metres, z up (y-up data is turned by +90 degrees about x:
(x, y, z) -> (x, -z, y)); the writers undo both so that `fix` writes outputs in the input's
layout (write_clips uses what the reader put into clip.meta).
"""

from __future__ import annotations

import csv
import re
from pathlib import Path

import numpy as np

from mocapfix.core.clip import NEAR_ORIGIN_M, Clip, MotionFileError, check_frame_rate, origin_near
from mocapfix.core.skeleton import PRESETS, Skeleton
from mocapfix.io.conventions import UP_AXES, from_z_up, guess_up_axis, parse_unit, resolve_unit, to_z_up
from mocapfix.io.files import atomic_write
from mocapfix.io.layouts import LAYOUTS, layout_skeleton
from mocapfix.io.npz import deflated, listed_keys, load_npz, npz_array
from mocapfix.io.npz import one_line as _one_line
from mocapfix.io.untrusted import printable, quoted, read_bytes
from mocapfix.rig.labels import guess_groups

_SPECIAL_COLUMNS = ("person", "frame", "time")
CONFIDENCE_WORDS = ("visibility", "vis", "confidence", "conf", "score", "c")  # a joint's 4th column


# --- skeleton from what a file gives ---


def skeleton_from(path: Path, joint_names, parents, num_joints: int, groups=None) -> Skeleton:
    """Preset when the names match one, else a custom skeleton with guessed limb groups."""
    if joint_names is not None and len(joint_names) != num_joints:
        raise MotionFileError(path, f"{len(joint_names)} joint names for {num_joints} joints")
    if parents is not None and len(parents) != num_joints:
        raise MotionFileError(path, f"{len(parents)} parents for {num_joints} joints")
    try:
        skel = None
        if joint_names is not None:
            names = tuple(str(n) for n in joint_names)
            for p in PRESETS.values():
                if names == p.joint_names and (parents is None or tuple(int(i) for i in parents) == p.parents):
                    skel = p
                    break
            if skel is None and parents is None:
                skel = _named_layout(path, names)
            if skel is None:
                if parents is None:
                    raise MotionFileError(path, f"joint names match no preset ({', '.join(PRESETS)}); give parents too")
                skel = Skeleton(names, tuple(parents), name="custom")
                skel = Skeleton(names, skel.parents, guess_groups(names, skel.parents), "custom")
        elif parents is not None:
            skel = Skeleton(tuple(f"joint{j}" for j in range(num_joints)), tuple(parents), name="custom")
        else:
            raise MotionFileError(path, "needs parents and/or joint_names to know the skeleton")
        if groups:
            skel = skel.with_groups(groups)
        return skel
    except (ValueError, KeyError) as e:
        if isinstance(e, MotionFileError):
            raise
        raise MotionFileError(path, _one_line(e).split(": ", 1)[-1]) from None


def _named_layout(path: Path, names: tuple[str, ...]) -> Skeleton | None:
    """The skeleton of the published keypoint layout whose joint names these are, in its order, any
    case, or each after one prefix they share (io/layouts.py: FreeMoCap's `mediapipe_body_3d_xyz.csv`
    names MediaPipe's 33 landmarks, `nose_x`, and since FreeMoCap 1.4 `body_nose_x`), under the
    file's own names; None where they are no layout's."""
    lowered = tuple(n.lower() for n in names)
    head = lowered[0].split("_", 1)[0] + "_"
    readings = [lowered] + (
        [tuple(n[len(head) :] for n in lowered)] if all(n.startswith(head) for n in lowered) else []
    )
    lay = next((lay for lay in LAYOUTS.values() if tuple(n.lower() for n in lay.joint_names) in readings), None)
    if lay is None:
        return None
    skel, order = layout_skeleton(lay)
    if order != list(range(len(order))):  # its tree is not parents-first in the file's order
        raise MotionFileError(path, f"joint names are the {lay.name} layout's, in an order that needs parents given")
    return Skeleton(names, skel.parents, skel.groups, lay.name, labels=skel.labels)


def _resolve_up(path, up_opt, up_file, raw, skeleton) -> str:
    for up, source in ((up_opt, "option"), (up_file, "file")):
        if up is not None and up != "auto":
            up = str(up).lower()
            if up not in UP_AXES:
                raise MotionFileError(path, f"unknown up axis {quoted(up)} (from {source}); use {', '.join(UP_AXES)}")
            return up
    return guess_up_axis(raw, skeleton.joint_names, skeleton.parents, skeleton.labels, signed=True)


def _check_fps(path, fps) -> float:
    return check_frame_rate(path, fps, "fps is")


def _clips(
    path: Path,
    raw: np.ndarray,
    fps: float,
    skeleton: Skeleton,
    unit_opt,
    unit_file,
    up_opt,
    up_file,
    fmt: str,
    layout: list[dict],
) -> list[Clip]:
    """raw: (P, T, J, 3) in the file's unit and axes -> P clips in metres, z up."""
    unit = resolve_unit(path, unit_opt, unit_file, raw, skeleton.joint_names, skeleton.parents)
    up_axis = _resolve_up(path, up_opt, up_file, raw, skeleton)
    with np.errstate(invalid="ignore", over="ignore"):
        pos = to_z_up(raw.astype(np.float64) * unit.metres, up_axis)  # (P, T, J, 3) float64
        # one origin for the file's people (written back together); float32 only after it is taken off
        origin = origin_near(pos)
        pos = (pos - origin).astype(np.float32)
    P = pos.shape[0]
    clips = []
    for i in range(P):
        meta = {
            "format": fmt,
            "person": i,
            "people": P,
            "unit": unit.name,
            "unit_source": unit.how,
            "up_axis": up_axis,
            **layout[i],
        }
        name = path.stem + (f"#p{i}" if P > 1 else "")
        clips.append(Clip(pos[i], fps, skeleton, name=name, source=str(path), meta=meta, origin=origin))
    return clips


# --- npz ---


def _npz_scalar_str(path, data, key) -> str | None:
    if key not in data.files:
        return None
    a = npz_array(path, data, key)
    if a.size != 1:
        raise MotionFileError(path, f"{key!r} must be one string, got shape {a.shape}")
    v = a.reshape(()).item()
    return v.decode() if isinstance(v, bytes) else str(v)


def read_positions_npz(
    path, unit: str = "auto", up_axis: str = "auto", fps: float | None = None, groups=None
) -> list[Clip]:
    path = Path(path)
    with load_npz(path) as data:
        if "positions" not in data.files:
            raise MotionFileError(path, f"no 'positions' array (keys: {listed_keys(data.files)})")
        raw = npz_array(path, data, "positions")
        if raw.dtype.kind not in "iuf":
            raise MotionFileError(path, f"positions must be numbers, got dtype {raw.dtype}")
        if raw.ndim not in (3, 4) or raw.shape[-1] != 3 or 0 in raw.shape:
            raise MotionFileError(
                path, f"positions must be (frames, joints, 3) or (people, frames, joints, 3), got {raw.shape}"
            )
        squeeze = raw.ndim == 3
        raw = raw[None] if squeeze else raw
        J = raw.shape[2]
        if fps is None:
            if "fps" not in data.files:
                raise MotionFileError(path, "no 'fps' value")
            f = npz_array(path, data, "fps")
            if f.size != 1 or f.dtype.kind not in "iuf":
                raise MotionFileError(path, f"fps must be one number, got {f.dtype} of shape {f.shape}")
            fps = f.reshape(()).item()
        fps = _check_fps(path, fps)
        parents = names = None
        if "parents" in data.files:
            parents = npz_array(path, data, "parents")
            if parents.ndim != 1 or parents.dtype.kind not in "iu":
                raise MotionFileError(
                    path, f"parents must be a list of ints, got {parents.dtype} of shape {parents.shape}"
                )
            parents = parents.tolist()
        if "joint_names" in data.files:
            names = npz_array(path, data, "joint_names")
            if names.ndim != 1 or names.dtype.kind not in "US":
                raise MotionFileError(
                    path, f"joint_names must be a list of strings, got {names.dtype} of shape {names.shape}"
                )
            names = [n.decode() if isinstance(n, bytes) else str(n) for n in names.tolist()]
        skel = skeleton_from(path, names, parents, J, groups)
        unit_file, up_file = _npz_scalar_str(path, data, "unit"), _npz_scalar_str(path, data, "up_axis")
        compressed = deflated(data)
    layout = [{"squeeze": squeeze, "compressed": compressed}] * raw.shape[0]
    return _clips(path, raw, fps, skel, unit, unit_file, up_axis, up_file, "positions-npz", layout)


# --- csv ---


def _parse_comments(path, lines) -> tuple[dict, int]:
    """Leading '# key=value' lines -> (dict, index of the first other line)."""
    meta, i = {}, 0
    while i < len(lines) and (not lines[i].strip() or lines[i].lstrip().startswith("#")):
        for token in lines[i].lstrip().lstrip("#").split():
            if "=" in token:
                k, v = token.split("=", 1)
                meta[k.strip().lower()] = v.strip()
        i += 1
    return meta, i


def _joint_columns(path, header: list[str]) -> tuple[dict, list[str], list[int], list[int] | None, str]:
    """header -> ({special column: index}, joint names, [x column of each joint], [confidence
    column of each joint] or None, the separator before x/y/z: "_" or ".")."""
    special, rest = {}, []
    for c, h in enumerate(header):
        key = h.strip().lower()
        if key in _SPECIAL_COLUMNS:
            if key in special:
                raise MotionFileError(path, f"column {quoted(key)} appears twice")
            special[key] = c
        else:
            rest.append(c)
    if not rest:
        raise MotionFileError(path, "no joint columns (<joint>_x, <joint>_y, <joint>_z)")
    names, x_cols, conf_cols, seps = [], [], [], set()
    k = 0
    while k < len(rest):
        triple = rest[k : k + 3]
        cols = [header[c].strip() for c in triple]
        m = re.fullmatch(r"(.+)([_.])[xX]", cols[0])
        ok = (
            len(triple) == 3
            and m is not None
            and triple == list(range(triple[0], triple[0] + 3))
            and [c.lower() for c in cols[1:]] == [(m.group(1) + m.group(2)).lower() + a for a in "yz"]
        )
        if not ok:
            raise MotionFileError(
                path,
                f"header columns {triple[0] + 1} to {triple[0] + len(triple)} are not <joint>_x,<joint>_y,<joint>_z",
            )
        names.append(m.group(1))
        x_cols.append(triple[0])
        seps.add(m.group(2))
        k += 3
        prefix = (m.group(1) + m.group(2)).lower()
        after = rest[k] if k < len(rest) else None  # a 4th column of this joint: its confidence
        if after == triple[2] + 1 and header[after].strip().lower() in {prefix + w for w in CONFIDENCE_WORDS}:
            conf_cols.append(after)
            k += 1
    if len(set(names)) != len(names):
        twice = next(n for k, n in enumerate(names) if n in names[:k])
        raise MotionFileError(path, f"joint {quoted(twice)} appears twice in the header")
    if len(seps) > 1:
        raise MotionFileError(path, "joint columns named both <joint>_x and <joint>.x")
    if conf_cols and len(conf_cols) != len(names):
        raise MotionFileError(
            path, f"{len(conf_cols)} of {len(names)} joints have a confidence column: every joint or none"
        )
    return special, names, x_cols, conf_cols or None, seps.pop()


def _to_float(path, cells: np.ndarray, header: list[str], cols: list[int], lines: list[int]) -> np.ndarray:
    """cells: (N, C) strings -> (N, C) float64; '' and 'nan' -> NaN; anything else non-numeric is
    an error naming its line (lines: (N,) the file's line number of each row) and column."""
    try:  # fast path: numpy parses " 1.5" and "nan" itself; only blank cells need a word
        return np.where(cells == "", "nan", cells).astype(np.float64)
    except ValueError:
        pass
    cells = np.char.strip(cells)
    cells = np.where(cells == "", "nan", cells)
    try:
        return cells.astype(np.float64)
    except ValueError:
        for r in range(cells.shape[0]):
            for c in range(cells.shape[1]):
                try:
                    float(cells[r, c])
                except ValueError:
                    raise MotionFileError(
                        path, f"line {lines[r]}: column {cols[c] + 1} ({quoted(header[cols[c]])}) is not a number"
                    ) from None
        raise


def _time_resolution(cells: np.ndarray) -> float:
    """cells: (N,) time column text -> the step its decimals resolve (0.001 for "0.033"), 0 when a
    cell has an exponent (no telling)."""
    s = np.char.lower(np.char.strip(cells))
    if (np.char.find(s, "e") >= 0).any():
        return 0.0
    dot = np.char.find(s, ".")
    decimals = np.where(dot >= 0, np.char.str_len(s) - dot - 1, 0)
    return 10.0 ** -int(decimals.max())


def _fps_from_times(path, times: np.ndarray, frame: np.ndarray, person: np.ndarray, resolution: float = 0.0) -> float:
    """Frames per second from the steps between a person's consecutive rows (seconds).

    The median seconds per frame d0 tells how many frames each step spans, round(dt / d0), so
    skipped frames count whether or not there are frame numbers; fps = frames counted / time
    they took. The median of per-step rates instead is biased by rounded times: 30 fps in ms
    (0.033, 0.067, 0.100, ...) has steps 0.033/0.034 and a median rate of 30.3.
    resolution: seconds the time text resolves (0.001 for ms), for snapping to a whole fps."""
    order = np.lexsort((frame, person))
    t, f, p = times[order], frame[order], person[order]
    with np.errstate(over="ignore", invalid="ignore"):  # times of +-1e308: an infinite step, left out below
        dt = np.diff(t)
    df = np.diff(f)
    ok = (np.diff(p) == 0) & (df > 0) & np.isfinite(dt) & (dt > 0)
    if not ok.any():
        raise MotionFileError(path, "no '# fps=' line and too few times in the time column to tell the fps")
    runs = int(ok[0]) + int((ok[1:] & ~ok[:-1]).sum())  # stretches of good steps: each spans t_end - t_start
    dt, df = dt[ok], df[ok]
    d0 = float(np.median(dt / df))  # seconds per frame
    span = float(dt.sum())
    fps = float(np.round(dt / d0).sum()) / span
    # Rounded times leave each stretch's span off by up to one resolution step: 1/0.0333333 is
    # 30.00003, and 30 fps in ms over 2 s is 29.995; both mean 30. Capped, so that 29.97 stays.
    tol = min(5e-4, max(1e-4, resolution * runs / span))
    return float(round(fps)) if abs(fps - round(fps)) <= tol * fps else fps


def _frame_times(tt: np.ndarray, fps: float) -> np.ndarray | None:
    """tt: (P, T) seconds from the time column, NaN where a person has no row (or an empty cell)
    -> (P, T) with the gaps filled: from the other people's rows at that frame (mean: they
    normally agree), else linear in the frame index between the nearest frames with a time,
    1 / fps per frame past either end. None when no row has a time."""
    known = np.isfinite(tt)
    n = known.sum(axis=0)  # (T,)
    if not n.any():
        return None
    shared = np.where(known, tt, 0.0).sum(axis=0) / np.maximum(n, 1)  # (T,)
    k = np.nonzero(n)[0]
    f = np.arange(tt.shape[1])
    fill = np.interp(f, k, shared[k])
    fill = np.where(f < k[0], shared[k[0]] - (k[0] - f) / fps, fill)
    fill = np.where(f > k[-1], shared[k[-1]] + (f - k[-1]) / fps, fill)
    return np.where(known, tt, fill)


def read_positions_csv(
    path, unit: str = "auto", up_axis: str = "auto", fps: float | None = None, groups=None, min_confidence: float = 0.0
) -> list[Clip]:
    path = Path(path)
    try:
        raw_text = read_bytes(path, "CSV file")  # a regular file only, no further than its size
    except OSError as e:
        raise MotionFileError(path, f"cannot read ({e.strerror or type(e).__name__})") from None
    try:
        text = raw_text.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        raise MotionFileError(path, f"cannot read as text: not UTF-8 (byte {e.start})") from None
    del raw_text
    lines = text.splitlines()
    comments, start = _parse_comments(path, lines)
    if start >= len(lines):
        raise MotionFileError(path, "empty file" if not comments else "no header row")
    rows = []  # (line number, cells)
    reader = csv.reader(lines[start:])
    try:
        for k, cells in enumerate(reader):
            if cells and (len(cells) > 1 or cells[0].strip()):
                rows.append((start + k + 1, cells))
    except csv.Error as e:  # a cell over csv's field limit (128 KiB), a NUL byte: never a table of numbers
        raise MotionFileError(path, f"line {start + reader.line_num}: not CSV ({printable(e, 60)})") from None
    header = [h.strip() for h in rows[0][1]]
    special, names, x_cols, conf_cols, separator = _joint_columns(path, header)
    data_rows = rows[1:]
    if not data_rows:
        raise MotionFileError(path, "no data rows after the header")
    for line, cells in data_rows:
        if len(cells) != len(header):
            raise MotionFileError(path, f"line {line} has {len(cells)} cells, the header has {len(header)}")
    cells = np.array([c for _, c in data_rows], dtype=str)  # (N, C)
    lines_of_rows = [line for line, _ in data_rows]
    J = len(names)
    coord_cols = [c + k for c in x_cols for k in range(3)]
    xyz = _to_float(path, cells[:, coord_cols], header, coord_cols, lines_of_rows).reshape(-1, J, 3)
    xyz[np.isnan(xyz).any(axis=-1)] = np.nan  # a joint with a missing coordinate is missing
    if conf_cols is not None:
        confidence = _to_float(path, cells[:, conf_cols], header, conf_cols, lines_of_rows)  # (N, J)
        seen = confidence > min_confidence  # NaN: not seen
        if not seen.any():
            raise MotionFileError(path, f"no joint has a confidence above {min_confidence:g} in any row")
        xyz[~seen] = np.nan

    # people: one clip per label, numeric labels in numeric order
    N = len(data_rows)
    if "person" in special:
        labels = np.char.strip(cells[:, special["person"]])
        if (labels == "").any():
            raise MotionFileError(path, f"line {data_rows[int(np.argmax(labels == ''))][0]}: empty person cell")
        uniq = list(dict.fromkeys(labels.tolist()))
        try:
            uniq.sort(key=float)
        except ValueError:
            uniq.sort()
        index = {s: i for i, s in enumerate(uniq)}
        person = np.array([index[s] for s in labels.tolist()], dtype=np.int64)
    else:
        uniq, person = ["0"], np.zeros(N, dtype=np.int64)

    times = None
    if "time" in special:
        times = _to_float(path, cells[:, [special["time"]]], header, [special["time"]], lines_of_rows)[:, 0]
    if "frame" in special:
        f = _to_float(path, cells[:, [special["frame"]]], header, [special["frame"]], lines_of_rows)[:, 0]
        with np.errstate(invalid="ignore"):
            bad = ~(np.abs(f) < 1e15) | (f != np.round(f))  # also NaN; 1e300 would not cast to int64
        if bad.any():
            raise MotionFileError(path, f"line {data_rows[int(np.argmax(bad))][0]}: frame must be an integer")
        frame = f.astype(np.int64)
    else:  # consecutive rows of a person are consecutive frames
        frame = np.zeros(N, dtype=np.int64)
        for p in range(len(uniq)):
            frame[person == p] = np.arange((person == p).sum())
    if fps is None and "fps" in comments:
        try:
            fps = float(comments["fps"])
        except ValueError:
            raise MotionFileError(path, "'# fps=' is not a number") from None
    if fps is None and times is not None:
        fps = _fps_from_times(path, times, frame, person, _time_resolution(cells[:, special["time"]]))
    if fps is None:
        raise MotionFileError(path, "no fps: add a '# fps=30' line or a time column in seconds")
    fps = _check_fps(path, fps)
    first_frame = int(frame.min())
    T = int(frame.max()) - first_frame + 1
    if T > 10 * N + 1000:
        raise MotionFileError(path, f"frame numbers span {T} frames for only {N} rows")
    P = len(uniq)
    if P * T > 10 * N + 1000:  # a table of people x frames mostly empty: never allocate it
        raise MotionFileError(path, f"{P} people over {T} frames for only {N} rows (most of them missing)")
    key = person * T + (frame - first_frame)
    dup = np.nonzero(np.bincount(key, minlength=P * T) > 1)[0]
    if dup.size:
        line = data_rows[int(np.nonzero(key == dup[0])[0][1])][0]
        raise MotionFileError(
            path, f"line {line}: person {quoted(uniq[dup[0] // T])} frame {dup[0] % T + first_frame} appears twice"
        )
    raw = np.full((P * T, J, 3), np.nan)
    raw[key] = xyz
    raw = raw.reshape(P, T, J, 3)
    frame_times = None  # (P, T) seconds: the writer gives each row the time it was read with
    if times is not None:
        tt = np.full(P * T, np.nan)
        tt[key] = times
        frame_times = _frame_times(tt.reshape(P, T), fps)

    parents = None
    if "parents" in comments:
        try:
            parents = [int(v) for v in comments["parents"].split(",")]
        except ValueError:
            raise MotionFileError(path, "'# parents=' must be comma-separated ints") from None
    skel = skeleton_from(path, names, parents, J, groups)
    layout = [
        {
            "person_id": uniq[i],
            "person_column": "person" in special,
            "time_column": times is not None,
            "frame_column": "frame" in special,
            "first_frame": first_frame,
            "comment_lines": bool(comments),  # a file without them (FreeMoCap's) is written without
        }
        for i in range(P)
    ]
    if frame_times is not None:
        for i in range(P):
            layout[i]["times"] = frame_times[i].tolist()  # (T,) seconds, plain floats like the rest of meta
    if separator != "_":
        for i in range(P):
            layout[i]["axis_separator"] = separator
    if conf_cols is not None:  # each row's confidence cells as written, "" where a frame has no row
        text = np.full((P * T, J), "", dtype=object)
        text[key] = cells[:, conf_cols]
        word = header[conf_cols[0]].strip()[len(names[0]) + 1 :]
        for i in range(P):
            layout[i].update(confidence_text=text.reshape(P, T, J)[i], confidence_word=word)
    return _clips(
        path,
        raw,
        fps,
        skel,
        unit,
        comments.get("unit"),
        up_axis,
        comments.get("up_axis", comments.get("up")),
        "positions-csv",
        layout,
    )


def read_positions(
    path, unit: str = "auto", up_axis: str = "auto", fps: float | None = None, groups=None, min_confidence: float = 0.0
) -> list[Clip]:
    """A .npz or .csv positions file -> one Clip per person (metres, z up).

    unit / up_axis: "auto" takes the file's value (unit guessed from bone lengths when the file
    has none, up axis z); anything else overrides the file. fps overrides the file's too.
    groups: {group name: [joint names or indices]} replacing the preset/guessed limb groups.
    min_confidence: a csv's confidence columns, at or below it a joint is missing in that row."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".npz":
        return read_positions_npz(path, unit, up_axis, fps, groups)
    if suffix == ".csv":
        return read_positions_csv(path, unit, up_axis, fps, groups, min_confidence)
    raise MotionFileError(path, f"positions files are .npz or .csv, not {suffix or 'no extension'!r}")


# --- writers ---


def _format_numbers(out: np.ndarray, scale: float, offset: np.ndarray | None = None) -> list[str]:
    """out: (N,) float64 in the file's unit and axes -> the text of each: the fewest significant
    digits (6 or more) that the reader turns back into the same float32 metres (float32(text *
    scale), scale = metres per unit), so a number read from a csv is written as it was
    ("-13.7228", not 9 digits' "-13.7227997"); "" for NaN. Six digits always suffice when the
    float32 came from a number with at most six; only the others are formatted again.
    offset: (N,) metres, the clip's origin along each value's axis, which the reader takes off
    before its float32 cast (a take far from the origin: Clip.origin): the text then reads back
    as the same float32 about it (float32(text * scale - offset)), up to 17 digits."""
    v = out.tolist()
    if offset is None:
        target = out.astype(np.float32) if scale == 1.0 else (out * scale).astype(np.float32)
    else:
        target = (out * scale - offset).astype(np.float32)
    text = [f"{x:.6g}" for x in v]
    todo = np.nonzero(~np.isnan(out))[0]
    for digits in range(7, 18):
        back = np.array([text[i] for i in todo.tolist()], dtype=np.float64) * scale
        if offset is not None:
            back = back - offset[todo]
        todo = todo[back.astype(np.float32) != target[todo]]
        if not todo.size:
            break
        for i in todo.tolist():
            text[i] = f"{v[i]:.{digits}g}"  # 9 digits read back as the same float32, 17 the same float64
    for i in np.nonzero(np.isnan(out))[0].tolist():
        text[i] = ""
    return text


def _format_time(t: float) -> str:
    """Seconds -> the shortest text that reads back as the same float64 ("0", "0.0333333333",
    "1700000000.0333"); "" for NaN."""
    if t != t:
        return ""
    r = repr(float(t))
    return r[:-2] if r.endswith(".0") else r


def write_positions(
    path,
    positions: np.ndarray,
    fps: float,
    skeleton: Skeleton,
    unit: str | float = "m",
    up_axis: str = "z",
    *,
    squeeze: bool | None = None,
    person_ids: list | None = None,
    person_column: bool | None = None,
    frame_column: bool = True,
    time_column: bool = True,
    first_frame: int = 0,
    times: np.ndarray | None = None,
    origin: np.ndarray | None = None,
    comment_lines: bool = True,
    axis_separator: str = "_",
    confidence: np.ndarray | None = None,
    confidence_word: str = "visibility",
    compressed: bool = True,
) -> Path:
    """Write positions (T, J, 3) or (P, T, J, 3), metres z up, NaN = missing, as .npz or .csv (by
    the path's extension) in `unit` (a name or metres per unit) and `up_axis`. The layout options
    mirror what the readers put into clip.meta: squeeze (npz: (T, J, 3) for one person; default
    when P == 1), person_ids and person_column (csv; the column is written when P > 1 by
    default), frame/time columns, first_frame and times (csv: (T,) or (P, T) seconds of each row;
    default (first_frame + t) / fps). origin: (3,) metres z up that the positions are relative
    to (Clip.origin), added back in float64; npz positions are float32, or float64 where a value
    lies beyond NEAR_ORIGIN_M (float32 would round it by more than 4 um). comment_lines: csv,
    the `# fps= unit= up_axis=` and `# parents=` lines above the header (False: a file read
    without them is written back without them; reading it again needs the same options).
    axis_separator: csv, "_" (<joint>_x) or "." (<joint>.x); confidence: csv, (P, T, J) the text
    of each joint's confidence column, <joint>_<confidence_word> after its z (as read)."""
    path = Path(path)
    origin = np.zeros(3) if origin is None else np.asarray(origin, dtype=np.float64).reshape(3)
    pos = np.asarray(positions, dtype=np.float64)
    if pos.ndim == 3:
        pos = pos[None]
    if pos.ndim != 4 or pos.shape[-1] != 3 or pos.shape[2] != skeleton.num_joints:
        raise ValueError(
            f"positions must be (T, {skeleton.num_joints}, 3) or (P, T, {skeleton.num_joints}, 3), "
            f"got {np.shape(positions)}"
        )
    if up_axis not in UP_AXES:
        raise ValueError(f"up_axis must be one of {list(UP_AXES)}")
    try:
        scale = parse_unit(unit, path, "write_positions")
    except MotionFileError as e:
        raise ValueError(e.problem) from None
    unit, scale = (scale.name, scale.metres) if scale is not None else ("m", 1.0)
    P, T, J, _ = pos.shape
    out = from_z_up(pos + origin, up_axis) / scale
    with np.errstate(invalid="ignore"):
        far = bool((np.abs(out[np.isfinite(out)]) * scale > NEAR_ORIGIN_M).any())
    suffix = path.suffix.lower()
    if suffix == ".npz":
        squeeze = P == 1 if squeeze is None else squeeze and P == 1
        arrays = {
            "positions": (out[0] if squeeze else out).astype(np.float64 if far else np.float32),
            "fps": np.float64(fps),
            "parents": np.array(skeleton.parents, dtype=np.int64),
            "joint_names": np.array(skeleton.joint_names, dtype=str),
            "unit": np.array(unit),
            "up_axis": np.array(up_axis),
        }
        atomic_write(path, lambda f: (np.savez_compressed if compressed else np.savez)(f, **arrays))
    elif suffix == ".csv":
        bad = [n for n in skeleton.joint_names if re.search(r"[,\"\s]", n) or n.lower() in _SPECIAL_COLUMNS]
        if bad:
            raise ValueError(f"joint names {bad} cannot be csv column prefixes")
        ids = [str(i) for i in (person_ids if person_ids is not None else range(P))]
        if len(ids) != P:
            raise ValueError(f"{len(ids)} person ids for {P} people")
        person_column = P > 1 if person_column is None else person_column or P > 1
        header = (
            (["person"] if person_column else [])
            + (["frame"] if frame_column else [])
            + (["time"] if time_column else [])
            + [
                f"{n}{axis_separator}{a}"
                for n in skeleton.joint_names
                for a in ("x", "y", "z") + ((confidence_word,) if confidence is not None else ())
            ]
        )
        lines = [
            *(
                [f"# fps={fps:.9g} unit={unit} up_axis={up_axis}", "# parents=" + ",".join(map(str, skeleton.parents))]
                if comment_lines
                else []
            ),
            ",".join(header),
        ]
        if times is None:
            time_text = [[f"{(first_frame + t) / fps:.9g}" for t in range(T)]] * P
        else:
            try:
                seconds = np.broadcast_to(np.asarray(times, dtype=np.float64), (P, T))
            except ValueError:
                raise ValueError(f"times must be ({T},) or ({P}, {T}), got {np.shape(times)}") from None
            time_text = [[_format_time(t) for t in row] for row in seconds.tolist()]
        C = J * 3
        # a take far from the origin: each value reads back about the origin (the file's axes)
        offset = np.broadcast_to(from_z_up(origin, up_axis), out.shape).reshape(-1) if origin.any() else None
        cells = _format_numbers(out.reshape(-1), scale, offset)  # (P * T * C,) row-major
        for p in range(P):
            for t in range(T):
                lead = (
                    ([ids[p]] if person_column else [])
                    + ([str(first_frame + t)] if frame_column else [])
                    + ([time_text[p][t]] if time_column else [])
                )
                r = (p * T + t) * C
                row = cells[r : r + C]
                if confidence is not None:  # each joint's x, y, z, then its confidence as read
                    row = [v for j in range(J) for v in (*row[3 * j : 3 * j + 3], str(confidence[p][t][j]))]
                lines.append(",".join(lead + row))
        payload = ("\n".join(lines) + "\n").encode()
        atomic_write(path, lambda f: f.write(payload))
    else:
        raise ValueError(f"write_positions writes .npz or .csv, not {path.suffix!r}")
    return path


def write_clips(path, clips: list[Clip]) -> Path:
    """Write the clips of one file (its people: same frames, fps and skeleton) in the layout the
    reader found: unit, up axis, people and columns come from clips[0].meta (defaults m, z up)."""
    if not clips:
        raise ValueError("write_clips needs at least one clip")
    c0 = clips[0]
    for c in clips[1:]:
        if c.num_frames != c0.num_frames or c.fps != c0.fps or c.skeleton.parents != c0.skeleton.parents:
            raise ValueError("clips written to one positions file need the same frames, fps and skeleton")
    m = c0.meta
    unit = m.get("unit", "m")
    up = m.get("up_axis", "z") if m.get("up_axis", "z") in UP_AXES else "z"
    from_csv = m.get("format") == "positions-csv"
    # The rows' times as read; a clip whose frames changed since (resampled) has no such times.
    times = None
    if from_csv and all(len(c.meta.get("times") or ()) == c.num_frames for c in clips):
        times = np.array([c.meta["times"] for c in clips], dtype=np.float64)  # (P, T) seconds
    # each person about the first one's origin (a file's people share one as read)
    shift = [c.origin - c0.origin for c in clips]
    positions = np.stack([c.positions + s if s.any() else c.positions for c, s in zip(clips, shift)])
    return write_positions(
        path,
        positions,
        c0.fps,
        c0.skeleton,
        unit,
        up,
        squeeze=m.get("squeeze"),
        compressed=m.get("compressed", True),
        person_ids=[c.meta.get("person_id", i) for i, c in enumerate(clips)],
        person_column=m.get("person_column") if from_csv else None,
        frame_column=m.get("frame_column", True) if from_csv else True,
        time_column=m.get("time_column", True) if from_csv else True,
        first_frame=int(m.get("first_frame", 0)),
        times=times,
        origin=c0.origin,
        comment_lines=m.get("comment_lines", True) if from_csv else True,
        axis_separator=m.get("axis_separator", "_") if from_csv else "_",
        confidence=[c.meta["confidence_text"] for c in clips] if from_csv and "confidence_text" in m else None,
        confidence_word=m.get("confidence_word", "visibility"),
    )
