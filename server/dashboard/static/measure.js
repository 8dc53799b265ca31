// Click-to-measure on the live map, as pure functions: the figures of a polyline of up to three clicked
// world points (metres) and its drawing. Two points give a distance and the bearing of the line (deg,
// counter-clockwise from +x, REP 103); a third gives the second leg and the angle at the middle point.

import { COLORS } from "./mapdraw.js";

export const MEASURE_POINTS = 3;

const deg = (rad) => (rad * 180) / Math.PI;

/** {legs: [m, ...], total_m, bearing_deg, angle_deg} of points [[x, y], ...] (null fields when too few). */
export function measureFigures(points) {
  const legs = [];
  for (let i = 1; i < points.length; i++) {
    legs.push(Math.hypot(points[i][0] - points[i - 1][0], points[i][1] - points[i - 1][1]));
  }
  const total_m = legs.length ? legs.reduce((a, b) => a + b, 0) : null;
  let bearing_deg = null;
  if (points.length >= 2) {
    const b = deg(Math.atan2(points[1][1] - points[0][1], points[1][0] - points[0][0]));
    bearing_deg = b < 0 ? b + 360 : b;
  }
  let angle_deg = null;
  if (points.length >= 3 && legs[0] > 0 && legs[1] > 0) {
    const [a, v, c] = points;
    const u1 = [a[0] - v[0], a[1] - v[1]];
    const u2 = [c[0] - v[0], c[1] - v[1]];
    const cos = (u1[0] * u2[0] + u1[1] * u2[1]) / (legs[0] * legs[1]);
    angle_deg = deg(Math.acos(Math.max(-1, Math.min(1, cos))));
  }
  return { legs, total_m, bearing_deg, angle_deg };
}

/** The readout of measureFigures: "2.35 m · bearing 90.0°", "... · 1.20 m · angle 45.0°". */
export function measureText(points) {
  if (!points.length) return "Click on the map: two points give a distance, a third an angle.";
  const f = measureFigures(points);
  if (!f.legs.length) return "Click a second point.";
  const parts = [`${f.legs[0].toFixed(2)} m`, `bearing ${f.bearing_deg.toFixed(1)}°`];
  if (f.legs.length > 1) parts.push(`then ${f.legs[1].toFixed(2)} m`, `angle ${f.angle_deg === null ? "—" : f.angle_deg.toFixed(1)}°`);
  return parts.join(" · ");
}

/** Draw the clicked points and the lines between them (screen = (x * scale + ox, oy - y * scale)). */
export function drawMeasure(ctx, points, scale, ox, oy) {
  if (!points.length) return;
  const s = points.map((p) => [p[0] * scale + ox, oy - p[1] * scale]);
  ctx.save();
  ctx.strokeStyle = COLORS.measure;
  ctx.fillStyle = COLORS.measure;
  ctx.lineWidth = 1.5;
  ctx.setLineDash([6, 4]);
  ctx.beginPath();
  s.forEach((p, i) => (i ? ctx.lineTo(p[0], p[1]) : ctx.moveTo(p[0], p[1])));
  ctx.stroke();
  ctx.setLineDash([]);
  for (const p of s) {
    ctx.beginPath();
    ctx.arc(p[0], p[1], 3.5, 0, 2 * Math.PI);
    ctx.fill();
  }
  ctx.restore();
}
