"""The effect plan: what a scene asks the walk to simulate, what fitlab derives from the scene
itself, and every effect skipped with its reason (data_formats/scene_toml.md, "Effects").

The plan decides what is compiled into the walk (walk.WalkConfig) and is written into the
output's metadata, so a simulated file says which physics it holds.
"""

from __future__ import annotations

from typing import NamedTuple

from fitlab.simulate.scene import CHANNEL_NAMES_RGB, Scene


class EffectPlan(NamedTuple):
    reflection: bool  # exits into the outside are tallied
    transmission: bool  # exits into the medium below are tallied (else such paths end at once)
    max_bounces: int | None  # None = all orders
    russian_roulette: bool
    volume: bool  # volume scattering code compiled
    volume_limit: int | None  # volume events allowed per path: 0 (none), 1 (single), None (all)
    absorption: bool  # σa attenuation compiled
    extinction_only: bool  # σs attenuates without scattering (volume_scattering = "none")
    delta: bool  # paths without any non-specular event are tallied
    channels: int  # channels simulated (1 or 3)
    channel_names: tuple
    walk_per_channel: bool  # σs differs by channel: one walk per channel
    channel_pick: int | None  # color = "R" | "G" | "B" of RGB properties: that channel's index
    end_downward_after_last_bounce: bool
    # branch forcing (item "forced branches" of the plan): a dielectric boundary whose one
    # branch leads only to an unobserved side takes the other with probability 1, weighted by
    # that branch's probability (F or 1 − F)
    force_top: bool  # reflection not observed: the top boundary keeps paths inside
    force_bottom: bool  # transmission not observed: the bottom boundary reflects every path
    split_first: bool  # splitting at the first interface (split_first_interface = true)
    simulated: tuple  # (effect, detail)
    skipped: tuple  # (effect, reason)

    def describe(self) -> str:
        sim = "; ".join(f"{k} ({v})" if v else k for k, v in self.simulated)
        skip = "; ".join(f"{k}: {v}" for k, v in self.skipped)
        return f"simulated: {sim}\nskipped: {skip or 'nothing'}"


def _any(values):
    return any(v > 0 for v in values)


def derive_effects(scene: Scene) -> EffectPlan:
    """The effect plan of ``scene``: the requested effects (``[effects]``, detector sides) narrowed
    by what the scene implies (no medium, σa = 0, grey properties, opaque substrate)."""
    eff = scene.effects
    sim, skip = [], []
    sides = scene.detector.sides
    reflection = "reflection" in sides
    transmission = "transmission" in sides and not scene.opaque_substrate
    top, bottom = scene.boundaries[0], scene.boundaries[-1]
    force_top = not reflection and top.kind == "dielectric"
    force_bottom = not transmission and not scene.opaque_substrate and bottom.kind == "dielectric"
    if reflection:
        sim.append(("reflection", "paths leaving into the outside are tallied"))
    elif force_top:
        skip.append(("reflection", "no reflection detector: the top boundary's branch into the "
                     "outside is not traced (forced branches)"))
    else:
        skip.append(("reflection", "no reflection detector: paths leaving upward are not tallied"))
    if transmission:
        sim.append(("transmission", "paths entering the medium below are tallied"))
    elif scene.opaque_substrate:
        skip.append(("transmission", "the substrate is opaque: no transmitted paths exist"))
    elif force_bottom:
        skip.append(("transmission", "no transmission detector: the bottom boundary's "
                     "refracted branch is not traced (forced reflection)"))
    else:
        skip.append(("transmission", "no transmission detector: paths entering the medium "
                     "below end at once"))
    if force_top:
        sim.append(("forced branches at the top", "reflection is not observed: light arriving "
                    "from outside is refracted and light arriving from inside reflected with "
                    "probability 1, weighted by 1 - F or F (unbiased)"))
    if force_bottom:
        sim.append(("forced reflection at the bottom", "transmission is not observed: paths "
                    "meeting the bottom boundary are reflected with probability 1, weighted "
                    "by F (unbiased), instead of ending when they would have crossed it"))

    if eff.split_first_interface:
        sim.append(("splitting at the first interface", "every path's first crossing of the top "
                    "boundary is split: its reflected branch (weight F) is tallied at once, "
                    "sampled apart, and the path continues refracted (weight 1 - F)"))

    # masking of the vMF boundaries (scene.py: eq. 7 integrated unless masking = "approx")
    where = {m: ", ".join(b.field or f"boundary {j}" for j, b in enumerate(scene.boundaries)
                          if b.masking == m) for m in ("exact", "approx")}
    if where["exact"]:
        sim.append(("exact vmf masking", f"at {where['exact']}: the Smith masking of the vMF "
                    "NDF, the extended-NDF paper's eq. 7 integrated by quadrature"))
    if where["approx"]:
        sim.append(("approximate vmf masking", f"at {where['approx']}, chosen by masking = "
                    "\"approx\": the extended-NDF paper's eq. 8, an approximation, not the "
                    "masking of the vMF NDF itself"))
        skip.append(("exact vmf masking", f"masking = \"approx\" at {where['approx']}: eq. 8 "
                     "traced instead of eq. 7's integral"))

    media = scene.media
    thick = [m for m in media if m.thickness > 0]
    # volume scattering
    scattering = [m for m in thick if _any(m.sigma_s)]
    if not media:
        skip.append(("volume scattering", "no medium in the stack: no volume code"))
        volume, limit, ext_only = False, 0, False
    elif not scattering:
        skip.append(("volume scattering", "every sigma_s is 0: no volume code"))
        volume, limit, ext_only = False, 0, False
    elif eff.volume_scattering == "none":
        skip.append(("volume scattering", "volume_scattering = \"none\": scattered light is "
                     "removed from the paths (extinction by sigma_a + sigma_s)"))
        volume, limit, ext_only = False, 0, True
    else:
        limit = 1 if eff.volume_scattering == "single" else None
        volume, ext_only = True, False
        phases = sorted({m.phase.type for m in scattering})
        sim.append(("volume scattering", f"{eff.volume_scattering} ({', '.join(phases)})"))
    # absorption
    absorbing = [m for m in thick if _any(m.sigma_a)]
    if not media:
        skip.append(("absorption", "no medium in the stack: no attenuation code"))
        absorption = False
    elif not absorbing:
        skip.append(("absorption", "every sigma_a is 0: no attenuation code"))
        absorption = False
    elif not eff.absorption:
        skip.append(("absorption", "absorption = false in [effects]"))
        absorption = False
    else:
        absorption = True
        sim.append(("absorption", "Beer-Lambert attenuation along every flight"))
    # bounces
    if eff.max_bounces is None:
        rr = eff.russian_roulette
        sim.append(("bounces", "all orders" + (" with Russian roulette" if rr else "")))
    else:
        rr = False
        sim.append(("bounces", f"at most {eff.max_bounces} below the top surface"))
        skip.append(("higher bounces", f"max_bounces = {eff.max_bounces}: paths making bounce "
                     f"{eff.max_bounces + 1} end there"))
    end_down = eff.max_bounces is not None and not transmission
    if end_down:
        sim.append(("early termination", "a path that has used its bounces and travels "
                    "downward ends at once (no transmission detector)"))
    # delta
    if top.kind in ("lambertian",) or (top.kind in ("dielectric", "conductor")
                                        and top.distribution != "smooth"):
        skip.append(("delta", "the top surface is rough or diffuse: every path has a "
                     "non-specular event, no delta paths exist"))
    elif eff.delta:
        sim.append(("delta", "unscattered transmission and specular reflection included"))
    else:
        skip.append(("delta", "delta = false: paths without a non-specular event are not tallied"))
    # estimator
    if scene.detector.estimator == "point":
        sim.append(("point estimates", "next-event estimation: every event that can be a path's "
                    "last non-specular one is connected to each requested direction (no bin or "
                    "cone average)"))
        if not any(k == "delta" for k, _ in skip):
            skip.append(("delta lobes in the values", "a specular reflection or unscattered "
                         "transmission is a delta, not a point value: it leaves the point "
                         "estimates out (it stays in the flux leaving each side)"))
    # colour
    pick = None
    if eff.color.upper() in CHANNEL_NAMES_RGB:
        one = eff.color.upper()
        channels, names, per_channel = 1, (one,), False
        if scene.channels == 3:
            pick = CHANNEL_NAMES_RGB.index(one)
            sim.append(("color", f"channel {one} alone (its values of the R, G, B properties)"))
            skip.append(("other channels", f"color = \"{one}\": the other channels are not "
                         "simulated"))
        else:
            sim.append(("color", f"one channel (grey properties), named {one}"))
    elif scene.channels == 3:
        channels, names = 3, CHANNEL_NAMES_RGB
        per_channel = any(len(set(m.sigma_s)) > 1 for m in scattering) and volume
        sim.append(("color", "R, G, B" + ("; one walk per channel (sigma_s differs by channel)"
                                          if per_channel else "; one walk carries all channels")))
    else:
        channels, names, per_channel = 1, ("Y",), False
        if eff.color == "rgb":
            skip.append(("color", "rgb requested but every property is grey: one channel "
                         "simulated, its value holds for R, G and B"))
        else:
            sim.append(("color", "one channel (grey properties)"))
    return EffectPlan(reflection, transmission, eff.max_bounces, rr, volume, limit, absorption,
                      ext_only, eff.delta, channels, names, per_channel, pick, end_down, force_top,
                      force_bottom, eff.split_first_interface, tuple(sim), tuple(skip))
