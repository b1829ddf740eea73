"""One process at a time in a folder (a run folder, a dataset folder): the trainer and the harness
take the same lock, so two of them never write the same folder at once.

The lock is a POSIX ``flock`` on a hidden file beside the folder (``.NAME.lock``), so it is
released when its process dies and it survives the folder being deleted and made again. It is
re-entrant within a thread: the harness locks a run folder, then calls the trainer in the same
thread, which takes the lock it already holds (another thread of the process waits, as another
process does). The holder's process id is written into the
file, so a refusal can name it.
"""
from __future__ import annotations

import fcntl
import os
import threading
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

_LOCAL = threading.local()
"""``held``: the locks this thread holds (by lock file) and how many times each was entered."""


def _held() -> dict[Path, int]:
    if not hasattr(_LOCAL, "held"):
        _LOCAL.held = {}
    return _LOCAL.held


class FolderBusy(ValueError):
    """Another running process holds the folder's lock; the message names the folder and the holder."""


def lock_path(folder: Path) -> Path:
    """The lock file of ``folder``: a hidden sibling, so the folder itself can be deleted and made again."""
    folder = Path(folder).absolute()
    return folder.with_name(f".{folder.name}.lock")


def _busy(folder: Path, lock: Path) -> FolderBusy:
    try:
        holder = lock.read_text().strip()
    except OSError:
        holder = ""
    who = f"process {holder}" if holder.isdigit() else "another process"
    return FolderBusy(f"{folder}: in use by another running job ({who} holds {lock}); wait for it to finish or "
                      "choose another folder")


@contextmanager
def folder_lock(folder: Path, wait: bool = True) -> Iterator[None]:
    """Hold ``folder``'s lock for the block: wait for another holder to finish, or with
    ``wait=False`` raise FolderBusy at once."""
    lock, held = lock_path(folder), _held()
    key = lock.resolve() if lock.exists() else lock
    if key in held:
        held[key] += 1
        try:
            yield
        finally:
            held[key] -= 1
        return
    lock.parent.mkdir(parents=True, exist_ok=True)
    with lock.open("a+") as fh:
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | (0 if wait else fcntl.LOCK_NB))
        except BlockingIOError:
            raise _busy(Path(folder), lock) from None
        key = lock.resolve()
        held[key] = 1
        try:
            fh.truncate(0)
            fh.write(str(os.getpid()))
            fh.flush()
            yield
        finally:
            del held[key]
            fcntl.flock(fh, fcntl.LOCK_UN)


def lock_held(folder: Path) -> bool:
    """Whether another process (or thread) holds ``folder``'s lock now (one training in it). Creates nothing."""
    lock = lock_path(folder)
    if not lock.is_file() or lock.resolve() in _held():
        return False
    with lock.open("a") as fh:
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            return True
        fcntl.flock(fh, fcntl.LOCK_UN)
        return False


def refuse_if_busy(folder: Path) -> None:
    """Raise FolderBusy, before any work, when another process holds ``folder``'s lock."""
    if lock_held(folder):
        raise _busy(Path(folder), lock_path(folder))
