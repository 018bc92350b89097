"""The one exception type users see.

Every error a user can cause (a bad file, a bad shape, a missing display, missing
weights) is raised as a :class:`PghmError` with one line naming the problem. The CLIs
print that line and exit with status 2; anything else escaping is a bug.

``PghmError`` derives from ``ValueError`` so that library callers validating inputs
(pose arrays, camera matrices) get the conventional exception type.
"""

from __future__ import annotations

EXIT_USER_ERROR = 2
"""Exit status of the CLIs when a :class:`PghmError` stops them."""


def listed(values, shown: int) -> str:
    """The first ``shown`` of ``values`` and how many more, for a one-line message ("3, 7 and 12 more")."""
    values = list(values)
    head = ", ".join(str(v) for v in values[:shown])
    return head + (f" and {len(values) - shown} more" if len(values) > shown else "")


class PghmError(ValueError):
    """A problem with the user's input, reported in one line."""


class AvatarFileError(PghmError):
    """An ``avatar.pt`` (or checkpoint) that cannot be read: truncated, foreign, wrong version."""


class MotionFileError(PghmError):
    """A motion file (``.bvh`` or ``.npz``) that cannot be imported."""


class DatasetError(PghmError):
    """A subject folder that does not follow the documented layout."""


class DisplayError(PghmError):
    """No OpenGL context or window could be created."""
