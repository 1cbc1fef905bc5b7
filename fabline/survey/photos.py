"""Survey photos read within bounds: a photo's size is read from its header (Pillow, no decoding) and one that
is too large is refused before any pixel is decoded; a JPEG cut short is noted, since its lost part decodes grey."""

from __future__ import annotations

import os
import warnings

from fabline.errors import FablineError
from fabline.fileio import vet_input

MAX_PHOTO_PIXELS = 150_000_000
"""Largest photo a survey decodes (150 megapixels, 150 MB as grey levels): larger than any phone or camera sensor."""
MAX_SIMULATED_PHOTOS = 1000
"""Most photos `survey simulate` renders."""


def check_photo(path: str | os.PathLike, notes: list[str] | None = None) -> None:
    """Refuse a photo whose header claims more than MAX_PHOTO_PIXELS; add to `notes` when a JPEG is cut short.
    Anything but a regular file of at most INPUT_LIMITS["photo"] bytes is refused first (`vet_input`).
    A file Pillow cannot identify is left to OpenCV, which reads more formats and names the file if it cannot."""
    from PIL import Image

    vet_input(path, "photo")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            with Image.open(path) as image:
                (width, height), kind = image.size, image.format
    except Image.DecompressionBombError:
        raise FablineError(f"{path}: the image is larger than {MAX_PHOTO_PIXELS / 1e6:g} megapixels (by its header): "
                           "not read") from None
    except (OSError, ValueError, SyntaxError):  # not identified, missing or unreadable: OpenCV says which
        return
    if width * height > MAX_PHOTO_PIXELS:
        raise FablineError(f"{path}: the image is {width} x {height} px, more than {MAX_PHOTO_PIXELS / 1e6:g} "
                           "megapixels: not read")
    if kind == "JPEG" and notes is not None and not _jpeg_complete(path):
        notes.append(f"{path}: the JPEG is cut short (no end marker): its missing part decodes grey, and tags there "
                     "are not found")


def _jpeg_complete(path: str | os.PathLike) -> bool:
    """Whether a JPEG file ends with its end-of-image marker (FF D9), allowing a little padding after it."""
    with open(path, "rb") as handle:
        handle.seek(max(0, os.fstat(handle.fileno()).st_size - 64))
        return b"\xff\xd9" in handle.read()
