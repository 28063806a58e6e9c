"""`mocapfix` / `python -m mocapfix`: one entry point, one module per command.

fit | validate | test | predict   apps/cli.py (LightningCLI, configs by name)
fix                               apps/fix_cli.py
adapt                             apps/adapt.py
inspect                           apps/inspect.py
demo                              apps/demo.py
models                            the shipped models (mocapfix/pretrained)
docs                              where the documentation (mocapfix/docs) is installed
"""

from __future__ import annotations

import logging
import os
import sys
from pathlib import Path

from mocapfix.apps.cli import LIGHTNING_COMMANDS, packaged_configs, run_lightning

# The docs/ pages of a checkout (a link to this folder there), installed with the package.
DOCS = Path(__file__).resolve().parents[1] / "docs"


def _no_options(command: str, description: str, example: str, argv: list[str]) -> None:
    """A command without options: its --help (description and an example), and an error for anything else."""
    import argparse

    argparse.ArgumentParser(
        prog=f"mocapfix {command}", description=description, epilog=f"example: {example}"
    ).parse_args(argv)


def list_docs(argv: list[str] | None = None) -> int:
    """`mocapfix docs`: where the documentation is installed, and each page's title."""
    _no_options(
        "docs",
        "Where the documentation (Markdown) is installed, and each page's title.",
        "mocapfix docs   (then open the page it names, e.g. training.md)",
        argv or [],
    )
    print(f"mocapfix documentation (Markdown): {DOCS}")
    for page in sorted(DOCS.glob("*.md")):
        lines = page.read_text(encoding="utf-8").splitlines()
        title = next((line[2:].strip() for line in lines if line.startswith("# ")), "")
        print(f"  {page.name:<16} {title}")
    return 0


def list_models(argv: list[str] | None = None) -> int:
    """`mocapfix models`: the shipped models, a line each, and where their cards are."""
    _no_options(
        "models",
        "The models shipped with mocapfix, a line each: what each was trained on, its license and joints.",
        "mocapfix models   (then: mocapfix fix take.bvh --model xmae-cpu-bandai -o take.fixed.bvh)",
        argv or [],
    )
    from mocapfix.fix import load_fixer
    from mocapfix.pretrained import MODELS, pretrained_path

    for name, m in MODELS.items():
        fixer = load_fixer(pretrained_path(name))
        print(f"{name}: {m.summary}. License: {m.license}.\n    joints: {', '.join(fixer.skeleton.joint_names)}")
    print(f"use: mocapfix fix INPUT --model NAME   (model cards: {DOCS / 'models.md'})")
    return 0


class _StderrHandler(logging.StreamHandler):
    """A StreamHandler on whatever sys.stderr is when it writes (pytest swaps it between calls)."""

    @property
    def stream(self):
        return sys.stderr

    @stream.setter
    def stream(self, value):
        pass


class _ReaderMayLeave:
    """A text stream (sys.stdout, sys.stderr) that goes quiet when its reader goes away
    (`mocapfix fix takes/ ... | head -1`): the work goes on, outputs are still written, and what
    would have been printed is dropped, instead of a BrokenPipeError stopping the run halfway."""

    def __init__(self, stream):
        self._stream, self._gone = stream, False

    def write(self, text: str) -> int:
        if not self._gone:
            try:
                return self._stream.write(text)
            except BrokenPipeError:
                self._went_away()
        return len(text)

    def flush(self) -> None:
        if not self._gone:
            try:
                self._stream.flush()
            except BrokenPipeError:
                self._went_away()

    def _went_away(self) -> None:
        self._gone = True
        # The interpreter flushes the real stream once more at exit, and that flush would fail
        # the same way (Python's docs, "Note on SIGPIPE"): its descriptor now points at devnull.
        try:
            devnull = os.open(os.devnull, os.O_WRONLY)
            try:
                os.dup2(devnull, self._stream.fileno())
            finally:
                os.close(devnull)
        except (OSError, ValueError, AttributeError):  # a stream without a descriptor (a test's)
            pass

    def __getattr__(self, name):  # isatty, fileno, encoding...: the stream's own
        return getattr(self._stream, name)


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    command = argv[0] if argv else None
    streams = sys.stdout, sys.stderr
    if command not in LIGHTNING_COMMANDS:  # Lightning's console (rich) keeps the real streams
        sys.stdout, sys.stderr = _ReaderMayLeave(sys.stdout), _ReaderMayLeave(sys.stderr)
    try:
        return _main(argv)
    except BrokenPipeError:  # a stream left unwrapped: stop quietly (Python's docs, "Note on SIGPIPE")
        _ReaderMayLeave(streams[0])._went_away()
        return 1
    finally:
        for stream in (sys.stdout, sys.stderr):  # what is still buffered, while a closed reader is quiet
            if isinstance(stream, _ReaderMayLeave):
                stream.flush()
        sys.stdout, sys.stderr = streams


def _main(argv: list[str]) -> int:
    # Our own progress lines (parsing, cache, windows); Lightning configures its own loggers.
    logger = logging.getLogger("mocapfix")
    if not any(isinstance(h, _StderrHandler) for h in logger.handlers):  # once, however often main runs
        handler = _StderrHandler()
        handler.setFormatter(logging.Formatter("%(message)s"))
        logger.addHandler(handler)
    logger.setLevel(logging.INFO)
    command = argv[0] if argv else None
    if command in (None, "-h", "--help"):
        print(
            "usage: mocapfix {fit,validate,test,predict} --config NAME|FILE [--key.path value ...]\n"
            "       mocapfix inspect FILE... [--json]\n"
            "       mocapfix fix INPUT... --ckpt CKPT|--model NAME [-o OUT|--out-dir DIR] [--mode MODE]\n"
            "       mocapfix inspect FILE... --ckpt CKPT|--model NAME  (how the file's joints map onto the model's)\n"
            "       mocapfix adapt FOLDER... --model NAME|--ckpt CKPT [--minutes M] [-o OUT.ckpt]\n"
            "       mocapfix render INPUT [FIXED...] -o OUT.gif|mp4|png [--start S] [--duration S]\n"
            "       mocapfix models | docs   (the shipped models; where the documentation is installed)\n"
            "       mocapfix demo\n"
            "       mocapfix --version\n"
            "`mocapfix COMMAND --help` lists its options; `mocapfix fit --config NAME --print_config` every setting.\n"
            "example: mocapfix fix take.bvh --model xmae-cpu-bandai -o take.fixed.bvh\n"
            f"packaged configs: {', '.join(packaged_configs())}",
            file=sys.stdout if command else sys.stderr,
        )
        return 0 if command else 2
    if command == "inspect":
        from mocapfix.apps.inspect import main as inspect_main

        return inspect_main(argv[1:])
    if command == "fix":
        from mocapfix.apps.fix_cli import main as fix_main

        return fix_main(argv[1:])
    if command == "adapt":
        from mocapfix.apps.adapt import main as adapt_main

        return adapt_main(argv[1:])
    if command == "render":
        from mocapfix.apps.render import main as render_main

        return render_main(argv[1:])
    if command == "models":
        return list_models(argv[1:])
    if command == "docs":
        return list_docs(argv[1:])
    if command == "demo":
        from mocapfix.apps.demo import main as demo_main

        return demo_main(argv[1:])
    if command in ("-V", "--version"):
        from mocapfix import __version__

        print(f"mocapfix {__version__}")
        return 0
    if command in LIGHTNING_COMMANDS:
        return run_lightning(command, argv)
    print(
        f"mocapfix: unknown command {command!r}; use fit, validate, test, predict, inspect, fix, adapt, render, "
        "models, docs or demo",
        file=sys.stderr,
    )
    return 2


if __name__ == "__main__":
    sys.exit(main())
