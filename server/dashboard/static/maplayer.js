// The walls of the live map, drawn progressively onto an off-screen layer so that no frame does more than
// a bounded amount of work, whatever a robot sent (docs/reliability/data.md):
// - items with a coordinate that is not finite or beyond ±FAR_M are never drawn (and counted);
// - walls outside the view are culled; a wall shorter than a pixel marks its pixel once (a pixel grid);
// - walls are clipped to the view before they reach the canvas (no 1e20 px coordinates);
// - each animation frame strokes at most INK_PX_PER_FRAME of line length and spends at most
//   SLICE_BUDGET_MS recording, then continues on the next frame (requestAnimationFrame slices); the
//   length per frame adapts so that a frame takes about FRAME_TARGET_MS on this machine;
// - the previous complete layer is shown, moved and scaled to the current view, while the next one is
//   drawn (pan and zoom answer at once; the new layer replaces it when complete).

export const FAR_M = 1e9;
const SLICE_BUDGET_MS = 8;
// CSS px of stroked wall length per frame (Chromium rasterises after the script, so time spent recording
// does not show the cost): adapted to the frames measured, between these limits.
const INK_MIN_PX = 5_000;
const INK_MAX_PX = 400_000;
const FRAME_TARGET_MS = 12; // within one frame of a 60 Hz display (16.7 ms), the work after the script included
const CHUNK = 128; // walls per stroke() call
const DIRECT_MAX = 20_000; // walls up to which one frame may draw them all directly, if their ink fits
const MARGIN_PX = 4;

/** True when x, y are finite and within ±FAR_M metres. */
export function drawable(x, y) {
  return Number.isFinite(x) && Number.isFinite(y) && Math.abs(x) <= FAR_M && Math.abs(y) <= FAR_M;
}

/** Cohen-Sutherland: the part of segment (x0, y0)-(x1, y1) inside [xa, xb] x [ya, yb], or null. Each cut
 * puts one coordinate exactly on the boundary and interpolates the other from it (no parametric t, which
 * loses the visible part of a 1e12 px long line to rounding). At most 4 cuts: O(1). */
export function clipSegment(x0, y0, x1, y1, xa, ya, xb, yb) {
  const code = (x, y) => (x < xa ? 1 : x > xb ? 2 : 0) | (y < ya ? 4 : y > yb ? 8 : 0);
  let c0 = code(x0, y0);
  let c1 = code(x1, y1);
  for (let guard = 0; guard < 8; guard++) {
    if (!(c0 | c1)) return [x0, y0, x1, y1];
    if (c0 & c1) return null;
    const out = c0 || c1;
    let x, y;
    if (out & 1) { x = xa; y = y0 + ((y1 - y0) * (xa - x0)) / (x1 - x0); }
    else if (out & 2) { x = xb; y = y0 + ((y1 - y0) * (xb - x0)) / (x1 - x0); }
    else if (out & 4) { y = ya; x = x0 + ((x1 - x0) * (ya - y0)) / (y1 - y0); }
    else { y = yb; x = x0 + ((x1 - x0) * (yb - y0)) / (y1 - y0); }
    if (!Number.isFinite(x) || !Number.isFinite(y)) return null;
    if (out === c0) { x0 = x; y0 = y; c0 = code(x0, y0); } else { x1 = x; y1 = y; c1 = code(x1, y1); }
  }
  return null;
}

function newLayer() {
  const canvas = document.createElement("canvas");
  return { canvas, ctx: canvas.getContext("2d"), key: null, i: 0, done: false, data: -1 };
}

export class WallLayer {
  constructor(color) {
    this.color = color;
    this.flat = new Float64Array(0); // x0, y0, x1, y1 per drawable wall
    this.count = 0;
    this.far = 0; // walls not drawn: a coordinate not finite or beyond ±FAR_M
    this.data = 0; // bumped on every change of the walls
    this.flatData = -1;
    this.front = null; // the last complete layer
    this.back = null; // the layer being drawn
    this.spare = null; // a former front, reused as the next back
    this.inkPx = 50_000; // stroked length per frame, adapted by feedback()
  }

  /** The last frame took frameMs (drawing included): adapt the length stroked per frame. */
  feedback(frameMs) {
    if (!Number.isFinite(frameMs)) return;
    if (frameMs > FRAME_TARGET_MS) this.inkPx = Math.max(INK_MIN_PX, this.inkPx * 0.6);
    else if (frameMs < FRAME_TARGET_MS / 2) this.inkPx = Math.min(INK_MAX_PX, this.inkPx * 1.25);
  }

  changed() {
    this.data++;
  }

  rebuild(segments) {
    if (this.flatData === this.data) return;
    const flat = new Float64Array(segments.size * 4);
    let n = 0;
    let far = 0;
    for (const s of segments.values()) {
      if (!drawable(s[0], s[1]) || !drawable(s[2], s[3])) { far++; continue; }
      flat[n++] = s[0]; flat[n++] = s[1]; flat[n++] = s[2]; flat[n++] = s[3];
    }
    this.flat = flat;
    this.count = n / 4;
    this.far = far;
    this.flatData = this.data;
  }

  /** A small map (at most DIRECT_MAX walls, whose clipped length fits the ink one frame strokes on this
   * machine, inkPx as adapted by feedback(), at most INK_MAX_PX): draw it straight onto ctx in one path,
   * as a frame of its own, and return true; false for a map that needs the layer and its slices.
   * O(walls). */
  direct(ctx, segments, view, w, hgt) {
    if (segments.size > DIRECT_MAX) return false;
    this.rebuild(segments);
    const { cx, cy, scale } = view;
    const ox = w / 2 - cx * scale, oy = hgt / 2 + cy * scale;
    const xa = -MARGIN_PX, ya = -MARGIN_PX, xb = w + MARGIN_PX, yb = hgt + MARGIN_PX;
    const flat = this.flat;
    const pieces = [];
    let ink = 0;
    for (let k = 0; k < this.count * 4; k += 4) {
      const c = clipSegment(flat[k] * scale + ox, oy - flat[k + 1] * scale,
        flat[k + 2] * scale + ox, oy - flat[k + 3] * scale, xa, ya, xb, yb);
      if (!c) continue;
      ink += Math.hypot(c[2] - c[0], c[3] - c[1]);
      if (ink > this.inkPx) return false;
      pieces.push(c);
    }
    ctx.beginPath();
    for (const c of pieces) { ctx.moveTo(c[0], c[1]); ctx.lineTo(c[2], c[3]); }
    ctx.strokeStyle = this.color;
    ctx.lineWidth = 2;
    ctx.lineCap = "round";
    ctx.stroke();
    this.front = null; // a later switch to the layer starts afresh
    this.back = null;
    this.directDrawn = pieces.length;
    return true;
  }

  /** Draw the next slice for view {cx, cy, scale} on a w x hgt CSS px canvas at dpr; true when more
   * slices are due (the caller asks for another frame). O(walls) per pass, bounded work per call. */
  step(segments, view, w, hgt, dpr) {
    const key = `${view.cx}|${view.cy}|${view.scale}|${w}|${hgt}|${dpr}`;
    let b = this.back;
    const restart = !b || b.key !== key || (b.done && b.data !== this.data);
    if (!restart && b.done) return false;
    if (restart) {
      this.rebuild(segments);
      if (!b || b === this.front) {
        b = this.spare || newLayer();
        this.spare = null;
      }
      const pw = Math.max(1, Math.round(w * dpr));
      const ph = Math.max(1, Math.round(hgt * dpr));
      if (b.canvas.width !== pw || b.canvas.height !== ph) { b.canvas.width = pw; b.canvas.height = ph; }
      b.ctx.setTransform(1, 0, 0, 1, 0, 0);
      b.ctx.clearRect(0, 0, pw, ph);
      b.ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
      Object.assign(b, {
        key, i: 0, done: false, data: this.data, view: { ...view }, w, hgt,
        ox: w / 2 - view.cx * view.scale, oy: hgt / 2 + view.cy * view.scale,
        drawn: 0,
      });
      const cells = Math.ceil(w) * Math.ceil(hgt);
      if (!b.pixels || b.pixels.length !== cells) b.pixels = new Uint8Array(cells);
      else b.pixels.fill(0);
      this.back = b;
    }
    this.slice(b);
    if (b.done) {
      if (this.front && this.front !== b) this.spare = this.front;
      this.front = b;
      if (b.data !== this.data) return true; // walls changed meanwhile: one more pass
    }
    return !b.done;
  }

  slice(b) {
    const { ctx, ox, oy, w, hgt, pixels } = b;
    const scale = b.view.scale;
    const flat = this.flat;
    const xa = -MARGIN_PX, ya = -MARGIN_PX, xb = w + MARGIN_PX, yb = hgt + MARGIN_PX;
    const cols = Math.ceil(w);
    const t0 = performance.now();
    ctx.strokeStyle = this.color;
    ctx.lineWidth = 2;
    ctx.lineCap = "round";
    ctx.beginPath();
    let inChunk = 0;
    let ink = 0;
    let i = b.i;
    const n = this.count;
    while (i < n) {
      const k = i * 4;
      i++;
      const sx0 = flat[k] * scale + ox, sy0 = oy - flat[k + 1] * scale;
      const sx1 = flat[k + 2] * scale + ox, sy1 = oy - flat[k + 3] * scale;
      if ((sx0 < xa && sx1 < xa) || (sx0 > xb && sx1 > xb) || (sy0 < ya && sy1 < ya) || (sy0 > yb && sy1 > yb)) continue;
      const dx = sx1 - sx0, dy = sy1 - sy0;
      if (dx * dx + dy * dy < 1) { // shorter than a pixel: mark the pixel once
        const px = Math.floor(sx0), py = Math.floor(sy0);
        if (px < 0 || py < 0 || px >= cols || py >= hgt) continue;
        const at = py * cols + px;
        if (pixels[at]) continue;
        pixels[at] = 1;
        ctx.moveTo(px + 0.5, py + 0.5); ctx.lineTo(px + 0.6, py + 0.5);
        ink += 1;
      } else {
        const c = clipSegment(sx0, sy0, sx1, sy1, xa, ya, xb, yb);
        if (!c) continue;
        ctx.moveTo(c[0], c[1]); ctx.lineTo(c[2], c[3]);
        ink += Math.hypot(c[2] - c[0], c[3] - c[1]);
      }
      b.drawn++;
      if (++inChunk >= CHUNK) {
        ctx.stroke();
        ctx.beginPath();
        inChunk = 0;
        if (ink >= this.inkPx || performance.now() - t0 >= SLICE_BUDGET_MS) break;
      } else if ((i & 4095) === 0 && performance.now() - t0 >= SLICE_BUDGET_MS) break;
    }
    if (inChunk) ctx.stroke();
    b.i = i;
    b.done = i >= n;
  }

  /** Draw the layer onto ctx (CSS px transform set) for the current view: the last complete layer moved
   * and scaled to it, then what the layer in progress has drawn so far. */
  composite(ctx, view, w, hgt) {
    const f = this.front;
    const b = this.back;
    if (f) this.blit(ctx, f, view, w, hgt);
    if (b && b !== f && b.view.scale === view.scale && b.view.cx === view.cx && b.view.cy === view.cy) {
      ctx.drawImage(b.canvas, 0, 0, b.w, b.hgt);
    }
  }

  blit(ctx, layer, view, w, hgt) {
    const k = view.scale / layer.view.scale;
    if (!Number.isFinite(k) || k > 64 || k < 1 / 64) return; // too far from the view it was drawn for
    const ox = w / 2 - view.cx * view.scale;
    const oy = hgt / 2 + view.cy * view.scale;
    const dx = ox - layer.ox * k;
    const dy = oy - layer.oy * k;
    const dw = layer.w * k;
    const dh = layer.hgt * k;
    if (![dx, dy, dw, dh].every(Number.isFinite) || dx > w || dy > hgt || dx + dw < 0 || dy + dh < 0) return;
    ctx.drawImage(layer.canvas, dx, dy, dw, dh);
  }

  /** Progress of the layer being drawn (for the HUD and window.linemapStats). */
  progress() {
    const b = this.back;
    if (!b && this.directDrawn !== undefined) {
      return { drawn: this.directDrawn, complete: true, far: this.far, total: this.count };
    }
    return { drawn: b ? b.drawn : 0, complete: !!(b && b.done), far: this.far, total: this.count };
  }
}
