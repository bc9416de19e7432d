"""A SpongeCake stack's multiple-scattering lobe, per material, by an ordinary fit (Wang et al.
2022, §5; fitlab's answer to "where do the lobe's parameters come from" without the network).

1. The stack (no substrate: the simulator's media have none) is simulated as a scene of
   index-matched SGGX / HG media (``spongecake.simulator_stack``) lit from ``theta_i`` and
   observed by point estimates at the centres of a hemisphere grid on both sides, all orders,
   without the unscattered delta.
2. Its multiple-scattering part is that result minus the exact single scattering, which the
   model computes (validated against the simulator's own single scattering:
   tests/models/test_spongecake.py, benchmarks/spongecake_furnace.py). Its standard error is the
   simulation's.
3. ``spongecake(LAYERS,multiple=only)`` — the modified single-scattering lobe W1·f_ss(p') and the
   Lambertian lobes W2/π, W2T/π — is fitted to it by :func:`fitlab.fit_measurement` (global
   search and Levenberg–Marquardt, covariance), each colour channel on its own, with the axes
   held at the stack's and ``albedo1_ms`` held at 1 (f_ss is linear in each albedo, so only
   W1·γ'₁ is determined).

The fitted parameters plug into ``spongecake(LAYERS,multiple=lobe)`` beside the stack's own:
:func:`lobe_parameters`.
"""

from __future__ import annotations

import numpy as np

#: Default incidences (degrees) and hemisphere grid of the simulation.
THETA_I = (0.0, 20.0, 40.0, 60.0, 75.0)
THETA_BINS = 6
PHI_BINS = 12
SAMPLES = 20_000


def stack_call(model_name: str):
    """The layer kinds of a SpongeCake model name without substrate or multiple=
    (fitlab.models.spongecake.stack_kinds; ValueError for any other model)."""
    from fitlab.models import get_model
    from fitlab.models.spongecake import stack_kinds

    return stack_kinds(get_model(model_name))


def stack_scene(kinds, channel_params: dict, *, theta_i=THETA_I, theta_bins=THETA_BINS,
                phi_bins=PHI_BINS) -> dict:
    """The stack as a simulator scene (a dict for fitlab.simulate.scene_from_dict): point
    estimates at the centres of a ``theta_bins`` × ``phi_bins`` grid on both sides, every
    volume scattering order, no delta."""
    from fitlab.models import spongecake

    return {"format": "fitlab-scene", "version": 1,
            "name": f"SpongeCake stack {','.join(kinds)}",
            "stack": spongecake.simulator_stack(kinds, channel_params),
            "illumination": {"theta_i": [float(t) for t in theta_i]},
            "detector": {"type": "hemisphere", "sides": ["reflection", "transmission"],
                         "theta_bins": int(theta_bins),
                         "phi_bins": int(phi_bins), "estimator": "point"},
            "effects": {"delta": False, "volume_scattering": "multiple"}}


def multiple_scattering_part(model_name: str, channel_params: dict, *, samples=SAMPLES, seed=0,
                             theta_i=THETA_I, theta_bins=THETA_BINS, phi_bins=PHI_BINS,
                             progress=False):
    """(measurement of the multiple-scattering part, the full simulation). ``channel_params``:
    {channel name: the stack's parameters}, the channels in the simulator's order (R, G, B or
    one)."""
    from fitlab._jax import jnp

    from fitlab.models import get_model
    from fitlab.simulate import scene_from_dict, simulate

    kinds = stack_call(model_name)
    scene = scene_from_dict(stack_scene(kinds, channel_params, theta_i=theta_i,
                                        theta_bins=theta_bins, phi_bins=phi_bins))
    full = simulate(scene, samples, seed=seed, progress=progress)
    m = full.to_measurement()
    single = get_model(model_name)
    names = list(channel_params)
    if len(m.channel_names) == 1 and len(names) > 1:
        # the channels' stacks are the same for the simulator (their parameters differ at most
        # where the simulator does not look): its one channel serves each
        m = _replicate(m, len(names))
    f_ss = np.zeros_like(m.value)
    for c, name in enumerate(names):
        rows = m.channel == c
        p = {k: jnp.asarray(v) for k, v in channel_params[name].items()}
        f_ss[rows] = np.asarray(single.eval(p, jnp.asarray(m.wi[rows]), jnp.asarray(m.wo[rows])))
    meta = dict(m.metadata)
    meta["component"] = "multiple scattering: simulated (all orders) minus the model's exact " \
                        "single scattering"
    return m._replace(value=m.value - f_ss, metadata=meta, channel_names=tuple(names)), full


def _replicate(m, n):
    """Measurement ``m`` (one channel) repeated as channels 0..n-1."""
    idx = np.tile(np.arange(m.n), n)
    take = {k: (None if v is None else v[idx]) for k, v in m._asdict().items()
            if isinstance(v, np.ndarray) and v.shape[:1] == (m.n,)}
    return m._replace(**take, channel=np.repeat(np.arange(n), m.n))


def held_parameters(model_name: str, channel_params: dict) -> dict:
    """What the lobe fit holds: the layers' axes (the stack's) and ``albedo1_ms`` = 1."""
    first = next(iter(channel_params.values()))
    held = {k: float(v) for k, v in first.items() if k.startswith(("theta_p", "phi_p"))}
    held["albedo1_ms"] = 1.0
    return held


def lobe_model_name(model_name: str, mode: str = "only") -> str:
    kinds = stack_call(model_name)
    return f"spongecake({','.join(kinds)},multiple={mode})"


def fit_lobe(model_name: str, channel_params: dict, *, samples=SAMPLES, seed=0,
             theta_i=THETA_I, theta_bins=THETA_BINS, phi_bins=PHI_BINS, starts=8,
             progress=False, measurement=None):
    """Simulate the stack and fit its multiple-scattering lobe. Returns (the
    :class:`fitlab.FitResult` of ``spongecake(LAYERS,multiple=only)``, the measurement fitted).
    ``measurement``: a multiple-scattering part already made (skips the simulation)."""
    from fitlab.fitting.api import fit as fit_data

    if measurement is None:
        measurement, _ = multiple_scattering_part(
            model_name, channel_params, samples=samples, seed=seed, theta_i=theta_i,
            theta_bins=theta_bins, phi_bins=phi_bins, progress=progress)
    fit = fit_data(measurement, lobe_model_name(model_name),
                   fix=held_parameters(model_name, channel_params), seed=seed,
                   starts=starts, bootstrap=0, progress=progress)
    return fit, measurement


def lobe_parameters(fit, channel_params: dict) -> dict:
    """{channel: the parameters of ``spongecake(LAYERS,multiple=lobe)``}: the stack's own and
    the fitted lobe's (held ones included); ``fit``: :func:`fit_lobe`'s FitResult."""
    fitted = fit.parameters
    return {name: {**{k: float(v) for k, v in params.items()},
                   **{k: float(v) for k, v in fitted[name].items()}}
            for name, params in channel_params.items()}
