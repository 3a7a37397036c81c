"""A damaged bag in words: what the bag libraries raise for damaged bytes, said as one line a user can act on.

``rosbags`` raises its ``ReaderError`` (ROS 1 and ROS 2) and ``AnyReaderError`` with the parser's own
wording; a ROS 2 sqlite3 bag's ``apsw`` raises its own errors; a compressed chunk's codec raises zstd's
``ZstdError``, lz4's ``RuntimeError`` or bz2's ``OSError`` / ``ValueError``. The bag reader catches
exactly these (``damage``), and says here what is wrong; anything else, a failed write to a full disk
included, is not damage and keeps its traceback.
"""

from __future__ import annotations

import re

#: What the bag libraries say of damaged bytes, and the same in words (first match wins).
BAG_DAMAGE = (
    (r"Truncated record|Got only \d+ of requested", "damaged: a record claims more bytes than the file holds"),
    (r"malformed|file is not a database|not a database", "damaged: its sqlite3 database is malformed"),
    (r"File end magic is invalid", "damaged: cut short (the MCAP file has no footer)"),
    (r"index looks damaged|Header could not be read", "damaged: its index cannot be read (cut short?)"),
    (r"Could not deserialize '([^']+)'", "damaged: a {0} message in it cannot be decoded"),
    (r"Could not parse", "damaged: a message definition in it cannot be parsed"),
    (r"checksum mismatch", "damaged: a compressed block fails its checksum"),
    (r"size mismatch", "damaged: a chunk decompresses to another size than it claims"),
)
#: What lz4 and bz2 say of a chunk they cannot decompress (they raise built-in exception types).
CODEC_MESSAGES = ("LZ4F_", "Invalid data stream", "end-of-stream marker")
DECOMPRESSION = "damaged: a compressed chunk cannot be decompressed"


def damage(error: BaseException) -> str | None:
    """What is wrong with a bag that raised ``error``, in words; None when ``error`` is not damage (a bug, a
    full disk), which must then keep its traceback."""
    import apsw
    from rosbags.highlevel import AnyReaderError
    from rosbags.rosbag1 import ReaderError as Ros1Error
    from rosbags.rosbag2 import ReaderError as Ros2Error

    try:
        from compression.zstd import ZstdError
    except ImportError:  # Python before 3.14: rosbags uses the backport
        from backports.zstd import ZstdError

    if isinstance(error, ZstdError):
        return DECOMPRESSION
    if isinstance(error, AnyReaderError | Ros1Error | Ros2Error | apsw.Error):
        return bag_damage(str(error))
    if isinstance(error, RuntimeError | OSError | ValueError) and any(m in str(error) for m in CODEC_MESSAGES):
        return DECOMPRESSION
    return None


def bag_damage(message: str) -> str:
    """What the bag libraries raised, in words: ``damaged: ...`` or ``not a readable ROS bag (...)``."""
    for pattern, words in BAG_DAMAGE:
        if found := re.search(pattern, message):
            return words.format(*found.groups())
    detail = message.split("\n")[0].rstrip(".")
    return f"not a readable ROS bag ({detail})"
