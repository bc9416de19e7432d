"""fitlab export: a fit (or a registry model) as a file a renderer loads: Mitsuba 3 scene XML or
dictionary (Mitsuba's own plugins, or fitlab's plugin for any model), a glTF 2.0 material, a
MaterialX OpenPBR Surface document."""

from __future__ import annotations

import sys

from fitlab.cli.common import add_channel, add_model, add_option, add_quiet, material_arguments


def add_parser(sub):
    from fitlab.export.renderers import EXPORTERS

    formats = "; ".join(f"{e.name}: {e.description} ({' or '.join(e.suffixes)}, {e.spec})"
                        for e in EXPORTERS.values())
    p = sub.add_parser(
        "export", help="export a fit for a renderer: Mitsuba 3 (native or fitlab's plugin), "
        "glTF 2.0, an ASAM OpenMATERIAL 3D BRDF table, a MaterialX OpenPBR Surface",
        description="Write FIT.json (or --model with --param) as a file a renderer loads, "
        "atomically (nothing is left on failure). A fit's 'scale' (relative data) is not "
        "applied: the file holds the absolute model f. One channel exports grey, R, G, B in "
        "colour; a spectral fit (channels that are wavelengths spanning 380-780 nm) goes to "
        "formats that take RGB as its colour block's linear sRGB (data_formats/fit_json.md, "
        "'Colour of a spectral fit'); other channel sets need --channel. A format that "
        "cannot represent the material is refused with what to use instead (exit status 2). Formats (--to; "
        f"otherwise from the suffix: .xml/.json mitsuba, .gltf gltf, .xompt openmaterial, "
        f".mtlx materialx): "
        f"{formats}.",
        epilog="examples: fitlab export fits/rgl_aurora_white_two_lobe_shared.json --to "
        "mitsuba --out aurora.xml --preview; fitlab export "
        "fits/brown_vinyl_weidlich_wilkie_lambert.json --to mitsuba-plugin --out vinyl.xml; "
        "fitlab export --model rough_conductor --param alpha=0.2 --param n=0.2 --param k=3.9 "
        "--out gold.json; fitlab export fits/brown_vinyl_lambert_ggx_dielectric.json --out "
        "vinyl.gltf",
    )
    p.add_argument("fit", nargs="?", metavar="FIT.json",
                   help="parameter file written by `fitlab fit --out` (or give --model)")
    from fitlab.export.renderers import EXPORTERS as E

    p.add_argument("--to", choices=list(E), help="export format (default: from --out's suffix)")
    p.add_argument("--out", required=True, metavar="FILE",
                   help="output file (.xml scene or .json dictionary for Mitsuba, .gltf, .xompt "
                   "for OpenMATERIAL, .mtlx for MaterialX)")
    add_model(p, help="export this registry model instead of a fit (see `fitlab models`)")
    p.add_argument("--param", action="append", metavar="NAME=VALUE",
                   help="a parameter of --model: NAME=V, or NAME=R,G,B for a colour material; "
                   "give every parameter")
    add_option(p, "an option of --model, e.g. distribution=beckmann_rational")
    add_channel(p, "export only this channel of the fit (as grey)")
    p.add_argument("--illuminant", metavar="NAME",
                   help="a spectral fit exported as RGB: the CIE illuminant of the reduction to "
                   "linear sRGB (a colour-science name: D65, D50, A, ...; default: the one the "
                   "fit's colour block states, else D65)")
    p.add_argument("--preview", action="store_true",
                   help="Mitsuba XML: a whole scene around the material (a sphere under a "
                   "white environment and a sun, a camera) that renders as it is")
    p.add_argument("--check", action="store_true",
                   help="render the export on a virtual goniometer (120 fixed direction pairs) "
                   "and print how far the renderer's values are from the fit's (relative RMS "
                   "and largest difference of f cos theta_i) and what that means: Mitsuba 3 "
                   "for the Mitsuba exports; three.js in headless Chromium for glTF (and the "
                   "Khronos glTF validator, where Node.js has it), else Mitsuba with glTF's "
                   "specified BRDF of the file's values; MaterialX's own GLSL of the .mtlx "
                   "document in Mesa's OpenGL (EGL, headless) against fitlab's OpenPBR of the "
                   "file's values. Without a renderer nothing is written "
                   "(exit status 2, with what to install)")
    add_quiet(p, help="print nothing on success")
    return p


def run(args):
    from fitlab.export.renderers import export_material

    params, options = material_arguments(args)
    made = export_material(args.fit, args.to, args.out, model=args.model, params=params,
                           options=options, channel=args.channel, preview=args.preview,
                           check=args.check, progress=not args.quiet,
                           illuminant=args.illuminant)
    if not args.quiet:
        conv = made.conversion
        line = f"wrote {args.out}"
        if "translation" in conv:
            line += f" (Mitsuba bsdf type {conv['translation']})"
        if "what" in conv:
            line += f" ({conv['what']})"
        if "relative_rms" in conv:
            line += (f"; {conv.get('target_title', 'glTF')} conversion error: relative RMS of "
                     f"f cos {conv['relative_rms']:.3g}, largest {conv['relative_max']:.3g}")
        elif conv.get("converted") is False:
            line += f" ({conv['summary']})"
        print(line, file=sys.stderr)
        colour = conv.get("colour")
        if colour:
            print(f"colour: spectral fit ({colour['bands']}) reduced to linear sRGB under "
                  f"{colour['illuminant']} (CIE 1931 2 degree observer)", file=sys.stderr)
            for note in colour["notes"]:
                print(f"  {note}", file=sys.stderr)
        for w in conv.get("warnings", ()):
            print(f"warning: {w}", file=sys.stderr)
        if "check" in conv:
            for text in check_lines(conv["check"]):
                print(text, file=sys.stderr)
    return 0


def check_lines(c: dict) -> list[str]:
    """What `fitlab export --check` prints of a check's figure (fitlab.export.check)."""
    lines = [f"check: {c['renderer']} on {c['pairs']} goniometer pairs: relative RMS "
             f"{c['relative_rms']:.3g}, largest {c['relative_max']:.3g} against fitlab",
             f"  compared: {c['compared']}", f"  meaning: {c['meaning']}"]
    a = c.get("against_fit")
    if a:
        lines.append(f"  against the material exported (conversion included): relative RMS "
                     f"{a['relative_rms']:.3g}, largest {a['relative_max']:.3g}")
    s = c.get("specification")
    if s:
        lines.append(f"  glTF's specified BRDF with the file's values: relative RMS "
                     f"{s['relative_rms']:.3g}, largest {s['relative_max']:.3g} against "
                     "fitlab (the conversion's share)")
    v = c.get("validator")
    if v is not None:
        lines.append(f"  glTF validator: not run ({v['skipped']})" if "skipped" in v else
                     f"  Khronos glTF validator {v['version']}: {v['errors']} errors, "
                     f"{v['warnings']} warnings, {v['infos']} infos, {v['hints']} hints")
    return lines
