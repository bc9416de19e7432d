"""Helpers of the glTF browser checks (not a test module): the npm packages, the Khronos
validator, and three.js rendering a glTF material on a virtual goniometer in headless Chromium
(tests/browser/README.md). Every missing tool skips the test that needs it (fails in CI)."""

from __future__ import annotations

import functools
import http.server
import json
import os
import shutil
import subprocess
import tempfile
import threading
from pathlib import Path

import numpy as np
from conftest import skip_or_fail

ROOT = Path(__file__).resolve().parent.parent
BROWSER = ROOT / "tests" / "browser"
PAGE = BROWSER / "gltf_goniometer.html"


def ensure_node_modules() -> Path:
    """node_modules with the pinned three and gltf-validator (``npm ci`` when missing)."""
    if not shutil.which("node") or not shutil.which("npm"):
        skip_or_fail("Node.js and npm are needed for the glTF checks (apt-get install nodejs "
                     "npm)")
    mods = ROOT / "node_modules"
    lock = json.loads((ROOT / "package-lock.json").read_text())
    want = {k.split("node_modules/", 1)[1]: v["version"]
            for k, v in lock["packages"].items() if k.startswith("node_modules/")}

    def have():
        for name, version in want.items():
            pj = mods / name / "package.json"
            if not pj.exists() or json.loads(pj.read_text())["version"] != version:
                return False
        return True

    if not have():
        out = subprocess.run(["npm", "ci", "--no-audit", "--no-fund"], cwd=ROOT,
                             capture_output=True, text=True, timeout=600)
        if out.returncode != 0 or not have():
            skip_or_fail(f"npm ci failed (the npm registry is needed once): {out.stderr[-500:]}")
    return mods


def validate_gltf(path) -> dict:
    """The Khronos glTF validator's issues report of ``path`` (numErrors, numWarnings,
    messages ...)."""
    ensure_node_modules()
    out = subprocess.run(["node", str(BROWSER / "validate_gltf.mjs"), str(path)], cwd=ROOT,
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout)


def _chromium() -> str:
    for name in ("chromium", "chromium-browser"):
        path = shutil.which(name)
        if path:
            return path
    skip_or_fail("chromium is not installed (apt-get install chromium)")


class _Quiet(http.server.SimpleHTTPRequestHandler):
    def log_message(self, *args):
        pass


def render_gltf_goniometer(gltf_path, wi, wo, *, size: int = 8) -> tuple[np.ndarray, dict]:
    """three.js's pixel values (N, 3) for each pair (wi[k], wo[k]): the glTF file's material on
    a flat patch under one directional light of irradiance 1 from wi, seen from wo, linear,
    no tone mapping: f(wi, wo)·cos θi as three.js computes it. Also the page's report
    (three.js revision, material type)."""
    ensure_node_modules()
    browser = _chromium()
    with tempfile.TemporaryDirectory(prefix="fitlab-gltf-page-") as tmp:
        tmp = Path(tmp)
        (tmp / "node_modules").symlink_to(ROOT / "node_modules")
        shutil.copy(PAGE, tmp / "index.html")
        shutil.copy(gltf_path, tmp / "material.gltf")
        pairs = np.concatenate([np.atleast_2d(wi), np.atleast_2d(wo)], axis=1)
        (tmp / "config.json").write_text(json.dumps(
            {"gltf": "material.gltf", "pairs": pairs.tolist(), "size": size}))
        handler = functools.partial(_Quiet, directory=str(tmp))
        server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
        thread = threading.Thread(target=server.serve_forever, daemon=True)
        thread.start()
        try:
            url = f"http://127.0.0.1:{server.server_address[1]}/index.html"
            cmd = [browser, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
                   "--no-first-run", "--disable-background-networking",
                   "--disable-component-update", "--disable-sync",
                   "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
                   f"--user-data-dir={tmp / 'profile'}", "--virtual-time-budget=60000",
                   "--dump-dom", url]
            out = subprocess.run(cmd, capture_output=True, text=True, timeout=180,
                                 env={**os.environ, "HOME": str(tmp)})
        finally:
            server.shutdown()
            server.server_close()
    text = out.stdout
    start = text.find('<pre id="result">')
    assert start >= 0, f"no result in the page (chromium said: {out.stderr[-1500:]})"
    body = text[start + len('<pre id="result">'):text.index("</pre>", start)]
    import html

    report = json.loads(html.unescape(body))
    assert report.get("ok"), f"the page failed: {report}"
    return np.asarray(report["values"], dtype=float), report
