"""Regenerate the deliberately broken Zemax files invalid/zemax_*.bsdf from zemax_brown_vinyl.bsdf.

Each is an excerpt of the brown vinyl file (its first two angles of incidence, 15° and 20°:
58 lines, DataEnd on line 58) with one fault; data_formats/zemax_bsdf.md lists them and
tests/io/test_io_zemax.py checks the error each one raises (file, line, what to do).

    python data_formats/examples/make_zemax_invalid.py
"""

from pathlib import Path

HERE = Path(__file__).resolve().parent
SOURCE = HERE / "zemax_brown_vinyl.bsdf"


def excerpt() -> list[str]:
    """Lines 1-57 of the source with 'AngleOfIncidence 2', then DataEnd (line 58)."""
    lines = SOURCE.read_text(encoding="ascii").splitlines()
    assert lines[8].startswith("AngleOfIncidence") and lines[37].startswith("TIS")
    lines[8], lines[9] = "AngleOfIncidence  2", "15\t20\t"
    return lines[:57] + ["DataEnd"]


def replace_field(line: str, index: int, token: str) -> str:
    fields = line.split("\t")
    fields[index] = token
    return "\t".join(fields)


def variants(base):
    def edit(**changes):  # 1-based line number -> new text (None deletes the line)
        out = list(base)
        for lineno in sorted((int(k[1:]) for k in changes), reverse=True):
            new = changes[f"l{lineno}"]
            if new is None:
                del out[lineno - 1]
            else:
                out[lineno - 1] = new
        return out

    yield "zemax_truncated", base[:45]
    yield "zemax_unknown_keyword", edit(l4="Symetry  PlaneSymmetrical")
    yield "zemax_bad_symmetry", edit(l4="Symmetry  Rotational")
    yield "zemax_missing_scattertype", edit(l6=None)
    yield "zemax_count_mismatch", edit(l14="\t".join(base[13].split("\t")[:10]) + "\t")
    yield "zemax_short_row", edit(l25="\t".join(base[24].split("\t")[:10]))
    yield "zemax_non_numeric", edit(l30=replace_field(base[29], 3, "5.8O9E-02"))
    yield "zemax_nan", edit(l42=replace_field(base[41], 5, "NaN"))
    yield "zemax_negative", edit(l50=replace_field(base[49], 2, "-1.200E-03"))
    yield "zemax_no_databegin", edit(l17=None)
    yield "zemax_no_dataend", base[:57]
    yield "zemax_missing_tis", edit(l38=None)
    yield "zemax_extra_block", edit(l9="AngleOfIncidence  1", l10="15\t")
    yield "zemax_aoi_out_of_range", edit(l10="15\t95\t")
    yield "zemax_empty", base[:2]


def main():
    out = HERE / "invalid"
    for name, lines in variants(excerpt()):
        (out / f"{name}.bsdf").write_text("\n".join(lines) + "\n", encoding="ascii")
        print(f"wrote invalid/{name}.bsdf")


if __name__ == "__main__":
    main()
