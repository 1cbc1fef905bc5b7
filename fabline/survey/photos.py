"""Survey photos read within bounds: a photo's size is read from its header (PNG IHDR, JPEG SOF, else Pillow; no
decoding, whatever the chunks' checksums) and one that is too large is refused before any pixel is decoded; a JPEG cut short is noted, since its lost part decodes grey."""

from __future__ import annotations

import os
import warnings

from fabline.errors import FablineError
from fabline.fileio import vet_input

MAX_PHOTO_PIXELS = 150_000_000
"""Largest photo a survey decodes (150 megapixels, 150 MB as grey levels): larger than any phone or camera sensor."""
MAX_SIMULATED_PHOTOS = 1000
"""Most photos `survey simulate` renders."""
MAX_SEED = 2**31 - 1
"""Largest random seed: OpenCV's cv2.setRNGSeed takes a C int."""
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
JPEG_SOF = {0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF}
"""JPEG start-of-frame markers (SOF0..SOF15 but DHT C4, JPG C8 and DAC CC), whose segment holds the image size."""


def check_simulation(width: int, height: int, photos: int, seed: int, names: dict[str, str]) -> None:
    """Refuse a simulated photo set larger than MAX_PHOTO_PIXELS a photo or MAX_SIMULATED_PHOTOS photos, or a seed
    outside 0..MAX_SEED, before anything is rendered; `names` spells each of resolution, photos, seed for the user."""
    if width * height > MAX_PHOTO_PIXELS:
        raise FablineError(f"{names['resolution']} {width}x{height} is {width * height / 1e6:.4g} megapixels a photo; "
                           f"the limit is {MAX_PHOTO_PIXELS / 1e6:g} (more than any camera sensor)")
    if photos > MAX_SIMULATED_PHOTOS:
        raise FablineError(f"{names['photos']} {photos}: the limit is {MAX_SIMULATED_PHOTOS}; {photos} photos of "
                           f"{width} x {height} px would render {photos * width * height / 1e9:.3g} gigapixels "
                           f"(about {photos * width * height / 2**30:.3g} GiB of grey levels)")
    if not 0 <= seed <= MAX_SEED:
        raise FablineError(f"{names['seed']} {seed}: a seed is a whole number in 0..{MAX_SEED} (2**31-1)")


def header_size(path: str | os.PathLike) -> tuple[int, int] | None:
    """(width, height) read from a PNG's IHDR or a JPEG's SOF segment without decoding and whatever the chunks'
    CRCs; None for any other file (left to Pillow's header read)."""
    with open(path, "rb") as handle:
        head = handle.read(24)
        if head[:8] == PNG_SIGNATURE and head[12:16] == b"IHDR":
            return int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")
        if head[:2] != b"\xff\xd8":
            return None
        handle.seek(2)
        while True:
            marker = handle.read(2)
            while marker[:1] == b"\xff" and marker[1:] == b"\xff":  # fill bytes before a marker
                marker = marker[1:] + handle.read(1)
            if len(marker) < 2 or marker[0] != 0xFF:
                return None
            if 0xD0 <= marker[1] <= 0xD7 or marker[1] == 0x01:  # markers without a segment
                continue
            length = int.from_bytes(handle.read(2), "big")
            if length < 2 or marker[1] == 0xDA:  # scan data before any frame header: not a JPEG to size here
                return None
            if marker[1] in JPEG_SOF:
                segment = handle.read(5)
                return (int.from_bytes(segment[3:5], "big"), int.from_bytes(segment[1:3], "big")) if len(segment) == 5 else None
            handle.seek(length - 2, os.SEEK_CUR)


def check_photo(path: str | os.PathLike, notes: list[str] | None = None) -> None:
    """Refuse a photo whose header claims more than MAX_PHOTO_PIXELS; add to `notes` when a JPEG is cut short.
    Anything but a regular file of at most INPUT_LIMITS["photo"] bytes is refused first (`vet_input`).
    A file Pillow cannot identify is left to OpenCV, which reads more formats and names the file if it cannot."""
    from PIL import Image

    vet_input(path, "photo")
    size = header_size(path)
    if size is not None and size[0] * size[1] > MAX_PHOTO_PIXELS:
        raise FablineError(f"{path}: the image is {size[0]} x {size[1]} px by its header, more than "
                           f"{MAX_PHOTO_PIXELS / 1e6:g} megapixels: not read")
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
