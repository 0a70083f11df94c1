"""Errors that are the user's to fix (a bad file, option, value), as opposed to bugs.

The ``franka-vs`` command prints a :class:`UserError` (and the other user-facing errors listed in
:data:`USER_ERRORS`) as one line, ``franka-vs <command>: error: <message>``, and exits with status 2; anything else
is a bug and keeps its traceback.
"""

from __future__ import annotations

import errno


class UserError(ValueError):
    """A mistake in the user's input (file, option, value); the message names the input and what was expected."""


class Interrupted(KeyboardInterrupt):
    """The job was interrupted (Ctrl-C or SIGTERM); the CLI prints one line and exits with status 130."""


# Exception types the CLI reports as one line (exit status 2). OSErrors (PermissionError, IsADirectoryError,
# NotADirectoryError, ENOSPC...) count as the user's when they name a path (``filename`` set): they come from paths
# the user gave.
USER_ERRORS: tuple[type[BaseException], ...] = (UserError, ValueError, FileNotFoundError, FileExistsError)


_FULL = (errno.ENOSPC, errno.EDQUOT)  # a full disk, a full quota


def is_user_error(e: BaseException) -> bool:
    """Whether ``e`` is the user's to fix (one line, exit 2) rather than a bug (traceback)."""
    if isinstance(e, USER_ERRORS):
        return True
    if isinstance(e, OSError) and e.errno in _FULL:  # the disk or quota filled while writing: the user's to free
        return True
    return isinstance(e, OSError) and getattr(e, "filename", None) is not None


def one_line(e: BaseException) -> str:
    """The message of ``e`` on one line (OSErrors as 'path: reason')."""
    if isinstance(e, OSError) and e.errno in _FULL:
        where = f" ({e.filename})" if e.filename is not None else ""
        msg = (f"{e.strerror or 'no space left on device'}{where} while writing the outputs; nothing was replaced "
               "(outputs are staged and renamed into place only when complete)")
    elif isinstance(e, OSError) and e.filename is not None and e.strerror:
        msg = f"{e.filename}: {e.strerror}"
    else:
        msg = str(e) or type(e).__name__
    if isinstance(e, KeyError) and msg.startswith("'"):
        msg = msg.strip("'\"")
    return " ".join(msg.split())


__all__ = ["Interrupted", "USER_ERRORS", "UserError", "is_user_error", "one_line"]
