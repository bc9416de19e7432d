"""Regenerate openmaterial/fitlab_lambertian_ggx.xompt (an OpenMATERIAL BRDF table fitlab writes)
and the deliberately broken invalid/openmaterial_*.xompt made from the lidar example.

The two upstream files in openmaterial/ are copies of ASAM OpenMATERIAL 3D's examples
(MPL-2.0, openmaterial/SOURCE.txt); they are not remade here. The broken files start from the
lidar file's metadata and its first eight rows (one incidence, θi = 86°) and break one rule
each; data_formats/openmaterial_xompt.md lists them and tests/io/test_io_openmaterial.py
checks the message each one gets (the file, the JSON path of the field, what to do).

    python data_formats/examples/make_openmaterial_examples.py
"""

import copy
import json
from pathlib import Path

HERE = Path(__file__).resolve().parent
LIDAR = HERE / "openmaterial" / "example_material_lidar_brdf.xompt"
WRITTEN = HERE / "openmaterial" / "fitlab_lambertian_ggx.xompt"
#: The written example: a Lambertian base and a GGX conductor at three wavelengths, on a small
#: grid (3 incidences × (4 view zeniths × 8 azimuths + the normal) = 99 rows a wavelength).
MODEL = "lambertian+rough_conductor"
CHANNELS = {"450nm": {"albedo": 0.10, "alpha": 0.25, "n": 1.4, "k": 1.9},
            "550nm": {"albedo": 0.30, "alpha": 0.25, "n": 0.4, "k": 2.4},
            "650nm": {"albedo": 0.60, "alpha": 0.25, "n": 0.2, "k": 3.5}}
GRID = ((0, 30, 60), (0, 20, 40, 60, 80), tuple(range(0, 360, 45)))


def written_example() -> str:
    from fitlab.export.material import material_from_model
    from fitlab.export.openmaterial import Grid, material_table

    material = material_from_model(MODEL, CHANNELS)
    text, _, _ = material_table(
        material, grid=Grid(*GRID), name="fitlab example: Lambertian + GGX conductor",
        description="A synthetic coloured metal: a Lambertian base under a GGX conductor "
        "lobe, parameters per wavelength.", author=["fitlab (generated example)"],
        license="BSD-3-Clause", sensor="camera", what=str(WRITTEN.name))
    return text


def base() -> dict:
    doc = json.loads(LIDAR.read_text(encoding="utf-8"))
    doc["brdf"]["lookupTable"] = doc["brdf"]["lookupTable"][:8]
    return doc


def variants(doc: dict):
    """(name, text) of each broken file."""
    def changed(edit):
        d = copy.deepcopy(doc)
        edit(d)
        return json.dumps(d, indent=4) + "\n"

    rows = lambda d: d["brdf"]["lookupTable"]  # noqa: E731

    def degrees(d):
        for r in rows(d):
            r[1:4] = [round(v * 180 / 3.141592653589793, 6) for v in r[1:4]]

    yield "degrees", changed(degrees)
    yield "missing_uuid", changed(lambda d: d["metadata"].pop("uuid"))
    yield "bad_uuid", changed(lambda d: d["metadata"].update(uuid="asphalt-1"))
    yield "short_row", changed(lambda d: rows(d)[3].pop())
    yield "negative", changed(lambda d: rows(d)[5].__setitem__(4, -0.0013255))
    yield "zenith_out_of_range", changed(lambda d: rows(d)[2].__setitem__(2, 1.6))
    yield "null", changed(lambda d: rows(d)[4].__setitem__(4, None))
    yield "duplicate", changed(lambda d: rows(d).insert(3, list(rows(d)[2])))
    yield "unlisted_wavelength", changed(lambda d: rows(d)[6].__setitem__(0, 9.5e-07))
    yield "unused_wavelength", changed(lambda d: d["brdf"]["wavelengths"].append(1.55e-06))
    yield "huge", changed(lambda d: rows(d)[1].__setitem__(4, 1e999)).replace(
        "Infinity", "1e999")
    yield "solid_angle", changed(lambda d: d["brdf"].update(receiverSolidAngles=[
        {"wavelength": 9.05e-07, "solidAngle": 7.0}]))
    yield "completion_unmatched", changed(lambda d: d.update(fitlabCompletion={
        "rows": [rows(d)[2][:4] + ["no_reading"], [9.05e-07, 0.5, 0.25, 0.0, "blocked"]]}))
    yield "not_json", json.dumps(doc, indent=4)[:700]


def main():
    WRITTEN.write_text(written_example(), encoding="utf-8")
    doc = base()
    for name, text in variants(doc):
        (HERE / "invalid" / f"openmaterial_{name}.xompt").write_text(text, encoding="utf-8")


if __name__ == "__main__":
    main()
