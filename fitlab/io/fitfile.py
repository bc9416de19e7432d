"""What tools read out of a fit parameter file (data_formats/fit_json.md) once it has been read
and validated (``fitlab.export.paramfile.read_fit``): the fitted values per channel, the
channels a tabulating writer takes, and the summary ``fitlab info`` prints."""

from __future__ import annotations

from pathlib import Path

from fitlab.errors import FitlabError
from fitlab.fitting.space import SCALE
from fitlab.io.files import read_bytes
from fitlab.io.gates import ANGLES, GATES, QUANTITIES
from fitlab.io.validate import (Any, Bool, Either, Int, List, Map, Num, Optional, Record, Str,
                                check)

#: A parameter file names its schema near the top; enough bytes to find it there.
SNIFF_BYTES = 256
SCHEMA_TAG = b'"fitlab-fit"'


#: Most channels one parameter file holds (a spectral fit has one per wavelength).
MAX_CHANNELS = 1024
#: Most parameters one fitted model has.
MAX_PARAMETERS = 256

_NAME = Str(max_len=200)
_NUM = Num()
_OPT_NUM = Optional(_NUM)
_TEXT_LIST = List(Str(), max_len=10_000)

_POSTERIOR = Record(optional={k: _NUM for k in ("mean", "median", "std", "p2_5", "p16",
                                                    "p50", "p84", "p97_5")})
_BOOTSTRAP_PARAMETER = Record(required={k: _NUM for k in ("std", "p2_5", "p16", "p50", "p84",
                                                           "p97_5")})
_PARAMETER = Record(
    required={"value": _NUM, "fixed": Bool()},
    optional={"unit": Str(max_len=200), "bounds": List(_NUM, length=2),
              "stderr": _OPT_NUM, "at_bound": Bool(), "transform": Str(max_len=50),
              "shared": Bool(),
              "posterior": Optional(_POSTERIOR), "bootstrap": _BOOTSTRAP_PARAMETER})
_COVARIANCE = Record(required={"parameters": List(_NAME, max_len=MAX_PARAMETERS),
                               "matrix": List(List(_OPT_NUM, max_len=MAX_PARAMETERS),
                                              max_len=MAX_PARAMETERS)},
                     optional={"source": Str()})
_MCMC = Record(optional={
    "nwalkers": Int(lo=1), "nsteps": Int(lo=1), "burn_in": Int(lo=0), "thin": Int(lo=1),
    "coordinates": List(_NAME, max_len=MAX_PARAMETERS + 1),
    "autocorrelation_time": List(_OPT_NUM, max_len=MAX_PARAMETERS + 1),
    "acceptance_fraction": _OPT_NUM, "effective_sample_size": _OPT_NUM,
    "samples": Int(lo=0), "trustworthy": Bool(), "warnings": _TEXT_LIST,
    "correlation": List(List(_OPT_NUM)), "prior": Str()})
_PER_INCIDENCE = Record(optional={
    "theta_i": _NUM, "phi_i": _NUM, "n": Int(lo=0), "n_fitted": Int(lo=0), "role": Str(),
    "rms_relative_error": _OPT_NUM, "max_abs_relative_error": _OPT_NUM,
    "rms_relative_error_fitted_rows": _OPT_NUM})
#: The fit error (fitlab.metrics.fit_error; data_formats/fit_json.md, "The fit error"): where
#: present, every field the tools print is required. Files written before it have
#: ``rms_relative_error_fit`` and ``relative_error_floor`` instead (still read).
_FIT_ERROR = Record(
    required={"rms_relative_error": _OPT_NUM, "rows": Int(lo=0), "rows_scored": Int(lo=0),
              "floor": Num(lo=0), "floor_rule": Str(choices=("incidence_peak",))},
    optional={"per_incidence": List(Record(
        required={"theta_i": _NUM, "phi_i": _NUM, "rows": Int(lo=0),
                  "rows_counted": Int(lo=0), "rms_relative_error": _OPT_NUM},
        optional={"max_abs_relative_error": _OPT_NUM}), max_len=100_000)})
_STATISTICS = Record(optional={
    "loss": Str(), "n_fit": Int(lo=0), "n_total": Int(lo=0), "cost": _OPT_NUM, "dof": Int(),
    "residual_noise_scale": _OPT_NUM, "rms_relative_error_fit": _OPT_NUM,
    "relative_error_floor": _OPT_NUM, "fit_error": _FIT_ERROR,
    "prediction_error": Optional(_FIT_ERROR), "chi2": _OPT_NUM, "chi2_per_dof": _OPT_NUM,
    "per_incidence": List(_PER_INCIDENCE, max_len=100_000)})
_VALUES = Map(_OPT_NUM, max_len=MAX_PARAMETERS + 1)
_EMPIRICAL_D = Record(optional={
    "points": Int(lo=0), "theta_m_deg": List(_NUM), "D_empirical": List(_NUM),
    "D_fitted": List(_NUM), "rms_log_ratio": _OPT_NUM, "method": Str()})
_APERTURE = Record(optional={
    "rows": Int(lo=0), "order": Int(lo=1), "order_choice": Str(max_len=20),
    "nodes_per_row": Int(lo=1), "rule": Str(),
    "quadrature_error": Record(optional={
        "reference_order": Int(lo=1), "max_row_error": _OPT_NUM, "rms_row_error": _OPT_NUM,
        "row_error_unit": Str(), "parameter_shift": _VALUES, "max_parameter_shift": _OPT_NUM,
        "parameter_shift_unit": Str(), "tolerance": _OPT_NUM, "within_tolerance": Bool()})})
#: Goodness of fit (fitlab.fitting.goodness) and the block bootstrap's summary
#: (fitlab.fitting.resampling): optional (older files have neither); where present, every field
#: the report reads is required.
_PPC_TEST = Record(required={"observed_mean": _NUM, "replicated_mean": _NUM,
                             "p_value": _NUM})
_GOODNESS = Record(
    required={
        "p_fail": _NUM, "noise": Str(), "describes_data": Bool(),
        "failed": List(Str(max_len=100), max_len=100),
        "incidence_level": Record(required={"statistic": Str(max_len=100),
                                            "min_p_value_sidak": _OPT_NUM},
                                  optional={"test": Str()}),
        "runs_test": Record(required={"runs": Int(lo=0), "expected_runs": _NUM,
                                      "p_value": _OPT_NUM, "ordering": Str()},
                            optional={"z": _OPT_NUM, "rows": Int(lo=0),
                                      "min_p_value_sidak": _OPT_NUM}),
        "per_incidence": List(Record(
            required={"theta_i": _NUM, "phi_i": _NUM, "n": Int(lo=0),
                      "level_p_value": _OPT_NUM, "runs": Int(lo=0), "expected_runs": _NUM,
                      "runs_p_value": _OPT_NUM},
            optional={"chi2_per_dof": _OPT_NUM, "variance_ratio": _OPT_NUM}),
            max_len=100_000),
        "posterior_predictive": Optional(Record(required={
            "draws": Int(lo=0), "chi2": _PPC_TEST, "worst_incidence": _PPC_TEST}))},
    optional={"chi2": Record(required={"chi2": _NUM, "dof": Int(), "chi2_per_dof": _NUM,
                                       "p_value": _NUM})})
_BOOTSTRAP = Record(
    required={"requested": Int(lo=0), "replicates": Int(lo=0), "blocks": Int(lo=0)},
    optional={"method": Str(), "non_finite": Int(lo=0), "max_iterations": Int(lo=0),
              "seed": Int(), "skipped": Str(), "note": Str(), "refits": Int(lo=0),
              "stopped": Str(choices=("converged", "max_iterations")), "stop_reason": Str(),
              "skipped_status": Str(choices=("at_bound", "max_iterations", "non_finite")),
              "at_bound": Map(Int(lo=0), max_len=MAX_PARAMETERS + 1)})
_FIT = Record(
    required={"channel": _NAME,
              "parameters": Map(_PARAMETER, min_len=1, max_len=MAX_PARAMETERS),
              "mcmc": Optional(_MCMC)},
    optional={"covariance": Optional(_COVARIANCE), "statistics": _STATISTICS,
              "warnings": _TEXT_LIST,
              "solver": Record(optional={"stopped": Str(), "iterations": Int(lo=0),
                                         "max_iterations": Int(lo=0), "algorithm": Str()}),
              "global_search": Record(optional={"evaluations": Int(lo=0),
                                                "non_finite": Int(lo=0), "lm_starts": Int(lo=0)}),
              "starts": List(Record(optional={"start": Optional(_VALUES), "end": Optional(_VALUES),
                                              "cost": _OPT_NUM, "lm_iterations": Int(lo=0),
                                              "lm_stopped": Str()}), max_len=100_000),
              "starts_disagree": Optional(Record(optional={"message": Str()})),
              "diagnostics": Record(optional={"empirical_D": _EMPIRICAL_D}),
              "goodness": _GOODNESS, "bootstrap": _BOOTSTRAP,
              "aperture": _APERTURE,
              "timings_s": _VALUES})
#: Most coordinates of a joint fit over channels (shared parameters once, the others per channel).
MAX_JOINT = 4096
_JOINT_NAMES = List(_NAME, max_len=MAX_JOINT)
#: A joint fit over channels (fitlab/fitting/joint.py; data_formats/fit_json.md, "Joint fits").
_JOINT = Record(
    required={"shared": List(_NAME, min_len=1, max_len=MAX_PARAMETERS),
              "parameters": _JOINT_NAMES},
    optional={"channels": List(_NAME, max_len=MAX_CHANNELS),
              "value": List(_NUM, max_len=MAX_JOINT), "stderr": List(_OPT_NUM, max_len=MAX_JOINT),
              "covariance": Record(required={"parameters": _JOINT_NAMES,
                                             "matrix": List(List(_OPT_NUM, max_len=MAX_JOINT),
                                                            max_len=MAX_JOINT)},
                                   optional={"source": Str()}),
              "n_fit": Int(lo=0), "cost": _OPT_NUM, "dof": Int(),
              "residual_noise_scale": _OPT_NUM,
              "mcmc": Record(optional={
                  "coordinates": List(_NAME, max_len=MAX_JOINT + 1),
                  "autocorrelation_time": List(_OPT_NUM, max_len=MAX_JOINT + 1),
                  "correlation": List(List(_OPT_NUM, max_len=MAX_JOINT + 1),
                                      max_len=MAX_JOINT + 1)})})
#: A spectral fit's colour block (fitlab/export/spectral_colour.py; data_formats/fit_json.md,
#: "Colour of a spectral fit"): ``parameters`` null (with ``reason``) where the bands do not span
#: the visible range.
_TRIPLE = List(_NUM, length=3)
_COLOUR = Record(
    required={"channels": List(_NAME, min_len=2, max_len=MAX_CHANNELS),
              "wavelength_nm": List(Num(lo=0, lo_open=True), min_len=2, max_len=MAX_CHANNELS),
              "parameters": Optional(Map(Record(
                  required={"role": Str(max_len=50),
                            "reduction": Str(choices=("colour", "one value",
                                                      "luminance-weighted mean"))},
                  optional={"xyz": _TRIPLE, "linear_srgb": _TRIPLE, "xyz_stderr": _TRIPLE,
                            "linear_srgb_stderr": _TRIPLE, "value": _NUM,
                            "range": List(_NUM, length=2), "stderr": _NUM}),
                  max_len=MAX_PARAMETERS))},
    optional={"reason": Str(), "note": Str(), "colour_conversion": Str(), "observer": Str(),
              "illuminant": Str(max_len=100), "rgb_space": Str()})
#: What a parameter file must hold, field by field (data_formats/fit_json.md): the fields the
#: tools read are checked for type and finiteness before any of them is used.
FIT_SCHEMA = Record(
    required={
        "schema": Str(), "schema_version": Int(),
        "model": Record(required={"name": Str(max_len=10_000)},
                        optional={"options": Map(Either((Str(max_len=100), _NUM, Bool())),
                                                 max_len=256),
                                  "lobes": Str(), "reference": Str()}),
        "data": Record(required={"path": Str(max_len=10_000)},
                       optional={"sha256": Str(max_len=64), "rows": Int(lo=0),
                                 "rows_fitted": Int(lo=0), "fit_subset": Optional(Str(max_len=10_000)),
                                 "file_quantity": Str(), "quantity": Str(),
                                 "channels": List(_NAME, max_len=MAX_CHANNELS),
                                 "wavelength_nm": List(Num(lo=0, lo_open=True),
                                                       max_len=MAX_CHANNELS),
                                 "metadata": Map(Any()),
                                 "read_options": Record(optional={
                                     "angles": Str(choices=ANGLES),
                                     "accept": List(Str(choices=tuple(GATES)), max_len=16),
                                     "quantity": Str(choices=QUANTITIES)})}),
        "fits": List(_FIT, min_len=1, max_len=MAX_CHANNELS),
        "loss": Str(max_len=100),
    },
    optional={"seed": Optional(Int()), "notes": _TEXT_LIST, "joint": _JOINT, "colour": _COLOUR,
              "conventions": Map(Str()), "software": Map(Str()), "timings_s": _VALUES,
              "created_utc": Str(), "chain": Record(required={"path": Str(max_len=10_000)},
                                                    optional={"sha256": Str(max_len=64)})})


def check_fit_record(path, record) -> dict:
    """``record`` (a parsed parameter file) checked against FIT_SCHEMA and for consistency
    (distinct channels; covariance names among the parameters and its matrix square), or an
    InputFileError naming ``path`` and the field."""
    from fitlab.errors import InputFileError

    hint = "give a file `fitlab fit` wrote (data_formats/fit_json.md)"
    check(record, FIT_SCHEMA, path, hint=hint)
    channels = [f["channel"] for f in record["fits"]]
    if len(set(channels)) != len(channels):
        raise InputFileError(path, "field fits lists a channel twice", hint=hint)
    for k, fit in enumerate(record["fits"]):
        cov = fit.get("covariance")
        if not cov:
            continue
        names, matrix = cov["parameters"], cov["matrix"]
        unknown = [n for n in names if n not in fit["parameters"]]
        if unknown:
            raise InputFileError(path, f"field fits[{k}].covariance.parameters names "
                                 f"{quote_names(unknown)}, not parameters of the fit", hint=hint)
        if len(matrix) != len(names) or any(len(row) != len(names) for row in matrix):
            raise InputFileError(path, f"field fits[{k}].covariance.matrix is not "
                                 f"{len(names)} x {len(names)}", hint=hint)
    data = record["data"]
    if "wavelength_nm" in data and len(data["wavelength_nm"]) != len(data.get("channels") or ()):
        raise InputFileError(path, f"field data.wavelength_nm has {len(data['wavelength_nm'])} "
                             f"entries for {len(data.get('channels') or ())} data.channels",
                             hint=hint)
    colour = record.get("colour")
    if colour and colour.get("illuminant") is not None:
        from fitlab.colorimetry import illuminant_table

        try:
            illuminant_table(colour["illuminant"])
        except ValueError as exc:
            raise InputFileError(path, f"field colour.illuminant: {exc}", hint=hint) from None
    joint = record.get("joint")
    if joint:
        n = len(joint["parameters"])
        for key in ("value", "stderr"):
            if key in joint and len(joint[key]) != n:
                raise InputFileError(path, f"field joint.{key} has {len(joint[key])} entries "
                                     f"for {n} joint.parameters", hint=hint)
        cov = joint.get("covariance")
        if cov and (len(cov["matrix"]) != len(cov["parameters"])
                    or any(len(row) != len(cov["parameters"]) for row in cov["matrix"])):
            raise InputFileError(path, "field joint.covariance.matrix is not "
                                 f"{len(cov['parameters'])} x {len(cov['parameters'])}", hint=hint)
    return record


def quote_names(names) -> str:
    from fitlab.io.validate import quote

    return ", ".join(quote(n, 30) for n in names[:5])


def is_fit_file(path) -> bool:
    """Whether ``path`` is a ``*.json`` file that calls itself a fitlab parameter file."""
    p = Path(path)
    if p.suffix.lower() != ".json" or not p.is_file():
        return False
    return SCHEMA_TAG in read_bytes(p, limit=SNIFF_BYTES)


def fit_parameters(record: dict, *, source="the parameter file", channel: str | None = None,
                   scale: bool = True) -> dict[str, dict[str, float]]:
    """{channel: {parameter: fitted value}} of a parameter file's fits, in file order.

    ``channel`` keeps that channel only (a FitlabError naming ``source`` and its channels if it
    has none of that name). ``scale=False`` leaves out the ``scale`` of a relative fit, which
    is not part of the model."""
    out = {f["channel"]: {k: v["value"] for k, v in f["parameters"].items()
                          if scale or k != SCALE}
           for f in record["fits"]}
    if channel is not None:
        if channel not in out:
            raise FitlabError(f"--channel {channel}: {source} has channels {', '.join(out)}")
        out = {channel: out[channel]}
    return out


def tabulation_channels(record: dict, *, source, channel: str | None, layout: tuple,
                        single: str, file_kind: str):
    """The model parameters of a fit for a writer whose files hold one channel (under the name
    ``single``) or the channels ``layout`` (e.g. X, Y, Z), and the notes to pass on.

    Returns ({channel: parameters}, notes); a fit's ``scale`` is left out (noted): the file
    holds the absolute model f. A spectral fit goes to an R, G, B layout as its reduction to
    linear sRGB (fitlab.export.spectral_colour; noted)."""
    fits = fit_parameters(record, source=source, channel=channel)
    notes = []
    relative = any(SCALE in p for p in fits.values())
    if len(fits) == 1:
        fits = {single: next(iter(fits.values()))}
    elif set(fits) != set(layout):
        spectral = _spectral_rgb(record, fits, layout, source, file_kind)
        if spectral is None:
            raise FitlabError(f"{source} has channels {', '.join(fits)}; a {file_kind} file "
                              f"holds one channel or {', '.join(layout)}: choose one with "
                              "--channel")
        fits, notes = spectral
    else:
        fits = {c: fits[c] for c in layout}
    if relative:
        notes.append(f"relative fit: the '{SCALE}' parameter is not applied; the file holds the "
                     "absolute model f")
        fits = {c: {k: v for k, v in p.items() if k != SCALE} for c, p in fits.items()}
    return fits, notes


def _spectral_rgb(record: dict, fits: dict, layout: tuple, source, file_kind: str):
    """(R, G, B channels, notes) of a spectral fit for a writer whose layout is R, G, B: its
    reduction to linear sRGB under the colour block's illuminant
    (fitlab.export.spectral_colour); None when the fit is not spectral or the layout is not RGB;
    a FitlabError when its bands do not span the visible range."""
    from fitlab.export.spectral_colour import (RGB, bands_of, check_illuminant,
                                               record_wavelengths, reduced_channels)
    from fitlab.models import get_model

    wl = record_wavelengths(record)
    bands = bands_of({c: wl.get(c) for c in fits})
    if bands is None or tuple(layout) != RGB:
        return None
    problem = bands.coverage_problem()
    if problem is not None:
        raise FitlabError(f"{source}: a {file_kind} file holds R, G, B, and this spectral fit has "
                          f"no colour: {problem}; choose one band with --channel")
    illuminant = check_illuminant((record.get("colour") or {}).get("illuminant"))
    plain = {c: {k: v for k, v in p.items() if k != SCALE} for c, p in fits.items()}
    channels, notes = reduced_channels(get_model(record["model"]["name"]), plain, bands,
                                       illuminant)
    return channels, [f"spectral fit ({len(bands.nm)} bands, {bands.nm[0]:g}-{bands.nm[-1]:g} "
                      f"nm) reduced to linear sRGB under {illuminant} (CIE 1931 2 degree "
                      "observer)"] + notes


def describe_fit(record: dict) -> dict:
    """What ``fitlab info`` shows of a parameter file."""
    return {"format": "fit-json", "format_description": "fitlab parameter file",
            "spec": "data_formats/fit_json.md", "schema_version": record["schema_version"],
            "model": record["model"], "loss": record["loss"], "data": record["data"]["path"],
            "channels": [f["channel"] for f in record["fits"]],
            "parameters": fit_parameters(record),
            "mcmc": [bool(f["mcmc"]) for f in record["fits"]]}


__all__ = ["FIT_SCHEMA", "check_fit_record", "is_fit_file", "fit_parameters", "tabulation_channels", "describe_fit"]
