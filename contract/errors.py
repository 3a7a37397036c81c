"""The one error type for mistakes a user can fix: a bad path, config, recording, card or option.

Command lines print a ``UserError`` as one line and exit 1; any other exception is a bug
and keeps its traceback. It is a ``ValueError``, so code that validates input can keep
catching ``ValueError`` and pydantic validators may raise it.
"""

from __future__ import annotations


class UserError(ValueError):
    """Input that cannot be used as given; the message says what was wrong and, where it can, what to do."""
