"""The project's user-error exceptions: problems with the user's input (flags, files, data, weights).

Console scripts turn exactly these into one ``error: <message>`` line and exit status 2; any other
exception is a bug and keeps its traceback. Each class also derives from the built-in exception that
callers caught before it existed (``ValueError``, ``KeyError``, ...), so library code keeps working.
"""

from __future__ import annotations


class UserError(Exception):
    """A problem with the user's input, reported as one line without a traceback."""

    def __str__(self) -> str:
        # KeyError quotes its message; a user error never should.
        return str(self.args[0]) if self.args else ""


class ConfigError(UserError, ValueError):
    """A setting is unknown, mistyped or out of range; the message names the file or flag and the key."""


class UnknownNameError(UserError, KeyError):
    """An unknown task, group or agent name; the message lists the known ones or the closest."""


class CheckpointError(UserError, ValueError):
    """A checkpoint file is missing, truncated or not a cliport checkpoint; the message names the file."""


class RunDirError(UserError, ValueError):
    """A run folder cannot be used as asked (not a run, nothing to resume, already holds a run)."""


class TrainError(RunDirError):
    """A training run cannot start or resume as asked; the message says why."""


class DemoImportError(UserError, ValueError):
    """A source folder, file or image of a demonstration import (``cliport-import``) is unusable; the message
    names the episode, step and field, or the file."""


class HubError(UserError, OSError):
    """The Hugging Face Hub could not be reached or refused (no network, no token, no such repo); one line."""
