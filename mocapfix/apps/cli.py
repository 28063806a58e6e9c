"""fit | validate | test | predict: LightningCLI (--config NAME or FILE, --print_config,
--key.path value) with the project's wiring: configs by name, logger, checkpoints, one-line
errors. The other commands: apps/main.py.

Configs (mocapfix/configs, shipped in the package; `configs/` in a checkout) are pieces,
data/*.yaml, model/*.yaml, trainer/*.yaml, and experiments that name their pieces in a
`defaults:` list and hold only what differs. `--config xmae` finds the packaged experiment by
name; expand_configs turns each --config into its pieces' --config options followed by itself,
and LightningCLI merges them in that order.
"""

from __future__ import annotations

import os
import signal
import sys
from pathlib import Path

LIGHTNING_COMMANDS = ("fit", "validate", "test", "predict")
# what each command's --help ends with
EXAMPLES = {
    "fit": "mocapfix fit --config xmae_cpu --data.path takes/ --experiment my_studio   "
    "(then: tensorboard --logdir logs/my_studio)",
    "validate": "mocapfix validate --config xmae_cpu --data.path takes/ --ckpt_path last   "
    "(the fill policy measured on the val split, written into checkpoints/xmae_cpu/last.ckpt)",
    "test": "mocapfix test --config xmae_cpu --data.path takes/ --ckpt_path last   (the test tables: eval.json)",
    "predict": "mocapfix predict --config xmae_cpu --data.path takes/ --ckpt_path last   "
    "(predictions.npz in the run's log folder; whole takes in their own format: mocapfix fix)",
}
CONFIG_DIR = Path(__file__).resolve().parents[1] / "configs"


def packaged_configs() -> list[str]:
    """The experiments shipped with mocapfix, by name."""
    return sorted(p.stem for p in CONFIG_DIR.glob("*.yaml"))


def resolve_config(name: str, base: Path | None = None) -> Path:
    """A --config value or a defaults entry -> its file: a path as given (relative to base for a
    defaults entry), else a packaged config by name ("xmae", "data/bvh", with or without .yaml)."""
    name = str(name)
    candidates = [Path(name)] if base is None else [base / name, base / f"{name}.yaml"]
    candidates += [CONFIG_DIR / name, CONFIG_DIR / f"{name}.yaml"]
    for c in candidates:
        if c.is_file():
            return c
    raise ValueError(
        f"{name}: no such config file, nor a packaged config (packaged: {', '.join(packaged_configs())}; "
        "pieces: data/, model/, trainer/)"
    )


def expand_configs(args: list[str]) -> list[str]:
    """Each `--config X` -> `--config PIECE ... --config X` for the pieces X names in its
    `defaults:` list (recursively, each piece once), with X resolved to its file."""
    import yaml

    def pieces(path: Path, seen: set) -> list[Path]:
        try:
            text = yaml.safe_load(path.read_text())
        except (OSError, yaml.YAMLError) as e:
            raise ValueError(f"{path}: not a readable YAML config ({' '.join(str(e).split())[:200]})") from None
        named = (text or {}).get("defaults") or [] if isinstance(text, dict) else []
        if not isinstance(named, list):
            raise ValueError(f"{path}: defaults must be a list of config names, got {named!r}")
        out = []
        for n in named:
            piece = resolve_config(n, path.parent)
            if piece.resolve() not in seen:
                seen.add(piece.resolve())
                out += pieces(piece, seen) + [piece]
        return out

    out, i = [], 0
    while i < len(args):
        if args[i].startswith("--config="):
            value, i = args[i].split("=", 1)[1], i + 1
        elif args[i] == "--config" and i + 1 < len(args):
            value, i = args[i + 1], i + 2
        else:
            out.append(args[i])
            i += 1
            continue
        path = resolve_config(value)
        for p in pieces(path, {path.resolve()}) + [path]:
            out += ["--config", str(p)]
    return out


def _lightning_cli(args: list[str]):
    import torch

    from mocapfix.apps.console import quiet_lightning
    from mocapfix.apps.lightning_cli import RUN_VERSION_ENV, MocapCLI
    from mocapfix.data.datamodule import MotionDataModule

    torch.set_float32_matmul_precision("high")
    # LightningCLI reads sys.argv, and warns when it is given args beside a non-empty sys.argv (as
    # for `mocapfix demo` or a call from Python): hand it the arguments as sys.argv for the run.
    # sys.argv[0] stays the program that runs (the `mocapfix` script, or __main__.py under
    # `python -m`): DDP starts the other processes by running it again. Usage lines say "mocapfix".
    argv_before = sys.argv
    sys.argv = [argv_before[0] if argv_before else "mocapfix", *expand_configs(args)]
    try:
        with quiet_lightning():
            return MocapCLI(
                datamodule_class=MotionDataModule,
                subclass_mode_model=True,
                parser_kwargs={
                    "parser_mode": "omegaconf",
                    "prog": "mocapfix",
                    **{c: {"epilog": f"example: {e}"} for c, e in EXAMPLES.items()},
                },
                save_config_kwargs={"overwrite": True},
                auto_configure_optimizers=False,
            )
    finally:
        sys.argv = argv_before
        os.environ.pop(RUN_VERSION_ENV, None)  # for this run's DDP processes only, not the next run


def _own_error(e: ValueError) -> BaseException:
    """The error a model's or data module's own setting check raised. jsonargparse wraps one raised
    while it builds the class in "Does not validate against any of the Union subtypes", followed
    by every setting of the class: the user needs the line that names their setting."""
    while str(e).startswith("Does not validate against any of the Union subtypes") and e.__cause__ is not None:
        e = e.__cause__
    return e


def run_lightning(command: str, argv: list[str]) -> int:
    """fit / validate / test / predict through LightningCLI; the project's input errors and
    SIGTERM become one line and an exit code."""
    from lightning.pytorch.utilities.exceptions import SIGTERMException

    try:
        _lightning_cli(argv)
    except SIGTERMException:  # a SystemExit without a code: the shell would read success
        print(
            f"mocapfix {command}: stopped by SIGTERM (a fit keeps its state in checkpoints/<experiment>/last.ckpt)",
            file=sys.stderr,
        )
        return 128 + signal.SIGTERM
    except ValueError as e:  # the project's input checks (MotionFileError is one) say file and problem
        if os.environ.get("MOCAPFIX_TRACEBACK"):
            raise
        print(f"mocapfix {command}: {_own_error(e)}  (MOCAPFIX_TRACEBACK=1 for the traceback)", file=sys.stderr)
        return 2
    return 0
