"""Regenerate the LUT examples of data_formats/lut_exr.md:

- lut_fresnel_copper.exr / .glsl: the Fresnel table of Elek 2010's copper (appendix A), 32
  samples, half channels R G B (what `fitlab lut fresnel --preset copper --size 32 --out ...`
  writes);
- invalid/lut_wrong_version.exr: the same with fitlab.schema_version = 2;
- invalid/lut_truncated.exr: its first half only;
- invalid/lut_nan.exr: one texel of channel G set to NaN;
- invalid/lut_plain.exr: an OpenEXR image without fitlab.* attributes;
- invalid/lut_axis_size_text.exr: the same with its axis's size written as the string "32"
  (refused by the header's JSON Schema, data_formats/schemas/lut.schema.json);
- lut_thin_layer_chromium.exr / .glsl: the thin layer's real-time table (a clear layer of
  η 1.5, τ 0.05 / 0.9 / 1.2, over rough chromium), 4 x 6 x 6, half (what `fitlab lut thin_layer
  --model 'thin_layer(rough_conductor)' --param eta=1.5 --param tau=0.05,0.9,1.2 --param
  n2=3.84,3.18,1.99 --param k2=4.37,4.41,4.22 --size 4x6x6 --out ...` writes);
- invalid/lut_thin_layer_axes.exr: the same with its second axis named alpha instead of kappa1.

    python data_formats/examples/make_lut_examples.py
"""

from pathlib import Path

import json

import numpy as np
import OpenEXR

from fitlab import lut
from fitlab.export import exr, shader

HERE = Path(__file__).resolve().parent


def _rewrite(src, dst, header=None, channels=None, drop_fitlab=False):
    with OpenEXR.File(str(src), separate_channels=True) as f:
        h = {k: v for k, v in f.header().items()
             if k not in ("channels", "dataWindow", "displayWindow")
             and not (drop_fitlab and k.startswith("fitlab."))}
        ch = {k: c.pixels for k, c in f.channels().items()}
    h.update(header or {})
    with OpenEXR.File(h, channels or ch) as f:
        f.write(str(dst))


def main():
    table = lut.bake(lut.make_spec("fresnel", params=lut.conductor_preset("copper"), size=(32,)),
                     "half")
    good = HERE / "lut_fresnel_copper.exr"
    exr.write_exr(good, table)
    good.with_suffix(".glsl").write_text(shader.glsl(table, source=good.name))
    inv = HERE / "invalid"
    _rewrite(good, inv / "lut_wrong_version.exr", header={"fitlab.schema_version": "2"})
    data = good.read_bytes()
    (inv / "lut_truncated.exr").write_bytes(data[: len(data) // 2])
    with OpenEXR.File(str(good), separate_channels=True) as f:
        ch = {k: c.pixels.copy() for k, c in f.channels().items()}
    ch["G"][0, 5] = np.nan
    _rewrite(good, inv / "lut_nan.exr", channels=ch)
    _rewrite(good, inv / "lut_plain.exr", drop_fitlab=True)
    with OpenEXR.File(str(good), separate_channels=True) as f:
        axes = json.loads(f.header()["fitlab.axes"])
    axes[0]["size"] = str(axes[0]["size"])
    _rewrite(good, inv / "lut_axis_size_text.exr", header={"fitlab.axes": json.dumps(axes)})

    params = {c: {"eta": 1.5, "tau": t, "n2": n, "k2": k} for c, t, n, k in
              (("R", 0.05, 3.84, 4.37), ("G", 0.9, 3.18, 4.41), ("B", 1.2, 1.99, 4.22))}
    thin = lut.bake(lut.make_spec("thin_layer", model="thin_layer(rough_conductor)",
                                  params=params, size=(4, 6, 6)), "half")
    good = HERE / "lut_thin_layer_chromium.exr"
    exr.write_exr(good, thin)
    good.with_suffix(".glsl").write_text(shader.glsl(thin, source=good.name))
    with OpenEXR.File(str(good), separate_channels=True) as f:
        axes = json.loads(f.header()["fitlab.axes"])
    axes[1]["name"] = "alpha"
    _rewrite(good, inv / "lut_thin_layer_axes.exr", header={"fitlab.axes": json.dumps(axes)})


if __name__ == "__main__":
    main()
