"""The one exception every loader raises on bad input data (:class:`DataError`), and the one of an unusable
model file (:class:`CheckpointError`)."""

from __future__ import annotations

import os


class DataError(ValueError):
    """Bad or missing input data. The message reads ``"<path>: <problem>; <fix>"``.

    ``DataError(path, problem, fix)`` builds that message; ``DataError(message)`` takes a ready one
    (for callers that format their own). ``path``, ``problem`` and ``fix`` stay available as attributes.
    """

    def __init__(self, path: str | os.PathLike, problem: str | None = None, fix: str | None = None):
        self.path = str(path)
        self.problem = problem
        self.fix = fix
        if problem is None:
            message = self.path
        else:
            message = f"{self.path}: {problem}" + (f"; {fix}" if fix else "")
        super().__init__(message)


class CheckpointError(DataError):
    """A model file (flow or depth) is missing, unreadable or does not fit its network; the message names the
    file and the fix. A :class:`DataError`, so a stage ends with that one line (``f2depth.stage``)."""
