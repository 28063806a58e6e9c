"""Does a learned correction of the cubic Hermite carry from one studio to another?

The simplest learned in-betweener: a ridge regression from the motion around a full-body hole
(8 frames each side, turned about z to one heading, the Hermite's own fill of the hole) to the Hermite's
error over the hole. Fitted and judged in four ways, at each hole length, everything at 30 fps on
the 17 joints every source has (body21 without hands and toes: ReActIdle has no hands, CMU no
toes), so neither frame rate nor rig differs between training and evaluation:
- within a studio: Bandai Namco's dataset-2, half of its files (by crc32 of the name) -> the
  other half; CMU subjects 35-37 -> 38-39 (the PFNN capture, other performers);
- leave one studio out: two of Bandai / ReActIdle / CMU 35-39 -> the third;
- the whole corpus -> the 14 CMU sample takes of 8 s or more (subjects 05-09, another capture
  of CMU's studio: the stranger benchmark's takes, bench/fix_strangers_cmu.py).
Each cell is the corrected fill's MPJPE over the hole divided by the Hermite's (below 1: the
correction helps), for every ridge strength; the strength a user would pick is the one that is
best on the studio held out. The corpus is bench/build_corpus.py's archive (docs/data.md).

    python bench/correction_carry.py --corpus .device_data/corpus_body21.npz
"""

from __future__ import annotations

import argparse
import time
import zlib
from pathlib import Path

import numpy as np
import torch
from common import describe, print_table, write_result

from mocapfix.data.datamodule import MotionDataModule  # noqa: E402
from mocapfix.fills.classical import hermite_infill  # noqa: E402

CONTEXT = 8  # frames each side of the hole the correction reads (0.27 s at 30 fps)
FPS = 30.0
HOLES_S = (0.5, 0.7, 0.9)
STRENGTHS = (1e-4, 1e-3, 1e-2, 1e-1, 1.0, 10.0)  # ridge penalty per sample on standardised features
LEFT_OUT = ("Hand_L", "Hand_R", "Toes_L", "Toes_R")


def performer(clip) -> str:
    """The corpus' folder per performer: bandai1, reactidle003, cmu35 (bench/build_corpus.py)."""
    return Path(clip.source).parent.name


def studio(clip) -> str:
    return performer(clip).rstrip("0123456789")


def windows(clips, keep: list[int], hole: int, stride: int) -> np.ndarray:
    """(N, 2 * CONTEXT + hole, J, 3) stretches of the kept joints with every joint observed."""
    size = 2 * CONTEXT + hole
    out = [
        w
        for c in clips
        for w in (c.positions[s : s + size, keep] for s in range(0, len(c.positions) - size + 1, stride))
        if not np.isnan(w).any()
    ]
    return np.stack(out).astype(np.float32)


class Holes:
    """A full-body hole in the middle of each window, the Hermite's fill, the features and target,
    turned about z so the line from the right hip to the left lies along +x at the last frame
    before the hole (every window at one heading)."""

    def __init__(self, stretches: np.ndarray, hole: int, hips: tuple[int, int]):
        n, size, joints, _ = stretches.shape
        observed = torch.ones(n, size, joints, dtype=torch.bool)
        observed[:, CONTEXT : CONTEXT + hole] = False
        base = hermite_infill(torch.from_numpy(stretches), observed).numpy()  # (N, T, J, 3)
        last = base[:, CONTEXT - 1]
        origin = last[:, 0] * np.array([1, 1, 0], np.float32)  # the root's ground point
        across = last[:, hips[0]] - last[:, hips[1]]
        angle = -np.arctan2(across[:, 1], across[:, 0])
        c, s = np.cos(angle), np.sin(angle)
        turn = np.zeros((n, 3, 3), np.float32)  # (N, 3, 3) rotation about z
        turn[:, 0, 0], turn[:, 0, 1], turn[:, 1, 0], turn[:, 1, 1], turn[:, 2, 2] = c, -s, s, c, 1

        aligned = np.einsum("nij,ntkj->ntki", turn, base - origin[:, None, None])  # (N, T, J, 3) facing frame
        around = np.concatenate([aligned[:, :CONTEXT], aligned[:, CONTEXT + hole :]], axis=1)
        # features: the context and every third coordinate of the Hermite's fill of the hole
        inside = aligned[:, CONTEXT : CONTEXT + hole].reshape(n, -1)[:, ::3]
        self.features = np.concatenate([around.reshape(n, -1), inside], axis=1)
        truth = stretches[:, CONTEXT : CONTEXT + hole]
        self.base = base[:, CONTEXT : CONTEXT + hole]  # (N, hole, J, 3) world
        self.target = np.einsum("nij,ntkj->ntki", turn, truth - self.base).reshape(n, -1)  # facing frame
        self.truth, self.turn = truth, turn

    def error_mm(self, model=None) -> float:
        """MPJPE (mm) over the hole of the Hermite, corrected by `model` (a fit_ridge output) if given."""
        fill = self.base
        if model is not None:
            mean, scale, weights = model
            step = (((self.features - mean) / scale) @ weights).reshape(self.base.shape)
            fill = self.base + np.einsum("nji,ntkj->ntki", self.turn, step)  # back to world: turn^T
        return 1000 * float(np.linalg.norm(fill - self.truth, axis=-1).mean())


def fit_ridge(sets: list[Holes]) -> dict[float, tuple]:
    """One ridge solution per strength over the pooled sets (features standardised on them)."""
    x = np.concatenate([h.features for h in sets]).astype(np.float64)
    y = np.concatenate([h.target for h in sets]).astype(np.float64)
    mean, scale = x.mean(0), x.std(0) + 1e-6
    xs = (x - mean) / scale
    gram, cross = xs.T @ xs, xs.T @ y
    eye = np.eye(len(gram))
    return {lam: (mean, scale, np.linalg.solve(gram + lam * len(x) * eye, cross)) for lam in STRENGTHS}


def row(hole_s: float, check: str, trained: str, judged: Holes, models: dict) -> dict:
    hermite = judged.error_mm()
    ratios = {lam: judged.error_mm(models[lam]) / hermite for lam in STRENGTHS}
    head = {"hole_s": hole_s, "check": check, "trained_on": trained, "windows": len(judged.truth)}
    return head | {"hermite_mm": hermite} | {f"x{lam:g}": r for lam, r in ratios.items()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--corpus", default=".device_data/corpus_body21.npz", help="bench/build_corpus.py's archive")
    ap.add_argument("--strangers", default="../shared/data/cmu-sample")
    ap.add_argument("--json-out")
    args = ap.parse_args()
    start = time.perf_counter()

    def load(source: str, path: str):
        return MotionDataModule(source=source, path=path, body="body21", fps=FPS, cache_dir=None).load_clips()

    corpus, cmu_sample = load("archive", args.corpus), load("bvh", args.strangers)
    strangers = [c for c in cmu_sample if len(c.positions) >= 8 * FPS]
    names = corpus[0].skeleton.joint_names
    keep = [j for j, name in enumerate(names) if name not in LEFT_OUT]
    hips = (keep.index(names.index("UpperLeg_L")), keep.index(names.index("UpperLeg_R")))
    by_studio = {s: [c for c in corpus if studio(c) == s] for s in ("bandai", "reactidle", "cmu")}
    stride = {"bandai": 15, "reactidle": 4, "cmu": 4}  # ~20k / 20k / 800 windows: Bandai is 87 % of the frames
    rows = []
    for hole_s in HOLES_S:
        hole = round(hole_s * FPS)
        sets = {s: Holes(windows(clips, keep, hole, stride[s]), hole, hips) for s, clips in by_studio.items()}
        # within a studio
        dataset2 = [c for c in by_studio["bandai"] if "dataset-2" in c.name]
        halves = [[c for c in dataset2 if zlib.crc32(c.name.encode()) % 2 == k] for k in (0, 1)]
        a, b = (Holes(windows(h, keep, hole, 15), hole, hips) for h in halves)
        rows.append(row(hole_s, "within studio", "Bandai dataset-2, half the files", b, fit_ridge([a])))
        a, b = (
            Holes(windows([c for c in by_studio["cmu"] if performer(c) in group], keep, hole, 4), hole, hips)
            for group in (("cmu35", "cmu36", "cmu37"), ("cmu38", "cmu39"))
        )
        rows.append(row(hole_s, "within studio", "CMU 35-37 -> 38-39", b, fit_ridge([a])))
        # leave one studio out
        for held in sets:
            models = fit_ridge([h for s, h in sets.items() if s != held])
            rows.append(row(hole_s, f"{held} held out", "the other two studios", sets[held], models))
        # the corpus -> strangers
        judged = Holes(windows(strangers, keep, hole, 6), hole, hips)
        rows.append(row(hole_s, "CMU sample (strangers)", "the whole corpus", judged, fit_ridge(list(sets.values()))))
        print(f"{hole_s} s done ({time.perf_counter() - start:.0f} s)", flush=True)
    columns = [
        ("hole_s", "hole s"),
        ("check", "judged on"),
        ("trained_on", "trained on"),
        ("windows", "windows"),
        ("hermite_mm", "Hermite mm"),
    ] + [(f"x{lam:g}", f"x ridge {lam:g}") for lam in STRENGTHS]
    print_table("corrected fill / Hermite (MPJPE over a full-body hole, 30 fps)", rows, columns)
    result = {"env": describe(torch.device("cpu")), "bench": "bench/correction_carry.py", "corpus": args.corpus}
    result |= {"strangers": args.strangers, "context_frames": CONTEXT, "fps": FPS}
    result |= {"seconds": time.perf_counter() - start, "rows": rows}
    print(f"wrote {write_result('correction_carry', result, args.json_out)}")


if __name__ == "__main__":
    main()
