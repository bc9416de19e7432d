"""Regenerate the capture-stack examples of data_formats/stack.md: the valid stack
``stack/`` and the invalid ones under ``invalid/stack_*/``.

``stack/``: a 4 x 4 texel, R G B capture of a flat sample of Lambert + GGX conductor
(``lambertian+rough_conductor``, n = 0.2, k = 3.9, fitlab's defaults) in 24 images: light at
θi = 0°, 30°, 60° (φi = 0°), camera at θo = 0°, 20°, 40°, 60° in and across the plane of
incidence. Truth per texel (x, y): albedo R, G, B = 0.1 + 0.05 (x, y, x + y) (so 0.1 to 0.4),
alpha = 0.1 + 0.1 y (0.1 to 0.4, the same in every channel). Readings carry 1 % multiplicative
log-normal noise (seed 35). Texel (x=3, y=3) has no reading in any image (NaN: fitted as "no
data"); texel (x=0, y=3) misses two readings (NaN in images 5 and 17).

    python data_formats/examples/make_stack_examples.py
"""

from pathlib import Path
import shutil

import numpy as np

HERE = Path(__file__).resolve().parent
SIZE = 4
N, K = 0.2, 3.9
NOISE, SEED = 0.01, 35


def directions():
    """(theta_i, phi_i, theta_o, phi_o) rows of the 24 images, degrees."""
    rows = []
    for ti in (0.0, 30.0, 60.0):
        for to in (0.0, 20.0, 40.0, 60.0):
            for po in (180.0, 90.0):
                rows.append((ti, 0.0, to, po))
    return np.array(rows)


def truth():
    """(albedo (4, 4, 3), alpha (4, 4)) by texel (y, x)."""
    y, x = np.mgrid[0:SIZE, 0:SIZE].astype(float)
    albedo = 0.1 + 0.05 * np.stack([x, y, x + y], axis=-1)
    alpha = 0.1 + 0.1 * y
    return albedo, alpha


def images():
    """(H, W, images, 3) readings, f in 1/sr."""
    from fitlab.api import eval_bsdf
    from fitlab.io.directions import degrees_to_direction

    d = directions()
    wi, wo = degrees_to_direction(d[:, 0], d[:, 1]), degrees_to_direction(d[:, 2], d[:, 3])
    albedo, alpha = truth()
    out = np.empty((SIZE, SIZE, len(d), 3))
    for c in range(3):
        params = {"albedo": albedo[..., c][..., None], "alpha": alpha[..., None],
                  "n": N, "k": K}
        out[..., c] = np.asarray(eval_bsdf("lambertian+rough_conductor", params, wi[None, None],
                                           wo[None, None]))
    rng = np.random.default_rng(SEED)
    out *= np.exp(NOISE * rng.standard_normal(out.shape))
    out[3, 3] = np.nan
    out[3, 0, [5, 17]] = np.nan
    return out


def write_stack(folder: Path, values, rows, *, cells=None, table_extra: str = "") -> None:
    """A stack folder: stack.csv and one OpenEXR per row (``values`` (H, W, images, C),
    channels R, G, B or Y by C); ``cells``: the table's file cells, if not the images' names."""
    from fitlab.io.exr_image import write_image

    if folder.exists():
        shutil.rmtree(folder)
    folder.mkdir(parents=True)
    channels = ("R", "G", "B") if values.shape[-1] == 3 else ("Y",)
    names = [f"img_{j:03d}.exr" for j in range(values.shape[2])]
    lines = ["# a fitlab capture stack (data_formats/stack.md)", "file,theta_i,phi_i,theta_o,phi_o"]
    for j, (name, r) in enumerate(zip(names, rows)):
        lines.append(f"{(cells or names)[j]}," + ",".join(f"{v:.9g}" for v in r))
        write_image(folder / name, {c: values[:, :, j, k] for k, c in enumerate(channels)})
    (folder / "stack.csv").write_text("\n".join(lines) + "\n" + table_extra, encoding="utf-8")


def invalid(values, rows):
    """The invalid examples: each a small stack with one thing wrong (data_formats/stack.md)."""
    from fitlab.io.exr_image import write_image

    base = HERE / "invalid"
    small = values[:2, :2, :4]
    r4 = rows[:4]
    # an image of another size
    write_stack(base / "stack_mismatched_size", small, r4)
    write_image(base / "stack_mismatched_size" / "img_002.exr",
                {c: np.full((3, 2), 0.1, np.float32) for c in "RGB"})
    # a row whose image is missing
    write_stack(base / "stack_missing_file", small, r4)
    (base / "stack_missing_file" / "img_003.exr").unlink()
    # an image with an alpha channel
    write_stack(base / "stack_extra_channel", small, r4)
    write_image(base / "stack_extra_channel" / "img_001.exr",
                {**{c: small[:, :, 1, k] for k, c in enumerate("RGB")},
                 "A": np.ones((2, 2), np.float32)})
    # an infinite reading
    bad = small.copy()
    bad[1, 0, 2, 1] = np.inf
    write_stack(base / "stack_infinite", bad, r4)
    # a path that leaves the folder
    write_stack(base / "stack_escaping_path", small, r4,
                cells=["img_000.exr", "../img_001.exr", "img_002.exr", "img_003.exr"])
    # angles in radians
    write_stack(base / "stack_radians", np.repeat(small, 2, axis=2)[:, :, :8],
                np.radians(rows[[0, 2, 4, 6, 9, 11, 13, 15]]))


def main():
    values = images()
    rows = directions()
    write_stack(HERE / "stack", values, rows)
    invalid(values, rows)


if __name__ == "__main__":
    main()
