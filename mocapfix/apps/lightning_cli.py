"""LightningCLI with the project's wiring, for fit | validate | test | predict (apps/cli.py runs
it): the run's own folders and logger, the checkpoints and callbacks every run gets, a checkpoint's
model built from mocapfix's own classes only, and what each command writes after it. Imported only
when one of those commands runs: Lightning's import is slow, and `mocapfix fix` needs none of it."""

from __future__ import annotations

import os
from pathlib import Path

import torch
from lightning.pytorch.callbacks import LearningRateMonitor, ProgressBar, TQDMProgressBar
from lightning.pytorch.cli import LightningCLI
from lightning.pytorch.loggers import TensorBoardLogger
from lightning.pytorch.utilities import rank_zero_only
from lightning.pytorch.utilities.exceptions import SIGTERMException

from mocapfix.training.fit_eta import FitETA
from mocapfix.training.interrupt_checkpoint import CheckpointOnInterrupt
from mocapfix.training.monitor_check import MonitorCheck
from mocapfix.training.predictions import WritePredictions
from mocapfix.training.rng_state import RNGStateInCheckpoint
from mocapfix.training.run_dirs import RunCheckpoint, claim_version, is_last_link, resolve_last
from mocapfix.training.time_schedule import FitScheduleToTime
from mocapfix.training.tracking import RunSummary

LOGGERS = ("tensorboard", "csv", "mlflow")
# a run's version_N, from the process that claimed it to the processes DDP starts from it
RUN_VERSION_ENV = "MOCAPFIX_RUN_VERSION"


def make_logger(kind: str, experiment: str, version: int | None = None):
    """The run's logger: TensorBoard (scalars, hyperparameters, figures) or CSV (scalars and
    hyperparameters only: no figures) in logs/<experiment>/version_N, or MLflow (its own store,
    ./mlruns by default; the experiment by name). version: the run's N, claimed by
    run_dirs.claim_version (None: Lightning's next free one). A fit's hyperparameters beside its results
    (TensorBoard's HPARAMS tab): training/tracking.py."""
    if kind == "tensorboard":
        from mocapfix.training.tracking import StepsTensorBoardLogger

        # default_hp_metric: Lightning's hp_metric card, a constant -1 (RunSummary logs real ones)
        return StepsTensorBoardLogger(save_dir="logs", name=experiment, version=version, default_hp_metric=False)
    if kind == "csv":
        from lightning.pytorch.loggers import CSVLogger

        return CSVLogger(save_dir="logs", name=experiment, version=version)
    if kind == "mlflow":
        import importlib.util

        if importlib.util.find_spec("mlflow") is None:
            raise ValueError("--logger mlflow needs the mlflow package (pip install mlflow)")
        from lightning.pytorch.loggers import MLFlowLogger

        return MLFlowLogger(experiment_name=experiment)
    raise ValueError(f"--logger must be one of {', '.join(LOGGERS)}, got {kind!r}")


class MocapCLI(LightningCLI):
    def _run_subcommand(self, subcommand: str) -> None:
        try:
            super()._run_subcommand(subcommand)
        except RuntimeError as e:
            # DDP after a SIGTERM: when another process stopped first, this one's next
            # collective fails; that is the SIGTERM stop too (last.ckpt is written)
            if self.trainer.received_sigterm:
                raise SIGTERMException() from e
            raise

    def add_arguments_to_parser(self, parser):
        parser.add_argument(
            "--experiment",
            type=str,
            default="default",
            help="run name: logs/<experiment>/version_N and checkpoints/<experiment>/version_N, a new N each run",
        )
        parser.add_argument(
            "--checkpoint_every_n_steps",
            type=int | None,
            default=None,
            help="also write last.ckpt every N optimiser steps",
        )
        parser.add_argument(
            "--monitor", type=str, default="val/mpjpe_mm", help="metric for the best checkpoint (lower is better)"
        )
        parser.add_argument(
            "--logger",
            type=str,
            default="tensorboard",
            help="experiment tracking: tensorboard, csv or mlflow (logs/<experiment>/ or ./mlruns); "
            "trainer.logger, when a config sets it, wins",
        )
        parser.add_argument(
            "--defaults",
            type=list[str] | None,
            default=None,
            help="config pieces a config builds on (in a config file; expanded before parsing)",
        )

    def _parse_ckpt_path(self):
        # LightningCLI builds the model from the checkpoint's hyperparameters when --ckpt_path
        # is a file, but leaves "last" to the Trainer, after the model is built from the
        # config alone: a model trained with other sizes would then fail to load. Resolve
        # "last" to this experiment's last.ckpt first (none: Lightning starts from scratch).
        cfg = self.config.get(self.config.get("subcommand") or "", None)
        ckpt_path = cfg.get("ckpt_path") if cfg is not None else None
        last = Path("checkpoints") / cfg.experiment / "last.ckpt"
        if ckpt_path and ckpt_path != "last" and is_last_link(Path(ckpt_path)) and Path(ckpt_path).is_file():
            last, ckpt_path = Path(ckpt_path), "last"
        if ckpt_path == "last" and last.is_file():
            # the run's own file behind the experiment's last.ckpt link (training/run_dirs.py):
            # `validate` writes its fill policy into that file, and the link keeps leading to it
            cfg.ckpt_path = ckpt_path = str(resolve_last(last.parent))
        elif ckpt_path == "last" and self.config.get("subcommand") != "fit":
            # fit starts afresh without one; evaluating an untrained model would look like a result
            raise ValueError(
                f"{last}: no such checkpoint (--ckpt_path last reads checkpoints/<--experiment>/"
                f"last.ckpt; --experiment is {cfg.experiment!r})"
            )
        elif ckpt_path and ckpt_path not in ("last", "best", "hpc", "registry") and not Path(ckpt_path).is_file():
            raise ValueError(f"{ckpt_path}: no such checkpoint file")
        if ckpt_path and Path(ckpt_path).is_file():
            self._model_from_checkpoint(ckpt_path)

    def _model_from_checkpoint(self, ckpt_path: str) -> None:
        """The model settings a checkpoint saved, over the config's: LightningCLI's
        _parse_ckpt_path, except that the checkpoint's class is one of mocapfix's own
        (training/registry.py), never a module imported by the name the file gives."""
        from jsonargparse import ArgumentError

        from mocapfix.models.checkpoint import HYPER_PARAMETERS, is_training_state, load_checkpoint
        from mocapfix.training.registry import checked_hyperparameters

        ckpt = load_checkpoint(ckpt_path)  # weights_only: a MotionFileError (one line) if not plain values
        hparams = checked_hyperparameters(ckpt_path, ckpt.get(HYPER_PARAMETERS) if isinstance(ckpt, dict) else 0)
        if not is_training_state(ckpt):
            # Lightning's loader would stop on a KeyError (adapt's and the benchmarks' files are such)
            raise ValueError(
                f"{ckpt_path}: not a checkpoint of a training run (no Lightning state); "
                "mocapfix fix --ckpt reads weights-only checkpoints"
            )
        if not hparams:
            return
        # jsonargparse would print its usage and the settings it was given, then exit: one line instead
        exit_on_error, self.parser.exit_on_error = self.parser.exit_on_error, False
        try:
            self.config = self.parser.parse_object({self.config.subcommand: {"model": hparams}}, self.config)
        except ArgumentError as e:  # its message quotes the settings: none of the file's contents on the line
            raise ValueError(f"{ckpt_path}: the checkpoint's model settings do not fit its model class") from e
        finally:
            self.parser.exit_on_error = exit_on_error

    def instantiate_trainer(self, **kwargs):
        cfg = self.config[self.subcommand]
        name = cfg.experiment
        trainer_cfg = cfg.trainer
        extra = []
        # Default tracking and checkpoints, unless the config brings its own: in the run's own
        # folders, logs/<experiment>/version_N and checkpoints/<experiment>/version_N, which
        # no other run shares (training/run_dirs.py)
        own_logs = trainer_cfg.get("logger") in (None, True) and cfg.logger in ("tensorboard", "csv")
        checkpointing = trainer_cfg.get("enable_checkpointing", True) is not False
        roots = [Path("logs") / name] if own_logs else []
        roots += [Path("checkpoints") / name] if checkpointing and self.subcommand == "fit" else []
        version = self._run_version(roots) if roots and not trainer_cfg.get("fast_dev_run") else None
        if trainer_cfg.get("logger") in (None, True):
            kwargs["logger"] = make_logger(cfg.logger, name, version)
        if checkpointing:
            experiment_dir = Path("checkpoints") / name
            dirpath = experiment_dir / f"version_{version}" if version is not None else experiment_dir
            # last.ckpt is always the newest state of this run (checkpoints/<experiment>/
            # last.ckpt links to it). With Lightning's version counter a second writer (the
            # every-N callback) would write last-v1.ckpt beside it and leave last.ckpt stale.
            extra.append(
                RunCheckpoint(
                    dirpath=dirpath,
                    filename="best-{epoch}-{step}",
                    monitor=cfg.monitor,
                    mode="min",
                    save_top_k=1,
                    save_last=True,
                    enable_version_counter=False,
                )
            )
            extra.append(MonitorCheck(cfg.monitor))
            extra.append(CheckpointOnInterrupt(dirpath / "last.ckpt", link_from=experiment_dir))
            if cfg.checkpoint_every_n_steps:
                extra.append(
                    RunCheckpoint(
                        dirpath=dirpath,
                        every_n_train_steps=cfg.checkpoint_every_n_steps,
                        save_top_k=0,
                        save_last=True,
                        enable_version_counter=False,
                    )
                )
        if trainer_cfg.get("max_time"):  # the cosine ends when the clock stops the run
            extra.append(FitScheduleToTime())
        if kwargs.get("logger", trainer_cfg.get("logger")) not in (None, False):
            extra.append(LearningRateMonitor(logging_interval="step"))
        extra.append(RNGStateInCheckpoint())
        # a fit's hyperparameters beside its best validation results (the other commands: its
        # state in the checkpoint, which Lightning wants a callback for)
        extra.append(RunSummary(seed=cfg.get("seed_everything")))
        if self.subcommand == "predict":
            extra.append(WritePredictions())
        if self.subcommand == "fit":  # how long the run will take, where the progress bar is
            extra.append(FitETA())
        configured = self.config_init[self.subcommand].trainer.get("callbacks") or []
        configured = list(configured if isinstance(configured, list) else [configured])
        if trainer_cfg.get("enable_progress_bar", True) is not False and not any(
            isinstance(cb, ProgressBar) for cb in configured
        ):
            # Each refresh reads the logged loss back from the GPU, which waits for the step to
            # finish; Lightning's default refreshes every step, a stall on every step. On the
            # CPU there is nothing to wait for, and a step can take a second.
            on_cpu = trainer_cfg.get("accelerator") == "cpu" or not torch.cuda.is_available()
            extra.append(TQDMProgressBar(refresh_rate=1 if on_cpu else 20))
        kwargs["callbacks"] = configured + extra
        return super().instantiate_trainer(**kwargs)

    def _run_version(self, roots: list[Path]) -> int | None:
        """This run's N: claimed by the first process; the processes DDP starts from it
        inherit it through the environment (other launchers start every process at once:
        there the others' folders are rank 0's, which Lightning hands them where they matter)."""
        if rank_zero_only.rank != 0 or os.environ.get("NODE_RANK", "0") != "0":
            inherited = os.environ.get(RUN_VERSION_ENV)
            return int(inherited) if inherited is not None and inherited.isdigit() else None
        version = claim_version(roots)
        os.environ[RUN_VERSION_ENV] = str(version)
        return version

    def after_fit(self):
        t = self.trainer
        ckpt = next((cb for cb in t.checkpoint_callbacks if cb.monitor), None)
        where = t.logger.log_dir if t.logger is not None else None
        if t.is_global_zero and where:
            if isinstance(t.logger, TensorBoardLogger):
                print(f"TensorBoard logs: {where}   (view: tensorboard --logdir {Path(where).parent})")
            else:
                print(f"{type(t.logger).__name__} logs: {where}")
            if ckpt is not None:
                print(f"checkpoints: best {ckpt.best_model_path or '-'}, last {ckpt.last_model_path or '-'}")

    def after_predict(self):
        writer = next((cb for cb in self.trainer.callbacks if isinstance(cb, WritePredictions)), None)
        if writer is not None and writer.path is not None and self.trainer.is_global_zero:
            print(f"predictions: {writer.path}")

    def after_validate(self):
        # `validate --ckpt_path X` is the calibrate step: the fill policy measured on the val
        # split goes into X, for fix and test (a checkpoint from before the policy gets one)
        ckpt = self.config[self.subcommand].get("ckpt_path")
        policy = getattr(self.model, "fill_policy", None)
        if ckpt and policy is not None and self.trainer.is_global_zero and Path(ckpt).is_file():
            from mocapfix.models.checkpoint import load_checkpoint, save_checkpoint, set_fill_policy

            state = load_checkpoint(ckpt)
            set_fill_policy(state, policy.to_dict())
            save_checkpoint(ckpt, state)
            print(f"fill policy (val split) written into {ckpt}:\n  " + "\n  ".join(policy.describe()))

    def after_test(self):
        path = getattr(self.model, "eval_json_path", None)
        if path is not None and self.trainer.is_global_zero:
            print(f"eval.json: {path}")
