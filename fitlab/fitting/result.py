"""``FitResult``: an immutable view of one fit (a parameter file and, where sampled, its MCMC
chain), as ``fitlab.fit`` returns it and ``fitlab.load_fit`` reads it back.

Everything in it is what the parameter file holds (data_formats/fit_json.md): the record is the
single source, so a result made in memory and one loaded from its file answer alike.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType

import numpy as np

from fitlab.fitting.space import SCALE
from fitlab.fitting.status import Status, channel_statuses, trusted


def _freeze(obj):
    """A read-only deep copy of a JSON-like record: dicts become mapping proxies, lists tuples."""
    if isinstance(obj, dict):
        return MappingProxyType({k: _freeze(v) for k, v in obj.items()})
    if isinstance(obj, (list, tuple)):
        return tuple(_freeze(v) for v in obj)
    return obj


def thaw(obj):
    """A plain, mutable deep copy (dicts and lists) of a frozen record."""
    if isinstance(obj, (dict, MappingProxyType)):
        return {k: thaw(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [thaw(v) for v in obj]
    return obj


def _matrix(rows) -> np.ndarray:
    """A read-only float matrix from a record's nested lists (null entries as NaN)."""
    return _frozen(np.array([[np.nan if v is None else v for v in row] for row in rows], float))


def _frozen(a):
    a = np.array(a, copy=True)
    a.setflags(write=False)
    return a


@dataclass(frozen=True)
class FitResult:
    """One fit: the model, per channel its parameters, standard errors, covariance, posterior
    samples and diagnostics; ``predict``, ``to_json``, ``save`` and ``report``.

    ``record`` is the parameter file's content (read-only, all the way down; ``thaw(record)``
    gives a mutable copy); ``chains`` the arrays of the chain
    file (read-only; empty without MCMC); ``path`` the file it was loaded from or saved to."""

    record: MappingProxyType
    chains: MappingProxyType = field(default_factory=lambda: MappingProxyType({}))
    path: str | None = None
    measurement: object = None  # the Measurement it was fitted to, when made in memory
    #: wall-clock seconds of this run (least_squares, mcmc); not part of the record, which
    #: holds them only on request (``timings_s``) so that files stay byte-identical
    seconds: MappingProxyType = field(default_factory=lambda: MappingProxyType({}))

    @classmethod
    def from_record(cls, record: dict, chains: dict | None = None, path=None, measurement=None,
                    seconds: dict | None = None):
        return cls(_freeze(thaw(record)),
                   MappingProxyType({k: _frozen(v) for k, v in (chains or {}).items()}),
                   None if path is None else str(path), measurement,
                   MappingProxyType(dict(seconds or {})))

    def with_record(self, record: dict) -> "FitResult":
        """The same fit with another record (e.g. run times added before saving)."""
        return FitResult.from_record(record, dict(self.chains), self.path, self.measurement,
                                     dict(self.seconds))

    # ---- what was fitted --------------------------------------------------------------

    @property
    def model(self) -> str:
        """The registry name of the fitted model (``fitlab.get_model(result.model)``)."""
        return self.record["model"]["name"]

    @property
    def options(self) -> dict:
        return dict(self.record["model"].get("options", {}))

    @property
    def loss(self) -> str:
        return self.record["loss"]

    @property
    def channels(self) -> tuple[str, ...]:
        return tuple(f["channel"] for f in self.record["fits"])

    def _fit(self, channel):
        if channel is None:
            if len(self.record["fits"]) != 1:
                raise ValueError(f"this fit has channels {', '.join(self.channels)}: name one")
            return self.record["fits"][0]
        for f in self.record["fits"]:
            if f["channel"] == channel:
                return f
        raise ValueError(f"no channel {channel!r}; channels: {', '.join(self.channels)}")

    # ---- numbers ----------------------------------------------------------------------

    @property
    def parameters(self) -> dict[str, dict[str, float]]:
        """{channel: {parameter: best-fit value}} in native units (``scale`` included for
        relative data)."""
        return {f["channel"]: {k: p["value"] for k, p in f["parameters"].items()}
                for f in self.record["fits"]}

    @property
    def stderr(self) -> dict[str, dict[str, float | None]]:
        """{channel: {free parameter: least-squares standard error}}."""
        return {f["channel"]: {k: p.get("stderr") for k, p in f["parameters"].items()
                               if not p["fixed"]}
                for f in self.record["fits"]}

    @property
    def fixed(self) -> dict[str, dict[str, float]]:
        return {f["channel"]: {k: p["value"] for k, p in f["parameters"].items() if p["fixed"]}
                for f in self.record["fits"]}

    @property
    def shared(self) -> tuple[str, ...]:
        """Parameters shared by every channel (a joint fit, ``share=``); () otherwise."""
        return tuple((self.record.get("joint") or {}).get("shared", ()))

    @property
    def colour(self) -> dict | None:
        """A spectral fit's colour block (data_formats/fit_json.md, "Colour of a spectral
        fit"): its bands, the illuminant and observer, and per parameter its reduction (a
        colour's ``xyz`` and ``linear_srgb``, another parameter's ``value``); ``parameters`` is
        None, with the ``reason``, where the bands do not span 380-780 nm. None for a fit that
        is not spectral."""
        c = self.record.get("colour")
        return None if c is None else thaw(c)

    def joint_covariance(self) -> tuple[tuple[str, ...], np.ndarray] | None:
        """(coordinates, covariance) of a joint fit's whole problem: each shared parameter
        once, the others per channel as ``name[channel]``; None without shared parameters."""
        joint = self.record.get("joint")
        if not joint or not joint.get("covariance"):
            return None
        cov = joint["covariance"]
        return tuple(cov["parameters"]), _matrix(cov["matrix"])


    def covariance(self, channel: str | None = None) -> tuple[tuple[str, ...], np.ndarray]:
        """(free parameter names, covariance matrix in native units) of a channel."""
        cov = self._fit(channel)["covariance"]
        return tuple(cov["parameters"]), _matrix(cov["matrix"])

    def posterior(self, channel: str | None = None) -> dict | None:
        """{parameter: {median, p16, p84, p2_5, p97_5, mean, std}} from MCMC, or None."""
        fit = self._fit(channel)
        out = {k: dict(p["posterior"]) for k, p in fit["parameters"].items() if p.get("posterior")}
        return out or None

    def samples(self, channel: str | None = None) -> np.ndarray | None:
        """Posterior samples (n, free parameters) in native units, or None without a chain."""
        tag = self._fit(channel)["channel"]
        return self.chains.get(f"samples_{tag}")

    def statistics(self, channel: str | None = None) -> dict:
        """Goodness of fit: cost, dof, χ²/dof (with sigma), RMS relative error, per incidence."""
        return thaw(self._fit(channel)["statistics"])

    def bootstrap(self, channel: str | None = None) -> dict | None:
        """{parameter: {std, p16, p50, p84, p2_5, p97_5}} of the block bootstrap over incidence
        directions (an uncertainty that accounts for misfit), or None where it did not run
        (older files, fewer than 3 fitted incidences, ``bootstrap=0``)."""
        fit = self._fit(channel)
        out = {k: dict(p["bootstrap"]) for k, p in fit["parameters"].items()
               if p.get("bootstrap")}
        return out or None

    def goodness(self, channel: str | None = None) -> dict | None:
        """Goodness of fit (``describes_data``, ``failed``, per-incidence χ²/dof or variance
        ratio, runs test, posterior predictive check; data_formats/fit_json.md), or None for
        files written before fitlab checked it."""
        g = self._fit(channel).get("goodness")
        return None if g is None else thaw(g)

    def diagnostics(self, channel: str | None = None) -> dict:
        """Solver, global search, starts, MCMC diagnostics and any extra diagnostics."""
        f = self._fit(channel)
        return thaw({k: f.get(k) for k in ("solver", "global_search", "starts",
                                                     "starts_disagree", "mcmc", "diagnostics",
                                                     "bootstrap")
                              if k in f})

    @property
    def warnings(self) -> dict[str, list[str]]:
        """{channel: sentences saying what did not go as planned}."""
        return {f["channel"]: list(f.get("warnings", [])) for f in self.record["fits"]}

    def statuses(self, channel: str | None = None) -> tuple[Status, ...]:
        """What limits trust in the fit of ``channel`` (``(Status.CONVERGED,)`` when nothing
        does; fitlab.fitting.status): read from the record, so a loaded fit answers alike."""
        return channel_statuses(thaw(self._fit(channel)))

    def _untrusted(self) -> list[tuple[str, Status]]:
        """(channel, status) of every status that is not ``ok``."""
        return [(f"channel {f['channel']}", s) for f in self.record["fits"]
                for s in channel_statuses(thaw(f)) if not s.ok]

    @property
    def ok(self) -> bool:
        """Whether every channel's fit can be used as it stands (every status ``ok``)."""
        return not self._untrusted()

    def raise_for_status(self) -> "FitResult":
        """This result if it is :attr:`ok`, else a :class:`fitlab.errors.FitlabError` naming
        each channel's statuses and what to do about each."""
        return trusted(self, "the fit is not to be trusted as it stands", self._untrusted())

    @property
    def notes(self) -> tuple[str, ...]:
        return tuple(self.record.get("notes", ()))

    # ---- using the fit ----------------------------------------------------------------

    def predict(self, wi, wo, channel: str | None = None, *, scaled: bool = True,
                aperture_deg=None, source_divergence_deg=None,
                aperture_order: int | None = None) -> np.ndarray:
        """The fitted model at direction pairs ``wi``, ``wo`` (arrays (..., 3), unit vectors in
        the local frame): f in 1/sr, times the fitted ``scale`` of relative data unless
        ``scaled=False`` (then the absolute model f).

        ``aperture_deg`` / ``source_divergence_deg`` (degrees, a number or one per pair): the
        cosine-weighted mean over a detector cone around ``wo`` / a source cone around ``wi``
        instead (fitlab.aperture), by the quadrature of ``aperture_order`` (default: the order
        the fit used, else fitlab.fitting.aperture.START_ORDER). For θ/φ bins, see
        :meth:`predict_measurement`."""
        from fitlab.aperture import row_rule
        from fitlab.fitting.space import model_values

        tag = self._fit(channel)["channel"]
        params = dict(self.parameters[tag])
        scale = params.pop(SCALE, 1.0)
        wi, wo = np.asarray(wi, float), np.asarray(wo, float)
        shape = np.broadcast_shapes(wi.shape, wo.shape)[:-1]
        wi, wo = (np.broadcast_to(w, shape + (3,)).reshape(-1, 3) for w in (wi, wo))
        options = tuple(sorted(self.options.items()))
        if aperture_deg is None and source_divergence_deg is None:
            f = model_values(self.model, options, params, wi, wo)
        else:
            n = wi.shape[0]
            per_row = lambda v: None if v is None else np.broadcast_to(  # noqa: E731
                np.asarray(v, float), shape).reshape(n)
            ni, no, w = row_rule(wi, wo, self._aperture_order(tag, aperture_order),
                                 aperture_deg=per_row(aperture_deg),
                                 source_divergence_deg=per_row(source_divergence_deg))
            f = np.sum(w * model_values(self.model, options, params, ni, no), axis=-1)
        return np.asarray(f).reshape(shape) * (scale if scaled else 1.0)

    def predict_measurement(self, measurement, channel: str | None = None, *,
                            scaled: bool = True, aperture_order: int | None = None) -> np.ndarray:
        """The fitted model at every row of ``measurement`` (a Measurement, e.g. from
        ``fitlab.read``), as the fit predicts that row: averaged over the row's aperture
        (detector cone or bin, source divergence) where it declares one. Each row is predicted
        with the fit of its own channel, or with ``channel``'s for every row. Returns (rows,)."""
        from fitlab.aperture import row_rule
        from fitlab.fitting.space import model_values

        m = measurement
        out = np.empty(m.n)
        options = tuple(sorted(self.options.items()))
        names = [channel] * len(m.channel_names) if channel is not None else m.channel_names
        for c, name in enumerate(names):
            rows = m.channel == c
            if not rows.any():
                continue
            tag = self._fit(name)["channel"]
            params = dict(self.parameters[tag])
            scale = params.pop(SCALE, 1.0) if scaled else 1.0
            pick = lambda a: None if a is None else np.asarray(a)[rows]  # noqa: E731
            ni, no, w = row_rule(m.wi[rows], m.wo[rows], self._aperture_order(tag, aperture_order),
                                 aperture_deg=pick(m.aperture_deg), bin_deg=pick(m.bin_o_deg),
                                 source_divergence_deg=pick(m.source_divergence_deg))
            f = model_values(self.model, options, params, ni, no)
            out[rows] = scale * np.sum(w * f, axis=-1)
        return out

    def _aperture_order(self, channel: str, order: int | None) -> int:
        from fitlab.aperture import check_order
        from fitlab.fitting.aperture import START_ORDER

        if order is not None:
            return check_order(order)
        ap = self._fit(channel).get("aperture")
        return int(ap["order"]) if ap and "order" in ap else START_ORDER

    def to_json(self) -> str:
        """The parameter file's text (data_formats/fit_json.md), exactly as ``save`` writes it."""
        from fitlab.export.paramfile import record_text

        return record_text(thaw(self.record))

    def save(self, path, chain=None) -> "FitResult":
        """Write the parameter file (and, with MCMC, the chain ``.npz`` at ``chain``) atomically;
        returns the result with its ``path`` set. Paths inside the file are stored relative to
        it."""
        from fitlab.export.paramfile import write_fit

        if chain is not None and not self.chains:
            from fitlab.errors import FitlabError

            raise FitlabError("this fit has no MCMC chain to save (fit with mcmc=True)")
        record = {k: v for k, v in thaw(self.record).items() if k != "chain"}
        if self.path is not None:  # paths in a loaded file are relative to that file
            data_path = Path(record["data"]["path"])
            if not data_path.is_absolute():
                record["data"]["path"] = str(Path(self.path).parent / data_path)
        write_fit(path, record, dict(self.chains) if chain is not None else None, chain)
        from fitlab.export.paramfile import read_fit

        return FitResult.from_record(read_fit(path), dict(self.chains), path, self.measurement,
                                     dict(self.seconds))

    def __repr__(self):
        parts = []
        for ch, params in self.parameters.items():
            err = self.stderr[ch]
            vals = ", ".join(f"{k}={v:.4g}" + (f"±{err[k]:.2g}" if err.get(k) else "")
                             for k, v in params.items())
            parts.append(f"{ch}: {vals}")
        return f"FitResult({self.model}; " + "; ".join(parts) + ")"


def load_fit(path) -> FitResult:
    """Read a parameter file (validated, data_formats/fit_json.md) and, when it names one that
    exists, its MCMC chain (checked against the recorded SHA-256)."""
    from fitlab.errors import InputFileError
    from fitlab.export.paramfile import read_fit
    from fitlab.io.files import sha256_of
    from fitlab.io.validate import read_npz

    record = read_fit(path)
    chains = {}
    if record.get("chain"):
        chain_path = Path(path).parent / record["chain"]["path"]
        if chain_path.is_file():
            want = record["chain"].get("sha256")
            if want and sha256_of(chain_path) != want:
                raise InputFileError(chain_path, f"is not the chain written with {path} (its "
                                     "SHA-256 differs from the one recorded)",
                                     hint="give the chain written together with the fit")
            chains = read_npz(chain_path, what="fitlab MCMC chain")
    return FitResult.from_record(record, chains, path)



__all__ = ["FitResult", "load_fit", "thaw"]
