"""The instrument's own floor under the real-data fits (issue 14, item 7).

A model's RMS relative error cannot go below what the instrument repeats to. This script
measures that floor, file by file, with fitlab's readers (``fitlab.read``: the same directions,
units, mirroring and masking as every fit), and prints tables.

Mirror pairs (RGL tensor files, pab pgII scans). An isotropic material scatters the same into
wo and into its mirror image wo' about the plane of incidence (wo' = wo − 2 (wo·e) e, e the
in-surface direction perpendicular to the incidence's azimuth). Each row on one side (wo·e > 0)
is paired with the value at its mirror direction, linearly interpolated (Delaunay triangulation
of the other side's rows in the projected disk (wo_x, wo_y)) when the nearest row on the other
side is within ``--tol`` degrees; on a grid that contains the mirror direction (the RGL reads)
the interpolation returns that grid value exactly. Pair difference d = (a − b) / ((a + b)/2),
counted where both are ≥ 1% of the channel's maximum (the fit statistics' floor). Two floors
follow: RMS(d)/2 is the RMS relative error that any mirror-symmetric (isotropic) model must leave
on these rows (it can at best predict the pair's mean), and RMS(d)/√2 is the per-row noise if
the two readings' errors are independent.

Normal incidence rings (RGL film). At θi = 0 an isotropic BRDF depends on θo alone, so the
readings on a ring of fixed θo repeat one value. Per ring, the best constant in the relative
sense, c = Σ f⁻¹ / Σ f⁻², leaves the least RMS relative error any isotropic model can leave
there; pooled over the rows a statistic counts it is the isotropic-model floor at θi = 0.

Brown vinyl (Zemax, PlaneSymmetrical): the file stores azimuths 0–180° only (fitlab mirrors
them), so there are no mirrored readings, and radial 0 is one value repeated for every azimuth
(a repeat of the number, not a repeated measurement). What can be measured:

* smoothness noise: second differences along the azimuth (10° steps) at fixed radial,
  σ ≈ RMS(Δ²f / f)/√6 (white noise; real curvature adds, so an upper bound); with ``--fit`` the
  fitted model's own second differences are subtracted first (curvature the model explains);
* the edge of the instrument's view: the last measured reading along each azimuth (the next one
  is a stored zero or below the horizon) against the trend of the two before it, by θo;
* TIS: ∫ f cos θo dω over the file's grid against each block's TIS line, the grid's coverage,
  and (with ``--fit``) the grid integral completed by the model outside the grid;
* neighbouring incidences: each block's reading against the mean of the two neighbouring blocks
  interpolated (bilinear in the file's radial × azimuth grid) at the same outgoing direction,
  over directions ≥ 30° from every block's specular direction (where f varies slowly with θi);
  a scale offset between alternate blocks would show as ratios alternating about 1;
* the specular excess E(θi) = f(radial 0) − (2 f̄(radial 5) − f̄(radial 10)) (ring means) and the
  Fresnel ratio a single microfacet lobe of fixed width would need between the smallest and the
  largest incidence, against the largest ratio a Fresnel factor of index n ≥ 1 can give;

``--errors FIT DATA`` (with ``--rows EXPR``, repeatable) prints a fit's RMS relative error per
incidence and pooled on row subsets (each incidence's rows ≥ 1% of its maximum, as `fitlab
compare` counts them), e.g. on the rows of an earlier fit subset.

    .venv/bin/python benchmarks/instrument_floor.py                      # every file found
    .venv/bin/python benchmarks/instrument_floor.py --only vinyl --fit fits/X.json
    .venv/bin/python benchmarks/instrument_floor.py --errors fits/X.json DATA \\
        --rows 'value > 0.01' --rows 'value > 0.01 and theta_o < 83'

The RGL and pgII files are read from ``../shared/data`` (not part of the project); a file that
is absent is skipped with a note.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
VINYL = ROOT / "data_formats" / "examples" / "zemax_brown_vinyl.bsdf"
SHARED = ROOT.parent / "shared" / "data"
FILM = SHARED / "rgl_epfl_via_fzy28" / "aurora_white_rgb.bsdf"
PGII = SHARED / "tekari_pgII" / "golden_glossy_paper_pgII_theta26.84.txt"
FLOOR = 0.01  # rows below this fraction of the maximum are not counted (fit statistics' rule)


def rms(x) -> float:
    x = np.asarray(x, float)
    return float(np.sqrt(np.mean(x * x))) if x.size else float("nan")


def table(header, rows):
    """A Markdown table (paste-ready for fits/README.md)."""
    out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    out += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return "\n".join(out)


def f3(x, digits=3):
    if x is None or not np.isfinite(x):
        return "—"
    return f"{x:.{digits}f}" if x == 0 or abs(x) >= 10 ** -digits else f"{x:.1e}"


# ----------------------------------------------------------------------------------------------
# Mirror pairs
# ----------------------------------------------------------------------------------------------


def mirror_differences(m, channel: int, tol_deg: float, delta_phi_deg: float = 0.0,
                       per_incidence_floor: bool = True, max_theta_o: float = 89.0,
                       floor_abs: float | None = None):
    """Per incidence: the pair differences d = (a − b)/((a + b)/2) of the channel's rows with
    wo·e > 0 against the interpolated value at their mirror direction (see the module text),
    where both are ≥ 1% of the incidence's maximum (``per_incidence_floor``, as `fitlab compare`
    counts rows) or of the channel's maximum (as a parameter file's overall RMS relative error
    counts them). ``delta_phi_deg`` turns the mirror plane about the normal (an alignment
    scan). ``floor_abs``: count pairs whose readings are both above this value instead. Rows at
    θo ≥ ``max_theta_o`` are left out: a detector reading divided by cos θo
    (pgII scans) turns the detector's noise there into arbitrarily large values."""
    from scipy.interpolate import LinearNDInterpolator
    from scipy.spatial import cKDTree

    in_chan = (m.channel == channel) & (m.theta_o < max_theta_o)
    vmax = float(np.max(np.abs(m.value[in_chan])))
    out = []
    keys = np.stack([m.theta_i, np.mod(m.phi_i, 360.0)], axis=1)
    for ti, pi in np.unique(keys[in_chan], axis=0):
        sel = in_chan & (keys[:, 0] == ti) & (keys[:, 1] == pi)
        phi = math.radians(pi + delta_phi_deg)
        e = np.array([-math.sin(phi), math.cos(phi), 0.0])
        wo, v = m.wo[sel], m.value[sel]
        side = wo @ e
        a_side, b_side = side > 1e-9, side < -1e-9
        if a_side.sum() < 3 or b_side.sum() < 3:
            continue
        wa = wo[a_side]
        mir = wa - 2.0 * (wa @ e)[:, None] * e[None, :]
        wb, vb = wo[b_side], v[b_side]
        near, _ = cKDTree(wb).query(mir, k=1)
        interp = LinearNDInterpolator(wb[:, :2], vb)
        b = interp(mir[:, :2])
        a = v[a_side]
        ok = (np.degrees(near) <= tol_deg) & np.isfinite(b)
        top = float(np.max(np.abs(v))) if per_incidence_floor else vmax
        lim = FLOOR * top if floor_abs is None else floor_abs
        ok &= (np.abs(a) >= lim) & (np.abs(b) >= lim)
        d = (a[ok] - b[ok]) / (0.5 * (a[ok] + b[ok]))
        out.append({"theta_i": float(ti), "phi_i": float(pi), "pairs": int(ok.sum()),
                    "rows_one_side": int(a_side.sum()), "d": d})
    return out


def report_mirror(name, m, tol_deg, channels=None, scan=None):
    chans = range(len(m.channel_names)) if channels is None else channels
    print(f"\n## {name}: mirror pairs (tolerance {tol_deg:g} deg; both readings >= 1% of the "
          "incidence's max, as `fitlab compare` counts rows; 'all, channel floor': >= 1% of the "
          "channel's max, as a parameter file's overall error counts them)\n")
    rows = []
    for c in chans:
        res = mirror_differences(m, c, tol_deg)
        all_d = np.concatenate([r["d"] for r in res]) if res else np.zeros(0)
        res_c = mirror_differences(m, c, tol_deg, per_incidence_floor=False)
        all_c = np.concatenate([r["d"] for r in res_c]) if res_c else np.zeros(0)
        for r in res:
            rows.append([m.channel_names[c], f"{r['theta_i']:.2f}", r["pairs"],
                         f3(rms(r["d"])), f3(float(np.median(np.abs(r["d"])))) if r["pairs"]
                         else "—", f3(rms(r["d"]) / 2), f3(rms(r["d"]) / math.sqrt(2))])
        rows.append([m.channel_names[c], "all", all_d.size, f3(rms(all_d)),
                     f3(float(np.median(np.abs(all_d)))) if all_d.size else "—",
                     f3(rms(all_d) / 2), f3(rms(all_d) / math.sqrt(2))])
        rows.append([m.channel_names[c], "all, channel floor", all_c.size, f3(rms(all_c)),
                     f3(float(np.median(np.abs(all_c)))) if all_c.size else "—",
                     f3(rms(all_c) / 2), f3(rms(all_c) / math.sqrt(2))])
    print(table(["channel", "θi", "pairs", "RMS d", "median |d|",
                 "floor of an isotropic model RMS(d)/2", "noise if independent RMS(d)/√2"],
                rows))
    if scan:
        print(f"\nMirror plane turned by δ about the normal (channel {m.channel_names[chans[0]]}),"
              " all incidences pooled:\n")
        srows, best = [], None
        for delta in scan:
            res = mirror_differences(m, chans[0], tol_deg, delta)
            d = np.concatenate([r["d"] for r in res])
            srows.append([f"{delta:+.2f}", d.size, f3(rms(d)), f3(float(np.mean(d)), 4)])
            if best is None or rms(d) < best[1]:
                best = (delta, rms(d), d.size)
        print(table(["δ (deg)", "pairs", "RMS d", "mean d"], srows))
        print(f"\nsmallest asymmetry at δ = {best[0]:+.2f} deg: RMS d {best[1]:.3f} over "
              f"{best[2]} pairs (floor of an isotropic model there {best[1] / 2:.3f}, noise if "
              f"independent {best[1] / math.sqrt(2):.3f})")
        return best


def pgii_refit(m, model, delta_deg):
    """Fit ``model`` to every 10th row as read (φi = 0) and with the light's azimuth turned to
    ``delta_deg`` (the scan's mirror plane); print both fits' RMS relative errors over the fitted
    rows and over the other rows (each counted ≥ 1% of the maximum of all rows, as a parameter
    file counts them, and with the rows at θo ≥ 89° left out)."""
    import fitlab
    from fitlab.io.directions import degrees_to_direction

    turned = m._replace(
        wi=np.broadcast_to(degrees_to_direction(m.theta_i[0], delta_deg), m.wi.shape).copy(),
        phi_i=np.full(m.n, delta_deg % 360.0))
    fit_rows = np.arange(m.n) % 10 == 0
    other = ~fit_rows
    lim = FLOOR * float(np.max(np.abs(m.value)))
    ok = m.theta_o < 89.0
    print(f"\n### pgII: {model} fitted to every 10th row, light azimuth as read and turned\n")
    rows = []
    for label, mm in (("as read (φi = 0)", m), (f"turned (φi = {delta_deg:+.2f}°)", turned)):
        t0 = time.perf_counter()
        r = fitlab.fit(mm, model, subset=fit_rows, bootstrap=0)
        pred = r.predict_measurement(mm)
        rel = (pred - mm.value) / mm.value
        count = np.abs(mm.value) >= lim
        rows.append([label, f3(rms(rel[fit_rows & count])), f3(rms(rel[other & count])),
                     f3(rms(rel[other & count & ok])),
                     ", ".join(f"{k} {v:.4g}" for k, v in r.parameters["Y"].items()),
                     f"{time.perf_counter() - t0:.0f} s"])
    print(table(["light azimuth", "fitted rows", "other rows", "other rows, θo < 89°",
                 "parameters", "time"], rows))


def film_peak_sensitivity(path, shift_deg=0.5):
    """The rows a parameter file's overall RMS relative error counts (≥ 1% of the channel's
    maximum) and how much the file's own BRDF changes when the outgoing direction moves by
    ``shift_deg`` (θo ± shift; φo + 2 shift, an arc of 2 shift sin θo): the error that an
    angular registration uncertainty of that size alone would leave on those rows."""
    from fitlab.io.rgl import read_rgl

    base = read_rgl(path)

    def at(dt=0.0, dp=0.0):
        th = sorted({float(t) for t in base.theta_o if 0.0 <= t + dt < 90.0})
        ph = sorted({float(p) for p in base.phi_o})
        mm = read_rgl(path, theta_o=[t + dt for t in th], phi_o=[(p + dp) % 360 for p in ph])
        key = {(c, round(ti, 6), round(to - dt, 6), round((po - dp) % 360, 6)): v
               for c, ti, to, po, v in zip(mm.channel, mm.theta_i, mm.theta_o, mm.phi_o,
                                           mm.value)}
        return np.array([key.get((c, round(ti, 6), round(to, 6), round(po % 360, 6)), np.nan)
                         for c, ti, to, po in zip(base.channel, base.theta_i, base.theta_o,
                                                  base.phi_o)])

    shifted = {"θo +": at(dt=shift_deg), "θo −": at(dt=-shift_deg)}
    shifted[f"φo + {2 * shift_deg:g}°"] = at(dp=2 * shift_deg)  # an arc of 2 shift sin θo
    rows = []
    for c, name in enumerate(base.channel_names):
        sel = base.channel == c
        top = float(np.max(base.value[sel]))
        counted = sel & (base.value >= FLOOR * top)
        for i in np.nonzero(counted)[0]:
            rows.append([name, f"{base.theta_i[i]:.2f}", f"{base.theta_o[i]:g}",
                         f"{base.phi_o[i]:g}", f"{base.value[i]:.4g}"]
                        + [f"{v[i] / base.value[i] - 1:+.2f}" for v in shifted.values()])
    return rows, list(shifted)


def normal_incidence_rings(m, channel: int):
    """At normal incidence an isotropic BRDF depends on θo alone, so every reading on a ring of
    fixed θo measures the same value. Per ring: the constant c that minimises the rows' squared
    relative error Σ ((c − f)/f)² (c = Σ f⁻¹ / Σ f⁻²; the best any isotropic model can
    predict there), the ring's max/min and the RMS relative error c leaves. Returns the ring
    table and the relative errors with the rows' values, for pooling over the counted rows."""
    sel = (m.channel == channel) & (np.abs(m.theta_i) < 1e-9)
    theta_o, v = m.theta_o[sel], m.value[sel]
    rings, rel, vals = [], [], []
    for to in np.unique(np.round(theta_o, 6)):
        f = v[np.abs(theta_o - to) < 1e-6]
        if f.size < 2 or np.any(f <= 0):
            continue
        c = float(np.sum(1.0 / f) / np.sum(1.0 / f ** 2))
        r = c / f - 1.0
        rings.append((float(to), f.size, float(np.max(f) / np.min(f)), rms(r), float(np.mean(f))))
        rel.append(r)
        vals.append(f)
    return rings, np.concatenate(rel), np.concatenate(vals), float(np.max(v))


def report_normal_incidence(m, channels=None):
    chans = range(len(m.channel_names)) if channels is None else channels
    print("\n### Normal incidence: the readings around each ring of fixed θo (an isotropic model "
          "predicts one value per ring)\n")
    pooled, ring_rows = [], []
    for c in chans:
        rings, rel, vals, vmax_i = normal_incidence_rings(m, c)
        vmax_c = float(np.max(m.value[m.channel == c]))
        inc, chan = vals >= FLOOR * vmax_i, vals >= FLOOR * vmax_c
        pooled.append([m.channel_names[c], int(inc.sum()), f3(rms(rel[inc])),
                       int(chan.sum()), f3(rms(rel[chan]) if chan.any() else float("nan"))])
        for to, n, ratio, e, mean in rings:
            if c == chans[0]:
                ring_rows.append([m.channel_names[c], f"{to:g}", n, f"{mean:.4g}",
                                  f"{ratio:.3f}", f3(e)])
    print(table(["channel", "θo", "readings", "mean f (1/sr)", "max/min", "RMS relative error "
                 "of the best constant"], ring_rows))
    print("\nPooled over the rows a statistic counts (the isotropic-model floor at θi = 0):\n")
    print(table(["channel", "rows >= 1% of the incidence max (compare)", "floor",
                 "rows >= 1% of the channel max (overall)", "floor"], pooled))


# ----------------------------------------------------------------------------------------------
# Brown vinyl (Zemax)
# ----------------------------------------------------------------------------------------------


def vinyl_grid(path):
    """The parsed file, its stored table (aoi, azimuth, radial), the outgoing directions and θo
    of every grid node (degrees), each block's light direction, and which nodes hold a
    measurement (nonzero, above the horizon): the reader's own geometry."""
    from fitlab.io.zemax import parse_zemax, scatter_directions, scatter_frame

    zf = parse_zemax(path)
    if zf.values.shape[:2] != (1, 1):
        raise SystemExit(f"{path}: one channel and one sample rotation expected")
    v = zf.values[0, 0]  # (aoi, azimuth, radial)
    frame = scatter_frame(zf.aoi[:, None, None], np.full((len(zf.aoi), 1, 1), zf.rotation[0]),
                          zf.scatter)
    wo = scatter_directions(frame, zf.radial[None, None, :], zf.azimuth[None, :, None])
    theta_o = np.degrees(np.arccos(np.clip(wo[..., 2], -1.0, 1.0)))
    measured = (v > 0) & (wo[..., 2] > 1e-9)
    return zf, v, wo, theta_o, measured


def model_on_grid(fit, zf, wo):
    """The fitted model (scale included) at every grid node of every block."""
    from fitlab.io.directions import degrees_to_direction

    out = np.empty(wo.shape[:-1])
    for k, aoi in enumerate(zf.aoi):
        wi = degrees_to_direction(aoi, zf.rotation[0])
        w = wo[k].reshape(-1, 3)
        out[k] = np.asarray(fit.predict(np.broadcast_to(wi, w.shape), w)).reshape(out[k].shape)
    return out


def vinyl_noise(zf, v, measured, floor_mask, theta_o, model=None, max_theta_o=83.0):
    """σ ≈ RMS(Δ²f/f)/√6 along the azimuth per AOI (radial ≥ 5°: radial 0 is one value), over
    triples of measured readings ≥ 1% of the block max and below ``max_theta_o`` (the edge of
    the view, see vinyl_edge); also the robust σ = 1.4826 MAD(Δ²f/f)/√6 and the number of
    readings more than 5 robust σ off their neighbours (isolated glitches)."""
    rows = []
    for k, aoi in enumerate(zf.aoi):
        num, num_m = [], []
        for j in range(1, v.shape[1] - 1):
            for r in range(1, v.shape[2]):
                trip = [(k, j - 1, r), (k, j, r), (k, j + 1, r)]
                if not all(measured[t] and floor_mask[t] and theta_o[t] < max_theta_o
                           for t in trip):
                    continue
                d2 = v[k, j - 1, r] - 2 * v[k, j, r] + v[k, j + 1, r]
                num.append(d2 / v[k, j, r])
                if model is not None:
                    dm = model[k, j - 1, r] - 2 * model[k, j, r] + model[k, j + 1, r]
                    num_m.append((d2 - dm) / v[k, j, r])
        x = np.asarray(num)
        robust = 1.4826 * float(np.median(np.abs(x - np.median(x)))) / math.sqrt(6)
        glitches = int(np.sum(np.abs(x) / math.sqrt(6) > 5 * robust))
        xm = np.asarray(num_m)
        robust_m = (1.4826 * float(np.median(np.abs(xm - np.median(xm)))) / math.sqrt(6)
                    if model is not None else None)
        rows.append([f"{aoi:g}", len(num), f3(rms(x) / math.sqrt(6)), f3(robust), glitches,
                     f3(rms(xm) / math.sqrt(6)) if model is not None else "—",
                     f3(robust_m) if model is not None else "—"])
    return rows


def vinyl_edge(zf, v, measured, theta_o):
    """The last measured reading along each azimuth against the trend before it, by its θo."""
    recs = []
    for k in range(len(zf.aoi)):
        for j in range(v.shape[1]):
            idx = np.nonzero(measured[k, j])[0]
            if idx.size < 3:
                continue
            last = idx.max()
            if last < 2 or not (measured[k, j, last - 1] and measured[k, j, last - 2]):
                continue
            drop = (v[k, j, last] / v[k, j, last - 1]) / (v[k, j, last - 1] / v[k, j, last - 2])
            recs.append((theta_o[k, j, last], drop, last == v.shape[2] - 1))
    recs = np.array(recs)
    rows = []
    for lo, hi in ((0, 80), (80, 82), (82, 83), (83, 84), (84, 90)):
        s = (recs[:, 0] >= lo) & (recs[:, 0] < hi)
        x = recs[s, 1]
        rows.append([f"{lo}–{hi}°", int(s.sum()),
                     f3(float(np.median(x))) if x.size else "—",
                     f3(float(np.min(x))) if x.size else "—",
                     int(np.sum(x < 0.6))])
    return rows


def vinyl_tis(zf, v, wo, measured, model=None, fit=None):
    """Grid integral vs TIS; with a model, the part of ∫ f cos dω outside the grid from the
    model (hemisphere integral − the model's own grid integral with the same masking)."""
    from fitlab.io.directions import degrees_to_direction
    from fitlab.io.zemax import cell_weights

    weights = cell_weights(zf.radial, zf.azimuth)  # stored azimuths 0..180: a half circle ...
    weights = weights * 2.0  # ... its mirror image is the other half (PlaneSymmetrical; the
    # cells of the in-plane azimuths 0 and 180 are half cells, ±5° together with their images)
    cos = np.clip(wo[..., 2], 0.0, None)
    rows = []
    if model is not None:  # hemisphere quadrature: Gauss-Legendre in cos θ x uniform φ
        x, w = np.polynomial.legendre.leggauss(96)
        mu = 0.5 * (x + 1.0)
        wmu = 0.5 * w
        phis = (np.arange(192) + 0.5) * 2 * np.pi / 192
        st = np.sqrt(1 - mu**2)
        hemi = np.stack([np.outer(st, np.cos(phis)), np.outer(st, np.sin(phis)),
                         np.outer(mu, np.ones_like(phis))], axis=-1).reshape(-1, 3)
        hw = (np.outer(wmu * mu, np.full(phis.size, 2 * np.pi / phis.size))).reshape(-1)
    for k, aoi in enumerate(zf.aoi):
        data_int = float(np.sum(np.where(measured[k], v[k], 0.0) * cos[k] * weights))
        cover = float(np.sum(np.where(wo[k][..., 2] > 1e-9, cos[k], 0.0) * weights) / np.pi)
        tis = float(zf.tis[0, 0, k])
        row = [f"{aoi:g}", f"{tis:.4f}", f"{data_int:.4f}", f"{data_int / tis - 1:+.1%}",
               f"{cover:.3f}"]
        if model is not None:
            wi = degrees_to_direction(aoi, zf.rotation[0])
            f_h = np.asarray(fit.predict(np.broadcast_to(wi, hemi.shape), hemi)).reshape(-1)
            full = float(np.sum(f_h * hw))
            grid = float(np.sum(np.where(measured[k], model[k], 0.0) * cos[k] * weights))
            done = data_int + (full - grid)
            row += [f"{full - grid:.4f}", f"{done:.4f}", f"{done / tis - 1:+.1%}",
                    f"{full:.4f}"]
        rows.append(row)
    return rows


def _interp_block(zf, v, measured, k, wo):
    """Block k's reading at directions wo (N, 3): bilinear in (azimuth folded to 0..180,
    radial) of block k's own pole frame; NaN where a corner is not measured or wo is off the
    grid."""
    from fitlab.io.zemax import scatter_frame

    frame = scatter_frame(zf.aoi[k], zf.rotation[0], zf.scatter)  # columns e0, e90, s
    local = wo @ frame
    radial = np.degrees(np.arccos(np.clip(local[:, 2], -1.0, 1.0)))
    az = np.degrees(np.arctan2(local[:, 1], local[:, 0]))
    az = np.abs(az)  # PlaneSymmetrical: a and 360 - a are one reading
    A, R = zf.azimuth, zf.radial
    out = np.full(wo.shape[0], np.nan)
    ja = np.searchsorted(A, az, side="right") - 1
    jr = np.searchsorted(R, radial, side="right") - 1
    ok = (ja >= 0) & (ja < len(A) - 1) & (jr >= 0) & (jr < len(R) - 1)
    for i in np.nonzero(ok)[0]:
        a0, r0 = ja[i], jr[i]
        corners = [(a0, r0), (a0 + 1, r0), (a0, r0 + 1), (a0 + 1, r0 + 1)]
        if not all(measured[k][c] for c in corners):
            continue
        ta = (az[i] - A[a0]) / (A[a0 + 1] - A[a0])
        tr = (radial[i] - R[r0]) / (R[r0 + 1] - R[r0])
        out[i] = ((1 - ta) * (1 - tr) * v[k][a0, r0] + ta * (1 - tr) * v[k][a0 + 1, r0]
                  + (1 - ta) * tr * v[k][a0, r0 + 1] + ta * tr * v[k][a0 + 1, r0 + 1])
    return out


def vinyl_neighbours(zf, v, wo, measured, min_specular_deg=30.0):
    from fitlab.io.directions import degrees_to_direction

    rows = []
    for k in range(1, len(zf.aoi) - 1):
        sel = measured[k] & (np.degrees(np.arccos(np.clip(wo[k][..., 2], -1, 1))) < 80.0)
        sel[:, 0] = False  # radial 0 (the pole) is near the specular direction anyway
        w = wo[k][sel]
        f = v[k][sel]
        far = np.ones(w.shape[0], dtype=bool)
        for kk in (k - 1, k, k + 1):
            spec = degrees_to_direction(zf.aoi[kk], zf.rotation[0] + 180.0)
            far &= np.degrees(np.arccos(np.clip(w @ spec, -1, 1))) >= min_specular_deg
        lo = _interp_block(zf, v, measured, k - 1, w)
        hi = _interp_block(zf, v, measured, k + 1, w)
        ok = far & np.isfinite(lo) & np.isfinite(hi)
        q = f[ok] / (0.5 * (lo[ok] + hi[ok]))
        rows.append([f"{zf.aoi[k]:g}", int(ok.sum()),
                     f"{np.median(q) - 1:+.3f}" if q.size else "—",
                     f"[{np.percentile(q, 25) - 1:+.3f}, {np.percentile(q, 75) - 1:+.3f}]"
                     if q.size else "—"])
    return rows


def fresnel_unpolarized(cos_i, eta):
    """Exact dielectric Fresnel reflectance (Walter eq. 22) for relative index eta."""
    g2 = eta**2 - 1.0 + cos_i**2
    g = np.sqrt(np.maximum(g2, 0.0))
    a = (g - cos_i) / (g + cos_i)
    b = (cos_i * (g + cos_i) - 1.0) / (cos_i * (g - cos_i) + 1.0)
    return np.where(g2 > 0, 0.5 * a * a * (1.0 + b * b), 1.0)


def vinyl_specular(zf, v, wo, measured):
    """The reading at the pole (the specular direction) per AOI, the largest reading of the
    block, and the lobe-ratio check between the smallest and the largest incidence: a microfacet
    lobe of fixed width contributes F(θi) G1(θi)² D(0) / (4 cos² θi) at the pole; if it holds
    at most the whole pole reading at the smallest θi and at least the pole reading minus the
    block's far-field level (median of readings ≥ 30° from the specular direction) at the
    largest, its Fresnel factor must grow at least by the ratio of the two over cos² θi_lo /
    cos² θi_hi (G1 ≤ 1 only makes it larger)."""
    from fitlab.io.directions import degrees_to_direction

    rows, far = [], []
    for k, aoi in enumerate(zf.aoi):
        spec = degrees_to_direction(aoi, zf.rotation[0] + 180.0)
        ang = np.degrees(np.arccos(np.clip(wo[k] @ spec, -1, 1)))
        level = float(np.median(v[k][measured[k] & (ang >= 30.0)]))
        far.append(level)
        imax = np.unravel_index(np.argmax(np.where(measured[k], v[k], 0.0)), v[k].shape)
        rows.append([f"{aoi:g}", f"{v[k, 0, 0]:.4g}", f"{level:.4g}",
                     f"{v[k][imax]:.4g} (azimuth {zf.azimuth[imax[0]]:g}°, radial "
                     f"{zf.radial[imax[1]]:g}°)"])
    aoi = np.asarray(zf.aoi, float)
    lo, hi = 0, len(aoi) - 1
    lobe_hi = float(v[hi, 0, 0]) - far[hi]
    lobe_lo = float(v[lo, 0, 0])
    geom = (math.cos(math.radians(aoi[lo])) / math.cos(math.radians(aoi[hi]))) ** 2
    etas = 1.0 + np.logspace(-4, 1, 400)
    c_lo, c_hi = math.cos(math.radians(aoi[lo])), math.cos(math.radians(aoi[hi]))
    ratio = fresnel_unpolarized(c_hi, etas) / fresnel_unpolarized(c_lo, etas)
    best = int(np.argmax(ratio))
    n_ok = etas[ratio >= lobe_hi / lobe_lo / geom]
    return rows, {"aoi_lo": aoi[lo], "aoi_hi": aoi[hi], "lobe_hi": lobe_hi, "lobe_lo": lobe_lo,
                  "geometry": geom, "needed": lobe_hi / lobe_lo / geom,
                  "max_ratio": float(ratio[best]), "at_eta": float(etas[best]),
                  "ratio_15": float(fresnel_unpolarized(c_hi, 1.5) / fresnel_unpolarized(c_lo, 1.5)),
                  "largest_n_ok": float(n_ok.max()) if n_ok.size else None}


def _rel(fit, m, expr, channel=None):
    from fitlab.fitting.subset import subset_mask

    mask = subset_mask(expr, m) if expr else np.ones(m.n, dtype=bool)
    pred = np.asarray(fit.predict(m.wi, m.wo, channel)).reshape(-1)
    return mask, pred


def per_incidence_errors(fit, m, expr, channel=None):
    """The fit's RMS relative error per incidence on the rows of ``expr`` (each incidence's rows
    ≥ 1% of its maximum: fitlab compare's rule). Returns [(θi, rows counted, RMS)]."""
    mask, pred = _rel(fit, m, expr, channel)
    out = []
    for ti in np.unique(m.theta_i):
        s = mask & (m.theta_i == ti)
        if not s.any():
            continue
        keep = np.abs(m.value[s]) >= FLOOR * np.max(np.abs(m.value[s]))
        rel = (pred[s][keep] - m.value[s][keep]) / m.value[s][keep]
        out.append((float(ti), int(keep.sum()), rms(rel)))
    return out


def pooled_errors(fit, m, expr, channel=None):
    """(rows, RMS) pooled over the incidences' counted rows (compare's pooled figure)."""
    mask, pred = _rel(fit, m, expr, channel)
    rel = []
    for ti in np.unique(m.theta_i):
        s = mask & (m.theta_i == ti)
        if s.any():
            keep = np.abs(m.value[s]) >= FLOOR * np.max(np.abs(m.value[s]))
            rel.append((pred[s][keep] - m.value[s][keep]) / m.value[s][keep])
    rel = np.concatenate(rel)
    return rel.size, rms(rel)


def report_vinyl(path, fit_path):
    import fitlab

    print(f"\n## Brown vinyl ({path.name}): what the file can tell about the instrument\n")
    zf, v, wo, theta_o, measured = vinyl_grid(path)
    print(f"Symmetry {zf.symmetry}: azimuths {zf.azimuth.min():g}..{zf.azimuth.max():g} deg "
          "stored, so no reading has a mirrored partner; radial 0 holds one value per block "
          f"repeated over the {len(zf.azimuth)} azimuths (a repeated number, not a repeated "
          "measurement): no repeatability can be measured from pairs.")
    fit = fitlab.load_fit(fit_path) if fit_path else None
    model = model_on_grid(fit, zf, wo) if fit is not None else None
    floor_mask = np.zeros_like(measured)
    for k in range(len(zf.aoi)):
        floor_mask[k] = v[k] >= FLOOR * np.max(v[k][measured[k]])
    print("\n### Smoothness noise along the azimuth (Δ² of 10° steps; readings ≥ 1% of the "
          "block max, radial ≥ 5°, θo < 83°)\n")
    noise_rows = vinyl_noise(zf, v, measured, floor_mask, theta_o, model)
    print(table(["AOI", "triples", "σ (RMS)", "σ (robust, MAD)", "readings > 5 σ",
                 "σ (RMS) after the model's curvature", "σ (robust) after it"], noise_rows))
    sig = [float(r[3]) for r in noise_rows]
    print(f"\nmedian over AOIs: robust σ {np.median(sig):.4f}" + (
        f"; model: {Path(fit_path).name}" if fit else ""))
    print("\n### Edge of the instrument's view: last reading along an azimuth / the trend of "
          "the two before it\n")
    print(table(["θo of the last reading", "azimuths", "median drop", "smallest",
                 "drops < 0.6"], vinyl_edge(zf, v, measured, theta_o)))
    print("\n### TIS lines against ∫ f cos θo dω\n")
    head = ["AOI", "TIS", "grid integral", "vs TIS", "coverage"]
    if fit is not None:
        head += ["model outside the grid", "completed", "completed vs TIS",
                 "model's own hemisphere integral"]
    print(table(head, vinyl_tis(zf, v, wo, measured, model, fit)))
    print("\n### Neighbouring incidences at the same outgoing direction (≥ 30° from the "
          "specular directions)\n")
    nb = vinyl_neighbours(zf, v, wo, measured)
    print(table(["AOI", "directions", "median f / mean(neighbours) − 1", "interquartile"], nb))
    q = np.array([float(r[2]) for r in nb])
    sign = np.array([(-1) ** k for k in range(q.size)])
    for a, b in ((0, q.size), (0, 5), (5, q.size)):
        amp = float(np.mean(q[a:b] * sign[a:b])) / 2.0
        print(f"\nalternating block scale ±a (q_k ≈ ±2a + curvature) over AOI "
              f"{nb[a][0]}–{nb[b - 1][0]}: a = {abs(amp):.3f}, mean q {np.mean(q[a:b]):+.3f}")
    print("\n### The specular reading and a single Fresnel-weighted lobe\n")
    rows, chk = vinyl_specular(zf, v, wo, measured)
    print(table(["AOI", "f at the pole (specular)", "far level (≥ 30° from specular, median)",
                 "largest reading"], rows))
    print(f"\nPole reading {chk['lobe_lo']:.4g} 1/sr at {chk['aoi_lo']:g}° and "
          f"{chk['lobe_hi'] + 0:.4g} 1/sr above the far level at {chk['aoi_hi']:g}°: a lobe of "
          "fixed width holding at most the first and at least the second needs its Fresnel "
          f"factor to grow at least {chk['lobe_hi'] / chk['lobe_lo']:.1f} / "
          f"{chk['geometry']:.2f} = {chk['needed']:.2f}x (G1 <= 1 only raises this). A "
          f"dielectric Fresnel factor grows {chk['ratio_15']:.2f}x for n = 1.5 and at most "
          f"{chk['max_ratio']:.0f}x (n -> 1); indices 1 < n <= "
          f"{chk['largest_n_ok'] if chk['largest_n_ok'] is None else round(chk['largest_n_ok'], 3)}"
          " reach the bound. So the pole readings alone do not exclude one Fresnel lobe "
          "with n >= 1; they do if the lobe holds only part of the smaller incidence's pole "
          "reading (a sharp lobe over a diffuse base): the fits decide.")



def report_errors(fit_path, data_path, row_exprs):
    """A fit's RMS relative error per incidence on each row subset (fit-subset syntax)."""
    import fitlab

    fit, m = fitlab.load_fit(fit_path), fitlab.read(data_path)
    exprs = row_exprs or [""]
    print(f"\n### {Path(fit_path).name} on {Path(data_path).name}: RMS relative error per "
          "incidence (each incidence's rows >= 1% of its max; counted rows in brackets)\n")
    for ch in fit.channels:
        sel = m.channel == m.channel_names.index(ch)
        mc = m.select(sel)
        cols = [per_incidence_errors(fit, mc, e, ch) for e in exprs]
        rows = []
        for i, (t, _, _) in enumerate(cols[0]):
            rows.append([ch, f"{t:g}"] + [f"{c[i][2]:.3f} ({c[i][1]})" for c in cols])
        pooled = [pooled_errors(fit, mc, e, ch) for e in exprs]
        rows.append([ch, "pooled"] + [f"{r:.3f} ({n})" for n, r in pooled])
        print(table(["channel", "θi"] + [f"rows {e!r}" if e else "every row" for e in exprs],
                    rows))


# ----------------------------------------------------------------------------------------------


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog="Method: the docstring at the head of "
                                        "benchmarks/instrument_floor.py.")
    ap.add_argument("--only", choices=("vinyl", "film", "pgii"), action="append",
                    help="measure only this file (repeatable; default all)")
    ap.add_argument("--tol", type=float, default=None,
                    help="mirror pairs: largest distance (deg) from the mirror direction to the "
                         "nearest row on the other side (default 1e-6 for the RGL grid, 0.5 "
                         "for the pgII scan)")
    ap.add_argument("--fit", help="brown vinyl: a fit file of the vinyl (the model's curvature "
                                  "in the noise estimate, the TIS completed by the model)")
    ap.add_argument("--errors", nargs=2, action="append", default=[], metavar=("FIT", "DATA"),
                    help="print the fit's RMS relative error per incidence on DATA, for each "
                         "--rows subset (repeatable); nothing else is measured unless --only")
    ap.add_argument("--rows", action="append", default=[],
                    help="with --errors: a row subset (fit-subset syntax, e.g. 'value > 0.01'); "
                         "repeatable; default every row")
    ap.add_argument("--no-scan", action="store_true",
                    help="pgII: skip the mirror-plane alignment scan")
    ap.add_argument("--pgii-refit", metavar="MODEL",
                    help="pgII: fit MODEL (every 10th row, least squares) with the incidence "
                         "azimuth of the file and with the one the scan finds, and print both "
                         "RMS relative errors (about a minute per fit)")
    args = ap.parse_args(argv)
    import fitlab

    only = set(args.only or (() if args.errors else ("vinyl", "film", "pgii")))
    t0 = time.perf_counter()
    for fit_path, data_path in args.errors:
        report_errors(fit_path, data_path, args.rows)
    if "vinyl" in only:
        report_vinyl(VINYL, args.fit)
    if "film" in only:
        if FILM.exists():
            m = fitlab.read(FILM)
            report_mirror(f"RGL Aurora White ({FILM.name}, fitlab's default read grid)", m,
                          1e-6 if args.tol is None else args.tol)
            report_normal_incidence(m)
            rows, cols = film_peak_sensitivity(FILM)
            print("\n### The rows a parameter file's overall error counts (>= 1% of the channel "
                  "max) and the file's BRDF 0.5° away\n")
            print(table(["channel", "θi", "θo", "φo", "f (1/sr)"]
                        + [f"f({c}{' 0.5°' if 'θ' in c else ''})/f − 1" for c in cols],
                        rows))
        else:
            print(f"\n{FILM} not found: skipped")
    if "pgii" in only:
        if PGII.exists():
            m = fitlab.read(PGII)
            best = report_mirror(f"pgII glossy paper ({PGII.name})", m,
                          0.5 if args.tol is None else args.tol,
                          scan=None if args.no_scan else [float(x) for x in
                                                         np.arange(-6.0, 2.01, 0.25)])
            for tol in (0.1, 0.25):
                res = mirror_differences(m, 0, tol)
                d = np.concatenate([r["d"] for r in res])
                print(f"\ntolerance {tol:g} deg: {d.size} pairs, RMS d {rms(d):.3f}")
            # the rows a fit counts: >= 1% of the maximum of every row, the horizon's too
            floor_fit = FLOOR * float(np.max(np.abs(m.value)))
            near = m.theta_o >= 89.0
            print(f"\nrows at theta_o >= 89 deg: {int(near.sum())}, largest value "
                  f"{float(np.max(m.value[near])):.3g} against {float(np.max(m.value[~near])):.3g}"
                  f" elsewhere; a fit's 1% floor is then {floor_fit:.3g} and counts "
                  f"{int(np.sum(near & (m.value >= floor_fit)))} of them")
            for delta in (0.0,) if best is None else (0.0, best[0]):
                res = mirror_differences(m, 0, 0.5, delta, floor_abs=floor_fit)
                d = np.concatenate([r["d"] for r in res])
                print(f"pairs with both readings >= the fit's floor, mirror plane at {delta:+.2f} "
                      f"deg: {d.size}, RMS d {rms(d):.3f} (isotropic-model floor {rms(d) / 2:.3f})")
            if args.pgii_refit:
                if best is None:
                    raise SystemExit("--pgii-refit needs the alignment scan (drop --no-scan)")
                pgii_refit(m, args.pgii_refit, best[0])
        else:
            print(f"\n{PGII} not found: skipped")
    print(f"\n({time.perf_counter() - t0:.1f} s)", file=sys.stderr)


if __name__ == "__main__":
    main()
