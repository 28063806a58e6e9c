"""MotionDataModule: any motion source -> clean fixed-length windows, split by file.

file -> io reader -> Clip -> joint selection -> resample -> (cache) -> windows (B, T, J, 3).
Corruption is not done here: it runs on the device, inside the LightningModule, where the
batch already is.
"""

from __future__ import annotations

import fnmatch
import logging
import time
from pathlib import Path

import lightning as L
import numpy as np
import torch
from lightning.pytorch.overrides.distributed import UnrepeatedDistributedSampler
from torch.utils.data import DataLoader, Dataset, WeightedRandomSampler

from mocapfix.core.clip import Clip, MotionFileError, check_human_scale
from mocapfix.core.resample import resample_clip
from mocapfix.core.skeleton import Skeleton, preset
from mocapfix.data.spec import DataSpec
from mocapfix.data.windows import (
    cache_key,
    load_clips,
    pattern_split,
    save_clips,
    split_groups,
    split_of,
    window_starts,
)
from mocapfix.rig.mapping import onto_skeleton

log = logging.getLogger(__name__)

SOURCES = ("synthetic", "bvh", "positions", "h36m", "amass", "archive")
PROGRESS_EVERY_S = 5.0  # a progress line while parsing, at most this often
SPLITS = ("train", "val", "test")


class WindowDataset(Dataset):
    """Windows cut from clips. Items are dicts of tensors; a whole batch is gathered in one
    indexing op (__getitems__), which keeps the loader cheap at large batch sizes."""

    def __init__(self, clips: list[Clip], window: int, stride: int, with_rotations: bool = False):
        self.window = window
        self.positions = (
            torch.from_numpy(np.concatenate([c.positions for c in clips])) if clips else torch.zeros(0, 0, 3)
        )
        self.with_rotations = with_rotations and bool(clips) and all(c.has_rotations for c in clips)
        if self.with_rotations:
            self.rotations = torch.from_numpy(np.concatenate([c.rotations for c in clips]))
            self.root_translation = torch.from_numpy(np.concatenate([c.root_translation for c in clips]))
            self.offsets = torch.from_numpy(np.stack([c.offsets for c in clips]))
        starts, clip_index, first = [], [], 0
        for i, c in enumerate(clips):
            s = window_starts(c.num_frames, window, stride)
            starts.append(s + first)
            clip_index.append(np.full(len(s), i))
            first += c.num_frames
        self.starts = torch.from_numpy(np.concatenate(starts)) if starts else torch.zeros(0, dtype=torch.long)
        self.clip_index = (
            torch.from_numpy(np.concatenate(clip_index)) if clip_index else torch.zeros(0, dtype=torch.long)
        )
        self.clip_names = [c.name for c in clips]
        self.weights: torch.Tensor | None = None  # (len,) how often each window is drawn in training

    def __len__(self) -> int:
        return len(self.starts)

    def to(self, device: torch.device) -> WindowDataset:
        """The same windows with every tensor on `device` (in place; returns self)."""
        for name in ("positions", "rotations", "root_translation", "offsets", "starts", "clip_index", "weights"):
            if getattr(self, name, None) is not None:
                setattr(self, name, getattr(self, name).to(device))
        return self

    def __getitems__(self, indices: list[int] | torch.Tensor) -> dict[str, torch.Tensor]:
        frames = self.starts[indices][:, None] + torch.arange(self.window, device=self.starts.device)  # (B, T)
        batch = {
            "positions": self.positions[frames],  # (B, T, J, 3)
            "clip_index": self.clip_index[indices],
            # (B,) each window's place in its split: what test corruption is seeded by, so a table
            # does not depend on batch size or on how many processes share the split
            "window": torch.as_tensor(indices, device=self.starts.device).long(),
        }
        if self.with_rotations:
            batch["rotations"] = self.rotations[frames]  # (B, T, J, 3)
            batch["root_translation"] = self.root_translation[frames]  # (B, T, 3)
            batch["offsets"] = self.offsets[self.clip_index[indices]]  # (B, J, 3)
        return batch

    def __getitem__(self, index: int) -> dict[str, torch.Tensor]:
        return {k: v[0] for k, v in self.__getitems__([index]).items()}


class DeviceBatches:
    """Training batches cut on the accelerator from windows that live there: no loader workers,
    no host-to-device copies and no host-device synchronisation per step (the host only queues
    work), so a fast GPU never waits for data. A training set of even a few hours of motion is a
    few hundred MB, small beside a GPU's memory.

    Each epoch is a fresh permutation seeded by torch's initial seed (seed_everything) and the
    epoch number, which Lightning hands over through set_epoch (so a resumed run continues the
    same sequence of epochs); with several processes (DDP), rank r takes every world_size-th
    window of the same permutation, so the ranks see disjoint windows. Incomplete last batches
    are dropped, as the training loader does."""

    def __init__(
        self, dataset: WindowDataset, batch_size: int, device: torch.device, rank: int = 0, world_size: int = 1
    ):
        self.dataset = dataset.to(device)
        self.batch_size, self.device, self.rank, self.world_size = batch_size, device, rank, world_size
        self.epoch = 0
        self.sampler = self  # where Lightning looks for set_epoch

    def set_epoch(self, epoch: int) -> None:
        self.epoch = epoch

    def __len__(self) -> int:
        per_rank = len(self.dataset) // self.world_size
        # one short batch when there are fewer windows than a batch, as the training loader does
        return per_rank // self.batch_size if per_rank >= self.batch_size else min(per_rank, 1)

    def __iter__(self):
        # the same permutation on every rank: seeded by the epoch, not by the rank's RNG state
        g = torch.Generator(device=self.device).manual_seed(torch.initial_seed() + self.epoch)
        if self.dataset.weights is not None:  # an epoch's worth of windows drawn by weight
            order = torch.multinomial(self.dataset.weights, len(self.dataset), replacement=True, generator=g)
        else:
            order = torch.randperm(len(self.dataset), generator=g, device=self.device)
        order = order[self.rank :: self.world_size][: len(self.dataset) // self.world_size]  # equal share per rank
        for i in range(len(self)):
            yield self.dataset.__getitems__(order[i * self.batch_size : (i + 1) * self.batch_size])


def _keep_batch(batch):
    """collate_fn for __getitems__ batches: they are already stacked."""
    return batch


class MotionDataModule(L.LightningDataModule):
    def __init__(
        self,
        source: str = "synthetic",
        path: str | list[str] | None = None,
        body: str | None = None,
        fps: float = 30.0,
        window_s: float = 1.0,
        stride_s: float = 0.5,
        eval_stride_s: float | None = None,
        drop_joints: list[str] | None = None,
        keep_joints: list[str] | None = None,
        groups: dict[str, list[str]] | None = None,
        unit: str = "auto",
        up_axis: str = "auto",
        body_model_path: str | None = None,
        val_fraction: float = 0.1,
        test_fraction: float = 0.1,
        split_seed: int = 0,
        split_by: str = "file",
        train_patterns: list[str] | None = None,
        val_patterns: list[str] | None = None,
        test_patterns: list[str] | None = None,
        synthetic_clips: int = 96,
        synthetic_seconds: float = 10.0,
        synthetic_seed: int = 0,
        with_rotations: bool = False,
        max_missing_fraction: float = 0.5,
        tempo_factors: list[float] | None = None,
        source_weights: dict[str, float] | None = None,
        batch_size: int = 128,
        eval_batch_size: int | None = None,
        num_workers: int = 0,
        pin_memory: bool = False,
        persistent_workers: bool = False,
        batches_on_device: bool = False,
        cache_dir: str | None = ".cache/mocapfix",
    ):
        """
        Args:
            source: one of synthetic, bvh, positions, h36m, amass, or archive (an .npz of parsed
                clips in the cache's format, e.g. to train on a machine without the raw files).
            path: a file or a folder of files, or a list of them (not used by synthetic).
            body: a skeleton preset (body21: the shipped models' 21 joints; smpl22, h36m17) that
                every recording is mapped onto by body part (rig/structure.py), so that folders
                of different rigs (and frame rates) train one model; positions only. None: the
                recordings' own skeleton, which must then be one.
            fps: every clip is resampled to this rate.
            window_s: window length in seconds; stride_s: step between training windows.
            eval_stride_s: step between val/test windows (default: window_s, no overlap).
            drop_joints / keep_joints: joint names to remove / to keep (e.g. Bandai's joint_Root).
            groups: named joint groups {left_arm: [names], ...} overriding the name-matching guess.
            unit, up_axis: for BVH / positions files ("auto" guesses).
            val_fraction, test_fraction, split_seed: the hash split by file name.
            split_by: "file", or "folder": each file's folder is one performer or session (CMU's
                subject folders) and whole folders go to one split, so the val split, the fill
                policy calibrated on it and best-*.ckpt judge the model on people it never trained
                on (fractions of the folders then).
            *_patterns: fnmatch patterns on file names that force a file into a split.
            with_rotations: also deliver rotations / root translation / offsets (rotation data only).
            max_missing_fraction: windows with more missing tokens are skipped in training.
            tempo_factors: the training split also holds each clip played this many times faster
                (e.g. [0.8, 1.25]: slower and faster performers; 1 is always there).
            source_weights: {fnmatch pattern on a file's path: weight}: the training windows of
                the files each pattern matches are drawn, together, in proportion to its weight
                (the first matching pattern counts; files that match none share a weight of 1).
                E.g. {"*/bandai*": 1, "*/cmu*": 1}: half the batches' windows from each studio
                whatever their sizes. None: every window equally often.
            cache_dir: where parsed clips are cached (None: no cache).
            batches_on_device: keep the training windows on the training device and cut batches
                there (DeviceBatches: for GPUs, where the loader would otherwise be the bottleneck).
        """
        super().__init__()
        if source not in SOURCES:
            raise ValueError(f"data.source: unknown source type {source!r}; known: {', '.join(SOURCES)}")
        if source != "synthetic" and not path:
            raise ValueError(f"data.path: source {source!r} needs a file or folder path")
        if source == "archive" and isinstance(path, (list, tuple)):
            raise ValueError("data.path: source 'archive' reads one archive file, not a list")
        if body is not None:
            from mocapfix.core.skeleton import preset

            preset(body)  # a ValueError naming the known presets
            if with_rotations:
                raise ValueError(f"data.body {body}: a canonical body has joint positions only (with_rotations)")
        if split_by not in ("file", "folder"):
            raise ValueError(f"data.split_by: 'file' or 'folder', got {split_by!r}")
        if not (0.0 <= val_fraction and 0.0 <= test_fraction and val_fraction + test_fraction <= 1.0):
            raise ValueError(
                f"data.val_fraction {val_fraction} and data.test_fraction {test_fraction}: fractions "
                "of the files, together at most 1 (the rest is the training split)"
            )
        for f in tempo_factors or ():
            if not 0.25 <= f <= 4.0:
                raise ValueError(f"data.tempo_factors: {f} is not a tempo (0.25 to 4 times the recorded speed)")
        for pattern, w in (source_weights or {}).items():
            if not w > 0:
                raise ValueError(f"data.source_weights: {pattern!r} has weight {w}; weights must be positive")
        self.save_hyperparameters()
        self.skeleton: Skeleton | None = None
        self.clips: dict[str, list[Clip]] = {}
        self.datasets: dict[str, WindowDataset] = {}

    @property
    def window_frames(self) -> int:
        return int(round(self.hparams.window_s * self.hparams.fps))

    # --- loading ---

    @property
    def paths(self) -> list[str]:
        path = self.hparams.path
        return [str(p) for p in path] if isinstance(path, (list, tuple)) else [str(path)]

    def _files(self) -> list[Path]:
        from mocapfix.io import list_motion_files

        return [f for p in self.paths for f in list_motion_files(p, self.hparams.source)]

    def _read_all(self) -> list[Clip]:
        hp = self.hparams
        if hp.source == "synthetic":
            from mocapfix.io.synthetic import generate_clips

            return generate_clips(hp.synthetic_clips, hp.synthetic_seconds, hp.fps, hp.synthetic_seed)
        if hp.source == "archive":  # a dataset parsed before (the cache's format): no re-parsing
            return load_clips(Path(hp.path))
        from mocapfix.io import read_motion

        clips, files = [], self._files()
        t0 = shown = time.perf_counter()
        for i, f in enumerate(files):
            if time.perf_counter() - shown > PROGRESS_EVERY_S:  # a big folder takes minutes the first time
                shown = time.perf_counter()
                log.info("parsing: %d of %d files, %.0f s", i, len(files), shown - t0)
            # Joint selection happens in the reader where it can (BVH: exact re-rooted rotations),
            # and again in _prepare for readers that don't take it (a no-op after the reader).
            clips.extend(
                read_motion(
                    f,
                    hp.source,
                    unit=hp.unit,
                    up_axis=hp.up_axis,
                    groups=hp.groups,
                    body_model_path=hp.body_model_path,
                    keep_joints=hp.keep_joints,
                    drop_joints=hp.drop_joints,
                )
            )
        return clips

    def _prepare(self, clips: list[Clip]) -> list[Clip]:
        """Joint selection and resampling; every clip must end on the same skeleton."""
        hp = self.hparams
        out = []
        by_file: dict[str, list[Clip]] = {}
        for c in clips:
            by_file.setdefault(c.source, []).append(c)
        for source, file_clips in by_file.items():  # a file in mm read as metres would train in km
            check_human_scale(file_clips, source)
        # drop_joints may name joints that only some files have (to bring them to one skeleton),
        # but a name no file has is a typo, and training on the joint it meant to drop is wrong.
        # (The BVH reader selects joints itself and has checked the names of its files.)
        others = [c for c in clips if c.meta.get("format") != "bvh"]
        unknown = set(hp.drop_joints or ()) - {n for c in others for n in c.skeleton.joint_names}
        if unknown and others:
            raise MotionFileError(
                ", ".join(self.paths),
                f"drop_joints not in any file's skeleton: {sorted(unknown)} "
                f"(joints: {', '.join(others[0].skeleton.joint_names)})",
            )
        for c in clips:
            names = c.skeleton.joint_names
            keep = list(range(len(names)))
            if hp.keep_joints:
                missing = [n for n in hp.keep_joints if n not in names]
                if missing:
                    raise MotionFileError(c.source, f"keep_joints not in this file's skeleton: {missing}")
                keep = [names.index(n) for n in hp.keep_joints]
            if hp.drop_joints:
                keep = [j for j in keep if names[j] not in set(hp.drop_joints)]
            if len(keep) != len(names):
                try:
                    c = c.select_joints(keep)
                except ValueError as e:  # the kept joints do not form one tree
                    raise MotionFileError(c.source, str(e)) from None
            if hp.body:
                c = onto_skeleton(c, preset(hp.body))
            if hp.groups:
                c = c.replace(skeleton=c.skeleton.with_groups(hp.groups))
            out.append(resample_clip(c, hp.fps))
        if out:
            ref = out[0].skeleton
            for c in out[1:]:
                if c.skeleton.joint_names != ref.joint_names or c.skeleton.parents != ref.parents:
                    raise MotionFileError(
                        c.source,
                        f"skeleton differs from {out[0].source}'s "
                        f"({c.skeleton.num_joints} vs {ref.num_joints} joints); "
                        "use data.body body21 to map every rig onto one body, or keep_joints / drop_joints",
                    )
        return out

    def load_clips(self) -> list[Clip]:
        """Parsed, prepared clips: from the cache when files and options are unchanged."""
        hp = self.hparams
        options = {
            k: hp[k]
            for k in (
                "source",
                "body",
                "fps",
                "drop_joints",
                "keep_joints",
                "groups",
                "unit",
                "up_axis",
                "body_model_path",
                "synthetic_clips",
                "synthetic_seconds",
                "synthetic_seed",
            )
        }
        if hp.source == "archive" and not Path(hp.path).is_file():
            raise MotionFileError(hp.path, "no such archive file")
        cache = None
        if hp.cache_dir:
            files = [] if hp.source == "synthetic" else [Path(hp.path)] if hp.source == "archive" else self._files()
            cache = Path(hp.cache_dir) / f"{hp.source}-{cache_key(files, options)}.npz"
            if cache.exists():
                t0 = time.perf_counter()
                clips = load_clips(cache)
                log.info("loaded %d clips from cache %s in %.2f s", len(clips), cache, time.perf_counter() - t0)
                return clips
        t0 = time.perf_counter()
        clips = self._prepare(self._read_all())
        if not clips:
            raise MotionFileError(", ".join(self.paths), f"no {hp.source} clips found")
        log.info("parsed %d clips in %.2f s", len(clips), time.perf_counter() - t0)
        if cache is not None:
            save_clips(cache, clips)
        return clips

    def prepare_data(self) -> None:
        # Runs once per node before setup: fills the cache so that DDP ranks don't all parse.
        self.load_clips()

    def setup(self, stage: str | None = None) -> None:
        if self.datasets:
            return
        hp = self.hparams
        clips = self.load_clips()
        if hp.with_rotations:
            self._require_rotations(clips)
        self.skeleton = clips[0].skeleton
        patterns = {"train": hp.train_patterns, "val": hp.val_patterns, "test": hp.test_patterns}
        self.clips = {s: [] for s in SPLITS}
        official = False
        by_folder = None
        if hp.split_by == "folder":
            by_folder = split_groups(
                [_folder(c) for c in clips if c.meta.get("split") not in SPLITS],
                hp.val_fraction,
                hp.test_fraction,
                hp.split_seed,
            )
        for c in clips:
            if c.meta.get("split") in SPLITS:  # an official split (Human3.6M subjects, AMASS sub-datasets)
                self.clips[c.meta["split"]].append(c)
                official = True
            elif by_folder is not None:
                self.clips[pattern_split(c.source, patterns) or by_folder[_folder(c)]].append(c)  # patterns win
            else:
                self.clips[split_of(c.source, hp.val_fraction, hp.test_fraction, hp.split_seed, patterns)].append(c)
        if official and not self.clips["val"]:
            # Human3.6M's standard split has no validation part: the field validates on S9/S11.
            self.clips["val"] = self.clips["test"]
        tempos = [f for f in (hp.get("tempo_factors") or ()) if f != 1.0]
        if tempos:  # each training clip also played faster and slower: resampled, then read at fps
            self.clips["train"] = self.clips["train"] + [
                resample_clip(c, hp.fps / f).replace(fps=float(hp.fps), name=f"{c.name}@{f:g}x")
                for f in tempos
                for c in self.clips["train"]
            ]
        eval_stride = hp.eval_stride_s or hp.window_s
        for s in SPLITS:
            stride = hp.stride_s if s == "train" else eval_stride
            ds = WindowDataset(
                self.clips[s], self.window_frames, max(1, int(round(stride * hp.fps))), hp.with_rotations
            )
            if s == "train" and len(ds):
                self._drop_mostly_missing(ds)
                if hp.get("source_weights"):
                    ds.weights = source_window_weights(self.clips[s], ds.clip_index, hp.source_weights)
            self.datasets[s] = ds
            self._name_idle_clips(self.clips[s], ds, s)
        log.info("windows: %s", {s: len(d) for s, d in self.datasets.items()})

    def _name_idle_clips(self, clips: list[Clip], ds: WindowDataset, split: str) -> None:
        """One line per clip that gives its split no window, with the reason: a user who hands
        over a folder should not find out from the numbers that half of it was never used."""
        used = torch.bincount(ds.clip_index, minlength=len(clips)) if len(clips) else torch.zeros(0)
        for c, n in zip(clips, used.tolist()):
            if n:
                continue
            if c.num_frames < ds.window:
                why = f"shorter than one window ({c.num_frames} frames at {c.fps:g} fps < {ds.window})"
            elif c.missing_mask().all():
                why = "every joint missing in every frame"
            else:
                why = f"every window misses more than {self.hparams.max_missing_fraction:.0%} of its joints"
            log.warning("warning: %s: contributes nothing to the %s split: %s", c.source or c.name, split, why)

    def _require_rotations(self, clips: list[Clip]) -> None:
        """with_rotations on data where some clips have rotations and some not (a BVH with a
        non-finite channel, say): the windows would lose them all, silently. Positions data (no
        clip has any) is fine: it is delivered without rotations (`has_rotations`)."""
        lacking = [c for c in clips if not c.has_rotations]
        if lacking and len(lacking) < len(clips):
            c = next((c for c in lacking if c.meta.get("no_rotations")), lacking[0])
            why = c.meta.get("no_rotations") or f"its {c.meta.get('format', self.hparams.source)} data has none"
            raise MotionFileError(
                c.source,
                f"no joint rotations ({why}), and {len(clips) - len(lacking)} other clips "
                f"have them: with_rotations needs them in every clip ({len(lacking)} "
                "lack them): mend or leave out those files, or train on positions "
                "(data.with_rotations: false, model.state: positions)",
            )

    @property
    def has_rotations(self) -> bool:
        """Whether the windows come with rotations (with_rotations, and rotation data)."""
        return all(ds.with_rotations for ds in self.datasets.values() if len(ds))

    def spec(self) -> DataSpec:
        """What a model needs to know of this data (after setup): skeleton, window, rotations."""
        if self.skeleton is None:
            raise RuntimeError("MotionDataModule.spec() before setup(): nothing is loaded yet")
        return DataSpec(
            self.skeleton,
            float(self.hparams.fps),
            self.window_frames,
            self.hparams.source,
            bool(self.hparams.with_rotations and self.has_rotations),
            dict(self.datasets),
        )

    def _drop_mostly_missing(self, ds: WindowDataset) -> None:
        keep = []
        for i in range(0, len(ds), 4096):
            idx = list(range(i, min(i + 4096, len(ds))))
            frac = torch.isnan(ds.__getitems__(idx)["positions"]).any(-1).float().mean((1, 2))
            keep.append(torch.tensor(idx)[frac <= self.hparams.max_missing_fraction])
        keep = torch.cat(keep)
        ds.starts, ds.clip_index = ds.starts[keep], ds.clip_index[keep]

    # --- loaders ---

    def _loader(self, split: str, shuffle: bool) -> DataLoader:
        hp = self.hparams
        ds = self.datasets[split]
        if len(ds) == 0:
            raise MotionFileError(
                hp.path or hp.source,
                f"the {split} split has no {hp.window_s} s windows; "
                "adjust val_fraction / test_fraction / patterns or window_s",
            )
        bs = hp.batch_size if split == "train" else (hp.eval_batch_size or hp.batch_size)
        sampler = None
        if shuffle and ds.weights is not None:
            sampler = WeightedRandomSampler(ds.weights.cpu().double(), len(ds), replacement=True)
            shuffle = False
        t = self.trainer
        if split != "train" and t is not None and t.world_size > 1:
            # every window once over the processes: Lightning's DistributedSampler would pad an
            # uneven split with repeated windows, counted twice in the metrics
            sampler = UnrepeatedDistributedSampler(ds, num_replicas=t.world_size, rank=t.global_rank, shuffle=False)
        return DataLoader(
            ds,
            batch_size=bs,
            shuffle=shuffle,
            sampler=sampler,
            drop_last=shuffle and len(ds) >= bs,
            num_workers=hp.num_workers,
            pin_memory=hp.pin_memory,
            persistent_workers=hp.persistent_workers and hp.num_workers > 0,
            collate_fn=_keep_batch,
        )

    def train_dataloader(self) -> DataLoader | DeviceBatches:
        if self.hparams.batches_on_device and self.trainer is not None:
            self._loader("train", shuffle=True)  # the same checks and messages
            t = self.trainer
            return DeviceBatches(
                self.datasets["train"], self.hparams.batch_size, t.strategy.root_device, t.global_rank, t.world_size
            )
        return self._loader("train", shuffle=True)

    def val_dataloader(self) -> DataLoader:
        return self._loader("val", shuffle=False)

    def test_dataloader(self) -> DataLoader:
        return self._loader("test", shuffle=False)

    def predict_dataloader(self) -> DataLoader:
        return self._loader("test", shuffle=False)


def source_window_weights(clips: list[Clip], clip_index: torch.Tensor, weights: dict[str, float]) -> torch.Tensor:
    """(windows,) sampling weights: each pattern's share split evenly over its files' windows.
    clip_index: (windows,) each window's clip."""
    group_of = []  # each clip's pattern (or None: matched none)
    for c in clips:
        path = c.source or c.name
        group_of.append(next((p for p in weights if fnmatch.fnmatch(path, p)), None))
    groups = torch.tensor([list(weights).index(g) if g is not None else len(weights) for g in group_of])
    share = torch.tensor([*weights.values(), 1.0], dtype=torch.float64)  # the unmatched share 1
    window_group = groups[clip_index.cpu()]
    count = torch.bincount(window_group, minlength=len(share)).double()
    for pattern, n in zip(weights, count.tolist()):
        if n == 0:
            log.warning("warning: data.source_weights: no training window comes from a file matching %r", pattern)
    return (share / count.clamp_min(1))[window_group].float()


def _folder(clip: Clip) -> str:
    """The name of the folder a clip's file is in (one performer or session under split_by
    folder; the name, not the path, so a split does not depend on where the data lies)."""
    return Path(clip.source).parent.name if clip.source else ""
