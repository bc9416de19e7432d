"""``simulate(scene, samples, seed)``: the Monte Carlo estimate of a scene's BSDF per detector bin
with standard errors, the split by bounce order, the effect plan and the time taken.

The walk is Dr.Jit (walk.py) on the CPU's LLVM backend or a GPU's CUDA backend (engine.py);
every path is one lane, launched in bounded batches, and the per-path results are summed on the
host in float64 in path order, so memory stays bounded for any sample count and the same seed
gives the same numbers whatever the thread count or batch size (on one engine and device).
"""

from __future__ import annotations

import sys
import time
from typing import NamedTuple

import numpy as np

from fitlab.simulate import components, detectors, engine
from fitlab.simulate.effects import EffectPlan, derive_effects
from fitlab.simulate.scene import Scene
from fitlab.simulate.walk import LAUNCH_PATHS, ORDER_CLASSES, Detector, Stack, WalkArrays, \
    WalkConfig, run, seed_words

#: Paths per launch of the compiled walk (per-path exit slots: ~32 bytes a path).
BATCH_SIZE = LAUNCH_PATHS
#: Events per path after which a path still alive is dropped (reported as truncated).
MAX_EVENTS = 512
#: Where the walk runs: a GPU when one is usable (else the CPU), the CPU, or a GPU.
DEVICES = engine.DEVICES


class SimulationResult(NamedTuple):
    """One row per (incidence, bin or cone); channels along the last axis."""

    theta_i: np.ndarray  # degrees, (rows,)
    phi_i: np.ndarray
    theta_o: np.ndarray
    phi_o: np.ndarray
    value: np.ndarray  # (rows, C) BSDF f in 1/sr (cosine-weighted mean over the bin)
    sigma: np.ndarray  # (rows, C) standard error of value
    by_order: np.ndarray  # (4, rows, C): bounce orders 0, 1, 2, >= 3 (sum = value)
    sigma_by_order: np.ndarray
    energy: np.ndarray  # (incidences, 2, C): flux fraction leaving up (0) and down (1), tallied sides
    energy_sigma: np.ndarray
    incidences: np.ndarray  # (incidences, 2) θi, φi in degrees
    channel_names: tuple
    plan: EffectPlan
    samples: int  # paths per incidence
    seed: int
    time_s: float
    events: int  # scattering events traced in total
    truncated: int  # paths still alive after MAX_EVENTS events (dropped)
    scene: Scene
    #: The aperture each row averages over (written to the CSV, fitted by the aperture-averaged
    #: model): hemisphere bins' edges θo_lo, θo_hi, φo_lo, φo_hi (rows, 4) in degrees, or the
    #: detector cones' half-angle (rows,) in degrees.
    bin_o_deg: np.ndarray | None = None
    aperture_deg: np.ndarray | None = None

    @property
    def paths_per_s(self) -> float:
        return self.samples * len(self.incidences) / max(self.time_s, 1e-12)

    def metadata(self) -> dict:
        """Metadata lines of the output CSV (data_formats/scene_toml.md, "Output"): what made
        the numbers, no run time (``time_s`` and ``paths_per_s`` are printed only), so the same
        scene, samples, seed and batch size give the same file."""
        sides = self.scene.detector.sides
        scatter = "brdf" if sides == ("reflection",) else "btdf" if sides == ("transmission",) \
            else "bsdf"
        return {
            "scatter": scatter,
            "generator": "fitlab simulate",
            "scene": self.scene.source,
            "scene_name": self.scene.name,
            "samples": str(self.samples),
            "seed": str(self.seed),
            "effects_simulated": "; ".join(f"{k} ({v})" for k, v in self.plan.simulated),
            "effects_skipped": "; ".join(f"{k}: {v}" for k, v in self.plan.skipped) or "nothing",
            "truncated_paths": str(self.truncated),
            "region_indices": ", ".join(f"{n:g}" for n in self.scene.region_indices),
            "estimator": self.scene.detector.estimator,
            "value": ("point estimate of the BSDF at each row's exact direction by next-event "
                      "estimation (1/sr); sigma = Monte Carlo standard error"
                      if self.scene.detector.estimator == "point" else
                      "cosine-weighted mean BSDF over each bin or cone (1/sr); sigma = Monte "
                      "Carlo standard error"),
        }

    def _eta_metadata(self) -> dict:
        """eta_outside / eta_inside (which make `fitlab fit` fix a model's eta) only for a single
        dielectric interface, the one stack a one-interface model describes exactly."""
        sc = self.scene
        if not sc.media and len(sc.boundaries) == 1 and sc.boundaries[0].kind == "dielectric":
            return {"eta_outside": f"{sc.outside_index:g}", "eta_inside": f"{sc.below_index:g}"}
        return {}

    def csv_text(self, scene: str, orders: bool = False, extra: dict | None = None) -> str:
        """The result as measurement CSV text (data_formats/measurement_csv.md) with the
        metadata of :meth:`metadata`; ``scene``: the scene as the output names it (a path
        relative to the output's folder, never one of this machine); ``extra``: more metadata
        lines (a sweep's point)."""
        from fitlab.io.measurement import format_measurement_csv

        return format_measurement_csv(self.to_measurement(orders=orders),
                                      {"scatter": self.metadata()["scatter"], "scene": scene,
                                       **(extra or {})})

    def to_measurement(self, orders: bool = False):
        """The result as a :class:`fitlab.io.measurement.Measurement` (quantity bsdf). Rows with
        no tallied path (sigma 0) are left out. ``orders``: one channel per bounce-order class
        (and colour channel) instead of the total."""
        from fitlab.io.directions import degrees_to_direction
        from fitlab.io.measurement import Measurement

        if orders:
            val = np.concatenate([self.by_order[k] for k in range(len(ORDER_CLASSES))], axis=1)
            sig = np.concatenate([self.sigma_by_order[k] for k in range(len(ORDER_CLASSES))], axis=1)
            names = tuple(o if len(self.channel_names) == 1 else f"{c}_{o}"
                          for o in ORDER_CLASSES for c in self.channel_names)
        else:
            val, sig, names = self.value, self.sigma, self.channel_names
        R, C = val.shape
        keep = (sig > 0).reshape(-1)
        rep = lambda a: np.repeat(a, C)[keep]  # noqa: E731
        ti, pi_, to, po = rep(self.theta_i), rep(self.phi_i), rep(self.theta_o), rep(self.phi_o)
        aperture = {}
        if self.aperture_deg is not None:
            aperture["aperture_deg"] = rep(self.aperture_deg)
        if self.bin_o_deg is not None:
            aperture["bin_o_deg"] = np.repeat(self.bin_o_deg, C, axis=0)[keep]
        meta = self.metadata()
        meta.update(self._eta_metadata())
        meta["empty_bins"] = str(int((~keep).sum()))
        return Measurement(
            path="<simulated>", sha256="", theta_i=ti, phi_i=pi_, theta_o=to, phi_o=po,
            wi=degrees_to_direction(ti, pi_), wo=degrees_to_direction(to, po),
            value=val.reshape(-1)[keep], sigma=sig.reshape(-1)[keep],
            channel=np.tile(np.arange(C), R)[keep], channel_names=names, wavelength_nm=None,
            quantity="bsdf", file_quantity="bsdf", metadata=meta,
            lines=np.zeros(int(keep.sum()), dtype=int), **aperture)


# --------------------------------------------------------------------------------------------
# Scene → walk configuration and arrays
# --------------------------------------------------------------------------------------------


def _channel_values(values, channel=None):
    """A property's three channel values (a grey one repeated); ``channel``: that channel's
    value in all three (a per-channel walk)."""
    v = np.asarray(values, dtype=float).reshape(-1)
    v = np.repeat(v, 3) if v.size == 1 else v
    return np.full(3, v[channel]) if channel is not None else v


def _walk_setup(scene: Scene, plan: EffectPlan, channel, max_events):
    """WalkConfig and WalkArrays; ``channel``: the single channel of a per-channel walk."""
    C = 1 if channel is not None else plan.channels
    M = len(scene.media)
    R = M + 2
    idx = scene.region_indices
    thickness = np.zeros(R)
    sigma_a = np.zeros((R, 3))
    sigma_s = np.zeros(R)
    sigma_s_c = np.zeros((R, 3))
    S = np.broadcast_to(np.eye(3), (R, 3, 3)).copy()
    flake_f0 = np.ones((R, 3))
    phases = [None] * R
    phase_values = [None] * R
    for j, m in enumerate(scene.media, start=1):
        thickness[j] = m.thickness
        if m.thickness == 0:
            continue
        sigma_a[j] = _channel_values(m.sigma_a, channel)
        ss = _channel_values(m.sigma_s, channel)
        sigma_s_c[j] = ss
        sigma_s[j] = ss[0]
        if max(m.sigma_s) > 0 or max(m.sigma_a) > 0:
            phases[j] = "sggx" if m.phase.type.startswith("sggx") else m.phase.type
        if m.phase.type.startswith("sggx"):
            flake_f0[j] = _channel_values(m.phase.f0, channel)
            S[j] = components.sggx_matrix(m.phase.type[len("sggx_"):], m.phase.roughness,
                                          m.phase.orientation)
        phase_values[j] = {"g": m.phase.g, "S": S[j]}
    specs, values = [], []
    eta = np.ones(len(scene.boundaries))
    for b, bd in enumerate(scene.boundaries):
        eta[b] = idx[b + 1] / idx[b]
        aniso = bd.alpha_y is not None
        specs.append(components.BoundarySpec(bd.kind, bd.family if bd.kind != "lambertian"
                                             else "smooth", aniso))
        v = components.BoundaryValues(alpha=bd.alpha,
                                      alpha_y=bd.alpha_y if aniso else bd.alpha, eta=eta[b])
        if bd.kind == "lambertian":
            v = v._replace(albedo=tuple(_channel_values(bd.albedo, channel)))
        elif bd.kind == "conductor":
            v = v._replace(n=tuple(_channel_values(bd.n, channel) / idx[b]),
                           k=tuple(_channel_values(bd.k, channel) / idx[b]))
        values.append(v)
    det = scene.detector
    cfg = WalkConfig(
        n_media=M, boundaries=tuple(specs), region_phase=tuple(phases), channels=C,
        reflection=plan.reflection, transmission=plan.transmission,
        max_bounces=-1 if plan.max_bounces is None else plan.max_bounces,
        russian_roulette=plan.russian_roulette, volume=plan.volume,
        volume_limit=-1 if plan.volume_limit is None else plan.volume_limit,
        absorption=plan.absorption, extinction_only=plan.extinction_only, delta=plan.delta,
        end_downward_after_last_bounce=plan.end_downward_after_last_bounce,
        force_top=plan.force_top, force_bottom=plan.force_bottom, split_first=plan.split_first,
        max_events=int(max_events), detector=_walk_detector(det),
        theta_bins=det.theta_bins, phi_bins=det.phi_bins,
        flake_fresnel=bool(np.any(flake_f0 < 1.0)), **_point_sides(scene, plan))
    arr = WalkArrays(thickness, sigma_a, sigma_s, sigma_s_c, tuple(phase_values), S,
                     tuple(values), eta, flake_f0)
    return cfg, arr


def _walk_detector(det) -> str:
    if det.estimator == "point":
        return "points"
    return "bins" if det.type == "hemisphere" else "cones"


def _point_sides(scene: Scene, plan: EffectPlan) -> dict:
    """WalkConfig.point_up / point_down: the connecting boundary of each observed side."""
    if scene.detector.estimator != "point":
        return {}
    from fitlab.simulate.scene import boundary_classes

    (k_up, _), (k_down, _) = detectors.point_connections(boundary_classes(scene.boundaries))
    return {"point_up": k_up if plan.reflection else None,
            "point_down": k_down if plan.transmission else None}


def _incidence_rows(scene: Scene):
    """[(θi, φi, Rows, cone axes or None)] for every incidence of the scene."""
    det = scene.detector
    out = []
    if det.type == "measurement":
        from fitlab.io.measurement import read_measurement

        m = read_measurement(det.file)
        key = np.stack([m.theta_i, np.mod(m.phi_i, 360.0), m.theta_o, np.mod(m.phi_o, 360.0)], 1)
        key = np.unique(key, axis=0)
        for ti, pi_ in np.unique(key[:, :2], axis=0):
            sel = (key[:, 0] == ti) & (key[:, 1] == pi_)
            if det.estimator == "point":
                rows, d = detectors.point_rows(key[sel, 2], key[sel, 3])
            else:
                rows, d = detectors.measurement_rows(key[sel, 2], key[sel, 3], det.acceptance_sr)
            out.append((float(ti), float(pi_), rows, d))
        return out
    for ti, pi_ in zip(scene.theta_i, scene.phi_i):
        if det.type == "hemisphere":
            rows = detectors.hemisphere_rows(det.theta_bins, det.phi_bins, det.sides)
            if det.estimator == "point":  # at the bin centres
                out.append((ti, pi_, *detectors.point_rows(rows.theta_o, rows.phi_o)))
            else:
                out.append((ti, pi_, rows, None))
        else:
            rows, d = detectors.inplane_rows(det.theta_o, pi_, det.acceptance_sr)
            if det.estimator == "point":
                rows, d = detectors.point_rows(rows.theta_o, rows.phi_o)
            out.append((ti, pi_, rows, d))
    return out


class _Progress:
    def __init__(self, total, enabled):
        self.total, self.enabled, self.done = total, enabled, 0
        self.t0 = self.last = time.perf_counter()

    def add(self, n, what):
        self.done += n
        now = time.perf_counter()
        if self.enabled and (now - self.last > 0.5 or self.done == self.total):
            self.last = now
            rate = self.done / max(now - self.t0, 1e-9)
            tty = sys.stderr.isatty()
            lead = "\r" if tty else ""
            print(f"{lead}simulate: {what}: {self.done}/{self.total} paths "
                  f"({rate:,.0f} paths/s)", end="" if tty and self.done < self.total else "\n",
                  file=sys.stderr, flush=True)


def simulate(scene: Scene, samples: int, seed: int = 0, *, batch_size: int = BATCH_SIZE,
             max_events: int = MAX_EVENTS, progress: bool = False,
             device: str = "auto") -> SimulationResult:
    """Trace ``samples`` paths per incident direction of ``scene`` and estimate the BSDF of every
    detector bin (data_formats/scene_toml.md).

    Parameters: ``seed`` fixes every random number (the same seed gives the same numbers on one
    engine and device, whatever the thread count and ``batch_size``); ``batch_size``: paths per
    launch of the compiled walk (bounds the memory; point estimates launch fewer when their
    per-path sums need it); ``max_events`` caps the events of one path
    (paths still alive are dropped and counted in ``truncated``); ``progress`` prints progress
    on stderr; ``device``: ``auto``, ``cpu`` or ``gpu`` (:func:`fitlab.simulate.engine.load`).
    Paths are float32 (Mitsuba's ``llvm_ad_rgb`` / ``cuda_ad_rgb``), tallies float64. Returns a
    :class:`SimulationResult`.
    """
    if samples < 2:
        raise ValueError("samples must be at least 2 (a standard error needs two paths)")
    if batch_size < 1:
        raise ValueError("batch_size must be a positive number of paths")
    engine.load(device)
    return _simulate(scene, samples, seed, batch_size, max_events, progress)


def _simulate(scene, samples, seed, batch_size, max_events, progress):
    plan = derive_effects(scene)
    t0 = time.perf_counter()
    incid = _incidence_rows(scene)
    channel_walks = list(range(plan.channels)) if plan.walk_per_channel else [plan.channel_pick]
    stacks = [Stack(*_walk_setup(scene, plan, c, max_events)) for c in channel_walks]
    C = plan.channels
    prog = _Progress(samples * len(incid) * len(channel_walks), progress)
    all_rows = []
    energy = np.zeros((len(incid), 2, C))
    energy_sig = np.zeros((len(incid), 2, C))
    events = truncated = 0
    for ii, (ti, pi_, rows, axes) in enumerate(incid):
        n_out = (2 * scene.detector.theta_bins * scene.detector.phi_bins
                 if axes is None else len(rows.tally))
        n_up = 0
        if axes is None:
            det = Detector(np.zeros((1, 3)), np.full((1,), 2.0))
        elif scene.detector.estimator == "point":
            # the walk takes the reflection rows first; tally maps each row to its position
            walk_order = np.argsort(axes[:, 2] <= 0, kind="stable")
            n_up = int(np.sum(axes[:, 2] > 0))
            rows = rows._replace(tally=np.argsort(walk_order, kind="stable"))
            det = Detector(np.asarray(axes[walk_order], dtype=np.float64),
                           np.zeros((len(axes),)))
        else:
            det = Detector(np.asarray(axes, dtype=np.float64),
                           np.full((len(axes),), detectors.cone_half_angle_cos(
                               scene.detector.acceptance_sr)))
        wi = detectors.direction(ti, pi_)
        S1 = np.zeros((len(ORDER_CLASSES), n_out, C))
        S2 = np.zeros((len(ORDER_CLASSES) + 1, n_out, C))  # per order, and the paths' totals
        E1 = np.zeros((2, 2, C))
        # splitting at the first interface: the reflected branches' sums (bins, per side)
        Q1, Q2, F1 = np.zeros((n_out, C)), np.zeros((n_out, C)), np.zeros((2, 2, C))
        for ci, stack in enumerate(stacks):
            sl = slice(None) if len(stacks) == 1 else slice(ci, ci + 1)
            t = run(stack, det, wi, samples, seed_words(seed, ii), n_out, n_up,
                    launch=batch_size, on_launch=lambda n, ti=ti: prog.add(n, f"θi = {ti:g}°"))
            S1[..., sl] += t.s1
            S2[..., sl] += t.s2
            E1[..., sl] += t.side
            if t.split is not None:
                Q1[..., sl] += t.split[0]
                Q2[..., sl] += t.split[1]
                F1[..., sl] += t.split[2]
            truncated += t.truncated
            events += t.events
        N = float(samples)
        # the split-off reflections are order 0, where the walk itself leaves no reflection
        # (every path that returns has bounced), and independent of the walk: their
        # variance adds to the all-order total's
        S1[0] += Q1
        S2[0] += Q2
        q_var = np.maximum(Q2 / N - (Q1 / N) ** 2, 0.0) / (N - 1.0)
        mean = S1 / N
        var = np.maximum(S2[:-1] / N - mean * mean, 0.0) / (N - 1.0)
        cw = rows.cos_solid_angle[None, :, None]
        by_order = mean[:, rows.tally] / cw
        sig_order = np.sqrt(var[:, rows.tally]) / cw
        tot_walk = (S1.sum(0) - Q1) / N
        tot = S1.sum(0) / N
        tot_var = np.maximum(S2[-1] / N - tot_walk * tot_walk, 0.0) / (N - 1.0) + q_var
        value = tot[rows.tally] / cw[0]
        sigma = np.sqrt(tot_var[rows.tally]) / cw[0]
        if scene.detector.estimator == "point":
            # a value every path gives alike (one rough interface: the first event's exact
            # BSDF) has no Monte Carlo spread; it is known to the paths' float32 rounding
            floor = float(np.finfo(np.float32).eps)
            sigma = np.maximum(sigma, floor * np.abs(value))
            sig_order = np.maximum(sig_order, floor * np.abs(by_order))
        all_rows.append((ti, pi_, rows, value, sigma, by_order, sig_order))
        energy[ii] = (E1[0] + F1[0]) / N
        energy_sig[ii] = np.sqrt(sum(np.maximum(e[1] / N - (e[0] / N) ** 2, 0.0)
                                     for e in (E1, F1)) / (N - 1.0))
    elapsed = time.perf_counter() - t0
    cat = lambda f: np.concatenate([f(r) for r in all_rows])  # noqa: E731
    return SimulationResult(
        theta_i=cat(lambda r: np.full(len(r[2].tally), r[0])),
        phi_i=cat(lambda r: np.full(len(r[2].tally), r[1])),
        theta_o=cat(lambda r: r[2].theta_o), phi_o=cat(lambda r: r[2].phi_o),
        value=cat(lambda r: r[3]), sigma=cat(lambda r: r[4]),
        by_order=np.concatenate([r[5] for r in all_rows], axis=1),
        sigma_by_order=np.concatenate([r[6] for r in all_rows], axis=1),
        energy=energy, energy_sigma=energy_sig,
        incidences=np.array([[r[0], r[1]] for r in all_rows]),
        channel_names=plan.channel_names, plan=plan, samples=int(samples), seed=int(seed),
        time_s=elapsed, events=events, truncated=truncated, scene=scene,
        bin_o_deg=(cat(lambda r: r[2].edges) if scene.detector.type == "hemisphere"
                   and scene.detector.estimator != "point" else None),
        aperture_deg=(None if scene.detector.type == "hemisphere"
                      and scene.detector.estimator != "point" else np.full(
            sum(len(r[2].tally) for r in all_rows),
            0.0 if scene.detector.estimator == "point"
            else detectors.cone_half_angle_deg(scene.detector.acceptance_sr))))
