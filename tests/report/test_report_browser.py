"""The report in a real browser: Debian's chromium, headless. A copy of index.html gets a tiny
inline probe (window.onerror writes JS errors into the DOM; on load it records how many images
decoded, naturalWidth > 0); the dumped DOM must show no errors and every image decoded, and a
screenshot must show a page (not blank). Skips (fails in CI) without chromium."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from conftest import skip_or_fail

from fitlab.cli import main

ROOT = Path(__file__).resolve().parents[2]
REFERENCE = ROOT / "reports" / "walter_rough_glass" / "index.html"
RGB = ROOT / "data_formats" / "examples" / "measurement_rgb_sigma.csv"

PROBE = """<script>
window.onerror = function (msg, src, line) {
  var b = document.documentElement;
  b.setAttribute('data-js-errors', (b.getAttribute('data-js-errors') || '') + msg + ' @' + line + ';');
};
window.addEventListener('load', function () {
  var imgs = document.images, ok = 0, bad = [];
  for (var i = 0; i < imgs.length; i++) {
    if (imgs[i].complete && imgs[i].naturalWidth > 0) { ok++; } else { bad.push(imgs[i].alt); }
  }
  var d = document.createElement('div');
  d.id = 'fitlab-probe';
  d.textContent = 'images=' + imgs.length + ' decoded=' + ok + ' broken=' + bad.join('|') +
    ' width=' + document.body.scrollWidth + ' height=' + document.body.scrollHeight;
  document.body.appendChild(d);
});
</script>"""


def _chromium():
    for name in ("chromium", "chromium-browser"):
        path = shutil.which(name)
        if path:
            return path
    skip_or_fail("chromium is not installed (apt-get install chromium)")


def _run(browser, *args, timeout=120):
    cmd = [browser, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
           "--virtual-time-budget=10000", *args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)


def _check(index: Path, tmp_path: Path, name: str):
    browser = _chromium()
    page = index.read_text(encoding="utf-8")
    probed = tmp_path / f"{name}.html"
    probed.write_text(page.replace("<head>", "<head>\n" + PROBE, 1), encoding="utf-8")
    n_img = len(re.findall(r"<img ", page))
    res = _run(browser, "--window-size=1200,2200", "--dump-dom", probed.as_uri())
    assert res.returncode == 0, res.stderr[-2000:]
    dom = res.stdout
    errors = re.search(r'<html[^>]*data-js-errors="([^"]*)"', dom)
    assert errors is None, errors.group(1)
    probe = re.search(r'<div id="fitlab-probe">([^<]*)</div>', dom)
    assert probe, "the load probe did not run"
    fields = dict(kv.split("=", 1) for kv in probe.group(1).split(" "))
    assert int(fields["images"]) == n_img > 0
    assert int(fields["decoded"]) == n_img, f"broken images: {fields['broken']}"
    assert fields["broken"] == ""
    assert int(fields["width"]) <= 1200  # nothing wider than the window: no horizontal scroll
    shot = tmp_path / f"{name}.png"
    res = _run(browser, f"--screenshot={shot}", "--window-size=1200,2200", index.as_uri())
    assert res.returncode == 0 and shot.exists(), res.stderr[-2000:]
    from PIL import Image  # matplotlib's own dependency

    img = np.asarray(Image.open(shot).convert("L"), dtype=float)
    assert img.shape == (2200, 1200)
    assert img.std() > 20  # text, tables and figures, not a blank page
    return fields


def test_reference_report_renders_in_chromium(tmp_path):
    assert REFERENCE.exists(), "the committed reference report is missing (README command 1)"
    fields = _check(REFERENCE, tmp_path, "reference")
    assert int(fields["images"]) >= 9


def test_fresh_report_without_chain_renders_in_chromium(tmp_path):
    fit, rep = tmp_path / "fit.json", tmp_path / "rep"
    assert main(["fit", str(RGB), "--model", "lambertian", "--out", str(fit), "--quiet"]) == 0
    assert main(["report", str(fit), "--out", str(rep), "--quiet"]) == 0
    _check(rep / "index.html", tmp_path, "fresh")


@pytest.mark.parametrize("bad", [
    '<img src="data:image/png;base64,AAAA" alt="corrupt">',  # an image that does not decode
    "<script>not_defined_anywhere();</script>",  # a JavaScript error
])
def test_probe_catches_broken_pages(tmp_path, bad):
    """The check above can fail: a page with a broken image or a script error is caught."""
    page = REFERENCE.read_text(encoding="utf-8").replace("</body>", bad + "\n</body>", 1)
    index = tmp_path / "index.html"
    index.write_text(page, encoding="utf-8")
    with pytest.raises(AssertionError):
        _check(index, tmp_path, "broken")
