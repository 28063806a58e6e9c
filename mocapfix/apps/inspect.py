"""`mocapfix inspect FILE...`: what is in motion files, before training on them or cleaning them.

Per file: format, people, frames, fps, joints, unit and up axis the reader used, missing
tokens, hip height, mean limb length and limb sigma (std over time of each limb's length, the
paper's jitter measure). A human table by default; --json gives one JSON object per file per line.
"""

from __future__ import annotations

import argparse
import json
import math
import sys

import numpy as np

from mocapfix.core.clip import Clip, body_limbs, limb_lengths, shown
from mocapfix.core.skeleton import Skeleton
from mocapfix.io import add_read_arguments, list_motion_files, read_motion, read_options
from mocapfix.io.joint_map import check_joint_map, read_joint_map
from mocapfix.rig.labels import pelvis
from mocapfix.rig.mapping import describe_mapping


def _nanmean(x) -> float:
    x = np.asarray(x, dtype=np.float64)
    x = x[np.isfinite(x)]
    return float(x.mean()) if x.size else math.nan


def motion_stats(clips: list[Clip]) -> dict:
    """Numbers of one file's clips (its people, or its sequences for Human3.6M)."""
    c0 = clips[0]
    skel = c0.skeleton
    people = int(c0.meta.get("people", 1))
    frames = sum(c.num_frames for c in clips) // max(people, 1)  # people share frames; sequences add up
    missing = sum(int(c.missing_mask().sum()) for c in clips)
    tokens = sum(c.missing_mask().size for c in clips)
    hip = pelvis(skel)  # the rig's structure, else its names, else where the legs and spine start
    lengths, sigmas = [], []
    for c in clips:
        L = limb_lengths(c.positions, skel.parents)[:, body_limbs(c.positions, skel.parents)]  # (T, L)
        valid = np.isfinite(L)
        n = valid.sum(axis=0)
        mean = np.where(valid, L, 0.0).sum(axis=0) / np.maximum(n, 1)
        var = (np.where(valid, L - mean, 0.0) ** 2).sum(axis=0) / np.maximum(n, 1)
        # a limb never seen has no length; a std needs two frames (not zero jitter)
        lengths.append(np.where(n > 0, mean, np.nan))
        sigmas.append(np.where(n > 1, np.sqrt(var), np.nan))
    fps = float(c0.fps)
    return {
        "format": c0.meta.get("format", "?"),
        "clips": len(clips),
        "people": people,
        "frames": int(frames),
        "fps": fps,
        "duration_s": frames / fps,
        "joints": skel.num_joints,
        "joint_names": list(skel.joint_names),
        "skeleton": skel.name,
        "unit": c0.meta.get("unit", "?"),
        "unit_source": c0.meta.get("unit_source", "?"),
        "stature_m": _nanmean([c.meta.get("stature_m", math.nan) for c in clips]),
        "up_axis": c0.meta.get("up_axis", "?"),
        "dropped_root": c0.meta.get("dropped_root"),
        "absurd_tokens": sum(int(c.meta.get("absurd_tokens", 0)) for c in clips),
        "warnings": sorted({c.meta["warning"] for c in clips if c.meta.get("warning")}),
        "missing_tokens": missing,
        "missing_pct": 100.0 * missing / tokens if tokens else 0.0,
        "hip_joint": skel.joint_names[hip],
        "hip_height_m": _nanmean(np.concatenate([c.positions[:, hip, 2] for c in clips])),
        "limb_length_mm": 1000.0 * _nanmean(np.concatenate(lengths)),
        "limb_sigma_mm": 1000.0 * _nanmean(np.concatenate(sigmas)),
    }


def _json_value(v):
    return None if isinstance(v, float) and not math.isfinite(v) else v


def _num(v: float, fmt: str) -> str:
    return "-" if not math.isfinite(v) else format(v, fmt)


def _table(rows: list[dict]) -> str:
    cols = [
        ("file", "file", "s"),
        ("format", "format", "s"),
        ("people", "people", "d"),
        ("frames", "frames", "d"),
        ("fps", "fps", ".4g"),
        ("dur s", "duration_s", ".1f"),
        ("joints", "joints", "d"),
        ("unit", "unit", "s"),
        ("stature m", "stature_m", ".2f"),
        ("up", "up_axis", "s"),
        ("missing %", "missing_pct", ".2f"),
        ("absurd", "absurd_tokens", "d"),
        ("hip m", "hip_height_m", ".3f"),
        ("limb mm", "limb_length_mm", ".1f"),
        ("sigma mm", "limb_sigma_mm", ".2f"),
    ]
    cells = [[h for h, _, _ in cols]]
    for r in rows:
        cells.append([_num(r[k], f) if isinstance(r[k], float) else format(r[k], f) for _, k, f in cols])
    widths = [max(len(row[i]) for row in cells) for i in range(len(cols))]
    lines = [
        "  ".join(c.ljust(w) if i == 0 else c.rjust(w) for i, (c, w) in enumerate(zip(row, widths))) for row in cells
    ]
    # how each unit was found, once per distinct way (a body's scale estimate says its number)
    how: dict[tuple, list[str]] = {}
    for r in rows:
        how.setdefault((r["unit"], r["unit_source"]), []).append(r["file"])
    for (unit, source), files in how.items():
        which = files[0] if len(files) == 1 else f"{len(files)} files"
        lines.append(f"unit {unit} ({which}): {source}")
    for r in rows:
        if r["dropped_root"]:
            lines.append(f"{r['file']}: root {r['dropped_root']!r} left out (a helper joint: one child, never turns)")
        if r["absurd_tokens"]:
            lines.append(
                f"{r['file']}: {r['absurd_tokens']} absurd joint positions (non-finite or far outside "
                "the body) read as missing"
            )
        lines.extend(f"warning: {w}" for w in r["warnings"])
    # joint names once per distinct skeleton: too long for a column
    seen: dict[tuple, list[str]] = {}
    for r in rows:
        seen.setdefault(tuple(r["joint_names"]), []).append(r["file"])
    for names, files in seen.items():
        which = files[0] if len(files) == 1 else f"{len(files)} files"
        lines.append(f"joints ({which}, {len(names)}): {', '.join(names)}")
    return "\n".join(lines)


def inspect_files(
    paths,
    as_json: bool = False,
    source: str = "auto",
    out=None,
    err=None,
    model: Skeleton | None = None,
    joint_map: dict[str, str] | None = None,
    **read_options,
) -> int:
    """Print what each motion file holds (folders: their motion files). -> exit code: 1 if any file failed.
    With a model's skeleton, also how the file's joints map onto it (rig/mapping.py).

    read_options go to mocapfix.io.read_motion (unit, up_axis, fps, groups, body_model_path, ...)."""
    out = out or sys.stdout
    err = err or sys.stderr
    failed = False
    rows = []

    def unreadable(e: Exception):
        nonlocal failed
        print(f"error: {_one_line(getattr(e, 'path', ''), e)}", file=err)
        failed = True

    for p in paths:
        try:  # a subfolder that cannot be read is one error line; the files around it still run
            files = list_motion_files(p, source, on_error=unreadable)
        except Exception as e:  # one bad argument must not stop the others
            print(f"error: {_one_line(p, e)}", file=err)
            failed = True
            continue
        if not files:
            print(f"error: {p}: no motion files in this folder", file=err)
            failed = True
        for f in files:
            try:
                clips = read_motion(f, source, **read_options)
                if not clips:
                    raise ValueError(f"{f}: no motion in the file")
                row = {"file": str(f), **motion_stats(clips)}
                if model is not None:
                    row["mapping"] = describe_mapping(clips[0].skeleton, model, joint_map)
            except Exception as e:
                print(f"error: {_one_line(f, e)}", file=err)
                failed = True
                continue
            if as_json:
                print(json.dumps({k: _json_value(v) for k, v in row.items()}), file=out, flush=True)
            else:
                rows.append(row)
    if rows:
        print(_table(rows), file=out)
    for row in rows:
        if "mapping" in row:
            print(f"\n{row['file']} onto the model's {model.num_joints} joints ({model.name}):", file=out)
            print("  " + "\n  ".join(row["mapping"]), file=out)
    return 1 if failed else 0


def _one_line(path, e: Exception) -> str:
    """MotionFileError already reads "path: problem"; anything else gets the path and its type."""
    text = " ".join(str(e).split())
    if text.startswith(shown(path)):
        return text
    return f"{shown(path)}: {type(e).__name__}: {text}" if text else f"{shown(path)}: {type(e).__name__}"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(
        prog="mocapfix inspect",
        description=__doc__.split("\n")[0],
        epilog="example: mocapfix inspect takes/   (how the joints map onto a model's: "
        "mocapfix inspect take.bvh --model xmae-cpu-bandai)",
    )
    ap.add_argument("paths", nargs="+", metavar="FILE", help="motion files or folders")
    ap.add_argument("--json", action="store_true", help="one JSON object per file per line")
    which = ap.add_mutually_exclusive_group()
    which.add_argument("--ckpt", default=None, help="also show how each file's joints map onto this model's")
    which.add_argument("--model", default=None, help="the same for a shipped model (`mocapfix models`)")
    ap.add_argument("--joint-map", default=None, help="YAML, `input name: model name` per line (with --ckpt)")
    add_read_arguments(ap)
    args = ap.parse_args(argv)
    model = joint_map = None
    if args.joint_map and not (args.ckpt or args.model):
        ap.error("--joint-map goes with --ckpt or --model")
    what = args.model or args.ckpt
    try:
        if what:
            from mocapfix.fix.fixers import load_fixer
            from mocapfix.pretrained import pretrained_path

            model = load_fixer(pretrained_path(args.model) if args.model else args.ckpt).skeleton
            what = args.joint_map
            joint_map = read_joint_map(args.joint_map) if args.joint_map else None
            if joint_map:
                check_joint_map(joint_map, model, args.joint_map)
    except Exception as e:
        print(f"error: {_one_line(what, e)}", file=sys.stderr)
        return 1
    return inspect_files(
        args.paths,
        args.json,
        model=model,
        joint_map=joint_map,
        source=args.source,
        **read_options(args),
    )


if __name__ == "__main__":
    sys.exit(main())
