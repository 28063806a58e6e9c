"""`mocapfix demo` (`make demo`): the whole loop in a few CPU minutes, ending with a result a
person can judge.

1. fit: fine-tune the shipped XMAE (`xmae-cpu-bandai`) on a few takes - a folder of yours
   (`--data`), or the embedded synthetic motion - with TensorBoard logs and checkpoints, as
   `mocapfix fit` does for any run;
2. break a take the fit never saw the way capture fails: the whole body missing for 0.5 s, an
   arm for 0.9 s, a leg for 0.7 s, and the other arm jumped 35 cm away for 0.6 s;
3. fix it with `mocapfix fix --mode both` and the fine-tuned checkpoint;
4. score input, the classical fills (cubic spline, Hermite, limb fill) and mocapfix against the
   unbroken take (MPJPE in mm over the holes and over the jumped arm, and how many clean tokens
   each changed), say which fill filled the holes, and draw the input beside the fixed take
   (`mocapfix render`).
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mocapfix.core.clip import Clip, MotionFileError, shown

START_FROM = "xmae-cpu-bandai"
JUMP_M = 0.35  # the jumped arm's offset: a marker swap or a mislabelled arm, not an absurd value
MOVED_M = 0.001  # a clean token "changed" when moved by more than this
MIN_TAKE_S = 6.0  # room for the three holes and the jump, 0.5 s or more apart
# the classical fills the table shows beside mocapfix (fills/classical.py), by their row names
CLASSICAL_ROWS = {"spline": "cubic spline", "hermite": "Hermite", "limb": "limb fill"}


@dataclass(frozen=True)
class Damage:
    """What `break_take` did to a take: (T, J) bool masks."""

    holes: np.ndarray  # tokens removed (NaN in the broken take)
    jumped: np.ndarray  # tokens moved by JUMP_M

    @property
    def clean(self) -> np.ndarray:
        return ~self.holes & ~self.jumped


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="mocapfix demo",
        description=__doc__.split("\n\n")[0],
        epilog="example: mocapfix demo --data my_takes/   (or `make demo` in a checkout)",
    )
    ap.add_argument(
        "--data",
        default=None,
        help="a folder of motion files (BVH, .npz/.csv positions; any humanoid rig): fine-tune on some, "
        "fix a held-out one (default: the embedded synthetic motion)",
    )
    ap.add_argument("--takes", type=int, default=40, help="at most this many files of --data to fine-tune on")
    ap.add_argument("--steps", type=int, default=300, help="fine-tuning steps (default 300: about 2 minutes)")
    ap.add_argument("--experiment", default="demo", help="logs/<experiment>/ and checkpoints/<experiment>/")
    return ap


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.steps < 3 or args.takes < 2:
        print("mocapfix demo: --steps >= 3 and --takes >= 2", file=sys.stderr)
        return 2
    try:
        held_out, data_args, what = _choose_data(args.data, args.takes)
    except (MotionFileError, ValueError) as e:
        print(f"mocapfix demo: {e}", file=sys.stderr)
        return 1
    print(f"mocapfix demo 1/3: fine-tuning {START_FROM} for {args.steps} steps on {what}")
    code = _fit(args, data_args)
    if code != 0:
        return code
    ckpt = Path("checkpoints") / args.experiment / "last.ckpt"
    out_dir = Path("logs") / args.experiment / "fixed_take"
    out_dir.mkdir(parents=True, exist_ok=True)

    from mocapfix.io.positions import write_positions

    truth, broken, damage = break_take(held_out)
    broken_path = write_positions(
        out_dir / f"{held_out.name}_broken.npz", broken.positions, broken.fps, broken.skeleton
    )
    fixed_path = out_dir / f"{held_out.name}_fixed.npz"
    print(f"mocapfix demo 2/3: fixing {shown(broken_path)} (a take the fit never saw, broken) with {shown(ckpt)}")
    import time

    from mocapfix.apps.fix_one import report_text
    from mocapfix.fix import fix_file, load_fixer
    from mocapfix.io import read_motion

    try:  # what `mocapfix fix BROKEN --ckpt CKPT --mode both -o FIXED` does, with its report kept
        t0 = time.perf_counter()
        result = fix_file(broken_path, load_fixer(ckpt), "both", output=fixed_path)
        result.write(overwrite=True)
    except MotionFileError as e:
        print(f"mocapfix demo: {e}", file=sys.stderr)
        return 1
    print(report_text(result, time.perf_counter() - t0, as_json=False))
    as_read = read_motion(broken_path)[0]  # what fix and the classical fills all start from
    fixed = read_motion(fixed_path)[0].positions
    table = score_table(
        truth.positions, as_read.positions, fixed, damage, truth.skeleton.parents, result.report.filled_by
    )
    print(table)

    print("mocapfix demo 3/3: drawing the input beside the fixed take")
    from mocapfix.apps.render import render_files

    first_hole = int(np.flatnonzero(damage.holes.any(1))[0])
    start_s = max(0.0, first_hole / truth.fps - 0.5)
    gif = render_files(broken_path, [fixed_path], out_dir / "demo.gif", start_s=start_s, fps=15)
    log_dir = out_dir.parent
    print(
        f"\nanimation (input | fixed; filled tokens green, replaced orange): {shown(gif)}\n"
        "next:\n"
        f"  tensorboard --logdir {log_dir}          # the fit's curves, figures and hyperparameters\n"
        f"  mocapfix fix YOUR_TAKE.bvh --model {START_FROM} --mode both -o fixed.bvh   # fix your own file\n"
        "  mocapfix render YOUR_TAKE.bvh fixed.bvh -o side_by_side.gif   # look at it\n"
        "  mocapfix fit --config xmae_cpu --data.path YOUR_FOLDER         # train on your folder"
    )
    return 0


def _choose_data(folder: str | None, takes: int) -> tuple[Clip, list[str], str]:
    """The held-out take (on the model's 21 joints) and the fit's data arguments.

    A folder: files go to train / val / test by the data module's hash of their names (the split
    the shipped model was trained with, so a test file is one neither model saw); the largest
    test file is the held-out take, and up to `takes` train and val files are fitted. No folder:
    synthetic clips, and a clip of another seed held out."""
    from mocapfix.core.skeleton import preset
    from mocapfix.data.windows import split_of
    from mocapfix.io import list_motion_files, read_motion
    from mocapfix.rig.mapping import onto_skeleton

    body = preset("body21")
    if folder is None:
        from mocapfix.io.synthetic import generate_clips

        clip = onto_skeleton(generate_clips(1, 12.0, 30.0, seed=1000)[0], body).replace(name="synthetic_take")
        data_args = ["--data.source", "synthetic", "--data.synthetic_clips", "24"]
        return clip, data_args, "the embedded synthetic motion (24 clips of 10 s)"
    files = list_motion_files(folder)
    if not files:
        raise MotionFileError(folder, "no motion files (.bvh, .npz, .csv) in this folder")
    split = {f: split_of(str(f), 0.1, 0.1, 0) for f in files}
    test = sorted((f for f in files if split[f] == "test"), key=lambda f: (-f.stat().st_size, f.name))
    fitted = [f for f in files if split[f] != "test"][:takes]
    if not any(split[f] == "val" for f in fitted):  # a validation needs a val file among those fitted
        fitted = fitted[:-1] + [next((f for f in files if split[f] == "val"), fitted[-1])]
    for f in test:
        clip = onto_skeleton(read_motion(f)[0], body).replace(name=f.stem)
        if clip.num_frames >= MIN_TAKE_S * clip.fps:
            break
    else:
        raise MotionFileError(
            folder, f"no held-out take of {MIN_TAKE_S:g} s or more (its test split has {len(test)} files); give more"
        )
    source = "bvh" if all(f.suffix.lower() == ".bvh" for f in fitted) else "positions"
    data_args = ["--data.source", source, "--data.path", "[" + ", ".join(str(f) for f in fitted) + "]"]
    return clip, data_args, f"{len(fitted)} files of {shown(folder)}"


def _fit(args, data_args: list[str]) -> int:
    from mocapfix.apps.cli import run_lightning

    validations = 3
    return run_lightning(
        "fit",
        [
            "fit",
            "--config",
            "xmae_cpu",
            "--experiment",
            args.experiment,
            *data_args,
            "--data.body",
            "body21",
            "--model.init_args.init_weights",
            START_FROM,
            "--model.init_args.lr",
            "3e-4",
            "--model.init_args.warmup_steps",
            str(max(1, args.steps // 10)),
            "--model.init_args.calibration_windows",
            "128",
            "--trainer.max_steps",
            str(args.steps),
            "--trainer.val_check_interval",
            str(max(1, args.steps // validations)),
            "--trainer.log_every_n_steps",
            "10",
            "--trainer.accelerator",
            "cpu",
        ],
    )


def break_take(clip: Clip) -> tuple[Clip, Clip, Damage]:
    """The take as captured, and broken the way capture fails: (truth, broken, damage).

    The whole body missing for 0.5 s at a quarter of the take, the left arm for 0.9 s at 45 %, the
    right leg for 0.7 s at 65 %, and the right arm JUMP_M away (up and out to its side) for 0.6 s
    at 82 %: places fixed by the take's length, so a rerun breaks it the same way."""
    x = clip.positions  # (T, J, 3) metres, z up
    T, fps, groups = clip.num_frames, clip.fps, clip.skeleton.groups
    holes, jumped = np.zeros(x.shape[:2], dtype=bool), np.zeros(x.shape[:2], dtype=bool)

    def span(at: float, seconds: float) -> slice:
        first = int(at * T)
        return slice(first, min(T, first + int(round(seconds * fps))))

    holes[span(0.25, 0.5)] = True
    holes[span(0.45, 0.9), list(groups["left_arm"])] = True
    holes[span(0.65, 0.7), list(groups["right_leg"])] = True
    jumped[span(0.82, 0.6), list(groups["right_arm"])] = True
    jumped &= np.isfinite(x).all(-1) & ~holes
    holes &= np.isfinite(x).all(-1)  # only what was there can go missing
    # up and out to the body's right: across the hips, left to right, turned a quarter clockwise
    hips = x[:, groups["right_leg"][0]] - x[:, groups["left_leg"][0]]  # (T, 3)
    side = np.nanmean(hips, axis=0) * np.array([1.0, 1.0, 0.0])
    offset = JUMP_M * (side / max(np.linalg.norm(side), 1e-6) + np.array([0.0, 0.0, 1.0])) / np.sqrt(2)
    broken = x.copy()
    broken[holes] = np.nan
    broken[jumped] += offset.astype(x.dtype)
    return clip, clip.replace(positions=broken), Damage(holes, jumped)


def score_table(
    truth: np.ndarray,
    as_read: np.ndarray,
    fixed: np.ndarray,
    damage: Damage,
    parents,
    filled_by: dict[str, int] | None = None,
) -> str:
    """The table the demo prints: MPJPE (mm) against the unbroken take over the holes and over the
    jumped arm, and the clean tokens each output changed; beside mocapfix, the classical fills of
    what the file, as read, lacks (a value no body can take is read as missing: io/absurd.py),
    which keep the rest (parents: the take's skeleton's, for the limb fill). filled_by: the fix
    report's count of tokens by fill: the last line says which fill filled the holes and how
    mocapfix compares with the best classical fill there."""
    import torch

    from mocapfix.fills.classical import CLASSICAL
    from mocapfix.fills.policy import is_learned

    seen = np.isfinite(as_read).all(-1)
    x, observed = torch.from_numpy(np.nan_to_num(as_read))[None], torch.from_numpy(seen)[None]
    classical = {name: CLASSICAL[key](x, observed, parents)[0].numpy() for key, name in CLASSICAL_ROWS.items()}

    def mean_mm(y: np.ndarray, where: np.ndarray) -> float:
        return float(1000 * np.linalg.norm(y - truth, axis=-1)[where].mean())

    def error_mm(y: np.ndarray, where: np.ndarray) -> str:
        e = mean_mm(y, where)
        return "missing" if not np.isfinite(e) else f"{e:.1f}"

    def changed(y: np.ndarray) -> str:
        moved = (np.linalg.norm(y - as_read, axis=-1) > MOVED_M) & damage.clean & seen
        return f"{int(moved.sum())} of {int((damage.clean & seen).sum())}"

    rows = [("input", as_read), *classical.items(), ("mocapfix", fixed)]
    holes, jumped = int(damage.holes.sum()), int(damage.jumped.sum())
    head = ("", f"holes ({holes} tokens)", f"jumped arm ({jumped})", "clean changed")
    cells = [head] + [
        (name, error_mm(y, damage.holes), error_mm(y, damage.jumped), "-" if name == "input" else changed(y))
        for name, y in rows
    ]
    widths = [max(len(r[i]) for r in cells) for i in range(len(head))]
    lines = ["  ".join(c.ljust(w) if i == 0 else c.rjust(w) for i, (c, w) in enumerate(zip(r, widths))) for r in cells]
    best = min(classical, key=lambda name: mean_mm(classical[name], damage.holes))
    ours, theirs = mean_mm(fixed, damage.holes), mean_mm(classical[best], damage.holes)
    verdict = f"holes: mocapfix {ours:.1f} mm, the best classical fill ({best}) {theirs:.1f} mm"
    if filled_by:
        learned = sum(n for m, n in filled_by.items() if is_learned(m))
        by = ", ".join(f"{m} {n}" for m, n in sorted(filled_by.items()))
        verdict += f"; filled by {by}: " + (
            f"the model filled {learned} tokens"
            if learned
            else "the model filled none (it fills a kind of hole only where it beat every classical fill on "
            "holes cut into this take)"
        )
    return "MPJPE in mm against the take before it was broken\n" + "\n".join(lines) + "\n" + verdict
