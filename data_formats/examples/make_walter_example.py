"""Regenerate walter_rough_glass.csv: a synthetic rough-glass BTDF in Walter et al. 2007's
geometry (section 6: light on the rough side at θi = 0, 30, 60, 80°, detector swept in the plane
of incidence on the transmission side, relative units, η = 1.51).

Truth: GGX rough dielectric, α = 0.394 (Walter's Fig. 12 value for ground glass), η = 1.51,
overall scale 1.3. The stored signal is proportional to f·|cos θi| (Walter: "a signal
proportional to the BTDF times the cosine of the incident angle"), with 5% multiplicative
log-normal noise, seed 2007.

    python data_formats/examples/make_walter_example.py
"""

from pathlib import Path

import numpy as np

import fitlab
from fitlab.io.directions import degrees_to_direction

ALPHA, ETA, SCALE, NOISE, SEED = 0.394, 1.51, 1.3, 0.05, 2007


def main():
    rng = np.random.default_rng(SEED)
    rows = []
    for ti in (0.0, 30.0, 60.0, 80.0):
        for t in np.arange(-85.0, 85.0 + 1e-9, 2.5):  # signed transmitted angle, + = forward
            theta_o, phi_o = 180.0 - abs(t), (180.0 if t >= 0 else 0.0)
            if t == 0:
                phi_o = 180.0
            rows.append((ti, 0.0, theta_o, phi_o))
    rows = np.asarray(rows)
    wi = degrees_to_direction(rows[:, 0], rows[:, 1])
    wo = degrees_to_direction(rows[:, 2], rows[:, 3])
    f = np.asarray(fitlab.eval_bsdf("rough_dielectric", {"alpha": ALPHA, "eta": ETA}, wi, wo))
    signal = SCALE * f * np.abs(wi[:, 2]) * np.exp(NOISE * rng.standard_normal(f.shape))
    out = Path(__file__).with_name("walter_rough_glass.csv")
    with open(out, "w", encoding="utf-8") as fh:
        fh.write("# Synthetic rough-glass BTDF in Walter et al. 2007's geometry (section 6).\n")
        fh.write(f"# Made by make_walter_example.py: GGX alpha={ALPHA}, eta={ETA}, scale={SCALE},\n")
        fh.write(f"# {NOISE:.0%} multiplicative log-normal noise, seed {SEED}.\n")
        fh.write("# quantity: relative\n")
        fh.write("# relative_to: bsdf_cos_i\n")
        fh.write("# scatter: btdf\n")
        fh.write("# eta_outside: 1.0\n")
        fh.write("# eta_inside: 1.51\n")
        fh.write("# sample: synthetic ground glass (GGX alpha 0.394)\n")
        fh.write("# instrument: simulated goniophotometer, in-plane, glass hemisphere backing\n")
        fh.write("theta_i,phi_i,theta_o,phi_o,value\n")
        for (ti, pi, to, po), v in zip(rows, signal):
            fh.write(f"{ti:g},{pi:g},{to:g},{po:g},{v:.6e}\n")
    print(f"wrote {out} ({len(rows)} rows)")


if __name__ == "__main__":
    main()
