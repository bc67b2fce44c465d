"""The project's own error types.

``InputError`` is the base of every "the user gave us something we cannot use" error:
a bad file, packet stream, connection, scenario, filter spec or option. The command line
maps it (and ``OSError``) to one line on stderr and exit 2; any other exception is an
internal error (exit 1, the traceback with ``-v``). It subclasses ``ValueError`` so that
library callers that caught ``ValueError`` keep working.
"""

from __future__ import annotations

__all__ = ["InputError"]


class InputError(ValueError):
    """Bad input from the user (file, link, scenario, spec or option); one-line message."""
