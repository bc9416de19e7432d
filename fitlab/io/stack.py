"""Capture stacks of a flat, spatially varying sample (``fitlab fit-maps STACK``; spec:
data_formats/stack.md): a folder with ``stack.csv`` (one row per image: ``file``, ``theta_i``,
``phi_i``, ``theta_o``, ``phi_o`` in degrees, fitlab's frame) and one OpenEXR image per row
(channels R, G, B or Y, all the same size; f in 1/sr; NaN where a texel has no reading).

Everything is validated before anything is fitted or written: the table as every fitlab CSV
(fitlab/io/csvtable.py) with the direction checks of the direction-pair files
(fitlab/io/directions.py) and the radians gate (fitlab/io/gates.py); each image's path stays
inside the folder; every image is OpenEXR with the same channels and size; values are finite
or NaN; the stack's size is bounded before any pixel is read.
"""

from __future__ import annotations

import hashlib
from pathlib import Path, PurePosixPath
from typing import NamedTuple

import numpy as np

from fitlab.errors import InputFileError
from fitlab.io.directions import COLUMNS as ANGLE_COLUMNS, check_angles, degrees_to_direction
from fitlab.io.exr_image import CHANNEL_SETS, check_size, image_header, read_image
from fitlab.io.files import read_bytes, sha256_of

#: The table's name inside a stack folder, and its columns.
TABLE = "stack.csv"
COLUMNS = ("file",) + ANGLE_COLUMNS
#: Most images (rows) a stack may have.
MAX_IMAGES = 4096


class Stack(NamedTuple):
    """A capture stack read and checked: per image its directions (degrees) and its pixels."""

    path: str  # the folder as given
    files: tuple[str, ...]  # the table's ``file`` cells (relative to the folder)
    theta_i: np.ndarray
    phi_i: np.ndarray
    theta_o: np.ndarray
    phi_o: np.ndarray
    lines: np.ndarray  # the table's line of each image
    channel_names: tuple[str, ...]
    #: (height, width, images, channels) float32, f in 1/sr, NaN: no reading
    values: np.ndarray
    metadata: dict  # the table's ``# key: value`` lines
    sha256: str  # of the table and every image, in order (provenance)

    @property
    def shape(self) -> tuple[int, int]:
        """(height, width) of the images."""
        return int(self.values.shape[0]), int(self.values.shape[1])

    @property
    def n_images(self) -> int:
        return int(self.values.shape[2])

    def directions(self) -> tuple[np.ndarray, np.ndarray]:
        """(wi, wo) of every image, unit vectors (images, 3)."""
        return (degrees_to_direction(self.theta_i, self.phi_i),
                degrees_to_direction(self.theta_o, self.phi_o))


def _count_rows(path: Path) -> int:
    """Lines of the table that are neither blank nor comments, less the header (an upper
    bound on its rows, counted before parsing)."""
    raw = read_bytes(path, folder_hint=f"a stack folder holds a file named {TABLE}")
    n = sum(1 for line in raw.splitlines() if line.strip() and not line.lstrip().startswith(b"#"))
    return max(n - 1, 0)


def _image_path(folder: Path, cell: str, table: Path, line: int) -> Path:
    """The image a ``file`` cell names, refused unless it is a relative path inside the
    folder (no absolute path, no '..', no link out of the folder) ending in .exr."""
    hint = "name the image by its path relative to the stack folder, e.g. img_000.exr"
    p = PurePosixPath(cell.replace("\\", "/"))
    if p.is_absolute() or (len(cell) > 1 and cell[1] == ":"):
        raise InputFileError(table, f"{cell!r} is an absolute path", line=line, column="file",
                             hint=hint)
    if ".." in p.parts:
        raise InputFileError(table, f"{cell!r} leaves the stack folder ('..')", line=line,
                             column="file", hint=hint)
    if p.suffix.lower() != ".exr":
        raise InputFileError(table, f"{cell!r} is not an OpenEXR file name (.exr)", line=line,
                             column="file", hint=hint)
    full = folder / Path(*p.parts)
    try:
        inside = full.resolve().is_relative_to(folder.resolve())
    except OSError:
        inside = False
    if not inside:
        raise InputFileError(table, f"{cell!r} resolves outside the stack folder (a link?)",
                             line=line, column="file", hint=hint)
    if not full.is_file():
        raise InputFileError(table, f"{cell!r}: no such image in {folder}", line=line,
                             column="file", hint="every row names an image of the folder")
    return full


def read_stack(folder) -> Stack:
    """Read and check the capture stack in ``folder`` (module text); InputFileError (exit
    status 2) naming the file, line or field and what to do."""
    from fitlab.io.csvtable import read_table
    from fitlab.io.gates import radians_finding
    from fitlab.io.validate import check_allocation

    folder = Path(folder)
    if not folder.is_dir():
        raise InputFileError(folder, "is not a folder" if folder.exists() else "no such folder",
                             hint=f"give a stack folder holding {TABLE} and its OpenEXR images "
                             "(data_formats/stack.md)")
    table_path = folder / TABLE
    if not table_path.is_file():
        raise InputFileError(table_path, "no such file",
                             hint=f"a stack folder holds {TABLE}: one row per image "
                             "(file, theta_i, phi_i, theta_o, phi_o)")
    n_rows = _count_rows(table_path)
    if n_rows > MAX_IMAGES:
        raise InputFileError(table_path, f"has {n_rows} rows, more than the {MAX_IMAGES} images "
                             "fitlab reads in one stack",
                             hint="split the capture, or thin its directions")
    table = read_table(table_path, COLUMNS, what="stack table", text_columns=("file",))
    check_angles(table)
    c = table.columns
    found = radians_finding(np.concatenate([c["theta_i"], c["theta_o"]]),
                            np.concatenate([c["phi_i"], c["phi_o"]]))
    if found is not None and found.tripped:
        raise InputFileError(table_path, found.message, column="theta_i",
                             hint="a stack's angles are degrees: convert them")
    lines = np.asarray(table.lines)
    cells = [str(x) for x in c["file"]]
    seen: dict = {}
    paths = []
    for cell, line in zip(cells, lines):
        full = _image_path(folder, cell, table_path, int(line))
        key = full.resolve()
        if key in seen:
            raise InputFileError(table_path, f"{cell!r} is also the image of line {seen[key]}",
                                 line=int(line), column="file",
                                 hint="each row is one image taken at its own directions")
        seen[key] = int(line)
        paths.append(full)
    names0, size0 = None, None
    for full, line in zip(paths, lines):
        names, size = image_header(full)
        channels = next((s for s in CHANNEL_SETS if set(s) == set(names)), None)
        if channels is None:
            missing = [n for n in ("R", "G", "B") if n not in names]
            extra = [n for n in names if n not in ("R", "G", "B", "Y")]
            what = (f"extra channel(s) {', '.join(extra)}" if extra else
                    f"channels {', '.join(names)} (missing {', '.join(missing)})")
            raise InputFileError(full, f"has {what}", column="channels",
                                 hint="a stack's images have exactly the channels R, G, B or "
                                 "exactly Y (drop alpha and other layers)")
        if names0 is None:
            names0, size0 = channels, size
            check_allocation((size[0], size[1], len(paths), len(channels)), table_path,
                             what="the stack", itemsize=4)
        elif channels != names0:
            raise InputFileError(full, f"has channels {', '.join(channels)}, the stack's first "
                                 f"image {', '.join(names0)}", column="channels",
                                 hint="every image of a stack has the same channels")
        elif size != size0:
            raise InputFileError(full, f"is {size[1]} x {size[0]} pixels, the stack's first "
                                 f"image {size0[1]} x {size0[0]}", column="dataWindow",
                                 hint="every image of a stack has the same size (texel (x, y) "
                                 "is the same point of the sample in every image)")
    check_size(paths[0], (size0[0], size0[1], len(names0)))
    values = np.empty((size0[0], size0[1], len(paths), len(names0)), dtype=np.float32)
    digest = hashlib.sha256(sha256_of(table_path).encode())
    for j, full in enumerate(paths):
        img = read_image(full, names0)
        bad = np.argwhere(np.isinf(img))
        if bad.size:
            y, x, k = (int(v) for v in bad[0])
            raise InputFileError(full, f"pixel (x={x}, y={y}) is {img[y, x, k]} (infinite)",
                                 column=names0[k],
                                 hint="write NaN where a texel has no reading; other values "
                                 "must be finite")
        values[:, :, j, :] = img
        digest.update(sha256_of(full).encode())
    return Stack(str(folder), tuple(cells), c["theta_i"], c["phi_i"], c["theta_o"], c["phi_o"],
                 lines, names0, values, dict(table.metadata), digest.hexdigest())


__all__ = ["TABLE", "COLUMNS", "MAX_IMAGES", "Stack", "read_stack"]
