"""Exceptions shown to users as one clear line by the CLI."""

from __future__ import annotations


class UserError(Exception):
    """Bad input or environment that the user can fix (names what and where)."""


class DatasetError(UserError, ValueError):
    """A nuScenes dataroot, table, split, scene or image problem."""


class RunStoreError(UserError, ValueError):
    """An unreadable, foreign or inconsistent run directory."""
