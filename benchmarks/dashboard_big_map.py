"""How the dashboard draws a stored map of 130,000 long overlapping walls (one accepted 3.7 MB snapshot):
first frame, complete drawing, longest frame and how fast the page answers meanwhile, against the former
drawing (every wall in one path and one stroke per frame) timed in the same browser on the same walls.

    .venv/bin/python benchmarks/dashboard_big_map.py [--walls 130000] [--no-former] [--json out.json]

Starts a real server on loopback (SQLite in a temporary folder), writes the walls straight into its
database (tests/server/dashboard/absurd.py) with 200 centroids and a 300-pose trajectory (in a square of
``2 * --half-extent-m``), opens the
robot's live map in Debian's Chromium through Playwright and reads ``window.linemapStats``.

Then the steady frames, once the walls are drawn: ``--redraws`` redraws (the view zoomed in and out by
the mouse wheel, each a whole frame), first with the walls alone (the baseline of this run), then with
every layer on (walls, centroids, trajectory, robot and the occupancy grid, waited for until loaded).
Prints medians and maxima; asserts nothing.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tests.server.dashboard.absurd import login, store_big_map
from tests.server.dashboard.browser import launch_chromium
from tests.server.live import start_live

# The former drawing of the walls, on the page's own data: one path, one stroke, rasterised at once.
FORMER = """() => {
  const src = document.querySelector('[data-testid=map-canvas]');
  const c = document.createElement('canvas');
  c.width = src.width; c.height = src.height;
  const ctx = c.getContext('2d');
  const walls = window.__walls;
  const scale = 3, ox = c.width / 2, oy = c.height / 2;
  const t0 = performance.now();
  ctx.beginPath();
  for (const s of walls) {
    ctx.moveTo(s[0] * scale + ox, oy - s[1] * scale);
    ctx.lineTo(s[2] * scale + ox, oy - s[3] * scale);
  }
  ctx.strokeStyle = '#e9eef4'; ctx.lineWidth = 2; ctx.lineCap = 'round';
  ctx.stroke();
  ctx.getImageData(0, 0, 1, 1);  // forces the deferred rasterisation
  return performance.now() - t0;
}"""


def _probe(page: Any, n: int) -> list[float]:
    """Round trips of a trivial evaluate while the page draws (ms)."""
    out = []
    for _ in range(n):
        t0 = time.perf_counter()
        page.evaluate("1")
        out.append((time.perf_counter() - t0) * 1000)
    return out


LAYERS = ("walls", "centroids", "trajectory", "robot", "occupancy")


def _set_layers(page: Any, on: set[str]) -> None:
    for key in LAYERS:
        box = page.get_by_test_id(f"map-layer-{key}")
        if box.is_checked() != (key in on):
            box.click()


def _redraw_frames(page: Any, n: int) -> list[float]:
    """The times (ms) of ``n`` whole-map frames, each after a wheel step over the canvas."""
    box = page.get_by_test_id("map-canvas").bounding_box()
    page.mouse.move(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
    out: list[float] = []
    for i in range(n):
        before = page.evaluate("window.linemapStats.frames")
        page.mouse.wheel(0, -40 if i % 2 else 40)
        page.wait_for_function(
            f"() => window.linemapStats.frames > {before} && window.linemapStats.walls_complete"
        )
        new = page.evaluate(f"window.linemapStats.frames - {before}")
        out.extend(page.evaluate(f"window.linemapStats.frame_ms.slice(-{new})"))
    return out


def _summary(frames: list[float]) -> dict[str, float]:
    return {
        "median_ms": round(statistics.median(frames), 2),
        "max_ms": round(max(frames), 2),
        "n": len(frames),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--walls", type=int, default=130_000)
    ap.add_argument("--json", type=Path)
    ap.add_argument("--no-former", action="store_true", help="skip the former drawing (it takes minutes)")
    ap.add_argument("--redraws", type=int, default=60, help="steady frames measured per configuration")
    ap.add_argument(
        "--half-extent-m",
        type=float,
        default=100.0,
        help="the walls fill a square of twice this (m); the occupancy grid (0.05 m cells) must stay "
        "under the server's 16 M cells, so 100 m makes none",
    )
    args = ap.parse_args()
    from playwright.sync_api import sync_playwright

    with tempfile.TemporaryDirectory() as tmp:
        servers = start_live("sqlite", Path(tmp))
        live = next(servers)
        rid = store_big_map(live, args.walls, centroids=200, poses=300, half_m=args.half_extent_m)
        with live.operator() as op:
            grid = op.get(f"/robots/{rid}/maps/export", params={"format": "pgm"}, timeout=600)
        occupancy = grid.status_code == 200  # else the layer is on but has nothing to draw (the reason)
        if not occupancy:
            print(
                f"occupancy grid not drawn: {grid.status_code} {grid.json().get('detail')}", file=sys.stderr
            )
        with sync_playwright() as p:
            browser = launch_chromium(p)
            page = browser.new_context(viewport={"width": 1280, "height": 800}).new_page()
            page.set_default_timeout(300_000)
            login(page, live)
            page.goto(f"{live.base_url}/#/robots/{rid}")
            page.wait_for_function(
                f"() => window.linemapStats && window.linemapStats.segments === {args.walls} "
                "&& window.linemapStats.walls_drawn > 0"
            )
            probes = _probe(page, 20)
            page.wait_for_function("() => window.linemapStats.walls_complete")
            st = page.evaluate("window.linemapStats")
            _set_layers(page, {"walls"})
            walls_only = _redraw_frames(page, args.redraws)
            _set_layers(page, set(LAYERS))
            if occupancy:
                page.wait_for_function("() => window.linemapStats.occupancy_version !== null")
            all_layers = _redraw_frames(page, args.redraws)
            former: list[float] = []
            if not args.no_former:
                with live.operator() as op:
                    page.evaluate(
                        "w => { window.__walls = w; }",
                        [s[1:] for s in op.get(f"/robots/{rid}/maps/latest").json()["segments"]],
                    )
                former = [page.evaluate(FORMER)]  # one run: it takes minutes
            browser.close()
        servers.close()
    frames = st["frame_ms"]
    figures = {
        "walls": args.walls,
        "first_frame_ms": round(st["first_frame_ms"], 1),
        "complete_ms": round(st["complete_ms"], 1),
        "frames": len(frames),
        "frame_median_ms": round(statistics.median(frames), 2),
        "frame_max_ms": round(max(frames), 2),
        "evaluate_while_drawing_median_ms": round(statistics.median(probes), 2),
        "evaluate_while_drawing_max_ms": round(max(probes), 2),
        "former_one_stroke_frame_ms": round(former[0], 1) if former else None,
        "steady_walls_only": _summary(walls_only),
        "steady_all_layers": _summary(all_layers),
        "occupancy_drawn": occupancy,
        "half_extent_m": args.half_extent_m,
    }
    print(json.dumps(figures, indent=2))
    if args.json:
        args.json.write_text(json.dumps(figures, indent=2) + "\n")


if __name__ == "__main__":
    main()
