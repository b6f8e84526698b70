"""One writer per run folder: the lock that `train`, `eval --save` and the study runner hold while they write.

An exclusive `flock` on `RUN/.sf2-lock`, released by the kernel when its process ends, however it ends. The
file names its holder (pid, host, command, start time) for a second writer's error; a file naming a holder
whose lock is gone is taken over, saying so. A child inherits the lock from a parent that passes the
descriptor and names it in `SF2_LOCK_FD` (the study runner, for the `train` it starts).
"""

from __future__ import annotations

import fcntl
import json
import os
import socket
import time
from pathlib import Path

from .runfolder import RunFolderError, _stderr

__all__ = ["FolderLock", "RunFolderBusy", "holder_of"]


class RunFolderBusy(RunFolderError):
    """Another process holds the run folder's lock (the CLIs exit with status 2)."""


def _describe(info: dict) -> str:
    return (f"pid {info.get('pid', '?')} on host {info.get('host', '?')} ({info.get('command', '?')}, "
            f"since {info.get('since', '?')})")


def _read(fd: int) -> dict | None:
    try:
        data = os.pread(fd, 4096, 0)
        return json.loads(data) if data.strip() else None
    except (OSError, ValueError):
        return {"pid": "?", "host": "?", "command": "unreadable lock file"}


def holder_of(folder) -> str | None:
    """Who holds `folder`'s lock now ("pid N on host H (command, since T)"), or None if nobody does."""
    path = Path(folder) / FolderLock.NAME
    try:
        fd = os.open(path, os.O_RDWR)
    except OSError:
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return _describe(_read(fd) or {})
    finally:
        os.close(fd)   # closing releases a lock this call took
    return None


class FolderLock:
    """The exclusive lock of one run folder (module docstring); a context manager.

    Args:
      folder: the run folder (created if missing).
      command: what the holder does, for the message another writer gets (e.g. "sf2-jax train").
      create: make the folder if it does not exist; False: a missing folder is not locked (there is
        nothing in it to protect, and the caller reports it).
    """

    NAME = ".sf2-lock"
    ENV = "SF2_LOCK_FD"

    def __init__(self, folder, command: str, create: bool = True):
        self.folder, self.command, self.create = Path(folder), command, create
        self.path = self.folder / self.NAME
        self.fd: int | None = None
        self.owned = False

    def acquire(self, say=None) -> FolderLock:
        """Take the lock, or inherit it from the parent process (`SF2_LOCK_FD`); returns self.

        Args:
          say: where the take-over of a stale lock is told (default: stderr).

        Raises:
          RunFolderBusy: another process holds it; the message names that process.
        """
        if not self.create and not self.folder.is_dir():
            return self
        self.folder.mkdir(parents=True, exist_ok=True)
        inherited = self._inherited()
        if inherited is not None:
            self.fd, self.owned = inherited, False
            return self
        while True:
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                holder = _describe(_read(fd) or {})
                os.close(fd)
                raise RunFolderBusy(
                    f"run folder {self.folder} is in use by {holder}: one process writes a run folder at a "
                    f"time. Wait for it to end, or use another --out; nothing was changed") from None
            if _same_file(fd, self.path):
                break
            os.close(fd)   # its holder removed the file while releasing it: take the new one
        stale = _read(fd)
        if stale:
            (say or _stderr)(f"{self.folder}: taking over the lock of {_describe(stale)}, which is gone")
        info = {"pid": os.getpid(), "host": socket.gethostname(), "command": self.command,
                "since": time.strftime("%Y-%m-%d %H:%M:%S")}
        os.ftruncate(fd, 0)
        os.pwrite(fd, (json.dumps(info) + "\n").encode(), 0)
        self.fd, self.owned = fd, True
        return self

    def release(self) -> None:
        """Give the lock back (an inherited one stays with the parent), removing the lock file while still
        holding it; a killed holder leaves it, naming itself, for the next one to take over."""
        if self.fd is None:
            return
        if self.owned:
            try:
                self.path.unlink(missing_ok=True)
            finally:
                os.close(self.fd)
        self.fd, self.owned = None, False

    def child_env(self) -> dict:
        """The environment entry that hands this lock to a child process (pass `self.fd` in its pass_fds)."""
        return {self.ENV: str(self.fd)}

    def _inherited(self) -> int | None:
        text = os.environ.get(self.ENV, "")
        return int(text) if text.isdigit() and _same_file(int(text), self.path) else None

    def __enter__(self) -> FolderLock:
        return self.acquire()

    def __exit__(self, *exc) -> None:
        self.release()


def _same_file(fd: int, path: Path) -> bool:
    try:
        mine, there = os.fstat(fd), os.stat(path)
    except OSError:
        return False
    return (mine.st_dev, mine.st_ino) == (there.st_dev, there.st_ino)
