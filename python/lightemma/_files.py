"""The one bounded reader of a regular file: every file lightemma reads whole from a place it does not control (a
nuScenes table, map expansion or CAN bus file, a reference result file, a run directory's small files) is read here.

A FIFO put in place of a file would block a plain ``open`` forever, ``/dev/zero`` never ends and a file of gigabytes
fills the memory: :func:`read_regular_file` opens without blocking, checks the open descriptor (a file swapped after a
listing is still the one checked), and reads at most ``limit`` + 1 bytes. Callers turn :class:`FileRefused` into their
own one-line error naming the file.
"""

from __future__ import annotations

import os
import stat

__all__ = ["FileRefused", "file_kind", "read_regular_file"]


class FileRefused(Exception):
    """A file :func:`read_regular_file` did not read. ``reason``: a phrase to follow the file's name ("is not a
    regular file (a FIFO)", "has 123 bytes, above the limit of 100", "grew above the limit of 100 bytes while being
    read", "is unreadable (Permission denied)"); ``kind``: ``unreadable``, ``not-regular``, ``too-large`` or
    ``grew``; ``size``: the size fstat reported (``None`` before the file was opened)."""

    def __init__(self, reason: str, kind: str, size: int | None = None) -> None:
        super().__init__(reason)
        self.reason = reason
        self.kind = kind
        self.size = size


def file_kind(mode: int) -> str:
    """What a file that is not a regular file is, from its ``st_mode``: ``a FIFO``, ``a character device``, ``a block
    device``, ``a socket``, ``a folder``, else ``not a plain file``."""
    for test, name in (
        (stat.S_ISFIFO, "a FIFO"),
        (stat.S_ISCHR, "a character device"),
        (stat.S_ISBLK, "a block device"),
        (stat.S_ISSOCK, "a socket"),
        (stat.S_ISDIR, "a folder"),
    ):
        if test(mode):
            return name
    return "not a plain file"


def read_regular_file(path: str | os.PathLike[str], limit: int) -> bytes:
    """The bytes of ``path`` (links followed) if it is a regular file of at most ``limit`` bytes.

    Opened non-blocking (a FIFO never blocks the open) and checked on the open descriptor; the read is sized by
    ``fstat`` (no buffer of the whole limit), then continues up to ``limit`` + 1 bytes if the file grew meanwhile, so
    a device such as ``/dev/zero`` is refused before any read and nothing past the limit is ever held. Raises
    :class:`FileRefused` (never ``OSError``) for a file that cannot be opened or read, is not a regular file, or is or
    grows larger than ``limit`` bytes.
    """
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0))
    except OSError as exc:
        raise FileRefused(f"is unreadable ({exc.strerror or exc})", "unreadable") from None
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode):
            raise FileRefused(f"is not a regular file ({file_kind(info.st_mode)})", "not-regular")
        if info.st_size > limit:
            raise FileRefused(f"has {info.st_size} bytes, above the limit of {limit}", "too-large", info.st_size)
        with os.fdopen(fd, "rb", closefd=False) as fh:
            data = fh.read(info.st_size + 1)
            if len(data) > info.st_size:  # grown since the fstat: read on, up to the limit
                data += fh.read(limit + 1 - len(data))
        if len(data) > limit:
            raise FileRefused(f"grew above the limit of {limit} bytes while being read", "grew", info.st_size)
        return data
    except OSError as exc:
        raise FileRefused(f"is unreadable ({exc.strerror or exc})", "unreadable") from None
    finally:
        os.close(fd)
