"""The console of the commands that run Lightning (fit / validate / test / predict, adapt): what a
person can act on, without Lightning's messages nobody running mocapfix can.

Silenced, while a command runs (`quiet_lightning`), and only then: importing mocapfix, or using
Lightning from Python, changes nothing.
- advertisements: "Tip: For seamless cloud logging ... litlogger" (and litmodels);
- hardware nobody here has: "TPU available: False ...", "HPU available ...", and on a machine
  without a GPU "GPU available: False, used: False" (with a GPU the line stays: it says the GPU is
  used); "LOCAL_RANK: 0 - CUDA_VISIBLE_DEVICES: [0]";
- torch's deprecation of `LeafSpec`, which Lightning's own pytree code uses (Lightning's to fix);
- "The number of training batches (N) is smaller than the logging interval": a folder of a few
  takes has short epochs, but the steps are logged every log_every_n_steps all the same (the
  interval counts the run's steps, not the epoch's);
- "The 'train_dataloader' does not have many workers": the windows are cut from takes held in
  memory (data/datamodule.py); a worker costs seconds to start and saves nothing.
Kept: the seed, a GPU that is used, the model summary, the progress bar and metrics, where logs
and checkpoints go, and every other warning.
"""

from __future__ import annotations

import logging
import re
import warnings
from collections.abc import Iterator
from contextlib import contextmanager

# (category, message regex): warnings.filterwarnings matches the regex at the message's start
WARNINGS = (
    (FutureWarning, r"`isinstance\(treespec, LeafSpec\)` is deprecated"),
    (Warning, r"The number of training batches \(\d+\) is smaller than the logging interval"),
    (Warning, r"The '\w+' does not have many workers"),
)
# Lightning's info lines (logging), by the logger that writes them
INFO = {
    "lightning.pytorch.utilities.rank_zero": (
        r"💡 Tip: ",
        r"(TPU|HPU|IPU) available: ",
        r"GPU available: False, used: False",
    ),
    "lightning.pytorch.accelerators.cuda": (r"LOCAL_RANK: \d+ - CUDA_VISIBLE_DEVICES: ",),
}


class _Drop(logging.Filter):
    def __init__(self, patterns: tuple[str, ...]):
        super().__init__()
        self.pattern = re.compile("|".join(f"(?:{p})" for p in patterns))

    def filter(self, record: logging.LogRecord) -> bool:
        return not self.pattern.match(record.getMessage())


@contextmanager
def quiet_lightning(info: dict[str, tuple[str, ...]] | None = None) -> Iterator[None]:
    """Lightning's messages above (and `info`'s: logger name -> message regexes) left out while
    the block runs; warnings filters and loggers as they were afterwards."""
    patterns = {name: list(p) for name, p in INFO.items()}
    for name, p in (info or {}).items():
        patterns.setdefault(name, []).extend(p)
    filters = [(logging.getLogger(name), _Drop(tuple(p))) for name, p in patterns.items()]
    with warnings.catch_warnings():
        for category, message in WARNINGS:
            warnings.filterwarnings("ignore", message=message, category=category)
        for logger, f in filters:
            logger.addFilter(f)
        try:
            yield
        finally:
            for logger, f in filters:
                logger.removeFilter(f)
