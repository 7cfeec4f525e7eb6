"""Exceptions shown to users as one clear line by the CLI."""

from __future__ import annotations


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


class DatasetError(UserError, ValueError):
    """A nuScenes dataroot, table, split, scene or image problem."""


class RunStoreError(UserError, ValueError):
    """An unreadable, foreign or inconsistent run directory."""
