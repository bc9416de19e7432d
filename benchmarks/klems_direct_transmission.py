"""The unscattered (direct) transmission of a Klems BSDF against a SpongeCake fit's declared delta
(issue 16, item 6: fits/README.md, "SpongeCake on the LBNL shade fabric").

A Klems file stores the direct beam inside the diagonal patch of its transmission block: the
direct transmittance for incident patch i is (f[i, i] − the median of column i) × Λ_i, Λ the
patch's projected solid angle (data_formats/klems_xml.md). SpongeCake declares it as a delta of
weight e^{−Σ Tρσ(ωi)/cos θi} (``spongecake.delta_transmittance``). Printed per ring of front
incidences (the ring's first patch), for each fit file given.

Run: ``python benchmarks/klems_direct_transmission.py DATA.XML FIT.json [FIT.json ...]``
(channel: the fit's).
"""

from __future__ import annotations

import sys

import jax
import jax.numpy as jnp
import numpy as np

import fitlab
from fitlab.io.directions import degrees_to_direction
from fitlab.io.klems import read_klems_file
from fitlab.models.spongecake import Layer, delta_transmittance
from fitlab.models.syntax import parse_call

jax.config.update("jax_enable_x64", True)


def direct_transmittance(block):
    """(θ of each ring's first incident patch, its direct transmittance)."""
    f = block.matrix
    lam = block.outgoing.projected_solid_angle()
    first = np.concatenate([[0], np.cumsum(block.incident.ring_nphis)[:-1]])
    return (block.incident.theta[first],
            np.array([(f[i, i] - np.median(f[:, i])) * lam[i] for i in first]))


def model_delta(fit, theta):
    call = parse_call(fit.model)
    layers = tuple(Layer(k, i + 1) for i, k in enumerate(call.args))
    p = {k: jnp.asarray(v) for k, v in fit.parameters[fit.channels[0]].items()}
    wi = jnp.asarray(degrees_to_direction(theta, 0 * theta))
    return np.asarray(delta_transmittance(layers, p, wi))


def main(argv):
    kf = read_klems_file(argv[0])
    fits = [fitlab.load_fit(p) for p in argv[1:]]
    channel = fits[0].channels[0]
    block = next(b for b in kf.blocks if b.direction == "Transmission Front"
                 and b.channel == channel)
    theta, t_data = direct_transmittance(block)
    print(f"# {kf.material.get('Name', argv[0])}, channel {channel}: direct transmittance")
    print("| θi | data (diagonal patch) | " + " | ".join(
        f"`{f.model}`" + (f" ({', '.join(f'{k} = {v:g}' for k, v in f.fixed[channel].items())})"
                          if f.fixed.get(channel) else "") for f in fits) + " |")
    print("|---|---|" + "---|" * len(fits))
    deltas = [model_delta(f, theta) for f in fits]
    for j, t in enumerate(theta):
        print(f"| {t:.1f}° | {t_data[j]:.4f} | "
              + " | ".join(f"{d[j]:.4f}" for d in deltas) + " |")


if __name__ == "__main__":
    main(sys.argv[1:])
