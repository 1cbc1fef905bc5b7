"""Ids as file names: the one way any id from data (a lamella, part or sheet id) becomes part of a file name.

The result is one path component of letters, digits, '.', '_', '-' and '~' only, so it never leaves the folder it
is written in (no separator, no absolute path, no NUL), never starts with '.' or '-' (so never `..`, no hidden
file, no option), is not a Windows device name (CON, NUL, COM1, ...) and is at most `MAX_STEM` characters long. An id
already of that form (without '~') is kept as it is; any other gets `~` and a hash of the whole id appended (ids
such as `a b` and `a/b`, which both sanitise to `a_b`, stay apart), so distinct ids always give distinct names.
"""

from __future__ import annotations

import hashlib
import re

MAX_STEM = 80
"""Longest stem: with a job name, a suffix (`.order.svg`) and the temp-file prefix still well under 255 bytes."""

_SAFE = re.compile(r"[A-Za-z0-9_][A-Za-z0-9._-]*")
_WINDOWS_DEVICES = re.compile(r"(CON|PRN|AUX|NUL|COM[0-9]|LPT[0-9])(\..*)?", re.IGNORECASE)
HASH_CHARS = 10
"""Hex digits of the id's SHA-256 appended to a changed id (40 bits: a clash among a model's ids is never met)."""


def file_stem(item_id: str) -> str:
    """`item_id` as a safe file-name stem (see the module): itself when it is already safe, else its safe
    characters (runs of others as one '_', leading dots dropped, a device name broken by a leading '_', cut to
    length) then `~` and its hash."""
    text = str(item_id)
    if _SAFE.fullmatch(text) and len(text) <= MAX_STEM and not _WINDOWS_DEVICES.fullmatch(text) \
            and not text.endswith("."):
        return text
    digest = hashlib.sha256(text.encode("utf-8", "surrogatepass")).hexdigest()[:HASH_CHARS]
    safe = re.sub(r"[^A-Za-z0-9._-]+", "_", text).lstrip(".-")[:MAX_STEM - HASH_CHARS - 2].rstrip(".")
    if _WINDOWS_DEVICES.fullmatch(safe):  # Windows takes `NUL.x~1.svg` for the device too: break the name
        safe = f"_{safe}"
    return f"{safe}~{digest}"
