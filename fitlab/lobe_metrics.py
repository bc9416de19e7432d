"""How far one BSDF is from another in the quantities a user sees: relative error of f·cos over
direction pairs, directional albedo (deterministic quadrature or the model's own importance
sampler), and images of the lobe compared by PSNR and SSIM (scikit-image). Shared by the glTF
conversion report (fitlab/export/gltf_material.py) and ``fitlab tradeoffs``.

An *evaluator* is a function ``(wi, wo) -> (N, C)`` array of f in 1/sr (C channels), so a
model in any precision, a lookup table or a simulation can be scored alike.
"""

from __future__ import annotations

import numpy as np

from fitlab import metrics

#: Values below this fraction of a channel's largest f·cos are left out of relative errors.
ERROR_FLOOR = 1e-3
#: Side of the lobe images (pixels).
IMAGE_SIZE = 64


def directions(theta_deg, phi_deg) -> np.ndarray:
    """Unit vectors (..., 3) from polar and azimuth angles in degrees."""
    t, p = np.radians(theta_deg), np.radians(phi_deg)
    return np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1)


def model_evaluator(model: str, channels: dict, options: dict, dtype=np.float64):
    """The evaluator of registry ``model`` with ``channels`` = {channel: params}, in ``dtype``
    (float32 directions give a float32 evaluation, fitlab.eval_bsdf)."""
    from fitlab.api import eval_bsdf

    def evaluate(wi, wo):
        wi, wo = np.asarray(wi, dtype), np.asarray(wo, dtype)
        return np.stack([np.asarray(eval_bsdf(model, p, wi, wo, options), np.float64)
                         for p in channels.values()], axis=-1)
    return evaluate


def relative_errors(ref: np.ndarray, test: np.ndarray, cos_o: np.ndarray,
                    floor: float = ERROR_FLOOR) -> dict:
    """RMS and largest |test - ref| / ref of f·|cos θo| over the pairs where the reference is
    above ``floor`` × its channel's largest value; ref, test: (N, C)."""
    a, b = ref * np.abs(cos_o)[:, None], test * np.abs(cos_o)[:, None]
    if not a.size:
        return {"relative_rms": 0.0, "relative_max": 0.0, "pairs": 0}
    rel = np.concatenate([metrics.relative_errors(b[:, c], a[:, c], floor)[0]
                          for c in range(a.shape[1])])
    if not rel.size:
        return {"relative_rms": 0.0, "relative_max": 0.0, "pairs": 0}
    return {"relative_rms": float(np.sqrt(np.mean(rel ** 2))),
            "relative_max": float(np.max(np.abs(rel))), "pairs": int(rel.size)}


def lobe_image(evaluate, theta_deg: float, size: int = IMAGE_SIZE, side: int = 1) -> np.ndarray:
    """f·|cos θo| on a size × size image of a hemisphere (x, y = the projected wo; ``side`` 1:
    the reflection hemisphere, -1: transmission), channels last; 0 outside the unit disk."""
    x = (np.arange(size) + 0.5) / (size / 2.0) - 1.0
    X, Y = np.meshgrid(x, x[::-1])
    r2 = X * X + Y * Y
    inside = (r2 < 1.0).ravel()
    wo = np.stack([X, Y, side * np.sqrt(np.clip(1.0 - r2, 0.0, 1.0))], -1).reshape(-1, 3)
    wi = np.broadcast_to(directions(theta_deg, 0.0), wo.shape)
    f = np.asarray(evaluate(wi, wo)) * np.abs(wo[:, 2:3])
    return np.where(inside[:, None], f, 0.0).reshape(size, size, -1)


def image_errors(ref: np.ndarray, test: np.ndarray) -> dict:
    """PSNR (dB; None when identical) and SSIM of ``test`` against ``ref`` (H, W, C), both
    divided by the reference's peak, so the figures are relative to the lobe's brightest
    pixel (scikit-image's metrics)."""
    from skimage.metrics import peak_signal_noise_ratio, structural_similarity

    peak = float(ref.max()) or 1.0
    a, b = np.clip(ref / peak, 0, None), np.clip(test / peak, 0, None)
    rng = float(max(a.max(), b.max())) or 1.0
    same = bool(np.array_equal(a, b))  # PSNR is infinite (JSON has no number for it)
    return {"psnr_db": None if same else float(peak_signal_noise_ratio(a, b, data_range=rng)),
            "ssim": float(structural_similarity(a, b, data_range=rng, channel_axis=-1))}


def albedo_quadrature(evaluate, theta_deg: float, order: int = 128,
                      transmission: bool = False) -> np.ndarray:
    """Directional albedo per channel at incidence θ by a product rule: Gauss–Legendre in
    cos θo (``order`` nodes on each hemisphere observed) × the periodic trapezoid rule in φo
    (2 × ``order`` nodes); both hemispheres when ``transmission``. Deterministic, so two
    evaluators compare without sampling noise."""
    x, w = np.polynomial.legendre.leggauss(order)
    mu, wmu = 0.5 * (x + 1.0), 0.5 * w
    n_phi = 2 * order
    phi = (np.arange(n_phi) + 0.5) * (2 * np.pi / n_phi)
    M, P = np.meshgrid(mu, phi, indexing="ij")
    s = np.sqrt(np.clip(1 - M * M, 0, 1))
    wo = np.stack([s * np.cos(P), s * np.sin(P), M], -1).reshape(-1, 3)
    weight = (wmu[:, None] * M * (2 * np.pi / n_phi)).reshape(-1)
    wi = np.broadcast_to(directions(theta_deg, 0.0), wo.shape)
    total = np.einsum("n,nc->c", weight, np.asarray(evaluate(wi, wo)))
    if transmission:
        below = wo * np.array([1.0, 1.0, -1.0])
        total = total + np.einsum("n,nc->c", weight, np.asarray(evaluate(wi, below)))
    return total


def albedo_sampled(model: str, channels: dict, options: dict, theta_deg: float,
                   n: int = 100_000, seed: int = 7, side: int = 1) -> np.ndarray:
    """Directional albedo per channel at incidence θ by the model's own importance sampler
    (mean of the sample weights): reflected (``side`` 1) or transmitted (-1)."""
    from fitlab.api import sample_bsdf

    rng = np.random.default_rng(seed)
    u = rng.random((n, 3))
    wi = np.broadcast_to(directions(theta_deg, 0.0), (n, 3))
    out = []
    for p in channels.values():
        wo, w, _ = sample_bsdf(model, p, wi, u, options)
        out.append(float(np.mean(np.where(side * np.asarray(wo)[:, 2] > 0, np.asarray(w),
                                          0.0))))
    return np.array(out)


__all__ = ["ERROR_FLOOR", "IMAGE_SIZE", "albedo_quadrature", "albedo_sampled", "directions",
           "image_errors", "lobe_image", "model_evaluator", "relative_errors"]
