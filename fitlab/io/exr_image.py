"""Plain OpenEXR images (not fitlab's lookup tables, fitlab/export/exr.py): the images of a
capture stack (data_formats/stack.md) read and validated, and the maps of ``fitlab fit-maps``
written atomically and deterministically (float32, ZIP, no clock time in the header: the same
arrays give the same bytes)."""

from __future__ import annotations

import contextlib
import os
from pathlib import Path

import numpy as np

from fitlab.errors import FitlabError, InputFileError
from fitlab.io.atomic import temporary_beside
from fitlab.io.files import read_bytes
from fitlab.io.validate import check_allocation, quote

#: First four bytes of every OpenEXR file.
MAGIC = b"\x76\x2f\x31\x01"
#: Channel sets an image may have, in the order fitlab lists them.
CHANNEL_SETS = (("R", "G", "B"), ("Y",))


def image_header(path) -> tuple[tuple[str, ...], tuple[int, int]]:
    """(channel names, (height, width)) of the OpenEXR image at ``path`` from its header, or
    InputFileError naming the file (not OpenEXR, damaged, a window of no pixels)."""
    import OpenEXR

    path = Path(path)
    if read_bytes(path, limit=len(MAGIC)) != MAGIC:
        raise InputFileError(path, "is not an OpenEXR file (wrong magic number)",
                             hint="each image of a stack is an OpenEXR file "
                             "(data_formats/stack.md)")
    try:
        header = OpenEXR.File(str(path), separate_channels=True, header_only=True).header()
        lo, hi = (np.asarray(v, dtype=np.int64) for v in header["dataWindow"])
        names = tuple(str(getattr(c, "name", c)) for c in header["channels"])
    except Exception as exc:  # the binding raises RuntimeError for any damage
        raise InputFileError(path, f"cannot be read as OpenEXR ({quote(str(exc), 120)})",
                             hint="the file is damaged or truncated; write it again") from None
    h, w = int(hi[1] - lo[1] + 1), int(hi[0] - lo[0] + 1)
    if h < 1 or w < 1:
        raise InputFileError(path, f"has an empty data window ({w} x {h} pixels)",
                             column="dataWindow")
    return names, (h, w)


def read_image(path, channels: tuple[str, ...]) -> np.ndarray:
    """The pixels of ``channels`` of the OpenEXR image at ``path`` as float32 (height, width,
    len(channels)), after :func:`image_header` (the caller has checked names and size)."""
    import OpenEXR

    path = Path(path)
    try:
        got = OpenEXR.File(str(path), separate_channels=True).channels()
        planes = [np.asarray(got[c].pixels) for c in channels]
    except Exception as exc:
        raise InputFileError(path, f"cannot be read as OpenEXR ({quote(str(exc), 120)})",
                             hint="the file is damaged or truncated; write it again") from None
    for c, p in zip(channels, planes):
        if p.ndim != 2 or p.dtype.kind != "f":
            raise InputFileError(path, f"holds {p.dtype} pixels of shape {p.shape}; fitlab reads "
                                 "HALF or FLOAT channels", column=c,
                                 hint="write the image with HALF or FLOAT channels")
    return np.stack([p.astype(np.float32) for p in planes], axis=-1)


def check_size(path, shape) -> None:
    """Refuse an image whose pixels would be more than fitlab reads from one file."""
    check_allocation(tuple(int(s) for s in shape), path, what="the image", itemsize=4)


def write_image(path, planes: dict, attributes: dict | None = None) -> None:
    """Write ``planes`` ({channel: (height, width) array}) as a float32 OpenEXR image at
    ``path``, atomically (a temporary file beside it, then a rename); ``attributes``: string
    header attributes (e.g. ``fitlab.quantity``)."""
    path = Path(path)
    if not path.parent.exists():
        raise FitlabError(f"{path}: the output folder {path.parent} does not exist; create it "
                          "first")
    channels = {name: np.ascontiguousarray(np.asarray(v, dtype=np.float32))
                for name, v in planes.items()}
    write_channels(path, channels, {k: str(v) for k, v in (attributes or {}).items()})


def write_channels(path, channels: dict, attributes: dict) -> None:
    """Write ``channels`` ({name: (height, width) array of the pixel type}) with the header
    ``attributes`` as a ZIP-compressed scanline OpenEXR at ``path``, atomically (a temporary
    file beside it, then a rename; nothing is left behind on failure)."""
    import OpenEXR

    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage,
              **attributes}
    fd, tmp = temporary_beside(path, suffix=".tmp.exr")  # mode from the umask
    os.close(fd)
    try:
        with OpenEXR.File(header, channels) as f:
            f.write(tmp)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


__all__ = ["CHANNEL_SETS", "image_header", "read_image", "check_size", "write_image",
           "write_channels"]
