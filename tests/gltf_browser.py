"""Helpers of the glTF browser checks (not a test module): the npm packages, the Khronos
validator, and three.js rendering a glTF material on a virtual goniometer in headless Chromium
(fitlab.export.threejs, tests/browser/README.md). Every missing tool skips the test that needs
it (fails in CI)."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
from conftest import skip_or_fail

ROOT = Path(__file__).resolve().parent.parent


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
    messages ...): fitlab.export.threejs.validate."""
    from fitlab.export import threejs

    ensure_node_modules()
    return threejs.validate(path)


def _chromium() -> str:
    from fitlab.export import threejs

    path = threejs.browser()
    if path is None:
        skip_or_fail("chromium is not installed (apt-get install chromium)")
    return path


def require_three_js() -> None:
    """Skip (fail in CI) unless three.js and Chromium can render here."""
    ensure_node_modules()
    _chromium()


def render_gltf_goniometer(gltf_path, wi, wo, *, size: int = 8) -> tuple[np.ndarray, dict]:
    """three.js's pixel values (N, 3) for each pair (wi[k], wo[k]): the glTF file's material on
    a flat patch under one directional light of irradiance 1 from wi, seen from wo, linear,
    no tone mapping: f(wi, wo)·cos θi as three.js computes it (fitlab.export.threejs, the
    renderer of ``fitlab export --check``). Also the page's report (three.js revision, material
    type)."""
    from fitlab.export import threejs

    ensure_node_modules()
    _chromium()
    return threejs.render_goniometer(gltf_path, wi, wo, size=size)
