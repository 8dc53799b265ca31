// The map's viewport as pure functions: what is drawn spans which bounds, the view that fits them, the
// world point under a screen pixel. A view is { cx, cy, scale }: the world centre (m) and CSS px per metre.

import { FAR_M, drawable } from "./maplayer.js";

/** Scale (CSS px per metre) kept within [1e-6, 5000]; a non-finite one becomes the default 40. */
export function clampScale(s) {
  return Math.min(5000, Math.max(1e-6, Number.isFinite(s) ? s : 40));
}

/** [minX, minY, maxX, maxY] of segments [x0, y0, x1, y1], trajectory rows [stamp, x, y, theta],
 * centroids [x, y] and the pose [x, y, theta] (or null), leaving out what is not drawable; null if empty. */
export function drawnBounds(segments, trajectory, centroids, pose) {
  let x0 = Infinity, y0 = Infinity, x1 = -Infinity, y1 = -Infinity;
  const add = (x, y) => {
    if (!drawable(x, y)) return;
    if (x < x0) x0 = x;
    if (x > x1) x1 = x;
    if (y < y0) y0 = y;
    if (y > y1) y1 = y;
  };
  for (const s of segments) { add(s[0], s[1]); add(s[2], s[3]); }
  for (const t of trajectory) add(t[1], t[2]);
  for (const c of centroids) add(c[0], c[1]);
  if (pose) add(pose[0], pose[1]);
  return x0 <= x1 ? [x0, y0, x1, y1] : null;
}

/** The view that shows bounds b in a w x hgt canvas with a 30 px margin (at least 4 m across); null for
 * no bounds. */
export function fittedView(b, w, hgt) {
  if (!b) return null;
  const bw = Math.min(Math.max(b[2] - b[0], 4), 4 * FAR_M);
  const bh = Math.min(Math.max(b[3] - b[1], 4), 4 * FAR_M);
  const scale = Math.min((w - 60) / bw, (hgt - 60) / bh);
  return { cx: (b[0] + b[2]) / 2, cy: (b[1] + b[3]) / 2, scale: clampScale(scale) };
}

/** The world point [x, y] (m) under screen pixel (sx, sy) of a w x hgt canvas showing view v. */
export function screenToWorld(v, w, hgt, sx, sy) {
  return [v.cx + (sx - w / 2) / v.scale, v.cy - (sy - hgt / 2) / v.scale];
}
