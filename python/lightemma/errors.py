"""lightemma's exceptions: the errors a user can fix, shown by the CLI as one clear line.

Every error lightemma raises for bad input is a :class:`UserError`; the ones about a value (an argument, an
array, a name, a dataset, a run directory) are also ``ValueError`` s, so ``except ValueError`` keeps catching
them. The Rust core's errors arrive as these classes too (one mapping, ``rust/python/errors.rs``, polars-style):

* ``CoreError::Shape`` → :class:`ShapeError` (an array of the wrong dimensions, extent or memory layout);
* ``CoreError::NonFinite`` → :class:`NonFiniteError` (NaN or infinity where only finite numbers go);
* ``CoreError::UnknownName`` → :class:`UnknownNameError` (a method, convention or mode lightemma lacks);
* ``CoreError::Argument`` → :class:`InputError` (any other refused argument).

The CLI (``lightemma.cli.main``) catches :class:`UserError` and ``OSError`` only: any other exception is a bug in
lightemma and prints its traceback.
"""

from __future__ import annotations

import errno
import signal


class UserError(Exception):
    """Bad input or environment that the user can fix (names what and where).

    ``cli`` is the same message in command-line terms (``--split all`` rather
    than ``split="all"``), for errors whose fix names an argument; the CLI
    prints it instead of the message.
    """

    def __init__(self, message: str = "", *, cli: str | None = None) -> None:
        super().__init__(message)
        self.cli = cli

    def for_cli(self) -> str:
        """The message as the command line prints it."""
        return self.cli or str(self)


class InputError(UserError, ValueError):
    """A value given to lightemma that it refuses: an argument out of its range, a wrong type, a malformed
    answer or file the caller passed. The message names the parameter (``concurrency must be ≥ 1, got 0``)."""


class ShapeError(InputError):
    """An array of the wrong number of dimensions, extent or memory layout (``pred must have shape (N, T, 2)``)."""


class NonFiniteError(InputError):
    """A NaN or infinity where only finite numbers are allowed (names the array, frame and step)."""


class UnknownNameError(InputError):
    """A name that is not one of the allowed ones (integration method, convention, parse mode …): the message lists
    the allowed names."""


class DatasetError(UserError, ValueError):
    """A nuScenes dataroot, table, split, scene or image problem."""


class RunStoreError(UserError, ValueError):
    """An unreadable, foreign or inconsistent run directory."""


class RunFatalError(UserError):
    """A cause no retry or re-ask can fix (rejected key, unknown model, the same failure on frame after frame).

    The run stops dispatching frames, lets the calls in flight finish, keeps what finished, and
    the CLI exits non-zero with one line naming the cause and the fix. ``cause`` is a short
    kind (``authentication``, ``billing``, ``unknown-model``, ``invalid-request``,
    ``reasoning-budget``, ``empty-answers``, ``unreachable``, ``rate-limit``, ``provider-error``,
    ``images``, ``local-model``, ``disk``, ``invalid-response``); ``error`` is the error class recorded on the calls
    it ended, if any.
    """

    def __init__(self, message: str, *, cause: str = "fatal", error: str | None = None) -> None:
        super().__init__(message)
        self.cause = cause
        self.error = error


class RunStopped(RunFatalError):
    """A run that stopped for a run-fatal cause: what finished is saved in ``run_dir``; ``--resume`` continues it."""

    def __init__(self, message: str, *, cause: str, error: str | None, run_dir: object, frames_run: int) -> None:
        super().__init__(message, cause=cause, error=error)
        self.run_dir = run_dir
        self.frames_run = frames_run


_OS_REASONS = {
    errno.ENOSPC: "no space left on the device (the disk is full)",
    errno.EDQUOT: "the disk quota is exhausted",
    errno.EACCES: "permission denied",
    errno.EPERM: "permission denied",
    errno.EROFS: "the file system is read-only",
    errno.ENOTDIR: "a part of the path is a file, not a directory",
    errno.EEXIST: "a file is in the way",
    errno.EISDIR: "it is a directory",
}


def os_error_line(exc: OSError, doing: str) -> str:
    """One line for an OS error met while ``doing`` something ("write frames.jsonl"): what, where, why."""
    reason = _OS_REASONS.get(exc.errno or 0) or exc.strerror or str(exc)
    where = f" {exc.filename}" if exc.filename else ""
    return f"cannot {doing}{where}: {reason}"


class Interrupted(KeyboardInterrupt):
    """A session stopped by SIGINT, SIGTERM or SIGHUP: all three are handled like Ctrl-C (``signum``, ``name``)."""

    def __init__(self, signum: int) -> None:
        self.signum = signum
        self.name = signal.Signals(signum).name
        super().__init__(self.name)


#: the signals a run and an import stop on, as on Ctrl-C (what Slurm, Kubernetes and systemd send first)
STOP_SIGNALS = tuple(getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name))
