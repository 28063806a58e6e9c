"""The XMAE paper's evaluation (section 4.1) as a list of tasks and a table of results.

Tasks: infilling (full skeleton, arms, legs) and constant arm displacement over centred gaps,
Gaussian noise on positions. Left and right limbs are scored separately and averaged in the
table, as the paper reports them.
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass
from pathlib import Path

import torch

from mocapfix.core.skeleton import Skeleton
from mocapfix.data.corruption import Corrupted, constant_displacement, gaussian_noise, infill_gap

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Task:
    task: str  # infill | displacement | noise
    part: str  # full | left_arm | right_arm | left_leg | right_leg
    gap_s: float | None = None
    sigma_m: float | None = None

    @property
    def key(self) -> str:
        param = f"gap{self.gap_s}" if self.gap_s is not None else f"sigma{self.sigma_m}"
        return f"{self.task}/{self.part}/{param}"

    def corrupt(
        self, positions: torch.Tensor, fps: float, skeleton: Skeleton, generator: torch.Generator | None
    ) -> Corrupted:
        joints = None if self.part == "full" else list(skeleton.groups[self.part])
        if self.task == "infill":
            return infill_gap(positions, fps, self.gap_s, joints)
        if self.task == "displacement":
            return constant_displacement(positions, fps, self.gap_s, joints, generator)
        return gaussian_noise(positions, self.sigma_m, generator)

    def corrupt_windows(
        self, positions: torch.Tensor, fps: float, skeleton: Skeleton, seeds: torch.Tensor
    ) -> Corrupted:
        """corrupt, each window (B, T, J, 3) with its own generator seeded by seeds (B,): the same
        window gets the same corruption whatever batch or process it is in."""
        if self.task == "infill":  # no random draw
            return self.corrupt(positions, fps, skeleton, None)
        parts = [
            self.corrupt(positions[b : b + 1], fps, skeleton, torch.Generator().manual_seed(int(seed)))
            for b, seed in enumerate(seeds.tolist())
        ]
        return Corrupted(*(torch.cat(field) for field in zip(*parts)))

    def evaluated(self, c: Corrupted, target: torch.Tensor) -> torch.Tensor:
        """(B, T, J) bool: removed or displaced tokens (every token for noise) that have ground truth."""
        has_truth = ~torch.isnan(target).any(-1)
        if self.task == "noise":
            return has_truth
        return has_truth & (~c.observed | c.displaced)


def paper_tasks(skeleton: Skeleton, gaps_s=(0.1, 0.3, 0.5, 0.7, 0.9), noise_sigmas_m=(0.02, 0.05)) -> list[Task]:
    tasks = []
    arms = [g for g in ("left_arm", "right_arm") if g in skeleton.groups]
    legs = [g for g in ("left_leg", "right_leg") if g in skeleton.groups]
    if len(arms) + len(legs) < 4:
        absent = sorted({"left_arm", "right_arm", "left_leg", "right_leg"} - set(arms) - set(legs))
        log.info(
            "skeleton %r has no %s group: those tasks are left out of the tables (data.groups names their joints)",
            skeleton.name,
            ", ".join(absent),
        )
    for gap in gaps_s:
        tasks += [Task("infill", p, gap_s=gap) for p in ["full", *arms, *legs]]
        tasks += [Task("displacement", p, gap_s=gap) for p in arms]
    tasks += [Task("noise", "full", sigma_m=s) for s in noise_sigmas_m]
    return tasks


def table_rows(results: dict[tuple[str, str], tuple[float, float]], tasks: list[Task]) -> list[dict]:
    """results[(task.key, method)] = (mpjpe_mm, mpjpe_rel_mm) -> rows averaged over left/right:
    {task, part, gap_s | sigma_m, method, mpjpe_mm, mpjpe_rel_mm}."""
    methods = sorted({m for _, m in results})
    groups: dict[tuple, list[tuple[float, float]]] = {}
    for t in tasks:
        part = t.part.split("_")[-1]  # left_arm -> arm
        for m in methods:
            if (t.key, m) in results:
                groups.setdefault((t.task, part, t.gap_s, t.sigma_m, m), []).append(results[(t.key, m)])
    rows = []
    for (task, part, gap, sigma, m), vals in groups.items():
        row = {"task": task, "part": part}
        row.update({"gap_s": gap} if gap is not None else {"sigma_m": sigma})
        row.update(
            method=m,
            mpjpe_mm=round(sum(v[0] for v in vals) / len(vals), 2),
            mpjpe_rel_mm=round(sum(v[1] for v in vals) / len(vals), 2),
        )
        rows.append(row)
    return rows


def format_table(rows: list[dict]) -> str:
    """The paper's layout: one line per (task, part, method, global/rel), one column per gap or sigma."""
    lines = []
    for task in dict.fromkeys(r["task"] for r in rows):
        sub = [r for r in rows if r["task"] == task]
        pkey = "gap_s" if "gap_s" in sub[0] else "sigma_m"
        params = sorted({r[pkey] for r in sub})
        unit = "Gap (s)" if pkey == "gap_s" else "Sigma (m)"
        lines.append(f"{task} — MPJPE (mm)")
        lines.append(f"{'part':6s} {'method':20s} {'':6s} " + " ".join(f"{p:>7g}" for p in params) + f"   <- {unit}")
        for part in dict.fromkeys(r["part"] for r in sub):
            for m in dict.fromkeys(r["method"] for r in sub if r["part"] == part):
                for col, label in (("mpjpe_mm", "global"), ("mpjpe_rel_mm", "rel.")):
                    vals = {r[pkey]: r[col] for r in sub if r["part"] == part and r["method"] == m}
                    lines.append(
                        f"{part:6s} {m:20s} {label:6s} " + " ".join(f"{vals.get(p, float('nan')):7.1f}" for p in params)
                    )
        lines.append("")
    return "\n".join(lines)


def write_eval_json(path: Path, rows: list[dict]) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(rows, indent=1))
    tmp.replace(path)
    return path


def window_seeds(batch: dict, batch_idx: int, k: int = 0, eval_seed: int = 0) -> torch.Tensor:
    """(B,) seeds for each test window's corruption k: from the window's place in its split
    (batch["window"], set by the data module), so a test table is the same for any batch size and
    number of processes. A batch without it (another dataset) falls back to its batch index."""
    B = len(batch["positions"])
    window = batch.get("window")
    if window is None:
        window = batch_idx * B + torch.arange(B)
    return eval_seed * 1_000_003 + window.cpu().long() * 101 + k
