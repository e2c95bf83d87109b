"""A real headless Chromium for the view's tests: the browser, and a page once the server answers."""
from __future__ import annotations

import shutil
import time

import pytest

CHROMIUM = next((p for p in (shutil.which(n) for n in ("chromium", "chromium-browser", "google-chrome")) if p), None)


def playwright_session():
    if CHROMIUM is None:
        pytest.skip("no Chromium on this machine (`apt-get install chromium`; .ci/run installs it)")
    playwright = pytest.importorskip("playwright.sync_api", reason="pip install playwright")
    return playwright.sync_playwright()


def launch(pw):
    return pw.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])


def open_page(page, port: int, what: str, wait_s: float = 60.0):
    """`page` showing the server on `port`, once it answers (the run starts it a little later)."""
    deadline = time.monotonic() + wait_s
    while True:
        try:
            page.goto(f"http://127.0.0.1:{port}/", timeout=5000)
            return page
        except Exception:
            assert time.monotonic() < deadline, f"{what} never answered"
            time.sleep(0.3)


# Each mover's colour where the page drew it (the centre of its cell), leaving out any the UAV's triangle,
# drawn last, may cover: [id, kind, [r, g, b]].
DRAWN = """() => {
  const ctx = document.getElementById("floor").getContext("2d"), p = window.viewState.pose;
  const ux = p.east_m / meta.cell_m * scale, uy = -p.north_m / meta.cell_m * scale;
  return Object.entries(window.viewState.movers).map(([id, [kind, x, y]]) => {
    const [cx, cy] = centre([x, y]);
    if (Math.hypot(cx - ux, cy - uy) < 2.5 * Math.max(8, scale)) return null;
    return [id, kind, Array.from(ctx.getImageData(Math.round(cx), Math.round(cy), 1, 1).data.slice(0, 3))];
  }).filter((m) => m);
}"""
PAGE_RGB = {"person": [255, 127, 14], "forklift": [255, 212, 0], "pallet": [31, 95, 214]}


def movers_at(report: dict, t: int) -> dict[str, list]:
    """The movers on the floor after tick `t` as the world recorded them: {id: [kind, x, y]}."""
    truth = report["truth"]["movers"]
    movers = {str(m["id"]): m for m in truth["movers"]}
    return {mid: [movers[mid]["kind"], *cells[t]] for mid, cells in truth["trace"].items()
            if movers[mid]["appears"] <= t}
