"""Output folders: checked before a run, locked while it runs, written as one set.

A set of files (a gap report: JSON, Markdown, PNGs) is written into a hidden folder beside the
output folder and renamed into place, so a kill leaves the previous complete set or the new one,
never a JSON without its Markdown and never a temporary file inside the output folder. A lock
file beside the folder makes a second run into the same folder refuse while the first runs.
"""
from __future__ import annotations

import fcntl
import os
import re
import shutil
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import Callable, Iterator

from msam_torch.errors import ConfigError


def check_folder(out: str | Path, key: str = "--out", belongs: Callable[[Path], bool] | None = None) -> Path:
    """``out`` can be written: not a file, its nearest existing ancestor a writable folder, and
    (with ``belongs``) holding nothing but files of the set about to replace it."""
    out = Path(out)
    try:
        if out.exists() and not out.is_dir():
            raise ConfigError(key, f"{out} is an existing file, not a folder")
        existing = out.absolute()
        while not existing.exists():
            existing = existing.parent
        if not existing.is_dir():
            raise ConfigError(key, f"{out} cannot be created: {existing} is a file")
        with tempfile.TemporaryFile(dir=existing):
            pass
        foreign = sorted(p.name for p in out.iterdir() if not belongs(p)) if belongs and out.is_dir() else []
    except OSError as exc:
        raise ConfigError(key, f"{out} is not writable ({exc.strerror or type(exc).__name__})") from None
    if belongs and Path.cwd().is_relative_to(out.absolute()):
        raise ConfigError(key, f"{out} holds the current folder, which a new set of outputs cannot replace; "
                               "give a sub-folder")
    if foreign:
        raise ConfigError(key, f"{out} holds other files ({', '.join(foreign[:3])}{', ...' if len(foreign) > 3 else ''}) "
                               "that a new set of outputs would replace; choose a new or empty folder")
    return out


@contextmanager
def locked(out: str | Path, key: str = "--out") -> Iterator[Path]:
    """Hold ``.<name>.lock`` beside ``out`` for the block; a second holder refuses at once.

    Leftovers of killed runs (hidden staging folders beside ``out``, temporary files of
    :func:`write_atomic` inside it) are removed on entry; folders made to hold the lock are
    removed on exit if they stayed empty."""
    out = Path(out).absolute()  # '.' too has a name and a parent
    made = [p for p in out.parents if not p.exists()]
    lock = out.parent / f".{out.name}.lock"
    while True:
        try:
            out.parent.mkdir(parents=True, exist_ok=True)
            handle = open(lock, "a")
        except OSError as exc:
            raise ConfigError(key, f"cannot lock {out}: {lock} cannot be written beside it "
                                   f"({exc.strerror or type(exc).__name__})") from None
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            handle.close()
            raise ConfigError(key, f"{out} is being written by another msam run; wait for it or choose "
                                   "another folder") from None
        try:
            if os.fstat(handle.fileno()).st_ino == os.stat(lock).st_ino:
                break  # still the file at that path (a finishing holder may have just removed it)
        except FileNotFoundError:
            pass
        handle.close()
    try:
        for stale in out.parent.glob(f".{out.name}.partial-*"):
            shutil.rmtree(stale, ignore_errors=True)
        for stale in out.glob(".*.tmp") if out.is_dir() else ():
            stale.unlink(missing_ok=True)
        yield out
    finally:
        lock.unlink(missing_ok=True)
        handle.close()
        for folder in made:
            try:
                folder.rmdir()
            except OSError:  # not empty: it holds the outputs
                break


@contextmanager
def one_set(out: str | Path) -> Iterator[Path]:
    """A fresh hidden folder beside ``out`` to write a set of files into; when the block ends
    normally it replaces ``out`` by renames, else it is removed."""
    out = Path(out).absolute()
    out.parent.mkdir(parents=True, exist_ok=True)
    stage = Path(tempfile.mkdtemp(dir=out.parent, prefix=f".{out.name}.partial-"))
    try:
        yield stage
        os.chmod(stage, 0o777 & ~_umask())
        if out.exists():
            previous = Path(tempfile.mkdtemp(dir=out.parent, prefix=f".{out.name}.partial-"))
            os.replace(out, previous)
            os.replace(stage, out)
            shutil.rmtree(previous, ignore_errors=True)
        else:
            os.replace(stage, out)
    except BaseException:
        shutil.rmtree(stage, ignore_errors=True)
        raise


def new_version(parent: str | Path) -> Path:
    """``parent/version_N`` with N one past the highest there (written or being written), so
    runs without ``--out`` never share a folder (like Lightning's ``version_N``)."""
    parent = Path(parent)
    taken = [int(m.group(1)) for p in (parent.iterdir() if parent.is_dir() else ())
             if (m := re.fullmatch(r"\.?version_(\d+)(?:\.lock)?", p.name))]
    return parent / f"version_{max(taken, default=-1) + 1}"


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def write_atomic(path: str | Path, text: str) -> Path:
    """Write ``text`` to ``path`` via a temporary file in the same folder and ``os.replace``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w") as handle:
            handle.write(text)
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path
