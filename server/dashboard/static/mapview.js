// Live map: keeps the robot's map from the SSE stream (snapshot + deltas) and draws it on a canvas
// (walls, centroids, trajectory, pose, grid, scale bar) with pan, zoom, fit and follow, layers switched on
// and off, click-to-measure and downloads of the shown version (the controls: maptools.js), and a history
// slider that shows a past version instead of the live one (history_slider.js; `pinned` while it does).
// Redraws only when something changed, at most once per animation frame; records latency and frame
// times in window.linemapStats (see brief: tests and a benchmark read them). Walls are drawn by
// maplayer.js in bounded slices; nothing non-finite or beyond ±FAR_M reaches the canvas, and every
// item is clipped or culled to the view, so absurd coordinates cannot stall or crash the page.

import { h } from "./dom.js";
import { api } from "./api.js";
import { downloadMap } from "./downloads.js";
import { COLORS, drawCentroids, drawGrid, drawRobot, drawTrajectory, scaleBarLength } from "./mapdraw.js";
import { FAR_M, WallLayer, drawable } from "./maplayer.js";
import { MapOverlay, poseText } from "./maptools.js";
import { MEASURE_POINTS, drawMeasure, measureText } from "./measure.js";
import { OccupancyLayer } from "./occupancy.js";
import { STATS_KEEP, median, pushCapped, stats } from "./mapstats.js";
import { PoseGraphLayer, drawnSample, sigmaText } from "./posegraph.js";

export { stats };
import { clampScale, drawnBounds, fittedView, screenToWorld } from "./viewport.js";
import { HistorySlider } from "./history_slider.js";

const TRAJECTORY_KEEP = 5000;
export class MapView {
  constructor() {
    this.segments = new Map(); // id -> [x0, y0, x1, y1]
    this.walls = new WallLayer(COLORS.wall);
    this.centroids = [];
    this.trajectory = []; // [stamp_s, x, y, theta]
    this.pose = null;
    this.graph = new PoseGraphLayer(); // keyframes, loop closures, pose covariance (posegraph.js)
    this.version = null;
    this.pendingWallTimes = [];
    this.pendingCorrections = []; // wall times of deltas that moved keyframes, until their frame
    this.view = { cx: 0, cy: 0, scale: 40 }; // world centre (m) and CSS px per metre
    this.follow = false;
    this.fitted = false;
    this.dirty = true;
    this.frame = 0;
    this.es = null;
    this.closed = false;
    this.status = "connecting";

    this.layers = { walls: true, centroids: true, trajectory: true, keyframes: true, loopClosures: true, robot: true, occupancy: false };
    this.occupancy = new OccupancyLayer(() => this.invalidate());
    this.measuring = false;
    this.measurePoints = []; // world [x, y] of the clicks, at most MEASURE_POINTS

    this.canvas = h("canvas", { class: "map-canvas", "data-testid": "map-canvas" });
    this.overlay = new MapOverlay({
      fit: () => this.fit(),
      zoomBy: (f) => this.zoomBy(f),
      setFollow: (on) => this.setFollow(on),
      setLayer: (key, on) => { this.layers[key] = on; this.invalidate(); },
      setMeasuring: (on) => this.setMeasuring(on),
      clearMeasure: () => { this.measurePoints = []; this.setMeasuring(true); },
      download: (key) => this.download(key),
    });
    this.pinned = null; // a past version shown by the history slider: {version, segments, centroids, trajectory, pose}
    this.history = new HistorySlider({
      showVersion: (m) => this.showVersion(m), goLive: () => this.showVersion(null), liveVersion: () => this.version,
    });
    this.el = h("div", { class: "map-wrap" }, this.canvas, this.overlay.el, this.history.el);
    this.ctx = this.canvas.getContext("2d", { alpha: false });
    this.bindInput();
    this.resizeObserver = new ResizeObserver(() => this.invalidate());
    this.resizeObserver.observe(this.canvas);
  }

  // ---- stream -------------------------------------------------------------------------------------

  connect(robotId) {
    this.robotId = robotId;
    this.closed = false;
    this.open();
    this.history.connect(robotId);
  }

  open() {
    if (this.closed) return;
    if (this.es) this.es.close();
    const es = new EventSource(api.streamUrl(this.robotId, TRAJECTORY_KEEP), { withCredentials: true });
    this.es = es;
    this.setStatus("connecting…");
    es.addEventListener("snapshot", (e) => this.onSnapshot(JSON.parse(e.data)));
    es.addEventListener("delta", (e) => this.onDelta(JSON.parse(e.data)));
    es.addEventListener("open", () => this.setStatus(""));
    es.addEventListener("error", () => {
      if (this.es !== es || this.closed) return;
      if (es.readyState === EventSource.CLOSED) {
        // Not retried by the browser (e.g. 401/404): check the session (a 401 leads to login), retry later.
        this.setStatus("stream closed — retrying…");
        api.whoami().catch(() => {});
        clearTimeout(this.retryTimer);
        this.retryTimer = setTimeout(() => this.open(), 3000);
      } else {
        this.setStatus("reconnecting…");
      }
    });
  }

  close() {
    this.closed = true;
    this.history.close();
    clearTimeout(this.retryTimer);
    if (this.es) this.es.close();
    this.es = null;
    cancelAnimationFrame(this.frame);
    this.frame = 0;
    this.resizeObserver.disconnect();
  }

  setStatus(text) {
    this.status = text;
    this.overlay.setStatus(text);
  }

  setMeasuring(on) {
    this.measuring = on;
    if (!on) this.measurePoints = [];
    this.canvas.classList.toggle("measuring", on);
    this.overlay.setMeasuring(on, measureText(this.measurePoints));
    this.invalidate();
  }

  /** A click (no drag) at screen (sx, sy) while measuring: the next point (a fourth starts again). */
  addMeasurePoint(sx, sy) {
    if (this.measurePoints.length >= MEASURE_POINTS) this.measurePoints = [];
    this.measurePoints.push(this.toWorld(sx, sy));
    this.overlay.setMeasuring(true, measureText(this.measurePoints));
    this.invalidate();
  }

  async download(key) {
    const version = this.shown().version;
    this.overlay.showDownload(`Preparing map v${version ?? "—"}…`);
    try {
      const got = await downloadMap(this.robotId, key, version);
      this.overlay.showDownload(`${got.note || `Downloaded map v${got.version}`}: ${got.files.join(", ")}`);
    } catch (e) {
      this.overlay.showDownload(`Download failed: ${e.detail || e.message}`, true);
    }
  }

  /** What is drawn: the past version the history slider pinned, else the live map. */
  shown() { return this.pinned || this; }

  /** Show map `m` (a MapOut) instead of the live map; null: the live map again. */
  showVersion(m) {
    this.pinned = m && {
      version: m.version, centroids: m.centroids || [], trajectory: m.trajectory || [],
      pose: m.pose && m.pose.length >= 2 ? m.pose : null,
      segments: new Map((m.segments || []).map((s) => [s[0], [s[1], s[2], s[3], s[4]]])),
    };
    this.walls.changed();
    this.invalidate();
  }

  onSnapshot(m) {
    this.receivedAt = performance.now();
    stats().snapshots++;
    if (!this.pinned) this.walls.changed();
    this.segments.clear();
    for (const s of m.segments || []) this.segments.set(s[0], [s[1], s[2], s[3], s[4]]);
    this.centroids = m.centroids || [];
    this.trajectory = (m.trajectory || []).slice(-TRAJECTORY_KEEP);
    this.pose = m.pose && m.pose.length >= 2 ? m.pose : null;
    this.graph.fromMap(m);
    this.version = m.version;
    this.setStatus(m.version ? "" : "no map yet: waiting for the robot's first upload");
    this.noteEvent(m);
    if (!this.fitted && (this.segments.size || this.trajectory.length || this.pose)) this.fit();
  }

  onDelta(d) {
    if (this.version === null || d.base_version !== this.version) {
      // Out of step: reopen; the server starts every stream with a fresh snapshot.
      this.open();
      return;
    }
    for (const s of d.segments || []) this.segments.set(s[0], [s[1], s[2], s[3], s[4]]);
    for (const id of d.removed || []) this.segments.delete(id);
    if (!this.pinned && ((d.segments && d.segments.length) || (d.removed && d.removed.length))) this.walls.changed();
    if (d.centroids) this.centroids = d.centroids;
    if (d.pose && d.pose.length >= 2) this.pose = d.pose;
    const corrections = this.graph.corrections;
    this.graph.applyDelta(d, this.trajectory); // corrected keyframes move the trajectory held, in place
    if (this.graph.corrections > corrections && typeof d.wall_time_s === "number") this.pendingCorrections.push(d.wall_time_s);
    if (d.trajectory && d.trajectory.length) {
      for (const row of d.trajectory) this.trajectory.push(row);
      if (this.trajectory.length > TRAJECTORY_KEEP * 1.2) {
        this.trajectory = this.trajectory.slice(-TRAJECTORY_KEEP);
        this.graph.prune(this.trajectory); // the keyframes of the rows dropped go with them
      }
    }
    this.version = d.version;
    if (this.status) this.setStatus("");
    this.noteEvent(d);
    if (!this.fitted && (this.segments.size || this.trajectory.length || this.pose)) this.fit();
  }

  noteEvent(ev) {
    if (typeof ev.wall_time_s === "number") {
      this.pendingWallTimes.push(ev.wall_time_s);
      if (this.pendingWallTimes.length > STATS_KEEP) this.pendingWallTimes.shift(); // no frames while hidden
    }
    this.history.onLive(this.version);
    this.invalidate();
  }

  // ---- view ---------------------------------------------------------------------------------------

  invalidate() {
    this.dirty = true;
    if (!this.frame && !this.closed) this.frame = requestAnimationFrame(() => this.onFrame());
  }

  setFollow(on) {
    this.follow = on;
    this.overlay.followBox.checked = on;
    this.invalidate();
  }

  /** Bounds of everything drawn: [minX, minY, maxX, maxY] or null (items beyond ±FAR_M are not drawn). */
  bounds() {
    const m = this.shown();
    return drawnBounds(m.segments.values(), m.trajectory, m.centroids, m.pose);
  }

  /** Fit everything in view (computed at the next frame, when the canvas has its size). */
  fit() {
    this.pendingFit = true;
    this.invalidate();
  }

  applyFit(w, hgt) {
    this.pendingFit = false;
    const view = fittedView(this.bounds(), w, hgt);
    if (!view) return;
    this.view = view;
    this.fitted = true;
  }

  zoomBy(f, sx, sy) {
    const { w, hgt } = this.size();
    if (sx === undefined) { sx = w / 2; sy = hgt / 2; }
    const before = this.toWorld(sx, sy);
    this.view.scale = clampScale(this.view.scale * f);
    const after = this.toWorld(sx, sy);
    if (!this.follow) {
      this.view.cx += before[0] - after[0];
      this.view.cy += before[1] - after[1];
    }
    this.invalidate();
  }

  size() {
    return { w: this.canvas.clientWidth || 1, hgt: this.canvas.clientHeight || 1 };
  }

  toWorld(sx, sy) {
    const { w, hgt } = this.size();
    return screenToWorld(this.view, w, hgt, sx, sy);
  }

  bindInput() {
    const c = this.canvas;
    let drag = null;
    c.addEventListener("pointerdown", (e) => {
      if (e.button !== 0) return;
      drag = { x: e.clientX, y: e.clientY, cx: this.view.cx, cy: this.view.cy, moved: false };
      c.setPointerCapture(e.pointerId);
      c.classList.add("dragging");
    });
    c.addEventListener("click", (e) => {
      if (!this.measuring || this.lastDragMoved) return;
      const r = c.getBoundingClientRect();
      this.addMeasurePoint(e.clientX - r.left, e.clientY - r.top);
    });
    window.addEventListener("keydown", (e) => { if (e.key === "Escape" && this.measuring) this.setMeasuring(false); });
    c.addEventListener("pointermove", (e) => {
      if (!drag) return;
      const dx = e.clientX - drag.x;
      const dy = e.clientY - drag.y;
      if (Math.hypot(dx, dy) > 3) drag.moved = true;
      if (this.follow && drag.moved) this.setFollow(false);
      this.view.cx = drag.cx - dx / this.view.scale;
      this.view.cy = drag.cy + dy / this.view.scale;
      this.invalidate();
    });
    const end = () => { this.lastDragMoved = Boolean(drag?.moved); drag = null; c.classList.remove("dragging"); };
    c.addEventListener("pointerup", end);
    c.addEventListener("pointercancel", end);
    c.addEventListener("wheel", (e) => {
      e.preventDefault();
      const r = c.getBoundingClientRect();
      const dy = e.deltaMode === 1 ? e.deltaY * 16 : e.deltaY;
      this.zoomBy(Math.exp(-dy * 0.0015), e.clientX - r.left, e.clientY - r.top);
    }, { passive: false });
    c.addEventListener("dblclick", () => this.fit());
  }

  // ---- drawing ------------------------------------------------------------------------------------

  onFrame() {
    this.frame = 0;
    if (this.closed || !this.dirty) return;
    this.dirty = false;
    const t0 = performance.now();
    const more = this.draw();
    const t1 = performance.now();
    const st = stats();
    pushCapped(st.frame_ms, t1 - t0);
    st.frames = (st.frames || 0) + 1; // frame_ms keeps the last STATS_KEEP only
    // what the frame cost, for the ink of the next one: its script (which holds the raster its composite
    // forced), or with a slice drawn in the frame before, the time beyond one display frame since that
    // one's script ended, if longer (a raster after the script). Every frame counts: one that draws all
    // the walls at once is the one to slow down.
    if (this.layers.walls) {
      const after = this.lastFrameAt !== undefined ? t1 - this.lastFrameAt - 16.7 : 0;
      this.walls.feedback(Math.max(t1 - t0, after));
    }
    this.lastFrameAt = more ? t1 : undefined;
    st.version = this.shown().version;
    st.live_version = this.version;
    st.scale = this.view.scale;
    st.segments = this.shown().segments.size;
    st.drawn_at = performance.timeOrigin + t1;
    const p = this.walls.progress();
    st.walls_drawn = p.drawn;
    st.walls_complete = p.complete;
    st.walls_far = p.far;
    if (this.receivedAt !== undefined) { // time from the first snapshot to its first and its complete frame
      if (st.first_frame_ms === null) st.first_frame_ms = t1 - this.receivedAt;
      if (p.complete && st.complete_ms === null) st.complete_ms = t1 - this.receivedAt;
    }
    this.overlay.far.hidden = !p.far;
    this.overlay.far.textContent = p.far ? `${p.far} walls not drawn: a coordinate beyond ±${FAR_M.toExponential(0)} m` : "";
    if (more) this.invalidate(); // the next slice of walls
    if (this.pendingWallTimes.length) {
      const now = performance.timeOrigin + performance.now();
      for (const wt of this.pendingWallTimes) pushCapped(st.latencies_ms, now - wt * 1000);
      this.pendingWallTimes = [];
      for (const wt of this.pendingCorrections) pushCapped(st.correction_latencies_ms, now - wt * 1000);
      this.pendingCorrections = [];
    }
    this.updateHud();
  }

  updateScaleBar(scale) {
    const len = scaleBarLength(scale);
    const px = Math.round(len * scale);
    if (this.scaleLen === len && this.scalePx === px) return;
    this.scaleLen = len;
    this.scalePx = px;
    this.overlay.scaleBar.style.width = `${px}px`;
    this.overlay.scaleText.textContent = `${len} m`;
    this.overlay.scaleBar.dataset.metres = String(len);
  }

  updateHud() {
    const o = this.overlay, m = this.shown();
    o.version.textContent = m.version === null ? "—" : String(m.version);
    o.walls.textContent = String(m.segments.size);
    o.pose.textContent = poseText(m.pose);
    o.sigma.textContent = this.pinned ? "" : sigmaText(this.graph.covariance); // the live pose's only
    o.sigma.hidden = !o.sigma.textContent;
    const lat = median(stats().latencies_ms.slice(-50));
    o.latency.textContent = lat === null ? "—" : `${Math.round(lat)} ms`;
  }

  draw() {
    const c = this.canvas;
    const dpr = window.devicePixelRatio || 1;
    const { w, hgt } = this.size();
    const pw = Math.round(w * dpr);
    const ph = Math.round(hgt * dpr);
    if (c.width !== pw || c.height !== ph) { c.width = pw; c.height = ph; }
    const ctx = this.ctx;
    ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
    ctx.fillStyle = COLORS.bg;
    ctx.fillRect(0, 0, w, hgt);

    if (this.pendingFit && w > 1 && hgt > 1) this.applyFit(w, hgt);
    const m = this.shown();
    if (this.follow && m.pose && drawable(m.pose[0], m.pose[1])) {
      this.view.cx = m.pose[0];
      this.view.cy = m.pose[1];
    }
    const { cx, cy, scale } = this.view;
    const ox = w / 2 - cx * scale;
    const oy = hgt / 2 + cy * scale;
    // screen = (x * scale + ox, oy - y * scale)

    drawGrid(ctx, w, hgt, scale, ox, oy);
    if (this.layers.occupancy) {
      this.occupancy.want(this.robotId, m.version);
      this.occupancy.draw(ctx, scale, ox, oy);
    }

    // Walls: a small map in one path; else the progressive layer (maplayer.js) and what it has so far.
    let more = false;
    if (this.layers.walls && !this.walls.direct(ctx, m.segments, this.view, w, hgt)) {
      more = this.walls.step(m.segments, this.view, w, hgt, dpr);
      this.walls.composite(ctx, this.view, w, hgt);
    }
    if (this.layers.trajectory) drawTrajectory(ctx, m.trajectory, scale, ox, oy, w, hgt);
    if (this.layers.centroids) drawCentroids(ctx, m.centroids, scale, ox, oy, w, hgt);
    if (!this.pinned) this.graph.draw(ctx, this.layers, scale, ox, oy, w, hgt); // the live graph's
    if (this.layers.robot && m.pose && drawable(m.pose[0], m.pose[1])) {
      const sx = m.pose[0] * scale + ox, sy = oy - m.pose[1] * scale;
      const theta = Number.isFinite(m.pose[2]) ? m.pose[2] : 0;
      if (!this.pinned) this.graph.drawEllipse(ctx, sx, sy, scale);
      if (sx >= -20 && sx <= w + 20 && sy >= -20 && sy <= hgt + 20) drawRobot(ctx, sx, sy, theta);
    }
    if (this.measuring) drawMeasure(ctx, this.measurePoints, scale, ox, oy);
    stats().layers = { ...this.layers };
    stats().graph = this.graph.stats();
    if (this.sampledAt !== this.version) { // what is drawn, for tests: walls' coordinate sum, every 25th pose
      this.sampledAt = this.version;
      Object.assign(stats(), drawnSample(this.segments, this.trajectory));
    }
    stats().occupancy_version = this.occupancy.grid?.version ?? null;
    this.updateScaleBar(scale);
    return more;
  }
}
