"""Regenerate spectral_scan.csv (an excerpt of a real spectral in-plane scan) and the
deliberately broken invalid/spectral_scan_*.csv made from it.

The source is ansys/optical-automation's tests/workflows/example_models/
test_brdf_viewer_2D_data.csv (MIT; LICENSE-spectral-scan.txt), kept in the shared data folder
beside the repository. The excerpt keeps its header's spelling (spaces around the band names),
two incidences (10° and 60°), three bands (450, 550, 650 nm) and a few measure angles each:
both sides of the normal, blocked zeros near retro-reflection and the specular peak.
data_formats/spectral_scan_csv.md lists the invalid files; tests/io/test_io_spectral_scan.py
checks the error each one raises (file, line, column, what to do).

    python data_formats/examples/make_spectral_scan_examples.py
"""

from pathlib import Path

HERE = Path(__file__).resolve().parent
SOURCE = HERE.parents[2] / "shared" / "data" / "ansys_optical_automation" / \
    "test_brdf_viewer_2D_data.csv"
BANDS = ("450nm", "550nm", "650nm")
KEEP = {"10": (-78, -60, -42, -24, -15, -9, -3, 0, 6, 9, 10, 11, 12, 15, 21, 39, 60, 78),
        "60": (-78, -57, -54, -36, -18, 0, 18, 42, 54, 57, 59, 60, 61, 63, 66, 78)}
NOTE = ("# excerpt of test_brdf_viewer_2D_data.csv from github.com/ansys/optical-automation "
        "(MIT licence: LICENSE-spectral-scan.txt)")


def excerpt() -> list[str]:
    lines = SOURCE.read_text(encoding="utf-8").splitlines()
    header = [f.strip() for f in lines[0].split(",")]
    cols = [0, 1] + [header.index(b) for b in BANDS]
    out = [NOTE, " Incident_angle,Measure_angle, " + " , ".join(BANDS) + " "]
    for line in lines[1:]:
        f = line.split(",")
        if f[0] in KEEP and int(f[1]) in KEEP[f[0]]:
            out.append(",".join(f[c] for c in cols))
    return out


def variants(base: list[str]):
    """(name, lines) of each broken file; base[1] is the header, base[2] the first row."""
    def row(k, **cells):
        f = base[k].split(",")
        for j, v in cells.items():
            f[int(j[1:])] = v
        return ",".join(f)

    yield "no_band", [base[0], "Incident_angle,Measure_angle"] + \
        [",".join(r.split(",")[:2]) for r in base[2:6]]
    yield "bad_wavelength", [base[0], base[1].replace("550nm", "0nm")] + base[2:6]
    yield "incident_out_of_range", base[:4] + [row(4, c0="90")] + base[5:8]
    yield "measure_out_of_range", base[:4] + [row(4, c1="-95")] + base[5:8]
    yield "duplicate", base[:6] + [base[5]] + base[6:8]
    yield "negative", base[:4] + [row(4, c3="-0.4")] + base[5:8]
    yield "non_numeric", base[:4] + [row(4, c2="n/a")] + base[5:8]
    yield "short_row", base[:4] + [",".join(base[4].split(",")[:4])] + base[5:8]


def main():
    base = excerpt()
    (HERE / "spectral_scan.csv").write_text("\n".join(base) + "\n", encoding="utf-8")
    for name, lines in variants(base):
        (HERE / "invalid" / f"spectral_scan_{name}.csv").write_text("\n".join(lines) + "\n",
                                                                     encoding="utf-8")


if __name__ == "__main__":
    main()
