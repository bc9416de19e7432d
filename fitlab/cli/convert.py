"""fitlab convert: measured data to measurement CSV (or OpenMATERIAL); a fit or a registry model
tabulated by any writer of the registry (fitlab.export.writers: Zemax IS-BSDF, MERL binary,
ASAM OpenMATERIAL 3D)."""

from __future__ import annotations

import sys

from fitlab.cli.common import (add_channel, add_format, add_model, add_option, add_param,
                               add_read_options, model_from_args, read_kwargs)
from fitlab.errors import FitlabError

#: Flags that describe the model to tabulate (read by writers that tabulate models).
MODEL_FLAGS = ("model", "param", "option")


def _writers():
    from fitlab.export.writers import DEFAULT, WRITERS

    return WRITERS, DEFAULT


def _suffix_text(writers) -> str:
    return " or ".join(f"*{s}" for w in writers for s in w.suffixes)


def add_parser(sub):
    writers, default = _writers()
    tabulating = [w for w in writers.values() if w.write_model]
    types = "; ".join(f"{w.name}: {w.description} ({_suffix_text([w])}, {w.spec})"
                      for w in writers.values())
    p = sub.add_parser(
        "convert", help="convert data to measurement CSV; tabulate a fit or model as "
        + " or ".join(f"{w.title} {w.suffixes[0]}" for w in tabulating),
        description="Four forms, each writing atomically (nothing is left on failure). "
        "(1) INPUT OUTPUT.csv: read any supported measurement format (e.g. a Zemax .bsdf) and "
        "write a fitlab measurement CSV (data_formats/measurement_csv.md). "
        "(2) FIT.json OUTPUT.bsdf or OUTPUT.binary: tabulate a fitted model (parameter file) as "
        "a Zemax / Radiant IS-BSDF text file (data_formats/zemax_bsdf.md) or a MERL BRDF binary "
        "(data_formats/merl_binary.md). A Zemax file holds one channel or X, Y, Z (tristimulus), "
        "a MERL file one channel (written to R, G and B) or R, G, B; other multi-channel fits "
        "need --channel; a relative fit's 'scale' is not applied (the file holds the absolute "
        "model f). "
        "(3) --model NAME --param NAME=VALUE ... OUTPUT.bsdf or OUTPUT.binary: the same for any "
        "registry model. "
        "(4) INPUT --complete FIT.json OUTPUT (.csv, .bsdf, .binary or .xompt): the measurement "
        "with the values it lacks filled in by the fit, marked, and a record "
        "OUTPUT.completion.json (data_formats/completion_json.md). "
        "The Zemax grid is --grid standard (light at 0..80 deg in 5 deg steps, azimuth 0..180 "
        "in 10 deg steps, plane-symmetric, radial 0..180 deg, fine near the specular ray) or "
        "the angles of an existing .bsdf file, with --aoi/--azimuth/--radial replacing lists. "
        "A MERL file holds the BRDF at the centres of its 90 x 90 x 180 (theta_h, theta_d, "
        "phi_d) bins: reflection only, so a model that does not reflect is refused. "
        "An OpenMATERIAL file (.xompt) holds the model's f on the standard grid (theta_i and "
        "theta_o 0..85 deg step 5, phi_o 0..345 step 15 relative to the incidence) or on the "
        "rows of --grid-from FILE.xompt, one wavelength per channel <N>nm (--wavelength-nm for "
        "one channel that names none); measured data (INPUT OUTPUT.xompt) keep their rows. Its "
        "header comes from the flags, else from the data's OpenMATERIAL file, else defaults "
        "(NOASSERTION where nothing is known). "
        f"Output types (--to; otherwise from the suffix, else {default}): {types}.",
        epilog="examples: fitlab convert data_formats/examples/zemax_brown_vinyl.bsdf vinyl.csv; "
        "fitlab convert fits/vinyl.json vinyl_fit.bsdf --grid data_formats/examples/"
        "zemax_brown_vinyl.bsdf; fitlab convert --model rough_dielectric --param alpha=0.3 "
        "--param eta=1.5 --scatter BTDF --aoi 0:40:5 glass_btdf.bsdf; fitlab convert "
        "fits/rgl_aurora_white_lambert_ggx_conductor.json aurora.binary; fitlab convert "
        "lidar_fit.json lidar_fit.xompt --grid-from data_formats/examples/openmaterial/"
        "example_material_lidar_brdf.xompt; fitlab convert data_formats/examples/"
        "zemax_brown_vinyl.bsdf --complete fits/brown_vinyl_two_lobe.json vinyl_complete.bsdf",
    )
    p.add_argument("paths", nargs="+", metavar="FILE",
                   help="INPUT OUTPUT, or only OUTPUT with --model (options may stand between "
                   "them: INPUT --complete FIT.json OUTPUT)")
    p.set_defaults(trailing_positionals="paths")
    add_format(p)
    add_read_options(p)
    p.add_argument("--to", choices=list(writers),
                   help="output type (default: from the suffix, "
                   + ", ".join(f"{w.name} for {_suffix_text([w])}" for w in writers.values()
                               if w.name != default) + f", else {default})")
    add_model(p, help="tabulate this registry model (see `fitlab models`)")
    add_param(p, "a parameter of --model; give every parameter")
    add_option(p, "an option of --model, e.g. distribution=beckmann")
    p.add_argument("--scatter", type=str.upper, choices=("BRDF", "BTDF"),
                   help="Zemax ScatterType (default BRDF); for BTDF the angles are about the "
                   "refracted ray and --aoi lists refraction angles")
    p.add_argument("--grid", metavar="standard|FILE.bsdf",
                   help="Zemax: 'standard' (default; with --complete of Zemax data: the "
                   "data's own grid) or a Zemax file whose angles to reuse")
    p.add_argument("--aoi", metavar="ANGLES", help="Zemax AngleOfIncidence list in degrees, "
                   "'0,15,30' or START:STOP:STEP (e.g. 0:80:5)")
    p.add_argument("--azimuth", metavar="ANGLES", help="Zemax ScatterAzimuth list; all within "
                   "0..180 writes PlaneSymmetrical data, beyond 180 Asymmetrical")
    p.add_argument("--radial", metavar="ANGLES", help="Zemax ScatterRadial list, 0..180")
    add_channel(p, "the channel of a multi-channel fit to write")
    co = p.add_argument_group(
        "completed measurement (INPUT --complete FIT.json OUTPUT; data_formats/completion_json.md)")
    co.add_argument("--complete", metavar="FIT.json",
                    help="write the measurement INPUT with the values it lacks replaced by this "
                    "fit's: places without reading (NaN, a Zemax stored zero, a MERL bin without "
                    "value), blocked readings (a spectral scan's zeros), places of a Zemax or "
                    "MERL output's grid the data do not cover (beyond the view edge; Zemax: "
                    "the data's own grid when INPUT is a Zemax file, else --grid), and readings "
                    "--complete-subset selects. Each replaced value is marked in the file "
                    "(CSV: column completion; OpenMATERIAL: field fitlabCompletion) and listed "
                    "in OUTPUT.completion.json with counts by reason and incidence and the "
                    "fit's error on the readings; channels are matched by name, and a fit of "
                    "other channels, quantity or conventions is refused (exit 2)")
    co.add_argument("--complete-subset", metavar="EXPR",
                    help="with --complete: readings to replace too, as fitlab fit's "
                    "--fit-subset (e.g. 'theta_o > 80' for a view edge the instrument "
                    "shadows)")
    om = p.add_argument_group("OpenMATERIAL output (.xompt; data_formats/openmaterial_xompt.md)")
    om.add_argument("--grid-from", metavar="FILE.xompt",
                    help="sample the model at the rows (wavelengths and angles) of this "
                    "OpenMATERIAL file instead of the standard grid")
    om.add_argument("--wavelength-nm", type=float, metavar="NM",
                    help="the wavelength of a single channel that states none (a fit of a "
                    "'Y' or --channel G channel, a --model); channels <N>nm state their own")
    om.add_argument("--name", help="metadata.name (default: the data's OpenMATERIAL name, "
                    "else the data file's stem and the model)")
    om.add_argument("--description", help="metadata.description (default: the data's, and "
                    "how fitlab made the file)")
    om.add_argument("--author", action="append", metavar="TEXT",
                    help="metadata.authors, repeatable (default: the data's, else NOASSERTION)")
    om.add_argument("--copyright", action="append", metavar="TEXT",
                    help="metadata.copyrights, repeatable, e.g. '(C) 2026 ACME Inc.' (default: "
                    "the data's, else NOASSERTION)")
    om.add_argument("--license", metavar="SPDX",
                    help="metadata.license: an SPDX identifier, URL or file name (default: the "
                    "data's, else NOASSERTION)")
    om.add_argument("--sensor", metavar="TEXT",
                    help="metadata.typicalSensorTechnology, e.g. lidar or camera (default: the "
                    "data's, else left out)")
    return p


def _reads(writer, flag: str) -> bool:
    """Whether ``writer`` uses the convert flag ``flag``."""
    if flag in MODEL_FLAGS:
        return writer.write_model is not None
    if flag == "channel":
        return writer.write_fit is not None
    return flag in writer.settings


def _elsewhere(what: str, writers) -> FitlabError:
    titles = " or ".join(w.title for w in writers)
    to = " or ".join(f"--to {w.name}" for w in writers)
    return FitlabError(f"{what}: applies to {titles} output only; name the output "
                       f"{_suffix_text(writers)} (or give {to})")


def _check_flags(args, writer, writers):
    """Refuse flags the chosen writer does not read, naming the outputs that do."""
    flags = list(MODEL_FLAGS) + ["channel"] + list(dict.fromkeys(
        s for w in writers.values() for s in w.settings))
    unread = [f for f in flags if getattr(args, f) and not _reads(writer, f)]
    if unread:
        takers = [w for w in writers.values() if all(_reads(w, f) for f in unread)]
        raise _elsewhere(" ".join(f"--{f}" for f in unread), takers)


def _complete(args, writer) -> int:
    """INPUT --complete FIT.json OUTPUT: the completed measurement and its record."""
    from fitlab.export.completion import complete_measurement

    if args.model or args.channel:
        raise FitlabError("--complete writes every channel of the measured INPUT; drop "
                          + ("--model/--param/--option" if args.model else "--channel"))
    if len(args.paths) != 2:
        raise FitlabError("give INPUT OUTPUT: fitlab convert DATA --complete FIT.json OUT")
    from fitlab.io.fitfile import is_fit_file

    if is_fit_file(args.paths[0]):
        raise FitlabError(f"{args.paths[0]} is a parameter file; --complete fills a measured "
                          "INPUT: fitlab convert DATA --complete FIT.json OUT")
    settings = {k: getattr(args, k) for k in writer.settings if getattr(args, k) is not None}
    done = complete_measurement(args.paths[0], args.complete, args.paths[1], to=writer.name,
                                subset=args.complete_subset, format=args.format,
                                **read_kwargs(args), **settings)
    for note in done["notes"]:
        print(f"note: {note}", file=sys.stderr)
    print(done["summary"])
    return 0


def run(args):
    from fitlab.export.writers import writer_for
    from fitlab.io.fitfile import is_fit_file

    writers, _ = _writers()
    if args.complete_subset and not args.complete:
        raise FitlabError("--complete-subset applies with --complete FIT.json only")
    if args.complete:
        writer = writer_for(args.paths[-1], args.to)
        _check_flags(args, writer, writers)
        return _complete(args, writer)
    if args.model:
        if len(args.paths) != 1:
            raise FitlabError("with --model give only the output file: fitlab convert --model "
                              "NAME --param NAME=VALUE ... OUT.bsdf")
        source, output = None, args.paths[0]
    elif len(args.paths) != 2:
        raise FitlabError("give INPUT OUTPUT (or --model NAME --param ... OUT.bsdf)")
    else:
        source, output = args.paths
    writer = writer_for(output, args.to)
    _check_flags(args, writer, writers)
    settings = {k: getattr(args, k) for k in writer.settings if getattr(args, k) is not None}
    if read_kwargs(args) and (args.model or is_fit_file(source)):
        raise FitlabError("--angles, --accept and --quantity apply to a measurement file read "
                          "as INPUT, not to a fit or --model")
    if args.model:
        model, params, options = model_from_args(args)
        summary = writer.write_model(output, model.name, params, options, **settings)
    elif is_fit_file(source):
        if writer.write_fit is None:
            raise _elsewhere(source, [w for w in writers.values() if w.write_fit])
        summary = writer.write_fit(output, source, channel=args.channel, **settings)
    elif writer.write_data is None:
        raise FitlabError(f"{source}: only a parameter file (fit JSON) or --model NAME can be "
                          f"written as a {writer.title} {writer.suffixes[0]}; measured data "
                          "would need resampling onto its grid (fit a model, then convert the "
                          "fit)")
    else:
        from fitlab.io.formats import read_any
        from fitlab.io.gates import notes

        m = read_any(source, args.format, **read_kwargs(args))
        for w in notes(m):
            print(f"note: {w}", file=sys.stderr)
        if m.gaps is not None:
            said = ", ".join(f"{k} {n}" for k, n in m.gaps.counts().items())
            print(f"note: {m.gaps.rows.n} places of {source} hold no reading ({said}), left "
                  "out; `fitlab convert DATA --complete FIT.json OUT` fills them from a fit",
                  file=sys.stderr)
        summary = writer.write_data(output, m, source, **settings)
    print(writer.describe(summary), file=sys.stderr)
    for note in summary.get("notes", []):
        print(f"note: {note}", file=sys.stderr)
    return 0
