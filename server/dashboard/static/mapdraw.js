// Canvas drawing helpers of the live map: colours, grid, trajectory, centroids, robot marker, scale bar.
// Screen = (x * scale + ox, oy - y * scale); everything is clipped or culled to the view.

import { clipSegment, drawable } from "./maplayer.js";

export const NICE = [0.1, 0.2, 0.5, 1, 2, 5, 10, 20, 50, 100, 200, 500, 1000];
export const COLORS = {
  bg: "#0f151c",
  gridMinor: "rgba(255,255,255,0.05)",
  gridMajor: "rgba(255,255,255,0.11)",
  axis: "rgba(255,255,255,0.22)",
  wall: "#e9eef4",
  centroid: "#f0b429",
  trajectory: "rgba(76,166,255,0.85)",
  robot: "#3ddc84",
  robotEdge: "#0f151c",
  text: "#d8dee6",
  measure: "#ff7ab6",
};

// At most this many grid lines per axis: a loop over x += step never ends where step is below the
// spacing of floating-point numbers (a view centred at 1e20 m), so lines are counted, not stepped to.
const GRID_LINES_MAX = 400;

export function drawGrid(ctx, w, hgt, scale, ox, oy) {
  // Minor lines: the smallest nice step at least 28 px apart; major lines every 1, 5 or 10 x 10^k m.
  const step = niceAtLeast(28 / scale);
  const major = step * (String(step).replace(/[0.]/g, "")[0] === "5" ? 2 : 5);
  const kx = Math.floor((0 - ox) / scale / step);
  const ky = Math.floor((oy - hgt) / scale / step);
  const nx = Math.min(GRID_LINES_MAX, Math.ceil(w / (step * scale)) + 1);
  const ny = Math.min(GRID_LINES_MAX, Math.ceil(hgt / (step * scale)) + 1);
  const minor = new Path2D();
  const majorP = new Path2D();
  for (let i = 0; Number.isFinite(kx) && i <= nx; i++) {
    const x = (kx + i) * step;
    const sx = Math.round(x * scale + ox) + 0.5;
    if (!(sx >= 0 && sx <= w + 1)) continue;
    const p = isMultiple(x, major) ? majorP : minor;
    p.moveTo(sx, 0); p.lineTo(sx, hgt);
  }
  for (let i = 0; Number.isFinite(ky) && i <= ny; i++) {
    const y = (ky + i) * step;
    const sy = Math.round(oy - y * scale) + 0.5;
    if (!(sy >= 0 && sy <= hgt + 1)) continue;
    const p = isMultiple(y, major) ? majorP : minor;
    p.moveTo(0, sy); p.lineTo(w, sy);
  }
  ctx.lineWidth = 1;
  ctx.strokeStyle = COLORS.gridMinor;
  ctx.stroke(minor);
  ctx.strokeStyle = COLORS.gridMajor;
  ctx.stroke(majorP);
  // World axes through the origin.
  ctx.beginPath();
  const ax = Math.round(ox) + 0.5;
  const ay = Math.round(oy) + 0.5;
  if (ax >= 0 && ax <= w + 1) { ctx.moveTo(ax, 0); ctx.lineTo(ax, hgt); }
  if (ay >= 0 && ay <= hgt + 1) { ctx.moveTo(0, ay); ctx.lineTo(w, ay); }
  ctx.strokeStyle = COLORS.axis;
  ctx.stroke();
}

export function drawRobot(ctx, sx, sy, theta) {
  const size = 13;
  ctx.save();
  ctx.translate(sx, sy);
  ctx.rotate(-theta); // world y up -> canvas y down
  ctx.beginPath();
  ctx.moveTo(size, 0);
  ctx.lineTo(-size * 0.65, size * 0.6);
  ctx.lineTo(-size * 0.35, 0);
  ctx.lineTo(-size * 0.65, -size * 0.6);
  ctx.closePath();
  ctx.fillStyle = COLORS.robot;
  ctx.strokeStyle = COLORS.robotEdge;
  ctx.lineWidth = 1.5;
  ctx.fill();
  ctx.stroke();
  ctx.restore();
}

/** The scale bar's length: the largest nice length (1, 2 or 5 x 10^k m, at least 0.1 m) at most 140 px
 * long (beyond 1000 m the same series goes on: 2000, 5000, 10000 m ...). */
export function scaleBarLength(scale) {
  let len = NICE[0];
  for (const n of NICE) if (n * scale <= 140) len = n;
  if (len === NICE[NICE.length - 1] && Number.isFinite(scale) && scale > 0) {
    for (let decade = 1000; decade <= 1e12; decade *= 10) {
      for (const m of [1, 2, 5]) if (m * decade * scale <= 140) len = m * decade;
    }
  }
  return len;
}

function niceAtLeast(v) {
  for (const n of NICE) if (n >= v) return n;
  return NICE[NICE.length - 1] * Math.ceil(v / NICE[NICE.length - 1]);
}

function isMultiple(v, step) {
  const r = Math.abs(v / step - Math.round(v / step));
  return r < 1e-6;
}

/** The trajectory [stamp_s, x, y, theta] rows as one path, each step clipped to the view (absurd points
 * never reach the canvas). */
export function drawTrajectory(ctx, tr, scale, ox, oy, w, hgt) {
  if (tr.length < 2) return;
  const xa = -20, ya = -20, xb = w + 20, yb = hgt + 20;
  ctx.beginPath();
  for (let i = 1; i < tr.length; i++) {
    const a = tr[i - 1], b = tr[i];
    if (!drawable(a[1], a[2]) || !drawable(b[1], b[2])) continue;
    const c = clipSegment(a[1] * scale + ox, oy - a[2] * scale, b[1] * scale + ox, oy - b[2] * scale, xa, ya, xb, yb);
    if (c) { ctx.moveTo(c[0], c[1]); ctx.lineTo(c[2], c[3]); }
  }
  ctx.strokeStyle = COLORS.trajectory;
  ctx.lineWidth = 1.25;
  ctx.lineJoin = "round";
  ctx.stroke();
}

/** Centroids [x, y] as small squares inside the view, one path, one fill. */
export function drawCentroids(ctx, cs, scale, ox, oy, w, hgt) {
  if (!cs.length) return;
  const r = 2;
  ctx.beginPath();
  for (const p of cs) {
    if (!drawable(p[0], p[1])) continue;
    const sx = p[0] * scale + ox, sy = oy - p[1] * scale;
    if (sx < -20 || sx > w + 20 || sy < -20 || sy > hgt + 20) continue;
    ctx.rect(sx - r, sy - r, 2 * r, 2 * r);
  }
  ctx.fillStyle = COLORS.centroid;
  ctx.fill();
}
