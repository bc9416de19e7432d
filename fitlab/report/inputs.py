"""What a report is made of: the fit record, its data and its MCMC chain, validated against each
other, plus the model predictions the figures show. Plain NumPy/JAX, no plotting.

Model values come from :mod:`fitlab.api` (``eval_bsdf``); posterior bands evaluate the model at
a few hundred chain samples in one broadcast call (samples × directions).
"""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import numpy as np

import fitlab.api
from fitlab.api import eval_bsdf
from fitlab.models import get_model
from fitlab.errors import InputFileError
from fitlab.io.validate import quote
from fitlab.fitting.space import SCALE, FitSpace, FreeParameter, StaticSpace

#: Posterior samples used for predictive bands (evenly spaced through the stored samples).
BAND_SAMPLES = 300
#: Quantiles of the bands: 95% and 68% central intervals and the median.
BAND_QUANTILES = (2.5, 16.0, 50.0, 84.0, 97.5)
#: Relative tolerance when checking a chain's samples against the medians the fit recorded.
CHAIN_MATCH_RTOL = 1e-9


class ChannelInputs(NamedTuple):
    name: str
    fit: dict  # the record's fits[k]
    params: dict  # native values of the model parameters (fixed and free), scale excluded
    scale: float  # 1 for absolute data
    free: tuple  # free parameter names in the covariance / sample order (scale last)
    space: FitSpace  # to map chain coordinates to native values
    rows: np.ndarray  # indices of this channel's rows in the measurement
    fitted: np.ndarray  # bool per row of ``rows``: inside the fit subset
    samples: np.ndarray | None  # (S, len(free)) thinned posterior samples, native units
    samples_all: np.ndarray | None  # every stored post-burn-in sample (corner plot)
    noise: np.ndarray | None  # σ_r of the loss's noise model at each thinned sample, if sampled
    noise_floor: float  # the relative loss's floor (1% of the fitted rows' max |value|)
    chain: np.ndarray | None  # (steps, walkers, coords) in sampler coordinates
    chain_coordinates: tuple
    log_prob: np.ndarray | None


class ReportInputs(NamedTuple):
    fit_path: str
    record: dict
    measurement: object  # fitlab.io.measurement.Measurement
    data_path: str
    chain_path: str | None
    chain_note: str | None  # why there is no chain, when there is none
    model: object  # fitlab.models.Model
    options: dict
    channels: tuple  # of ChannelInputs


def _resolve(recorded: str, fit_path: Path) -> Path | None:
    """A path recorded in a fit file: as given (relative to the working folder), else relative
    to the fit file's folder or one of its parents (the fit was made from a project root)."""
    p = Path(recorded)
    if p.is_absolute() or p.exists():
        return p if p.exists() else None
    for base in [fit_path.resolve().parent, *fit_path.resolve().parents]:
        if (base / p).exists():
            return base / p
    return None


def load_data(record: dict, fit_path: Path, data_path=None, read_options: dict | None = None):
    """The measurement the fit was made from, checked by its SHA-256, read as the fit read it
    (``data.read_options``: --angles, --accept, --quantity) unless ``read_options`` are given."""
    from fitlab.io.files import sha256_of
    from fitlab.io.formats import read_any

    recorded = record["data"].get("path")
    if data_path is None:
        if not recorded:
            raise InputFileError(fit_path, "records no data file", column="data.path",
                                 hint="give the data file with --data FILE")
        found = _resolve(recorded, fit_path)
        if found is None:
            raise InputFileError(fit_path, f"names the data file {quote(recorded)}, which does not "
                                 "exist (relative to this folder or the fit file's folders)",
                                 column="data.path", hint="give the data file with --data FILE")
        data_path = found
    data_path = Path(data_path)
    if not data_path.is_file():
        raise InputFileError(data_path, "no such data file", hint="check the --data path")
    want = record["data"].get("sha256")
    if want and sha256_of(data_path) != want:
        raise InputFileError(data_path, f"is not the file {fit_path} was fitted to (its SHA-256 "
                             "differs from the one recorded in data.sha256)",
                             hint="give the original data file with --data, or refit")
    if read_options is None:
        read_options = record["data"].get("read_options") or {}
    m = read_any(data_path, **read_options)
    label = (record["data"].get("metadata") or {}).get("dataset")
    if m.dataset is not None:  # a file of several datasets: the one the fit was made from
        if label not in m.dataset_names:
            raise InputFileError(fit_path, f"names the dataset {quote(str(label))}, which "
                                 f"{data_path} does not hold", column="data.metadata.dataset",
                                 hint="give the original data file with --data")
        m = m.dataset_named(label)
    if m.n != record["data"].get("rows", m.n):
        raise InputFileError(data_path, f"has {m.n} rows; the fit recorded "
                             f"{record['data']['rows']}", hint="give the original data file")
    names = [f["channel"] for f in record["fits"]]
    missing = [c for c in names if c not in m.channel_names]
    if missing:
        raise InputFileError(fit_path, f"names the channel(s) {', '.join(missing)}, which "
                             f"{data_path} lacks", column="fits.channel",
                             hint="give the data file the fit was made from with --data")
    return m, str(data_path)


def _space_of(fit: dict, record: dict) -> FitSpace:
    free = []
    for name in fit["covariance"]["parameters"]:
        p = fit["parameters"][name]
        free.append(FreeParameter(name, float(p["bounds"][0]), float(p["bounds"][1]),
                                  p.get("transform") == "log", p.get("unit", "")))
    fixed = {k: v["value"] for k, v in fit["parameters"].items() if v["fixed"]}
    static = StaticSpace(get_model(record["model"]["name"]),
                         tuple(sorted(record["model"]["options"].items())),
                         tuple(f.name for f in free), tuple(f.log for f in free),
                         tuple(sorted(fixed)), SCALE in fit["parameters"])
    return FitSpace(static, tuple(free), fixed)


def _open_chain(chain_path: Path) -> dict:
    """The arrays of a chain file, read through the checked .npz reader (sizes, dtypes,
    corruption) before any is used."""
    from fitlab.io.validate import read_npz

    if not chain_path.exists():
        raise InputFileError(chain_path, "no such chain file", hint="check the --chain path, or "
                             "rerun `fitlab fit ... --mcmc --chain FILE.npz`")
    return read_npz(chain_path, what="fitlab MCMC chain",
                    hint="give the file `fitlab fit --chain` wrote")


def _channel_chain(npz, chain_path, fit, free, fit_path):
    """(samples, chain, coordinates, log_prob) of one channel, checked against the fit."""
    tag = fit["channel"]
    need = [f"{k}_{tag}" for k in ("samples", "chain", "coordinates", "log_prob")]
    absent = [k for k in need if k not in npz]
    if absent:
        raise InputFileError(chain_path, f"has no array(s) {', '.join(absent)} for channel "
                             f"{tag} (arrays: {', '.join(sorted(npz))})",
                             hint=f"give the chain written together with {fit_path}")
    for key in need:
        want = "U" if key.startswith("coordinates") else "iuf"
        if npz[key].dtype.kind not in want:
            raise InputFileError(chain_path, f"array {key} holds {npz[key].dtype} values; "
                                 f"expected {'names' if want == 'U' else 'numbers'}", column=key,
                                 hint=f"give the chain written together with {fit_path}")
    samples = np.asarray(npz[f"samples_{tag}"], dtype=float)
    coords = tuple(str(c) for c in np.atleast_1d(npz[f"coordinates_{tag}"]))
    chain = np.asarray(npz[f"chain_{tag}"], dtype=float)
    log_prob = np.asarray(npz[f"log_prob_{tag}"], dtype=float)
    if coords[: len(free)] != tuple(free):
        raise InputFileError(chain_path, f"channel {tag}: the chain's coordinates "
                             f"({', '.join(coords)}) do not match the fit's free parameters "
                             f"({', '.join(free)})", column=f"coordinates_{tag}",
                             hint=f"give the chain written together with {fit_path}")
    if samples.ndim != 2 or samples.shape[1] != len(free) or samples.shape[0] < 2:
        raise InputFileError(chain_path, f"channel {tag}: samples have shape {samples.shape}; "
                             f"expected (n, {len(free)})", column=f"samples_{tag}")
    if chain.ndim != 3 or chain.shape[2] != len(coords) or log_prob.shape != chain.shape[:2]:
        raise InputFileError(chain_path, f"channel {tag}: chain shape {chain.shape} and log_prob "
                             f"shape {log_prob.shape} are inconsistent with "
                             f"{len(coords)} coordinates", column=f"chain_{tag}")
    if not np.all(np.isfinite(samples)):
        raise InputFileError(chain_path, f"channel {tag}: samples contain NaN or infinity",
                             column=f"samples_{tag}")
    mc = fit.get("mcmc")
    if mc:
        if mc.get("samples") is not None and mc["samples"] != samples.shape[0]:
            raise InputFileError(chain_path, f"channel {tag}: holds {samples.shape[0]} samples; "
                                 f"{fit_path} recorded {mc['samples']}",
                                 hint=f"give the chain written together with {fit_path}")
        for k, name in enumerate(free):
            post = fit["parameters"][name].get("posterior")
            if post is None:
                continue
            med = float(np.percentile(samples[:, k], 50))
            if not np.isclose(med, post["median"], rtol=CHAIN_MATCH_RTOL, atol=0.0):
                raise InputFileError(
                    chain_path, f"channel {tag}: is not this fit's chain (its posterior median "
                    f"of {name} is {med:.9g}; {fit_path} records {post['median']:.9g})",
                    hint=f"give the chain written together with {fit_path}, or rerun the fit")
    return samples, chain, coords, log_prob


def thin_index(n_total: int, n: int = BAND_SAMPLES) -> np.ndarray:
    """Indices of at most ``n`` samples, evenly spaced through ``n_total`` (deterministic)."""
    if n_total <= n:
        return np.arange(n_total)
    return np.round(np.linspace(0, n_total - 1, n)).astype(int)


def noise_scales(chain, coords, samples_all, fit, space):
    """σ_r (the sampled noise scale of losses other than chi2) for every stored sample, or None.

    The stored samples are emcee's ``get_chain(discard=burn, thin=thin, flat=True)``: steps
    burn + thin − 1, burn + 2 thin − 1, ... of every walker. The same rows of the full chain
    give each sample's ``log_noise``; they are used only if their parameter columns reproduce
    the stored samples exactly."""
    mc = fit.get("mcmc") or {}
    nfree = len(space.free)
    if "log_noise" not in coords[nfree:] or "burn_in" not in mc or "thin" not in mc:
        return None
    burn, thin = int(mc["burn_in"]), int(mc["thin"])
    flat = chain[burn + thin - 1::thin].reshape(-1, chain.shape[2])
    if flat.shape[0] != samples_all.shape[0]:
        return None
    if not np.allclose(space.to_native(flat[:, :nfree]), samples_all, rtol=1e-12, atol=0.0):
        return None
    return np.exp(flat[:, coords.index("log_noise")])


def load_inputs(fit_path, data_path=None, chain_path=None, *, progress=None,
                read_options: dict | None = None) -> ReportInputs:
    """Read and cross-check the fit record, its data file and (if any) its chain file."""
    from fitlab.export.paramfile import read_fit
    from fitlab.fitting.subset import subset_mask
    from fitlab.io.fitfile import fit_parameters

    say = progress or (lambda msg: None)
    fit_path = Path(fit_path)
    record = read_fit(fit_path)
    model = get_model(record["model"]["name"])
    try:
        options = fitlab.api.resolve_options(model, record["model"].get("options"))
    except ValueError as exc:
        raise InputFileError(fit_path, str(exc), column="model.options") from None
    if not record["fits"]:
        raise InputFileError(fit_path, "holds no fitted channel", column="fits")
    for fit in record["fits"]:
        for key in ("channel", "parameters", "covariance", "statistics"):
            if key not in fit:
                raise InputFileError(fit_path, f"a fit entry lacks {key!r}", column=f"fits.{key}")
    say(f"report: reading the data of {fit_path}")
    m, data_used = load_data(record, fit_path, data_path, read_options)

    note = None
    has_mcmc = any(f.get("mcmc") for f in record["fits"])
    recorded_chain = (record.get("chain") or {}).get("path")
    if chain_path is None and recorded_chain:
        found = _resolve(recorded_chain, fit_path)
        if found is not None:
            chain_path = found
        else:
            note = (f"no chain: the fit records the chain file {recorded_chain}, which is not "
                    "there (chains are not committed; rerun the fit's command with --chain, or "
                    "give --chain FILE.npz)")
    if chain_path is None and note is None:
        note = ("no chain: the fit ran without MCMC (fitlab fit --mcmc --chain FILE.npz gives "
                "posterior bands, a corner plot and MCMC diagnostics)" if not has_mcmc else
                "no chain: the fit ran with MCMC but its chain file was not given (--chain "
                "FILE.npz); the posterior table comes from the parameter file")
    npz = None
    if chain_path is not None:
        chain_path = Path(chain_path)
        if not has_mcmc:
            raise InputFileError(chain_path, f"was given, but {fit_path} records no MCMC run",
                                 hint="give the parameter file of the --mcmc fit that wrote it")
        npz = _open_chain(chain_path)
        want = (record.get("chain") or {}).get("sha256")
        if want:
            from fitlab.io.files import sha256_of

            if sha256_of(chain_path) != want:
                raise InputFileError(chain_path, f"is not the chain written with {fit_path} (its "
                                     "SHA-256 differs from the one recorded in chain.sha256)",
                                     hint="give the chain file written together with the fit, "
                                     "or rerun the fit with --chain")

    rows_fit = (np.ones(m.n, dtype=bool) if not record["data"].get("fit_subset")
                else subset_mask(record["data"]["fit_subset"], m,
                                 source=f"{fit_path}: field data.fit_subset"))
    channels = []
    values = fit_parameters(record, source=fit_path)
    for fit in record["fits"]:
        idx = m.channel_names.index(fit["channel"])
        rows = np.flatnonzero(m.channel == idx)
        free = tuple(fit["covariance"]["parameters"])
        params = {k: float(v) for k, v in values[fit["channel"]].items() if k != SCALE}
        scale = float(values[fit["channel"]].get(SCALE, 1.0))
        try:
            fitlab.api.check_params(model, params)
        except ValueError as exc:
            raise InputFileError(fit_path, f"channel {fit['channel']}: {exc}",
                                 column="fits.parameters") from None
        samples = samples_all = chain = log_prob = noise = None
        coords = ()
        space = _space_of(fit, record)
        if npz is not None and fit.get("mcmc"):
            samples_all, chain, coords, log_prob = _channel_chain(npz, chain_path, fit, free,
                                                                  fit_path)
            idx = thin_index(samples_all.shape[0])
            samples = samples_all[idx]
            noise_all = noise_scales(chain, coords, samples_all, fit, space)
            noise = None if noise_all is None else noise_all[idx]
        fitted_values = m.value[rows][rows_fit[rows]]
        floor = 0.01 * float(np.max(np.abs(fitted_values))) if fitted_values.size else 0.0
        channels.append(ChannelInputs(fit["channel"], fit, params, scale, free, space, rows,
                                      rows_fit[rows], samples, samples_all, noise, floor, chain,
                                      coords, log_prob))
    return ReportInputs(str(fit_path), record, m, data_used,
                        None if chain_path is None else str(chain_path), note, model, options,
                        tuple(channels))


# --------------------------------------------------------------------------------------------
# Model values
# --------------------------------------------------------------------------------------------


def model_f(inputs: ReportInputs, params: dict, wi, wo) -> np.ndarray:
    """The fitted model's f (1/sr, no cosine) at direction pairs, via fitlab.api."""
    return np.asarray(eval_bsdf(inputs.model.name, params, np.asarray(wi, float),
                                np.asarray(wo, float), inputs.options))


def prediction(inputs: ReportInputs, ch: ChannelInputs, wi, wo) -> np.ndarray:
    """What the fit predicts for the data: scale · f at the best fit."""
    return ch.scale * model_f(inputs, ch.params, wi, wo)


def data_prediction(inputs: ReportInputs, ch: ChannelInputs) -> np.ndarray:
    """What the fit predicts for the channel's rows: scale · f at the best fit, averaged over
    each row's aperture as the fit did (``fits[k].aperture``, fitlab.fitting.aperture) where
    the fit records one, else at the rows' directions."""
    m = inputs.measurement
    rec = ch.fit.get("aperture")
    if not rec or not m.has_aperture:
        return prediction(inputs, ch, m.wi[ch.rows], m.wo[ch.rows])
    from fitlab.aperture import row_rule

    pick = lambda a: None if a is None else np.asarray(a)[ch.rows]  # noqa: E731
    wi, wo, w = row_rule(m.wi[ch.rows], m.wo[ch.rows], int(rec["order"]),
                         aperture_deg=pick(m.aperture_deg), bin_deg=pick(m.bin_o_deg),
                         source_divergence_deg=pick(m.source_divergence_deg))
    return ch.scale * np.sum(w * model_f(inputs, ch.params, wi, wo), axis=-1)


def sample_params(ch: ChannelInputs):
    """(params, scale) with a leading sample axis of shape (S, 1), from the thinned samples."""
    params = {k: np.full((ch.samples.shape[0], 1), v) for k, v in ch.params.items()}
    scale = np.ones((ch.samples.shape[0], 1))
    for k, name in enumerate(ch.free):
        if name == SCALE:
            scale = ch.samples[:, k:k + 1]
        else:
            params[name] = ch.samples[:, k:k + 1]
    return params, scale


def replicate_data(loss: str, model, noise, cos_o, floor: float, rng):
    """New data drawn from the fit's noise model given model values ``model`` (S, P) and noise
    scales ``noise`` (S,): the loss's residual r ~ N(0, σ_r) solved for the data value
    (``fitlab/fitting/losses.py``; the relative loss's scale |v| is taken as max(|m|, floor))."""
    eps = noise[:, None] * rng.standard_normal(np.shape(model))
    return _data_at(loss, np.asarray(model, float), eps, cos_o, floor)


def _data_at(loss: str, model, eps, cos_o, floor: float):
    """The data value whose residual under the loss's noise model is ``eps`` (decreasing in
    ``eps``; the model value itself where the loss gives a direction no weight)."""
    c = np.abs(np.asarray(cos_o, float))[None, :]
    if loss == "relative":  # r = (m − v) / max(|v|, floor)
        return model - eps * np.maximum(np.abs(model), floor)
    if loss == "log":  # r = log(1 + m c) − log(1 + v c)
        c_safe = np.where(c > 0, c, 1.0)
        return np.where(c > 0, ((1.0 + model * c) * np.exp(-eps) - 1.0) / c_safe, model)
    if loss == "cos_l2":  # r = (m − v) c
        return np.where(c > 0, model - eps / np.where(c > 0, c, 1.0), model)
    raise ValueError(f"no noise model for the loss {loss!r}")


def _residual_of(loss: str, model, y, cos_o, floor: float):
    """The inverse of :func:`_data_at`: the residual ε that gives the data value ``y`` (+inf
    where no ε reaches it from above, −inf from below)."""
    c = np.abs(np.asarray(cos_o, float))[None, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        if loss == "relative":
            return (model - y) / np.maximum(np.abs(model), floor)
        step = np.where(y >= model, -np.inf, np.inf)  # c = 0: the data value is the model's
        if loss == "log":
            inside = 1.0 + y * c > 0
            eps = np.log1p(model * c) - np.log(np.where(inside, 1.0 + y * c, 1.0))
            return np.where(c > 0, np.where(inside, eps, np.inf), step)
        if loss == "cos_l2":
            return np.where(c > 0, (model - y) * c, step)
    raise ValueError(f"no noise model for the loss {loss!r}")


#: Bisection steps of the predictive quantiles: the bracket (the data within ±9 noise scales of
#: every sample) shrinks by 2**-40, far below a pixel of any figure.
QUANTILE_STEPS = 40


def predictive_quantiles(loss: str, model, noise, cos_o, floor: float,
                         quantiles=BAND_QUANTILES) -> np.ndarray:
    """Quantiles (len(quantiles), P) of new data under the posterior predictive, exactly: at
    each direction the data are a mixture over the S samples of the loss's noise model about
    that sample's model value (``model`` (S, P), noise scales ``noise`` (S,)), and its CDF
    P(v ≤ y) = mean_s Φ(−ε_s(y)/σ_s) is inverted by bisection. No random draws: the bands
    are as smooth as the model curves, and the same on every run."""
    from scipy.special import ndtr

    model = np.asarray(model, float)
    sigma = np.asarray(noise, float)[:, None]
    lo = _data_at(loss, model, 9.0 * sigma, cos_o, floor).min(axis=0)  # every sample's data
    hi = _data_at(loss, model, -9.0 * sigma, cos_o, floor).max(axis=0)  # lie in [lo, hi]
    q = np.asarray(quantiles, float)[:, None] / 100.0
    lo, hi = np.repeat(lo[None, :], len(q), 0), np.repeat(hi[None, :], len(q), 0)
    for _ in range(QUANTILE_STEPS):
        mid = 0.5 * (lo + hi)
        cdf = np.stack([np.mean(ndtr(-_residual_of(loss, model, m[None, :], cos_o, floor)
                                     / sigma), axis=0) for m in mid])
        below = cdf < q
        lo, hi = np.where(below, mid, lo), np.where(below, hi, mid)
    return 0.5 * (lo + hi)


def predictive_band(inputs: ReportInputs, ch: ChannelInputs, wi, wo, *, with_noise=False):
    """Quantiles BAND_QUANTILES (5, P) over the posterior samples at P direction pairs: of the
    model scale · f (evaluated at every thinned sample in one broadcast (S, P) call), or with
    ``with_noise`` of new data (the model plus the fit's sampled noise: the posterior
    predictive, :func:`predictive_quantiles`). None without a chain, or with ``with_noise`` when
    no noise scale was sampled."""
    if ch.samples is None or (with_noise and ch.noise is None):
        return None
    params, scale = sample_params(ch)
    wi = np.asarray(wi, float)[None, ...]
    wo = np.asarray(wo, float)[None, ...]
    vals = scale * model_f(inputs, params, wi, wo)
    if with_noise:
        return predictive_quantiles(inputs.record["loss"], vals, ch.noise, wo[0, :, 2],
                                    ch.noise_floor)
    return np.percentile(vals, BAND_QUANTILES, axis=0)
