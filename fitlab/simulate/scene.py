"""Scenes for ``fitlab simulate``: a TOML file (data_formats/scene_toml.md) or a dict → a validated,
immutable :class:`Scene`.

The stack is normalised into *regions* and *boundaries* so the random walk never looks at the
TOML structure again:

- region 0 is the outside (index ``outside_index``), regions 1..M are the media from the top,
  region M+1 is the medium below the stack (index ``below_index``; unused under an opaque
  substrate);
- boundary j separates region j (above) from region j+1 (below): a dielectric interface
  (smooth or rough), ``pass`` (no interface: equal indices on both sides), or, for the last
  boundary, an opaque substrate (``lambertian`` or ``conductor``).

Every error names the file, the field (``stack[2].thickness``) and what to do. TOML itself
carries no line numbers into the parsed data; syntax errors keep tomllib's line and column.
"""

from __future__ import annotations

import difflib
import math
from pathlib import Path
from typing import NamedTuple

from fitlab import microfacet
from fitlab.errors import InputFileError
from fitlab.io.validate import is_finite_number, load_toml, quote
from fitlab.io.files import read_bytes
from fitlab.fresnel import CONDUCTOR_PRESETS

#: Microfacet distributions an interface or substrate may use ("smooth" = a flat interface):
#: every registry distribution (fitlab.microfacet.REGISTRY), the vMF NDF once, as ``vmf``: its
#: families differ only in their masking, which the key ``masking`` chooses.
_VMF_VARIANTS = frozenset(microfacet.VMF_MASKING.values()) - {"vmf"}
INTERFACE_DISTRIBUTIONS = ("smooth",) + tuple(n for n in microfacet.REGISTRY
                                              if n not in _VMF_VARIANTS)
#: Masking of a vmf interface: the paper's eq. 7 integrated (exact, the default: the simulator
#: is the ground truth the thin layer is validated against) or its eq. 8 (approx).
MASKINGS = tuple(microfacet.VMF_MASKING)
DEFAULT_MASKING = "exact"
#: ... and these take anisotropic widths alpha_x, alpha_y.
ANISOTROPIC_DISTRIBUTIONS = microfacet.names(walter=None, anisotropic=True)
PHASES = ("isotropic", "hg", "sggx_surface", "sggx_fiber")
SUBSTRATES = ("lambertian", "conductor", "dielectric")
DETECTORS = ("hemisphere", "inplane", "measurement")
SIDES = ("reflection", "transmission")
#: How a detector estimates its values: averages over its bins or cones, or point estimates at
#: the exact directions (next-event estimation, walk.py "Point estimates").
ESTIMATORS = ("cone", "point")
VOLUME_SCATTERING = ("none", "single", "multiple")
CHANNEL_NAMES_RGB = ("R", "G", "B")
COLORS = ("auto", "mono", "rgb", "r", "g", "b")  # "R", "G", "B" (any case): that channel alone


class Phase(NamedTuple):
    """Phase function of a medium (fitlab/phase.py). ``g``: HG asymmetry; ``roughness`` and
    ``orientation`` (unit axis: flake normal for sggx_surface, fiber direction for sggx_fiber)."""

    type: str = "isotropic"
    g: float = 0.0
    roughness: float = 1.0
    orientation: tuple = (0.0, 0.0, 1.0)
    #: SGGX flakes' Schlick reflectance at normal incidence per channel (SpongeCake eq. 5 and
    #: Table 2: F(h) = Schlick(f0, |h·ωi|) scales each scattering; 1 = no Fresnel term)
    f0: tuple = (1.0,)


class Medium(NamedTuple):
    """A homogeneous slab. ``sigma_a`` / ``sigma_s`` are per channel (1 or 3 values) in the
    inverse of ``thickness``'s length unit; for SGGX media they are the coefficients of a
    direction whose projected flake area σ(ω) = sqrt(ωᵀSω) is 1 (SpongeCake eqs 3, 7)."""

    index: float
    thickness: float
    sigma_a: tuple
    sigma_s: tuple
    phase: Phase


class Boundary(NamedTuple):
    """The surface between region j and j+1.

    kind: ``pass`` (no interface), ``dielectric``, ``lambertian`` or ``conductor``.
    distribution / alpha: microfacet NDF and width (alpha = 0 for ``smooth``); for ``vmf`` the
    width maps to the concentration by κ = 2/α² (fitlab/microfacet.py); alpha_y: the width
    along the tangent +y of an anisotropic NDF (alpha is then the width along +x), None when
    isotropic.
    albedo (lambertian), n and k (conductor, relative to vacuum: divided by the index of the
    medium above at simulation time): per channel, 1 or 3 values.
    masking: a vmf NDF's masking, ``exact`` (eq. 7 integrated) or ``approx`` (eq. 8); None for
    the other distributions. field: the scene field the boundary comes from (``stack[2]``,
    ``substrate``, ``below``), for messages and the effect plan."""

    kind: str
    distribution: str = "smooth"
    alpha: float = 0.0
    albedo: tuple = ()
    n: tuple = ()
    k: tuple = ()
    alpha_y: float | None = None
    masking: str | None = None
    field: str = ""

    @property
    def family(self) -> str:
        """The microfacet registry family the walk samples: the distribution, or for vmf the
        family of its masking (fitlab.microfacet.VMF_MASKING)."""
        return self.distribution if self.masking is None else microfacet.VMF_MASKING[self.masking]


class Detector(NamedTuple):
    """What is observed.

    hemisphere: ``theta_bins`` uniform θ bins over [0°, 90°] of each observed side and
    ``phi_bins`` uniform φ bins over [0°, 360°).
    inplane: cones of ``acceptance_sr`` steradians around in-plane directions ``theta_o``
    (signed degrees, see the schema), on the sides those angles fall on.
    measurement: cones of ``acceptance_sr`` around the exact directions of ``file``'s rows.

    ``estimator``: "cone" (the bin or cone average, as above) or "point" (point estimates of f
    at the bin centres or the exact directions, no aperture; ``acceptance_sr`` is then 0).
    """

    type: str
    sides: tuple
    theta_bins: int = 0
    phi_bins: int = 0
    theta_o: tuple = ()
    acceptance_sr: float = 0.0
    file: str | None = None
    estimator: str = "cone"


class Effects(NamedTuple):
    """What the scene asks the walk to simulate (before fitlab's own derivations, effects.py).

    max_bounces: None = all orders (with Russian roulette when ``russian_roulette``); k = paths
    with at most k bounces below the top surface (a bounce: the path turns from downward to
    upward below the top interface; 0 = top-surface reflection and direct transmission only).
    """

    max_bounces: int | None = None
    russian_roulette: bool = True
    absorption: bool = True
    volume_scattering: str = "multiple"
    delta: bool = True
    color: str = "auto"
    split_first_interface: bool = False


class Scene(NamedTuple):
    source: str  # file the scene came from, or "<dict>"
    name: str
    outside_index: float
    media: tuple  # Medium per region 1..M
    boundaries: tuple  # Boundary per boundary 0..M
    below_index: float
    opaque_substrate: bool
    theta_i: tuple  # degrees
    phi_i: tuple  # degrees
    detector: Detector
    effects: Effects
    channels: int  # 1 or 3: how many values the properties carry

    @property
    def region_indices(self) -> tuple:
        """Refractive index of every region 0..M+1."""
        return (self.outside_index, *(m.index for m in self.media), self.below_index)


# --------------------------------------------------------------------------------------------
# Validation helpers: each raises InputFileError(source, "FIELD: what is wrong", hint=...)
# --------------------------------------------------------------------------------------------


class _Ctx(NamedTuple):
    source: str

    def fail(self, field, message, hint=None):
        raise InputFileError(self.source, f"{field}: {message}" if field else message, hint=hint)


def _check_keys(ctx, table, field, allowed):
    if not isinstance(table, dict):
        ctx.fail(field, f"must be a table, got {type(table).__name__}",
                 f"write it as [{field}] with key = value lines")
    for key in table:
        if key not in allowed:
            close = difflib.get_close_matches(key, allowed, n=1)
            hint = f"did you mean {close[0]!r}?" if close else f"allowed keys: {', '.join(allowed)}"
            ctx.fail(f"{field}.{key}" if field else key, "unknown key", hint)


def _number(ctx, table, field, key, *, default=None, lo=None, hi=None, lo_open=False,
            hi_open=False, hint=None):
    where = f"{field}.{key}" if field else key
    if key not in table:
        if default is None:
            ctx.fail(where, "is missing", hint)
        return default
    v = table[key]
    if not is_finite_number(v):
        ctx.fail(where, f"{quote(v)} is not a finite number", hint)
    v = float(v)
    bad = (lo is not None and (v <= lo if lo_open else v < lo)) or \
        (hi is not None and (v >= hi if hi_open else v > hi))
    if bad:
        lo_s = "" if lo is None else f"{'>' if lo_open else '>='} {lo:g}"
        hi_s = "" if hi is None else f"{'<' if hi_open else '<='} {hi:g}"
        rng = " and ".join(s for s in (lo_s, hi_s) if s)
        ctx.fail(where, f"{v:g} is out of range: it must be {rng}", hint)
    return v


def _per_channel(ctx, table, field, key, *, default=None, lo=0.0, hi=None, hint=None):
    """A property given as one number (grey) or a list of 3 (R, G, B)."""
    where = f"{field}.{key}"
    if key not in table:
        if default is None:
            ctx.fail(where, "is missing", hint)
        return tuple(default)
    v = table[key]
    values = v if isinstance(v, list) else [v]
    if len(values) not in (1, 3):
        ctx.fail(where, f"has {len(values)} values", "give one number (grey) or three (R, G, B)")
    out = []
    for j, x in enumerate(values):
        sub = {key: x}
        out.append(_number(ctx, sub, field, key, lo=lo, hi=hi,
                           hint=hint or "give one number (grey) or a list of three (R, G, B)"))
    return tuple(out)


def _choice(ctx, table, field, key, choices, default=None):
    where = f"{field}.{key}" if field else key
    if key not in table:
        if default is None:
            ctx.fail(where, "is missing", f"choose one of {', '.join(choices)}")
        return default
    v = table[key]
    if not isinstance(v, str) or v.lower() not in choices:
        ctx.fail(where, f"{quote(v)} is not one of {', '.join(choices)}",
                 f"choose one of {', '.join(choices)}")
    return v.lower()


def _bool(ctx, table, field, key, default):
    if key not in table:
        return default
    v = table[key]
    if not isinstance(v, bool):
        ctx.fail(f"{field}.{key}", f"{quote(v)} is not true or false", "write true or false (no quotes)")
    return v


def _angle_list(ctx, table, field, key, lo, hi, *, hi_open=False):
    where = f"{field}.{key}"
    v = table.get(key)
    values = v if isinstance(v, list) else [v]
    if v is None or not values:
        ctx.fail(where, "is missing or empty", "give a list of angles in degrees, e.g. [0, 30, 60]")
    return tuple(_number(ctx, {key: x}, field, key, lo=lo, hi=hi, hi_open=hi_open,
                         hint=f"angles are degrees in [{lo:g}, {hi:g}{')' if hi_open else ']'}")
                 for x in values)


# --------------------------------------------------------------------------------------------
# Sections
# --------------------------------------------------------------------------------------------


def _roughness(ctx, table, field):
    """The keyword arguments distribution, alpha, alpha_y, masking of the :class:`Boundary` of
    an interface or a substrate; alpha_y is None unless the widths are given as alpha_x, alpha_y
    (anisotropic), masking None unless the distribution is vmf."""
    dist, alpha, alpha_y = _widths(ctx, table, field)
    masking = None
    if dist == "vmf":
        masking = _choice(ctx, table, field, "masking", MASKINGS, default=DEFAULT_MASKING)
    elif "masking" in table:
        ctx.fail(f"{field}.masking", "only a vmf distribution has a masking choice",
                 "remove it, or choose distribution = \"vmf\" (masking = \"exact\": eq. 7 "
                 "integrated, the default; \"approx\": eq. 8)")
    return {"distribution": dist, "alpha": alpha, "alpha_y": alpha_y, "masking": masking}


def _widths(ctx, table, field):
    """(distribution, alpha, alpha_y) of an interface or a rough substrate."""
    dist = _choice(ctx, table, field, "distribution", INTERFACE_DISTRIBUTIONS, default="smooth")
    if dist == "smooth":
        for key in ("alpha", "kappa", "alpha_x", "alpha_y"):
            if key in table:
                ctx.fail(f"{field}.{key}", "a smooth interface has no roughness",
                         "remove it, or choose distribution = \"ggx\", \"beckmann\" or \"vmf\"")
        return dist, 0.0, None
    if "alpha_x" in table or "alpha_y" in table:
        if dist not in ANISOTROPIC_DISTRIBUTIONS:
            ctx.fail(f"{field}.alpha_x", f"the {dist} distribution is isotropic",
                     f"give one width alpha, or choose distribution = "
                     f"{' or '.join(repr(d) for d in ANISOTROPIC_DISTRIBUTIONS)}")
        if "alpha" in table or "kappa" in table:
            ctx.fail(f"{field}.alpha", "give either alpha or alpha_x and alpha_y, not both",
                     "alpha_x, alpha_y are the widths along the tangent +x and +y")
        widths = [_number(ctx, table, field, key, lo=1e-4, hi=1.0,
                          hint="give both widths alpha_x and alpha_y in [1e-4, 1]")
                  for key in ("alpha_x", "alpha_y")]
        return dist, widths[0], widths[1]
    if dist == "vmf" and "kappa" in table:
        if "alpha" in table:
            ctx.fail(f"{field}.kappa", "give either alpha or kappa, not both",
                     "kappa = 2/alpha^2 (fitlab/microfacet.py)")
        kappa = _number(ctx, table, field, "kappa", lo=1e-2, hi=1e7,
                        hint="the vMF concentration must lie in [1e-2, 1e7] (the thin "
                        "layer's range; kappa < 2 is wider than alpha = 1)")
        return dist, math.sqrt(2.0 / kappa), None
    if "kappa" in table:
        ctx.fail(f"{field}.kappa", "only a vmf distribution has a concentration kappa",
                 "use alpha for ggx and beckmann")
    alpha = _number(ctx, table, field, "alpha", lo=1e-4, hi=1.0,
                    hint="give the microfacet width alpha in [1e-4, 1] (or distribution = \"smooth\")")
    return dist, alpha, None


def _phase(ctx, table, field):
    ptype = _choice(ctx, table, field, "phase", PHASES, default="isotropic")
    g, rough, orient = 0.0, 1.0, (0.0, 0.0, 1.0)
    if ptype != "hg" and "g" in table:
        ctx.fail(f"{field}.g", f"only phase = \"hg\" has an asymmetry g (phase is {quote(ptype)})",
                 "remove g or set phase = \"hg\"")
    if not ptype.startswith("sggx"):
        for key in ("roughness", "orientation", "flake_f0"):
            if key in table:
                ctx.fail(f"{field}.{key}", f"only SGGX phases have {key} (phase is {quote(ptype)})",
                         "remove it or set phase = \"sggx_surface\" / \"sggx_fiber\"")
    if ptype == "hg":
        g = _number(ctx, table, field, "g", lo=-1.0, hi=1.0, lo_open=True, hi_open=True,
                    hint="the Henyey-Greenstein asymmetry g must lie in (-1, 1)")
    if ptype.startswith("sggx"):
        rough = _number(ctx, table, field, "roughness", lo=1e-3, hi=1.0,
                        hint="the SGGX roughness (SpongeCake's alpha) must lie in [1e-3, 1]")
        if "orientation" in table:
            v = table["orientation"]
            if not (isinstance(v, list) and len(v) == 3):
                ctx.fail(f"{field}.orientation", f"{quote(v)} is not a list of three numbers",
                         "give a direction [x, y, z], e.g. [0, 0, 1]")
            xyz = [_number(ctx, {"orientation": x}, field, "orientation") for x in v]
            norm = math.sqrt(sum(x * x for x in xyz))
            if norm == 0:
                ctx.fail(f"{field}.orientation", "is the zero vector", "give a non-zero direction")
            orient = tuple(x / norm for x in xyz)
        f0 = _per_channel(ctx, table, field, "flake_f0", default=(1.0,), hi=1.0,
                          hint="the flakes' Schlick reflectance f0 lies in [0, 1] (one value or "
                          "R, G, B; 1 = no Fresnel term)")
        return Phase(ptype, g, rough, orient, f0)
    return Phase(ptype, g, rough, orient)


#: Largest thickness or coefficient a scene may give: the walk runs in float32 (max 3.4e38), and
#: their product, an optical depth, must stay finite.
MAX_LENGTH = 1e30

_ROUGHNESS_KEYS = ("distribution", "alpha", "kappa", "alpha_x", "alpha_y", "masking")
_INTERFACE_KEYS = ("type",) + _ROUGHNESS_KEYS
_MEDIUM_KEYS = ("type", "index", "thickness", "sigma_a", "sigma_s", "phase", "g", "roughness",
                "orientation", "flake_f0")


def _medium(ctx, table, field):
    _check_keys(ctx, table, field, _MEDIUM_KEYS)
    index = _number(ctx, table, field, "index", lo=0.0, lo_open=True, hint="give the refractive "
                    "index of the medium, e.g. 1.5")
    thick = _number(ctx, table, field, "thickness", lo=0.0, hi=MAX_LENGTH,
                    hint="give the thickness (>= 0) in the length unit of 1/sigma")
    coeff = ("a coefficient in 1/length, at most 1e30 (the walk runs in float32); one value "
             "or R, G, B")
    sa = _per_channel(ctx, table, field, "sigma_a", default=(0.0,), hi=MAX_LENGTH, hint=coeff)
    ss = _per_channel(ctx, table, field, "sigma_s", default=(0.0,), hi=MAX_LENGTH, hint=coeff)
    phase = _phase(ctx, table, field)
    if thick == 0 and (max(sa) > 0 or max(ss) > 0):
        ctx.fail(f"{field}.thickness", "is 0 but the medium absorbs or scatters",
                 "give a positive thickness or set sigma_a = sigma_s = 0")
    if math.isinf(thick):
        ctx.fail(f"{field}.thickness", "must be finite", "use a large finite thickness")
    return Medium(index, thick, sa, ss, phase)


def _substrate(ctx, table, above_index):
    field = "substrate"
    kind = _choice(ctx, table, field, "type", SUBSTRATES)
    if kind == "lambertian":
        _check_keys(ctx, table, field, ("type", "albedo"))
        albedo = _per_channel(ctx, table, field, "albedo", hi=1.0,
                              hint="the albedo is a reflectance in [0, 1] (one value or R, G, B)")
        return Boundary("lambertian", albedo=albedo), None
    if kind == "conductor":
        _check_keys(ctx, table, field, ("type",) + _ROUGHNESS_KEYS + ("n", "k", "preset"))
        rough = _roughness(ctx, table, field)
        if "preset" in table:
            if "n" in table or "k" in table:
                ctx.fail("substrate.preset", "give either a preset or n and k, not both")
            name = _choice(ctx, table, field, "preset", tuple(CONDUCTOR_PRESETS))
            n, k = CONDUCTOR_PRESETS[name]["n"], CONDUCTOR_PRESETS[name]["k"]
        else:
            n = _per_channel(ctx, table, field, "n", lo=0.0, hint="the conductor's real index "
                             "n > 0 (one value or R, G, B), or a preset")
            k = _per_channel(ctx, table, field, "k", lo=0.0, hint="the extinction k >= 0")
            if min(n) <= 0:
                ctx.fail("substrate.n", "must be > 0", "give the real part of the complex index")
        return Boundary("conductor", n=tuple(n), k=tuple(k), **rough), None
    _check_keys(ctx, table, field, ("type",) + _ROUGHNESS_KEYS + ("index",))
    rough = _roughness(ctx, table, field)
    index = _number(ctx, table, field, "index", lo=0.0, lo_open=True,
                    hint="give the refractive index of the semi-infinite dielectric below")
    return Boundary("dielectric", **rough), index


def _detector(ctx, table, base_dir, illum_given):
    field = "detector"
    dtype = _choice(ctx, table, field, "type", DETECTORS)
    if dtype == "hemisphere":
        _check_keys(ctx, table, field, ("type", "sides", "theta_bins", "phi_bins", "estimator"))
        estimator = _estimator(ctx, table)
        sides = table.get("sides", list(SIDES))
        if not isinstance(sides, list) or not sides or any(s not in SIDES for s in sides) \
                or len(set(sides)) != len(sides):
            ctx.fail("detector.sides", f"{quote(sides)} is not a list of distinct sides",
                     "use [\"reflection\"], [\"transmission\"] or [\"reflection\", \"transmission\"]")
        tb = _number(ctx, table, field, "theta_bins", default=9.0, lo=1, hi=900)
        pb = _number(ctx, table, field, "phi_bins", default=36.0, lo=1, hi=3600)
        if tb != int(tb) or pb != int(pb):
            ctx.fail("detector.theta_bins", "bin counts must be whole numbers")
        return Detector("hemisphere", tuple(s for s in SIDES if s in sides), int(tb), int(pb),
                        estimator=estimator), None
    if dtype == "inplane":
        _check_keys(ctx, table, field, ("type", "theta_o", "acceptance_sr", "estimator"))
        estimator = _estimator(ctx, table)
        theta = _angle_list(ctx, table, field, "theta_o", -180.0, 180.0)
        if any(abs(abs(t) - 90.0) < 1e-9 for t in theta):
            ctx.fail("detector.theta_o", "±90° lies in the surface plane, where no flux leaves",
                     "remove it")
        omega = _acceptance(ctx, table, estimator)
        sides = tuple(s for s, on in (("reflection", any(abs(t) < 90 for t in theta)),
                                      ("transmission", any(abs(t) > 90 for t in theta))) if on)
        return Detector("inplane", sides, theta_o=theta, acceptance_sr=omega,
                        estimator=estimator), None
    _check_keys(ctx, table, field, ("type", "file", "acceptance_sr", "estimator"))
    estimator = _estimator(ctx, table)
    if illum_given:
        ctx.fail("illumination", "a measurement detector takes its incident directions from the "
                 "file", "remove the [illumination] table")
    name = table.get("file")
    if not isinstance(name, str) or not name:
        ctx.fail("detector.file", "is missing", "give the measurement CSV whose directions to "
                 "simulate, relative to the scene file")
    path = (base_dir / name) if not Path(name).is_absolute() else Path(name)
    if not path.is_file():
        ctx.fail("detector.file", f"{quote(name)} does not exist (looked for {path})",
                 "give a path relative to the scene file's folder")
    omega = _acceptance(ctx, table, estimator)
    from fitlab.io.formats import HEAD_BYTES
    from fitlab.io.measurement import FORMAT, read_measurement

    if not FORMAT.detect(read_bytes(path, limit=HEAD_BYTES), path):
        # say so without showing the file: it may be anything the scene points at
        ctx.fail("detector.file", f"{quote(name)} is not a fitlab measurement CSV (no header "
                 "line with theta_i, phi_i, theta_o, phi_o)",
                 "give a measurement CSV (data_formats/measurement_csv.md)")
    m = read_measurement(path)  # raises its own InputFileError naming that file
    if (m.wi[:, 2] <= 0).any():
        ctx.fail("detector.file", f"{path} has incidence from below the surface (theta_i > 90)",
                 "fitlab simulate illuminates from the outside (+z) only")
    trans = (m.wo[:, 2] < 0)
    sides = tuple(s for s, on in (("reflection", (~trans).any()), ("transmission", trans.any())) if on)
    return Detector("measurement", sides, acceptance_sr=omega, file=str(path),
                    estimator=estimator), m


def _estimator(ctx, table):
    return _choice(ctx, table, "detector", "estimator", ESTIMATORS, default="cone")


def _acceptance(ctx, table, estimator="cone"):
    if estimator == "point":
        if "acceptance_sr" in table:
            ctx.fail("detector.acceptance_sr", "a point estimate has no acceptance solid angle",
                     "remove acceptance_sr, or set estimator = \"cone\"")
        return 0.0
    return _number(ctx, table, "detector", "acceptance_sr", lo=0.0, hi=1.0, lo_open=True,
                   hint="give the detector's acceptance solid angle in steradians, e.g. 0.001")


def _effects(ctx, table):
    field = "effects"
    _check_keys(ctx, table, field, ("max_bounces", "russian_roulette", "absorption",
                                    "volume_scattering", "delta", "color",
                                    "split_first_interface"))
    mb = table.get("max_bounces", "all")
    if mb == "all":
        max_bounces = None
    elif isinstance(mb, int) and not isinstance(mb, bool) and 0 <= mb <= 1000:
        max_bounces = int(mb)
    else:
        ctx.fail("effects.max_bounces", f"{quote(mb)} is not \"all\" or a whole number 0..1000",
                 "0 = top surface only, 1 = one-bounce subsurface reflection, ..., \"all\"")
    return Effects(
        max_bounces=max_bounces,
        russian_roulette=_bool(ctx, table, field, "russian_roulette", True),
        absorption=_bool(ctx, table, field, "absorption", True),
        volume_scattering=_choice(ctx, table, field, "volume_scattering", VOLUME_SCATTERING,
                                  default="multiple"),
        delta=_bool(ctx, table, field, "delta", True),
        color=_choice(ctx, table, field, "color", COLORS, default="auto"),
        split_first_interface=_bool(ctx, table, field, "split_first_interface", False),
    )


_TOP_KEYS = ("format", "version", "name", "description", "outside", "stack", "substrate", "below",
             "illumination", "detector", "effects")


def scene_from_dict(d: dict, source: str = "<dict>", base_dir=".") -> Scene:
    """Validate a scene given as a dict with the TOML file's structure (data_formats/scene_toml.md).

    ``source`` names the origin in error messages; ``base_dir`` resolves a measurement
    detector's relative ``file``. Raises :class:`fitlab.errors.InputFileError`."""
    ctx = _Ctx(str(source))
    _check_keys(ctx, d, "", _TOP_KEYS)
    if d.get("format", "fitlab-scene") != "fitlab-scene":
        ctx.fail("format", f"{d['format']!r} is not \"fitlab-scene\"", "remove it or fix it")
    if d.get("version", 1) != 1:
        ctx.fail("version", f"{quote(d['version'])} is not a version this fitlab reads (1)",
                 "write version = 1")
    name = d.get("name", Path(str(source)).stem)
    if not isinstance(name, str):
        ctx.fail("name", "must be a string")
    outside = d.get("outside", {})
    _check_keys(ctx, outside, "outside", ("index",))
    n_out = _number(ctx, outside, "outside", "index", default=1.0, lo=0.0, lo_open=True,
                    hint="give the refractive index of the outside medium, e.g. 1.0")

    stack = d.get("stack", [])
    if not isinstance(stack, list):
        ctx.fail("stack", "must be an array of tables", "write each item as [[stack]]")
    media, boundaries, origin = [], [], []
    pending = None  # an interface waiting for the region under it
    pending_field = None
    last_index = n_out
    for j, item in enumerate(stack):
        field = f"stack[{j}]"
        if not isinstance(item, dict):
            ctx.fail(field, "must be a table", "write each item as [[stack]] with type = ...")
        kind = _choice(ctx, item, field, "type", ("interface", "medium"))
        if kind == "interface":
            _check_keys(ctx, item, field, _INTERFACE_KEYS)
            if pending is not None:
                ctx.fail(field, "two interfaces in a row", "put a [[stack]] type = \"medium\" "
                         "between them (an interface separates two media)")
            pending = Boundary("dielectric", **_roughness(ctx, item, field))
            pending_field = field
        else:
            med = _medium(ctx, item, field)
            if pending is None:
                if med.index != last_index:
                    ctx.fail(f"{field}.index", f"{med.index:g} differs from the index above "
                             f"({last_index:g}) but no interface separates them",
                             "add a [[stack]] type = \"interface\" above this medium, or make "
                             "the indices equal")
                pending, pending_field = Boundary("pass"), field
            boundaries.append(pending)
            origin.append(pending_field)
            media.append(med)
            pending = None
            last_index = med.index

    sub = d.get("substrate")
    below = d.get("below")
    opaque = False
    if sub is not None:
        if below is not None:
            ctx.fail("below", "a scene with a [substrate] has no [below] medium",
                     "remove [below] (a dielectric substrate states its own index)")
        if pending is not None:
            ctx.fail("substrate", "sits directly under an interface",
                     "put a medium between the last interface and the substrate")
        b, index = _substrate(ctx, sub, last_index)
        if b.kind == "dielectric":
            if index == last_index:
                ctx.fail("substrate.index", "equals the index above it, so there is no interface",
                         "use [below] index = ... instead, or change the index")
            boundaries.append(b)
            origin.append("substrate")
            n_below = index
        else:
            boundaries.append(b)
            origin.append("substrate")
            n_below = last_index
            opaque = True
    else:
        below = below if below is not None else {}
        _check_keys(ctx, below, "below", ("index",))
        n_below = _number(ctx, below, "below", "index", default=n_out, lo=0.0, lo_open=True,
                          hint="give the refractive index of the medium under the stack")
        if pending is not None:
            boundaries.append(pending)
            origin.append(pending_field)
        else:
            if n_below != last_index:
                ctx.fail("below.index", f"{n_below:g} differs from the index above it "
                         f"({last_index:g}) but no interface separates them",
                         "end the stack with a [[stack]] type = \"interface\"")
            boundaries.append(Boundary("pass"))
            origin.append("below")
    if not any(b.kind != "pass" for b in boundaries) and not media:
        ctx.fail("stack", "the scene has no interface, medium or substrate",
                 "describe at least one [[stack]] item or a [substrate]")
    for j, b in enumerate(boundaries):
        if b.kind == "dielectric":
            above = (n_out, *(m.index for m in media))[j]
            under = (*(m.index for m in media), n_below)[j]
            if above == under:
                ctx.fail(origin[j],
                         f"both sides have index {above:g}: the interface would be invisible",
                         "remove the interface or change an index")

    det_table = d.get("detector")
    if det_table is None:
        ctx.fail("detector", "is missing", "add a [detector] table (type = \"hemisphere\", "
                 "\"inplane\" or \"measurement\")")
    illum = d.get("illumination")
    detector, meas = _detector(ctx, det_table, Path(base_dir), illum is not None)
    if meas is not None:
        theta_i, phi_i = (), ()
    else:
        if illum is None:
            ctx.fail("illumination", "is missing", "add [illumination] theta_i = [0, 30, 60]")
        _check_keys(ctx, illum, "illumination", ("theta_i", "phi_i"))
        theta_i = _angle_list(ctx, illum, "illumination", "theta_i", 0.0, 90.0, hi_open=True)
        if "phi_i" in illum:
            phi_i = _angle_list(ctx, illum, "illumination", "phi_i", -360.0, 360.0)
            if len(phi_i) != len(theta_i):
                ctx.fail("illumination.phi_i", f"has {len(phi_i)} values for {len(theta_i)} "
                         "theta_i", "give one phi_i per theta_i, or leave phi_i out (0)")
        else:
            phi_i = (0.0,) * len(theta_i)
        if len(set(zip(theta_i, phi_i))) != len(theta_i):
            ctx.fail("illumination.theta_i", "lists the same incident direction twice",
                     "remove the repetition")
    if opaque and detector.sides == ("transmission",):
        ctx.fail("detector.sides", "only transmission is observed but the substrate is opaque",
                 "observe reflection, or use a dielectric substrate")
    effects = _effects(ctx, d.get("effects", {}))
    if detector.estimator == "point":
        _check_point_estimates(ctx, boundaries, detector.sides)
    if effects.split_first_interface:
        _check_split(ctx, boundaries[0], detector)

    counts = {len(m.sigma_a) for m in media} | {len(m.sigma_s) for m in media} | \
        {len(m.phase.f0) for m in media} | \
        {len(b.albedo) for b in boundaries if b.albedo} | {len(b.n) for b in boundaries if b.n} | \
        {len(b.k) for b in boundaries if b.k}
    channels = 3 if 3 in counts else 1
    if effects.color == "mono" and channels == 3:
        ctx.fail("effects.color", "is \"mono\" but some properties have three (R, G, B) values",
                 "set color = \"rgb\" (or \"auto\"), or give single values")
    boundaries = [b._replace(field=where) for b, where in zip(boundaries, origin)]
    return Scene(str(source), name, n_out, tuple(media), tuple(boundaries), n_below, opaque,
                 theta_i, phi_i, detector, effects, channels)


def boundary_classes(boundaries) -> tuple:
    """What each boundary does to a crossing path, for point estimates
    (:func:`fitlab.simulate.detectors.point_connections`)."""
    from fitlab.simulate.detectors import PASS, ROUGH, SMOOTH

    return tuple(PASS if b.kind == "pass" else SMOOTH if b.distribution == "smooth"
                 and b.kind in ("dielectric", "conductor") else ROUGH for b in boundaries)


def _check_split(ctx, top, detector):
    """Splitting at the first interface needs a dielectric top, observed reflection, and bins
    or cones (point estimates connect the first crossing exactly already)."""
    where = "effects.split_first_interface"
    if top.kind != "dielectric":
        ctx.fail(where, "the top of the stack is not a dielectric interface, so its first "
                 "crossing has no reflected and refracted branch to split",
                 "remove split_first_interface, or start the stack with an interface")
    if "reflection" not in detector.sides:
        ctx.fail(where, "reflection is not observed: the split-off reflection would not be "
                 "tallied (the walk already forces the refracted branch)",
                 "remove split_first_interface")
    if detector.estimator == "point":
        ctx.fail(where, "point estimates already take the first crossing's reflection "
                 "exactly (a next-event connection)", "remove split_first_interface")


def _check_point_estimates(ctx, boundaries, sides):
    from fitlab.simulate.detectors import point_connections

    up, down = point_connections(boundary_classes(boundaries))
    for side, (_, why) in zip(SIDES, (up, down)):
        if side in sides and why is not None:
            ctx.fail("detector.estimator", f"point estimates of {side} are not possible for "
                     f"this stack: {why}", "use estimator = \"cone\" (with acceptance_sr)")


def load_scene(path) -> Scene:
    """Read and validate a scene TOML file (data_formats/scene_toml.md)."""
    path = Path(path)
    raw = read_bytes(path, folder_hint="give a scene TOML file")
    d = load_toml(path, raw, what="scene",
                  hint="see data_formats/scene_toml.md for the scene's syntax and shape")
    return scene_from_dict(d, source=str(path), base_dir=path.parent)
