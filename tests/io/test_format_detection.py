"""When no format recognizes a file, the message says why (fitlab/io/formats.py: unrecognized):
an empty file is called empty; otherwise the closest format (the one the file's ending names,
text or binary as the file is; fitlab's CSV for other text) reads it and its first error is
named, with the line and column; a binary file of no known ending keeps the short message."""

from __future__ import annotations

from pathlib import Path

import pytest

import fitlab
from fitlab.cli import main
from fitlab.errors import InputFileError
from fitlab.io.formats import closest_format, formats

EXAMPLES = Path(__file__).resolve().parents[2] / "data_formats" / "examples"


@pytest.mark.parametrize("name, content, says", [
    ("empty.csv", b"", "empty.csv: is empty. give a measurement file"),
    ("blank.csv", b"  \n\n", "blank.csv: holds only white space"),
    ("columns.csv", b"angle_in,angle_out,brdf\n10,20,0.3\n",
     "columns.csv: is in no format fitlab recognizes; read as the "
     "closest, csv (by its ending .csv), it fails at line 1: column 'angle_in': unknown column"),
    ("notes", b"hello\nworld\n", "read as the closest, csv (a text file)"),
    ("scan.bsdf", b"# exported\nfoo bar\n", "read as the closest, zemax (by its ending .bsdf), "
     "it fails at"),
    ("blob.dat", b"\x00\x01\x02\x03", "blob.dat: is in no format fitlab recognizes. formats:"),
])
def test_an_unrecognized_file_is_explained(tmp_path, capsys, name, content, says):
    path = tmp_path / name
    path.write_bytes(content)
    with pytest.raises(InputFileError) as err:
        fitlab.read(path)
    assert says in str(err.value) and str(path) in str(err.value)
    assert main(["info", str(path)]) == 2
    message = capsys.readouterr().err
    assert says in message
    # short, as every input error is (tests/hostile.py: MAX_MESSAGE, with room for the path)
    assert len(message) - len(str(path)) < 450, len(message)


def test_shared_endings_go_by_the_bytes(tmp_path):
    """.bsdf is Zemax's (text) and RGL's (binary) ending: the file's bytes pick the closest."""
    known = formats()
    text, binary = tmp_path / "a.bsdf", tmp_path / "b.bsdf"
    text.write_bytes(b"Symmetry PlaneSymmetrical\n")
    binary.write_bytes(b"tensor\x00\x01")
    assert closest_format(text, text.read_bytes(), known)[0].name == "zemax"
    assert closest_format(binary, binary.read_bytes(), known)[0].name == "rgl"
    assert closest_format(tmp_path / "c.dat", b"\x00\x01", known) is None


def test_a_valid_file_is_still_detected_and_forcing_a_format_still_works(tmp_path):
    m = fitlab.read(EXAMPLES / "walter_rough_glass.csv")
    assert m.n == 276
    odd = tmp_path / "walter.data"  # no known ending: detected from its content
    odd.write_bytes((EXAMPLES / "walter_rough_glass.csv").read_bytes())
    assert fitlab.read(odd).n == 276 and fitlab.read(odd, "csv").n == 276
