"""Run folders that two processes never share.

Each run of an experiment owns version_N: logs/<experiment>/version_N (its logs, config.yaml,
eval.json) and, for a fit, checkpoints/<experiment>/version_N (its last.ckpt and best). The run
claims N by creating those folders: os.mkdir is atomic, so of two runs started together the one
that creates version_N owns it and the other takes N+1; a folder left by any earlier run is never
reused. checkpoints/<experiment>/last.ckpt is a link to the last.ckpt written last by any of the
experiment's runs: the file `--ckpt_path last`, the docs and configs (a denoising stage's
prior_ckpt) name.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

from lightning.pytorch.callbacks import ModelCheckpoint

RUN_FOLDER = re.compile(r"version_(\d+)")
LAST = "last.ckpt"


def claim_version(roots: list[Path]) -> int:
    """The lowest N above every version_K in roots for which this process creates
    root/version_N in each root: an N nobody used. Another process that claims at the same time
    gets another N."""
    for root in roots:
        root.mkdir(parents=True, exist_ok=True)
    used = [int(m.group(1)) for root in roots for p in root.iterdir() if (m := RUN_FOLDER.fullmatch(p.name))]
    n = max(used, default=-1) + 1
    while True:
        made = []
        try:
            for root in roots:
                (root / f"version_{n}").mkdir()
                made.append(root / f"version_{n}")
            return n
        except FileExistsError:  # another run holds version_n in one of the roots: not ours
            for folder in made:
                folder.rmdir()  # ours and still empty; nobody else writes into a folder they did not create
            n += 1


def point_last(experiment_dir: Path, run_last: Path) -> None:
    """experiment_dir/last.ckpt -> run_last (a relative link, swapped in atomically, so a reader
    never meets a missing or half-made one). A last.ckpt that is a file (from before runs had
    folders) stays, under last-unversioned*.ckpt."""
    top = experiment_dir / LAST
    if top.exists() and not top.is_symlink():
        _set_aside(top)
    tmp = experiment_dir / f".{LAST}.{os.getpid()}.tmp"
    tmp.unlink(missing_ok=True)
    target = os.path.relpath(run_last, experiment_dir)
    try:
        os.symlink(target, tmp)
    except OSError:  # no symbolic links here (some Windows setups): a hard link to this version of it
        os.link(run_last, tmp)
    os.replace(tmp, top)


def _set_aside(top: Path) -> None:
    for i in range(1000):
        keep = top.with_name(f"last-unversioned{'' if i == 0 else f'-{i}'}.ckpt")
        try:
            os.link(top, keep)  # never over an existing name; top itself is replaced by the caller
            return
        except FileExistsError:
            if keep.exists() and os.path.samefile(keep, top):
                return
        except FileNotFoundError:  # another run set it aside first
            return
    raise FileExistsError(f"{top}: cannot set the earlier last.ckpt aside (last-unversioned-*.ckpt all taken)")


def resolve_last(experiment_dir: Path) -> Path | None:
    """The run's own file behind experiment_dir/last.ckpt (checkpoints/<experiment>/version_N/
    last.ckpt, relative as the link is; the file itself for a layout from before runs had
    folders); None when there is none."""
    top = experiment_dir / LAST
    if not top.is_file():  # missing, or a link to nothing
        return None
    if top.is_symlink():
        target = Path(os.readlink(top))
        return target if target.is_absolute() else experiment_dir / target
    return top


def is_last_link(path: Path) -> bool:
    """Whether path is an experiment's last.ckpt link into one of its run folders."""
    path = Path(path)
    if path.name != LAST or not path.is_symlink():
        return False
    target = Path(os.readlink(path))
    return len(target.parts) == 2 and RUN_FOLDER.fullmatch(target.parts[0]) is not None and target.name == LAST


class RunCheckpoint(ModelCheckpoint):
    """ModelCheckpoint into the run's folder (checkpoints/<experiment>/version_N) that points the
    experiment's last.ckpt at the run's each time it writes it, and, on a resume from another run
    of the experiment, carries on with its best (a new best is written only when it beats it)."""

    @property
    def state_key(self) -> str:
        # ModelCheckpoint's key: a checkpoint written before run folders (or read by tools that look
        # for "ModelCheckpoint{...}") resumes with its best score, and ours read back the same way
        key = super().state_key
        return "ModelCheckpoint" + key.removeprefix(type(self).__qualname__)

    def _save_checkpoint(self, trainer, filepath: str) -> None:
        super()._save_checkpoint(trainer, filepath)
        path = Path(filepath)
        if path.name == LAST and RUN_FOLDER.fullmatch(path.parent.name) and trainer.is_global_zero:
            point_last(path.parent.parent, path)

    def load_state_dict(self, state_dict: dict) -> None:
        theirs = state_dict.get("dirpath")
        if theirs and self.dirpath and theirs != self.dirpath and _same_experiment(Path(theirs), Path(self.dirpath)):
            state_dict = {**state_dict, "dirpath": self.dirpath}
        super().load_state_dict(state_dict)


def _same_experiment(theirs: Path, ours: Path) -> bool:
    """theirs: another run folder of ours' experiment (or the experiment's folder itself, where
    runs wrote before they had folders)."""
    experiment = ours.parent
    return theirs == experiment or (theirs.parent == experiment and RUN_FOLDER.fullmatch(theirs.name) is not None)
