"""A damaged bag in words: what the bag libraries raise for damaged bytes, said as one line a user can act on.

``rosbags`` raises its ``ReaderError`` (ROS 1 and ROS 2) and ``AnyReaderError`` with the parser's own
wording, and a compressed chunk's codec raises lz4's ``RuntimeError`` or bz2's ``OSError``. The bag
reader catches exactly these, and says what is wrong here; anything else is a bug and keeps its traceback.
"""

from __future__ import annotations

import re

#: What the bag libraries say of damaged bytes, and the same in words (first match wins).
BAG_DAMAGE = (
    (r"Truncated record|Got only \d+ of requested", "damaged: a record claims more bytes than the file holds"),
    (r"database disk image is malformed|file is not a database", "damaged: its sqlite3 database is malformed"),
    (r"File end magic is invalid", "damaged: cut short (the MCAP file has no footer)"),
    (r"index looks damaged|Header could not be read", "damaged: its index cannot be read (cut short?)"),
    (r"Could not deserialize '([^']+)'", "damaged: a {0} message in it cannot be decoded"),
    (r"Could not parse", "damaged: a message definition in it cannot be parsed"),
)


def bag_damage(message: str) -> str:
    """What the bag libraries raised, in words: ``damaged: ...`` or ``not a readable ROS bag (...)``."""
    for pattern, words in BAG_DAMAGE:
        if found := re.search(pattern, message):
            return words.format(*found.groups())
    detail = message.split("\n")[0].rstrip(".")
    return f"not a readable ROS bag ({detail})"


def is_decompression_error(error: BaseException) -> bool:
    """Whether an error is a bag chunk's failed decompression: lz4's RuntimeError, or bz2's OSError (no errno,
    unlike a failed read or write of a file)."""
    if isinstance(error, RuntimeError):
        return str(error).startswith("LZ4F_")
    return isinstance(error, OSError) and error.errno is None
