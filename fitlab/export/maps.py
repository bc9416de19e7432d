"""The folder of a map fit (``fitlab fit-maps STACK --out-dir DIR``, :func:`write_maps`;
data_formats/stack.md, "Outputs"): float32 OpenEXR maps, ``maps.json`` and the renderer
hand-off, written all or nothing.

* ``PARAM.exr`` per free parameter (channels R, G, B for a per-channel parameter, Y for one
  shared by the channels or of a one-channel stack) and ``PARAM_std.exr``, its standard error;
* ``rms.exr``: the fit error per texel and channel (the RMS relative error of fitlab.metrics);
* ``status.exr`` (Y): ``Status.code`` per texel, 0 converged;
* ``maps.json``: model, conventions, settings, provenance, the files and the status counts;
* ``mitsuba.xml`` with ``mitsuba/*.exr`` where Mitsuba 3 evaluates the model natively
  (fitlab/export/mitsuba.py's translation, made for every texel at once on arrays over the
  texels: a property that varies over the texels becomes a ``bitmap`` texture of its values,
  one that does not stays a number);
* with ``gltf``: ``material.gltf`` (its PNG textures embedded) and ``gltf/conversion_rms.exr``
  (fitlab/export/gltf_maps.py).

The files go to a temporary folder beside DIR, which then replaces DIR (an earlier map fit's
folder, or an empty one): a failure leaves nothing partial. The same inputs give the same
bytes (no clock time, no absolute path).
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np

from fitlab.errors import FitlabError
from fitlab.fitting.status import Status

SCHEMA = "fitlab-maps"
SCHEMA_VERSION = 1
RECORD = "maps.json"
MITSUBA_SCENE = "mitsuba.xml"
MITSUBA_FOLDER = "mitsuba"


def check_out_dir(out_dir) -> Path:
    """``out_dir`` if a map fit may write there: absent (it is made, with its parents, when the
    maps are written), empty, or an earlier map fit's folder (it holds maps.json of this
    schema); FitlabError otherwise, before anything is fitted."""
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise FitlabError(f"--out-dir {out}: is a file; give a folder (it is created)")
    if out.is_dir() and any(out.iterdir()):
        rec = out / RECORD
        try:
            ok = json.loads(rec.read_text(encoding="utf-8")).get("schema") == SCHEMA
        except (OSError, ValueError, AttributeError):
            ok = False
        if not ok:
            raise FitlabError(f"--out-dir {out}: the folder holds other files; give a new or "
                              "empty folder, or an earlier fit-maps folder (it is replaced)")
    if out.parent.exists() and not out.parent.is_dir():
        raise FitlabError(f"--out-dir {out}: {out.parent} is a file, not a folder")
    return out


def _channels(width: int, names) -> tuple[str, ...]:
    return ("Y",) if width == 1 else tuple(names)


def _planes(array, names) -> dict:
    """{EXR channel: (H, W) plane} of an (H, W, k) array."""
    return {c: array[:, :, k] for k, c in enumerate(_channels(array.shape[2], names))}


def _num(x) -> float | None:
    x = float(x)
    return x if np.isfinite(x) else None


def material_at(result, y: int, x: int):
    """The fitted material of texel (x, y) (fitlab.export.material.Material: per channel its
    parameters, fixed ones included), or None where it was not fitted."""
    from fitlab.export.material import Material

    channels = {}
    for k, c in enumerate(result.channel_names):
        params = dict(result.fixed)
        for p, arr in result.values.items():
            v = arr[y, x, 0 if arr.shape[2] == 1 else k]
            if not np.isfinite(v):
                return None
            params[p] = float(v)
        channels[c] = params
    return Material(result.model, dict(result.options), channels, RECORD)


def _leaves(obj, path=()):
    """(path, value) of every number of a Mitsuba plugin dict (an ``rgb`` value is one leaf
    of three numbers), and (path, other) of its structure."""
    if isinstance(obj, dict) and obj.get("type") == "rgb":
        yield path, ("rgb", tuple(float(v) for v in obj["value"]))
        return
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield from _leaves(v, path + (k,))
        return
    if isinstance(obj, float) and not isinstance(obj, bool):
        yield path, ("float", (obj,))
        return
    yield path, ("fixed", obj)


def _set(obj, path, value):
    for k in path[:-1]:
        obj = obj[k]
    obj[path[-1]] = value


def _texels_material(result, seen):
    """The material of every fitted texel at once (``seen``: (H, W) which), its values
    arrays over those texels in row-major order (fitlab.export.material.Material)."""
    from fitlab.export.material import Material

    channels = {}
    for k, c in enumerate(result.channel_names):
        params = dict(result.fixed)
        for p, arr in result.values.items():
            params[p] = arr[:, :, 0 if arr.shape[2] == 1 else k][seen].astype(float)
        channels[c] = params
    return Material(result.model, dict(result.options), channels, RECORD)


def _batch_handoff(result):
    """:func:`mitsuba_handoff` from one translation of every fitted texel at once (the
    translation on arrays over the texels: fitlab/export/mitsuba.py), or None where that
    cannot say the same (a refusal, a form that changes, a spectrum: the texel by texel
    translation says why)."""
    from fitlab.export.material import ExportError
    from fitlab.export.mitsuba import native_bsdf

    seen = np.ones(result.shape, dtype=bool)
    for arr in result.values.values():
        seen &= np.all(np.isfinite(arr), axis=2)
    if not seen.any():
        return None
    try:
        bsdf = native_bsdf(_texels_material(result, seen))
    except ExportError:
        return None
    leaves = {}
    for path, obj in _batch_leaves(bsdf):
        if obj is None:
            return None
        leaves[path] = obj
    T = int(seen.sum())
    first = json.loads(json.dumps(_first_texel(bsdf)))
    textures, scene = {}, json.loads(json.dumps(first))
    for p, (kind, v) in leaves.items():
        if kind == "fixed":
            continue
        flat = np.stack([np.broadcast_to(np.asarray(a, float), (T,)) for a in v], axis=1)
        width = flat.shape[1]
        if np.all(flat == flat[0]):  # the same at every texel: a number stays a number
            v0 = flat[0]
            _set(scene, p, float(v0[0]) if width == 1 else {"type": "rgb",
                                                            "value": [float(a) for a in v0]})
            continue
        arr = np.zeros(result.shape + (width,))
        arr[seen] = flat
        arr[~seen] = flat[0]
        name = f"{MITSUBA_FOLDER}/{'.'.join(p)}.exr"
        textures[name] = arr
        _set(scene, p, {"type": "bitmap", "filename": name, "raw": True,
                        "filter_type": "nearest"})
    return scene, textures


def _batch_leaves(obj, path=()):
    """:func:`_leaves` of a translation of many texels: a number is a float or an array over
    the texels; (path, None) where an array sits elsewhere (a spectrum's pairs)."""
    if isinstance(obj, dict) and obj.get("type") == "rgb":
        yield path, ("rgb", tuple(obj["value"]))
        return
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield from _batch_leaves(v, path + (k,))
        return
    if isinstance(obj, np.ndarray) or (isinstance(obj, float) and not isinstance(obj, bool)):
        yield path, ("float", (obj,))
        return
    yield path, (None if _has_array(obj) else ("fixed", obj))


def _has_array(obj) -> bool:
    if isinstance(obj, np.ndarray):
        return True
    if isinstance(obj, (list, tuple)):
        return any(_has_array(x) for x in obj)
    if isinstance(obj, dict):
        return any(_has_array(x) for x in obj.values())
    return False


def _first_texel(obj):
    """A translation of many texels at its first texel (JSON-ready)."""
    if isinstance(obj, dict):
        return {k: _first_texel(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_first_texel(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return float(obj[0])
    return obj


def mitsuba_handoff(result):
    """(scene dict with ``bitmap`` textures, {texture file: (H, W, k) array}) of the model's
    native Mitsuba 3 translation at every fitted texel, or (None, reason) where it has none.
    Texels not fitted take the first fitted texel's values (status.exr marks them). One
    translation on arrays over the texels (:func:`_batch_handoff`); texel by texel where that
    cannot say the same."""
    from fitlab.export.material import ExportError
    from fitlab.export.mitsuba import native_bsdf

    batch = _batch_handoff(result)
    if batch is not None:
        return batch

    H, W = result.shape
    first, form, per = None, None, {}
    for y in range(H):
        for x in range(W):
            mat = material_at(result, y, x)
            if mat is None:
                continue
            try:
                bsdf = native_bsdf(mat)
            except ExportError as exc:
                return None, str(exc)
            leaves = dict(_leaves(bsdf))
            # the dict's form: its keys, its non-numbers, which numbers are RGB
            shape = tuple((p, v[0], v[1] if v[0] == "fixed" else None)
                          for p, v in leaves.items())
            if first is None:
                first, form = bsdf, shape
            elif shape != form:
                return None, ("Mitsuba's translation of the model changes form from texel to "
                              f"texel (texel x={x}, y={y} against the first fitted one)")
            per[(y, x)] = leaves
    if first is None:
        return None, "no texel was fitted"
    textures, scene = {}, json.loads(json.dumps(first))
    numbers = [p for p, v in dict(_leaves(first)).items() if v[0] != "fixed"]
    seen = np.zeros((H, W), dtype=bool)
    for (y, x) in per:
        seen[y, x] = True
    for p in numbers:
        width = len(per[next(iter(per))][p][1])
        arr = np.zeros((H, W, width))
        for (y, x), leaves in per.items():
            arr[y, x] = leaves[p][1]
        arr[~seen] = per[next(iter(per))][p][1]
        flat = arr[seen]
        if np.all(flat == flat[0]):  # the same at every texel: a number stays a number
            v = flat[0]
            _set(scene, p, float(v[0]) if width == 1 else {"type": "rgb",
                                                          "value": [float(a) for a in v]})
            continue
        name = f"{MITSUBA_FOLDER}/{'.'.join(p)}.exr"
        textures[name] = arr
        _set(scene, p, {"type": "bitmap", "filename": name, "raw": True,
                        "filter_type": "nearest"})
    return scene, textures


def build_record(result, out_dir, files: dict, mitsuba, gltf: dict) -> dict:
    """``maps.json`` (data_formats/stack.md, "maps.json")."""
    from fitlab.io.conventions import CONVENTIONS
    from fitlab.io.files import path_for_record
    from fitlab.models import get_model
    from fitlab.version import __version__

    model = get_model(result.model)
    stack = result.stack
    params = {}
    for p, arr in result.values.items():
        spec = next(q for q in model.parameters if q.name == p)
        params[p] = {"file": f"{p}.exr", "stderr_file": f"{p}_std.exr",
                     "channels": list(_channels(arr.shape[2], result.channel_names)),
                     "shared": p in result.shared, "unit": spec.unit, "lower": spec.lower,
                     "upper": spec.upper, "description": spec.description}
    codes = {str(s.code): s.value for s in Status}
    return {
        "schema": SCHEMA, "schema_version": SCHEMA_VERSION,
        "model": result.model, "options": dict(result.options),
        "fixed": {k: float(v) for k, v in result.fixed.items()},
        "conventions": CONVENTIONS,
        "stack": {"folder": path_for_record(stack.path, Path(out_dir) / RECORD),
                  "sha256": stack.sha256, "images": stack.n_images,
                  "width": result.shape[1], "height": result.shape[0],
                  "channels": list(result.channel_names)},
        "settings": result.settings,
        "parameters": params,
        "rms": {"file": "rms.exr", "channels": list(result.channel_names),
                "definition": "the fit error of fitlab fit (statistics.fit_error, "
                "fitlab.metrics): RMS relative error (pred - value)/value over the texel's "
                "fitted readings, readings below 1% of their incidence's peak left out; NaN "
                "where the texel was not fitted"},
        "status": {"file": "status.exr", "channels": ["Y"],
                   "rule": "per texel the code of its first status that is not converged "
                   "(channels in order), 0 when every channel converged",
                   "codes": codes, "counts": result.counts()},
        "texel_layout": "texel (x, y) of every map is pixel (x, y) of the stack's images (y "
                        "down from the top row)",
        "handoff": {"mitsuba": mitsuba, "gltf": gltf},
        "notes": list(result.notes),
        "files": sorted(files),
        "version": __version__,
    }


#: maps.json's word for a glTF hand-off that was not asked for.
GLTF_NOT_ASKED = ("not requested: --gltf (gltf=True) fits glTF's BRDF to every texel, a second "
                  "fit per texel")


def _gltf_part(result, conv, images: dict, others: dict) -> dict:
    """The glTF document and textures of the conversion ``conv`` into ``others`` and
    ``images`` (its fit error map); maps.json's ``handoff.gltf``."""
    from fitlab.export.gltf_maps import DOCUMENT, FOLDER, gltf_maps
    from fitlab.export.gltf_material import gltf_text

    doc, textures = gltf_maps(conv, result.model)
    others[DOCUMENT] = gltf_text(doc).encode("utf-8")
    rms_name = f"{FOLDER}/conversion_rms.exr"
    images[rms_name] = (_planes(conv.rms, result.channel_names),
                        {"fitlab.quantity": "glTF conversion: rms relative error"})
    finite = conv.rms[np.isfinite(conv.rms)]
    return {"written": True, "document": DOCUMENT, "embedded_textures": sorted(textures),
            "gltf_model": "gltf_pbr", "fixed": {"ior": 1.5, "specular_color": 1.0},
            "pairs": int(conv.stack.n_images), "pair_stride": conv.settings.get("pair_stride"),
            "conversion_rms_file": rms_name,
            "conversion_rms": {"median": _num(np.median(finite)) if finite.size else None,
                               "max": _num(np.max(finite)) if finite.size else None},
            "status_counts": conv.counts()}


def read_maps_record(folder) -> dict:
    """A map-fit folder's ``maps.json``, checked against its JSON Schema
    (data_formats/schemas/maps.schema.json): what ``fitlab report`` and the three.js render
    read; InputFileError naming the file and field otherwise."""
    from fitlab.errors import InputFileError
    from fitlab.io.files import read_bytes
    from fitlab.io.validate import check_schema, load_json

    path = Path(folder) / "maps.json"
    rec = load_json(path, read_bytes(path), what="maps record")
    hint = "give a folder written by fitlab fit-maps"
    if not isinstance(rec, dict) or rec.get("schema") != "fitlab-maps":
        raise InputFileError(path, "is not a fitlab-maps record", column="schema", hint=hint)
    return check_schema(rec, "maps", path, hint=hint)


def write_maps(result, out_dir, *, gltf=None) -> dict:
    """Write ``result`` (fitlab.fitting.maps.MapsResult) into ``out_dir`` (module text);
    returns ``maps.json``'s record. ``gltf``: the glTF conversion
    (fitlab.fitting.maps.convert_to_gltf's MapsResult), or why there is none (text), or None
    (not asked for)."""
    from fitlab.export.mitsuba import scene_xml
    from fitlab.io.exr_image import write_image

    out = check_out_dir(out_dir)
    names = result.channel_names
    images = {}
    for p, arr in result.values.items():
        images[f"{p}.exr"] = (_planes(arr, names), {"fitlab.parameter": p})
        images[f"{p}_std.exr"] = (_planes(result.stderr[p], names),
                                  {"fitlab.parameter": f"{p} standard error"})
    images["rms.exr"] = (_planes(result.rms, names), {"fitlab.quantity": "rms relative error"})
    images["status.exr"] = ({"Y": result.status.astype(np.float32)},
                            {"fitlab.quantity": "status code (maps.json)"})
    scene, textures = mitsuba_handoff(result)
    if scene is None:
        mitsuba = {"written": False, "reason": textures}
    else:
        mitsuba = {"written": True, "scene": MITSUBA_SCENE, "textures": sorted(textures)}
        for name, arr in textures.items():
            images[name] = (_planes(arr, ("R", "G", "B")) if arr.shape[2] == 3
                            else {"Y": arr[:, :, 0]}, {"fitlab.quantity": "Mitsuba property"})
    others = {}  # other files: name -> bytes
    if gltf is None or isinstance(gltf, str):
        gltf_rec = {"written": False, "reason": gltf or GLTF_NOT_ASKED}
    else:
        gltf_rec = _gltf_part(result, gltf, images, others)
    files = dict.fromkeys(list(images) + list(others))
    if scene is not None:
        files[MITSUBA_SCENE] = None
    files[RECORD] = None
    record = build_record(result, out, files, mitsuba, gltf_rec)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".tmp", dir=out.parent))
    try:
        for name, (planes, attrs) in images.items():
            (tmp / name).parent.mkdir(parents=True, exist_ok=True)
            write_image(tmp / name, planes, {"fitlab.schema": SCHEMA, **attrs})
        for name, data in others.items():
            (tmp / name).parent.mkdir(parents=True, exist_ok=True)
            (tmp / name).write_bytes(data)
        if scene is not None:
            (tmp / MITSUBA_SCENE).write_text(scene_xml(scene, comment=(
                f"fitlab fit-maps: {result.model}; textures under {MITSUBA_FOLDER}/ "
                "(data_formats/stack.md)")), encoding="utf-8")
        (tmp / RECORD).write_text(json.dumps(record, indent=1, allow_nan=False) + "\n",
                                  encoding="utf-8")
        os.chmod(tmp, 0o777 & ~_umask())
        _replace_dir(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return record


def _umask() -> int:
    from fitlab.io.atomic import current_umask

    return current_umask()


def _replace_dir(tmp: Path, out: Path) -> None:
    """Put the finished folder ``tmp`` at ``out`` (an earlier one is removed after)."""
    if out.exists():
        old = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".old", dir=out.parent))
        os.rmdir(old)
        os.replace(out, old)
        os.replace(tmp, out)
        shutil.rmtree(old, ignore_errors=True)
    else:
        os.replace(tmp, out)


__all__ = ["SCHEMA", "SCHEMA_VERSION", "RECORD", "check_out_dir", "material_at",
           "mitsuba_handoff", "build_record", "write_maps"]
