"""A glTF file in a real glTF renderer: three.js renders its first material in headless
Chromium on a virtual goniometer, and the Khronos glTF validator (Node.js) checks the file
(``fitlab export X.gltf --check``; the tests in tests/export/test_gltf_browser.py).

The goniometer page (``web/gltf_goniometer.html``, tests/browser/README.md): for each direction
pair (wi, wo) a flat patch (normal +z, tangent +x: fitlab's local frame) with the file's
material under one directional light of irradiance 1 from wi, seen by an orthographic camera
from wo, rendered into a float target with no tone mapping; each pixel is f(wi, wo)·cos θi as
three.js computes it. The page loads three.js from a ``node_modules`` folder (never a CDN) and is
served from localhost (ES modules do not load from ``file://``). The views page
(``web/gltf_views.html``, :func:`render_views`) renders a file's own scene, e.g. a map fit's
textured quad, under the same light and camera and returns whole images with the cameras'
matrices (fitlab/export/gltf_maps_render.py). :func:`run_page` is the plumbing both share.

What it needs, found here (:func:`missing`): the npm package ``three`` (and ``gltf-validator``
for the validator) in a ``node_modules`` folder (``$FITLAB_NODE_MODULES``, else ``./node_modules``,
else the one beside a fitlab checkout: ``npm ci`` there installs the versions package.json pins),
Chromium (``$FITLAB_CHROMIUM``, else ``chromium``, ``chromium-browser``, ``google-chrome`` on the
PATH) and, for the validator, ``node``.
"""

from __future__ import annotations

import functools
import html
import http.server
import json
import os
import shutil
import subprocess
import tempfile
import threading
from pathlib import Path

import numpy as np

from fitlab.errors import FitlabError

WEB = Path(__file__).resolve().parent / "web"
PAGE = WEB / "gltf_goniometer.html"
VIEWS_PAGE = WEB / "gltf_views.html"
VALIDATOR_SCRIPT = WEB / "validate_gltf.mjs"
#: Environment variables naming the node_modules folder and the browser.
NODE_MODULES_ENV = "FITLAB_NODE_MODULES"
CHROMIUM_ENV = "FITLAB_CHROMIUM"
BROWSERS = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")
#: What a user installs for the three.js check (printed when it cannot run).
INSTALL = ("Chromium (apt-get install chromium) and the npm package three in a node_modules "
           "folder (npm ci in a fitlab checkout, or npm install three gltf-validator in the "
           f"working folder; ${NODE_MODULES_ENV} may name the folder; needs Node.js: apt-get "
           "install nodejs npm)")


class RenderError(FitlabError):
    """three.js (or the browser, or the validator) did not give an answer."""


def node_modules() -> Path | None:
    """The node_modules folder to load three.js from (see the module's doc), or None."""
    env = os.environ.get(NODE_MODULES_ENV, "").strip()
    candidates = [Path(env)] if env else [
        Path.cwd() / "node_modules", Path(__file__).resolve().parents[2] / "node_modules"]
    for c in candidates:
        if (c / "three" / "build" / "three.module.js").is_file():
            return c
    return None


def browser() -> str | None:
    """The Chromium executable, or None."""
    env = os.environ.get(CHROMIUM_ENV, "").strip()
    if env:
        return shutil.which(env) or (env if os.access(env, os.X_OK) else None)
    for name in BROWSERS:
        path = shutil.which(name)
        if path:
            return path
    return None


def _version(mods: Path, package: str) -> str | None:
    try:
        return json.loads((mods / package / "package.json").read_text())["version"]
    except (OSError, ValueError, KeyError):
        return None


def missing() -> str | None:
    """Why three.js cannot render here (None: it can)."""
    lacks = []
    if node_modules() is None:
        where = os.environ.get(NODE_MODULES_ENV) or "./node_modules or a fitlab checkout's"
        lacks.append(f"the npm package three (not in {where})")
    if browser() is None:
        lacks.append("Chromium")
    return " and ".join(lacks) + " not found" if lacks else None


def validator_missing() -> str | None:
    """Why the Khronos validator cannot run here (None: it can)."""
    mods = node_modules()
    if not shutil.which("node"):
        return "Node.js is not installed"
    if mods is None or _version(mods, "gltf-validator") is None:
        return "the npm package gltf-validator is not installed"
    return None


class _Quiet(http.server.SimpleHTTPRequestHandler):
    def log_message(self, *args):
        pass


#: Chromium's virtual-time budgets (ms) of a page's runs: the second only if the first ended
#: with the page still pending.
VIRTUAL_TIME_MS = (60_000, 600_000)


def _dump(chrome: str, url: str, tmp: Path, budget_ms: int, timeout: float):
    """One headless Chromium run of ``url``: (the text of ``<pre id="result">`` or None, the
    completed process)."""
    cmd = [chrome, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
           "--no-first-run", "--disable-background-networking",
           "--disable-component-update", "--disable-sync",
           "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
           f"--user-data-dir={tmp / 'profile'}", f"--virtual-time-budget={budget_ms}",
           "--dump-dom", url]
    try:
        out = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout,
                             env={**os.environ, "HOME": str(tmp)})
    except subprocess.TimeoutExpired:
        raise RenderError(f"{chrome} did not finish the three.js render in "
                          f"{timeout:g} s") from None
    text = out.stdout
    start = text.find('<pre id="result">')
    if start < 0:
        return None, out
    return html.unescape(text[start + len('<pre id="result">'):text.index("</pre>", start)]), out


def run_page(page: Path, config: dict, files: dict, *, timeout: float = 180.0) -> dict:
    """Serve ``page`` (as index.html) with ``config`` (config.json), ``files`` (name -> path,
    copied beside it) and node_modules from localhost, load it in headless Chromium and return
    the JSON the page writes into ``<pre id="result">`` (``ok`` true, or ``error``). The
    plumbing of every three.js page of fitlab (web/)."""
    mods, chrome = node_modules(), browser()
    if mods is None or chrome is None:
        raise RenderError(f"three.js cannot render here: {missing()}; install {INSTALL}")
    with tempfile.TemporaryDirectory(prefix="fitlab-gltf-page-") as tmp:
        tmp = Path(tmp)
        (tmp / "node_modules").symlink_to(mods.resolve())
        shutil.copy(page, tmp / "index.html")
        for name, source in files.items():
            shutil.copy(source, tmp / name)
        (tmp / "config.json").write_text(json.dumps(config))
        handler = functools.partial(_Quiet, directory=str(tmp))
        server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
        thread = threading.Thread(target=server.serve_forever, daemon=True)
        thread.start()
        try:
            url = f"http://127.0.0.1:{server.server_address[1]}/index.html"
            # Chromium dumps the page when its virtual time runs out: a page still "pending"
            # then (a loaded machine: SwiftShader renders in real time) gets one more run
            # with ten times the budget
            for budget in VIRTUAL_TIME_MS:
                body, out = _dump(chrome, url, tmp, budget, timeout)
                if body != "pending":
                    break
        finally:
            server.shutdown()
            server.server_close()
    if body is None:
        raise RenderError(f"three.js gave no result ({chrome} said: "
                          f"{out.stderr.strip()[-600:]})")
    try:
        report = json.loads(body)
    except ValueError:
        raise RenderError(f"three.js gave no result (the page says {body[:200]!r})") from None
    if not report.get("ok"):
        raise RenderError(f"three.js could not render the file: {report.get('error')}")
    return report


def render_goniometer(gltf_path, wi, wo, *, size: int = 8, timeout: float = 180.0
                      ) -> tuple[np.ndarray, dict]:
    """three.js's pixel values (N, 3) for each pair (wi[k], wo[k]): f(wi, wo)·cos θi of the
    file's first material (linear, no tone mapping), and the page's report (``three``: its
    revision, ``material``: the three.js material type)."""
    pairs = np.concatenate([np.atleast_2d(wi), np.atleast_2d(wo)], axis=1)
    report = run_page(PAGE, {"gltf": "material.gltf", "pairs": pairs.tolist(),
                             "size": int(size)}, {"material.gltf": gltf_path}, timeout=timeout)
    values = np.asarray(report["values"], dtype=float)
    if values.shape != (pairs.shape[0], 3):
        raise RenderError(f"three.js returned {values.shape} values for {pairs.shape[0]} pairs")
    return values, report


def render_views(gltf_path, wi, wo, *, size: int, extent: float, timeout: float = 180.0
                 ) -> tuple[np.ndarray, np.ndarray, dict]:
    """The glTF file's own scene seen from each pair (wi[k], wo[k]), directions in the file's
    world frame (glTF: y up): one directional light of irradiance 1 from wi, an orthographic
    camera from wo covering [-extent, extent]² of its view, a float image of ``size`` ×
    ``size`` pixels with no tone mapping (``web/gltf_views.html``). Returns the images (N,
    size, size, 3), row 0 at the bottom (OpenGL's order), the world-to-clip matrices (N, 4, 4)
    of the cameras, and the page's report."""
    import base64

    pairs = np.concatenate([np.atleast_2d(wi), np.atleast_2d(wo)], axis=1)
    report = run_page(VIEWS_PAGE, {"gltf": "scene.gltf", "pairs": pairs.tolist(),
                                   "size": int(size), "extent": float(extent)},
                      {"scene.gltf": gltf_path}, timeout=timeout)
    if len(report.get("images", ())) != len(pairs):
        raise RenderError(f"three.js returned {len(report.get('images', ()))} images for "
                          f"{len(pairs)} pairs")
    images = np.stack([np.frombuffer(base64.b64decode(b), dtype="<f4").reshape(size, size, 3)
                       for b in report.pop("images")]).astype(float)
    # three.js's Matrix4.elements are column-major
    vp = np.asarray(report.pop("view_projection"), dtype=float).reshape(-1, 4, 4)
    return images, np.transpose(vp, (0, 2, 1)), report


def validate(path, *, timeout: float = 120.0) -> dict:
    """The Khronos glTF validator's issues report of ``path`` (``numErrors``,
    ``numWarnings``, ``numInfos``, ``numHints``, ``messages``) and ``validator``: its version."""
    why = validator_missing()
    if why:
        raise RenderError(f"the glTF validator cannot run: {why}")
    mods = node_modules()
    with tempfile.TemporaryDirectory(prefix="fitlab-gltf-validator-") as tmp:
        tmp = Path(tmp)
        (tmp / "node_modules").symlink_to(mods.resolve())
        shutil.copy(VALIDATOR_SCRIPT, tmp / "validate.mjs")
        try:
            out = subprocess.run(["node", str(tmp / "validate.mjs"), str(Path(path).resolve())],
                                 cwd=tmp, capture_output=True, text=True, timeout=timeout)
        except subprocess.TimeoutExpired:
            raise RenderError(f"the glTF validator did not finish in {timeout:g} s") from None
    if out.returncode != 0:
        raise RenderError(f"the glTF validator failed: {out.stderr.strip()[-600:]}")
    report = json.loads(out.stdout)
    report["validator"] = _version(mods, "gltf-validator")
    return report


__all__ = ["INSTALL", "RenderError", "browser", "missing", "node_modules", "render_goniometer",
           "render_views", "run_page", "validate", "validator_missing"]
