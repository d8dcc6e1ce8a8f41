"""Exception types shared by every layer of xcalib.

``ProtocolError`` (bad per-frame inputs) lives in :mod:`xcalib.protocol`; the errors here are
for files and formats: each names the file, the field and what was wrong.
"""

from __future__ import annotations

from pathlib import Path

__all__ = ["XcalibError", "FormatError", "MissingFileError", "CalibrationFailedError", "MemoryLimitError"]


class XcalibError(Exception):
    """Base class of xcalib's own errors."""


class FormatError(XcalibError, ValueError):
    """A file could not be read as the format it claims to be.

    Attributes: ``path`` (the file), ``field`` (the key/dataset/header field, or None) and
    ``problem`` (what was wrong, with what was expected and what was found).
    """

    def __init__(self, path: str | Path | None, problem: str, field: str | None = None):
        self.path = None if path is None else str(path)
        self.field = field
        self.problem = problem
        where = self.path or "<input>"
        if field:
            where += f" [{field}]"
        super().__init__(f"{where}: {problem}")


class MissingFileError(FormatError, FileNotFoundError):
    """A file named inside another file (``path``, at ``field``) does not exist: a FormatError
    naming the file that names it, and a FileNotFoundError for callers that catch missing files."""


class CalibrationFailedError(XcalibError, RuntimeError, ValueError):
    """A pose was asked of a failed ``CalibrationResult`` (``success=False``: there is none).
    A ``RuntimeError`` as in the reference, and a ``ValueError`` as xcalib raised before."""


class MemoryLimitError(XcalibError, MemoryError):
    """An input whose frames would not fit the stated memory limit (refused up front, or as soon as
    the frames read so far exceed it). Attributes: ``source`` (the input), ``estimate_bytes`` and
    ``limit_bytes``; the message says how the estimate was made and what to do."""

    def __init__(self, source, problem: str, estimate_bytes: int, limit_bytes: int):
        self.source, self.estimate_bytes, self.limit_bytes = str(source), int(estimate_bytes), int(limit_bytes)
        super().__init__(f"{self.source}: {problem}")
