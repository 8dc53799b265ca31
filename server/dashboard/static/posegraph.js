// The pose graph's part of the live map (issue 21 item 2, issue 23 item 3): keyframes, loop closures and
// the pose covariance from the SSE stream, the trajectory moved in place when a delta corrects keyframes,
// the "keyframes" and "loop closures" layers, the 95 % ellipse at the robot and the 1-sigma readout.
// The correction rule is the server's (shared/protocol/posegraph.py correct_trajectory): a pose recorded
// after keyframe k moves by K'_k K_k^-1 when k moved. O(N log K) per correcting delta, O(K) per frame.

import { clipSegment, drawable } from "./maplayer.js";

export const GRAPH_COLORS = {
  keyframe: "#b48cff",
  closure: "#ff5d73",
  ellipse: "rgba(61,220,132,0.9)",
};
// chi-square quantile of 2 degrees of freedom at 95 %: the ellipse's scale in standard deviations squared
const CHI2_95_2DOF = 5.991;

function compose(a, b) { // rigid motions [x, y, th] a ∘ b
  const c = Math.cos(a[2]), s = Math.sin(a[2]);
  let th = a[2] + b[2];
  th = th - 2 * Math.PI * Math.floor((th + Math.PI) / (2 * Math.PI));
  return [a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], th];
}

function inverse(a) {
  const c = Math.cos(a[2]), s = Math.sin(a[2]);
  return [-(c * a[0] + s * a[1]), s * a[0] - c * a[1], -a[2]];
}

/** The trajectory rows [stamp_s, x, y, th] moved in place with the keyframes that moved: before and moved
 * are Maps id -> [stamp_s, x, y, th]. Returns the number of rows moved. O(N log K). */
export function correctTrajectory(rows, before, moved) {
  if (!rows.length || !moved.size) return 0;
  const ids = [...before.keys()].sort((a, b) => before.get(a)[0] - before.get(b)[0] || a - b);
  const stamps = ids.map((k) => before.get(k)[0]);
  const deltas = ids.map((k) => {
    const n = moved.get(k);
    if (!n) return null;
    const o = before.get(k);
    return compose([n[1], n[2], n[3]], inverse([o[1], o[2], o[3]]));
  });
  let count = 0;
  for (const row of rows) {
    let lo = 0, hi = stamps.length; // the last keyframe at or before the row's stamp
    while (lo < hi) { const mid = (lo + hi) >> 1; if (stamps[mid] <= row[0]) lo = mid + 1; else hi = mid; }
    const d = lo > 0 ? deltas[lo - 1] : null;
    if (!d) continue;
    const p = compose(d, [row[1], row[2], row[3]]);
    row[1] = p[0]; row[2] = p[1]; row[3] = p[2];
    count++;
  }
  return count;
}

/** "±x 1.2 cm · ±y 0.8 cm · ±heading 0.40°" (1 sigma) from a 3x3 covariance, or "" without one. */
export function sigmaText(cov) {
  if (!Array.isArray(cov) || cov.length !== 3) return "";
  const sd = [0, 1, 2].map((i) => Math.sqrt(Math.max(Number(cov[i][i]), 0)));
  if (!sd.every(Number.isFinite)) return "";
  return `±x ${(sd[0] * 100).toFixed(1)} cm · ±y ${(sd[1] * 100).toFixed(1)} cm · ±heading ${((sd[2] * 180) / Math.PI).toFixed(2)}°`;
}

/** The 95 % ellipse of the x-y block of cov: [semi-axis a (m), semi-axis b (m), angle (rad)], or null. */
export function ellipse95(cov) {
  if (!Array.isArray(cov) || cov.length !== 3) return null;
  const a = cov[0][0], b = cov[0][1], d = cov[1][1];
  if (![a, b, d].every(Number.isFinite)) return null;
  const mean = (a + d) / 2, diff = Math.sqrt(((a - d) / 2) ** 2 + b * b);
  const l1 = Math.max(mean + diff, 0), l2 = Math.max(mean - diff, 0);
  return [Math.sqrt(CHI2_95_2DOF * l1), Math.sqrt(CHI2_95_2DOF * l2), 0.5 * Math.atan2(2 * b, a - d)];
}

/** What is drawn, for tests: the walls' coordinate sum and every 25th trajectory pose. O(walls + poses/25). */
export function drawnSample(segments, trajectory) {
  let sum = 0;
  for (const w of segments.values()) sum += w[0] + w[1] + w[2] + w[3];
  return { walls_sum: sum, trajectory_sample: trajectory.filter((_, i) => i % 25 === 0) };
}

export class PoseGraphLayer {
  constructor() {
    this.keyframes = new Map(); // id -> [stamp_s, x, y, th]
    this.closures = []; // [id_a, id_b]
    this.covariance = null;
    this.corrections = 0; // deltas that moved keyframes
    this.movedPoses = 0; // trajectory rows moved by the last correction
  }

  /** A snapshot (whole map): everything replaced. */
  fromMap(m) {
    this.keyframes = new Map((m.keyframes || []).map((r) => [r[0], [r[1], r[2], r[3], r[4]]]));
    this.closures = (m.loop_closures || []).map((p) => [p[0], p[1]]);
    this.covariance = m.pose_covariance || null;
  }

  /** A delta, before its own trajectory rows are appended to `trajectory` (which is corrected in place
   * when the delta moves keyframes held here). */
  applyDelta(d, trajectory) {
    this.covariance = d.pose_covariance || null;
    // a row of a keyframe the server dropped with the poses it owned (not held, older than the newest
    // held: server/mapgraph.py prune_graph) moves nothing here either
    let newest = -1;
    for (const k of this.keyframes.keys()) if (k > newest) newest = k;
    const dropped = (k) => !this.keyframes.has(k) && k < newest;
    if (d.keyframes) {
      const rows = d.keyframes.filter((r) => !dropped(r[0]));
      const moved = new Map();
      for (const r of rows) {
        const old = this.keyframes.get(r[0]);
        if (old && (old[1] !== r[2] || old[2] !== r[3] || old[3] !== r[4])) moved.set(r[0], [r[1], r[2], r[3], r[4]]);
      }
      if (moved.size) {
        this.movedPoses = correctTrajectory(trajectory, this.keyframes, moved);
        this.corrections++;
      }
      for (const r of rows) this.keyframes.set(r[0], [r[1], r[2], r[3], r[4]]);
    }
    if (d.loop_closures) {
      const seen = new Set(this.closures.map((p) => `${p[0]}:${p[1]}`));
      for (const p of d.loop_closures) {
        if (!seen.has(`${p[0]}:${p[1]}`) && !dropped(p[0]) && !dropped(p[1])) this.closures.push([p[0], p[1]]);
      }
    }
  }

  /** Keep the keyframes the held trajectory rows need and the loop closures between kept ones: each row's
   * owner (the last keyframe at or before it by stamp, then id) and every keyframe after the last row, the
   * server's rule when it thins its poses (shared/protocol/posegraph.py keyframes_in_use). Called when the
   * page drops its oldest trajectory rows, so a page left open for days holds as many keyframes as its
   * rows need, not one per keyframe the robot ever made. Returns the number dropped. O((N + K) log K). */
  prune(trajectory) {
    if (!this.keyframes.size) return 0;
    const ids = [...this.keyframes.keys()].sort((a, b) => this.keyframes.get(a)[0] - this.keyframes.get(b)[0] || a - b);
    const stamps = ids.map((k) => this.keyframes.get(k)[0]);
    const used = new Uint8Array(ids.length);
    let last = -Infinity;
    for (const row of trajectory) {
      let lo = 0, hi = stamps.length;
      while (lo < hi) { const mid = (lo + hi) >> 1; if (stamps[mid] <= row[0]) lo = mid + 1; else hi = mid; }
      if (lo > 0) used[lo - 1] = 1;
      if (row[0] > last) last = row[0];
    }
    for (let i = ids.length - 1; i >= 0 && stamps[i] > last; i--) used[i] = 1;
    let dropped = 0;
    ids.forEach((k, i) => { if (!used[i]) { this.keyframes.delete(k); dropped++; } });
    if (dropped) this.closures = this.closures.filter(([a, b]) => this.keyframes.has(a) && this.keyframes.has(b));
    return dropped;
  }

  /** Keyframes as small circles; loop closures as lines between their keyframes. O(K + C). */
  draw(ctx, layers, scale, ox, oy, w, hgt) {
    if (layers.loopClosures && this.closures.length) {
      ctx.beginPath();
      for (const [a, b] of this.closures) {
        const p = this.keyframes.get(a), q = this.keyframes.get(b);
        if (!p || !q || !drawable(p[1], p[2]) || !drawable(q[1], q[2])) continue;
        const c = clipSegment(p[1] * scale + ox, oy - p[2] * scale, q[1] * scale + ox, oy - q[2] * scale, -20, -20, w + 20, hgt + 20);
        if (c) { ctx.moveTo(c[0], c[1]); ctx.lineTo(c[2], c[3]); }
      }
      ctx.strokeStyle = GRAPH_COLORS.closure;
      ctx.lineWidth = 1.5;
      ctx.setLineDash([4, 3]);
      ctx.stroke();
      ctx.setLineDash([]);
    }
    if (layers.keyframes && this.keyframes.size) {
      ctx.beginPath();
      for (const k of this.keyframes.values()) {
        if (!drawable(k[1], k[2])) continue;
        const sx = k[1] * scale + ox, sy = oy - k[2] * scale;
        if (sx < -10 || sx > w + 10 || sy < -10 || sy > hgt + 10) continue;
        ctx.moveTo(sx + 3, sy);
        ctx.arc(sx, sy, 3, 0, 2 * Math.PI);
      }
      ctx.strokeStyle = GRAPH_COLORS.keyframe;
      ctx.lineWidth = 1.25;
      ctx.stroke();
    }
  }

  /** The 95 % position ellipse at the robot (screen sx, sy), when the map carries a covariance. */
  drawEllipse(ctx, sx, sy, scale) {
    const e = ellipse95(this.covariance);
    if (!e) return;
    const rx = Math.min(e[0] * scale, 1e4), ry = Math.min(e[1] * scale, 1e4);
    ctx.beginPath();
    ctx.ellipse(sx, sy, Math.max(rx, 0.5), Math.max(ry, 0.5), -e[2], 0, 2 * Math.PI);
    ctx.strokeStyle = GRAPH_COLORS.ellipse;
    ctx.lineWidth = 1.25;
    ctx.stroke();
  }

  /** Figures for tests and benchmarks (window.linemapStats). */
  stats() {
    return { keyframes: this.keyframes.size, loop_closures: this.closures.length, corrections: this.corrections,
      moved_poses: this.movedPoses, covariance: this.covariance };
  }
}
