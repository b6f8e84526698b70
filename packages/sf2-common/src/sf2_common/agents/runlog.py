"""The run folder's log (`train.log`): what libraries log that a user cannot act on (absl, Orbax, asyncio
from Orbax's threads) goes there with the run's own notices, not between the progress bar's lines."""

from __future__ import annotations

import contextlib
import logging
import sys
import traceback

__all__ = ["LIBRARY_LOGGERS", "library_log"]

LIBRARY_LOGGERS = ("absl", "orbax", "asyncio")


@contextlib.contextmanager
def library_log(run):
    """Within the block, the records of `LIBRARY_LOGGERS` and unraisable exceptions (errors in library
    threads that no caller can catch) are appended to `run.log_path` instead of reaching stderr."""
    handler = logging.FileHandler(run.log_path, delay=True)
    handler.setFormatter(logging.Formatter("%(asctime)s %(name)s %(levelname)s: %(message)s",
                                           "%Y-%m-%d %H:%M:%S"))
    saved = []
    for name in LIBRARY_LOGGERS:
        logger = logging.getLogger(name)
        saved.append((logger, logger.propagate))
        logger.addHandler(handler)
        logger.propagate = False
    previous_hook = sys.unraisablehook

    def unraisable(info):
        text = "".join(traceback.format_exception(info.exc_type, info.exc_value, info.exc_traceback))
        message = f"{info.err_msg or 'exception'} {info.object!r}\n{text}"
        handler.handle(logging.LogRecord("unraisable", logging.ERROR, "", 0, message, None, None))

    sys.unraisablehook = unraisable
    try:
        yield
    finally:
        sys.unraisablehook = previous_hook
        for logger, propagate in saved:
            logger.removeHandler(handler)
            logger.propagate = propagate
        handler.close()
