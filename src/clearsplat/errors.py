"""The one error type that clearsplat raises for bad input.

Every problem with user input (a file, a field, an array) is reported as a
:class:`ClearsplatError`, a subclass of :class:`ValueError` whose message names
the file and the field, so the command line can print it on one line.
"""

from __future__ import annotations

import os

__all__ = ["ClearsplatError"]


class ClearsplatError(ValueError):
    """Bad input: the message names the file (when there is one) and the field.

    Parameters
    ----------
    message : str
        What is wrong and, where it helps, what to do.
    path : str or os.PathLike, optional
        The file the problem was found in.
    field : str, optional
        The property, key or array at fault (``"opacity"``, ``"frames[2].K"``).
    """

    def __init__(self, message: str, *, path: str | os.PathLike | None = None,
                 field: str | None = None):
        self.path = None if path is None else os.fspath(path)
        self.field = field
        self.reason = message
        parts = [p for p in (self.path, field) if p]
        super().__init__(": ".join(parts + [message]))
