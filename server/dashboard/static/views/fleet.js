// Fleet view: every robot's map and pose at a glance, a card each (name, online, map version, walls,
// pose, a small drawing of its map, trajectory and pose), refreshed every few seconds; a map is fetched
// again only when its version changed. Click a card to open the robot.

import { h, mount, badge } from "../dom.js";
import { api } from "../api.js";
import { COLORS, drawRobot, drawTrajectory } from "../mapdraw.js";
import { clipSegment, drawable } from "../maplayer.js";
import { poseText } from "../maptools.js";
import { drawnBounds, fittedView } from "../viewport.js";

const REFRESH_MS = 3000;
const CARD_W = 320;
const CARD_H = 220;

/** Draw map m ({segments: [[id, x0, y0, x1, y1]], trajectory, pose}) fitted into canvas c. */
export function drawThumbnail(c, m) {
  const dpr = window.devicePixelRatio || 1;
  c.width = CARD_W * dpr;
  c.height = CARD_H * dpr;
  const ctx = c.getContext("2d", { alpha: false });
  ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
  ctx.fillStyle = COLORS.bg;
  ctx.fillRect(0, 0, CARD_W, CARD_H);
  const segs = (m.segments || []).map((s) => [s[1], s[2], s[3], s[4]]);
  const traj = m.trajectory || [];
  const pose = m.pose && m.pose.length >= 2 ? m.pose : null;
  const view = fittedView(drawnBounds(segs, traj, [], pose), CARD_W, CARD_H);
  if (!view) return 0;
  const { cx, cy, scale } = view;
  const ox = CARD_W / 2 - cx * scale;
  const oy = CARD_H / 2 + cy * scale;
  let drawn = 0;
  ctx.beginPath();
  for (const s of segs) {
    if (!drawable(s[0], s[1]) || !drawable(s[2], s[3])) continue;
    const q = clipSegment(s[0] * scale + ox, oy - s[1] * scale, s[2] * scale + ox, oy - s[3] * scale, 0, 0, CARD_W, CARD_H);
    if (q) { ctx.moveTo(q[0], q[1]); ctx.lineTo(q[2], q[3]); drawn++; }
  }
  ctx.strokeStyle = COLORS.wall;
  ctx.lineWidth = 1.5;
  ctx.stroke();
  drawTrajectory(ctx, traj, scale, ox, oy, CARD_W, CARD_H);
  if (pose && drawable(pose[0], pose[1])) drawRobot(ctx, pose[0] * scale + ox, oy - pose[1] * scale, pose[2] || 0);
  return drawn;
}

export function renderFleet(root, ctx) {
  const grid = h("div", { class: "fleet-grid", "data-testid": "fleet-grid" });
  const status = h("div", { class: "muted small", "data-testid": "fleet-status" }, "Loading…");
  mount(root, h("div", { class: "page" },
    h("div", { class: "page-head" }, h("h2", null, "Fleet"), status),
    h("p", { class: "muted small" }, "Every robot's map and pose as the server holds them; click a map to open the robot."),
    grid));
  const cards = new Map(); // robot id -> {el, canvas, info, version}

  const card = (r) => {
    let c = cards.get(r.id);
    if (!c) {
      const canvas = h("canvas", { class: "fleet-map", width: CARD_W, height: CARD_H });
      const info = h("div", { class: "fleet-info small" });
      const el = h("a", { class: "fleet-card", href: `#/robots/${r.id}`, "data-testid": "fleet-card", "data-robot-id": r.id }, canvas, info);
      c = { el, canvas, info, version: null };
      cards.set(r.id, c);
    }
    return c;
  };

  const refresh = async () => {
    let robots;
    try {
      robots = await api.robots();
    } catch (e) {
      if (ctx.alive) status.textContent = `Could not refresh: ${e.detail}`;
      return;
    }
    if (!ctx.alive) return;
    const order = [];
    for (const r of robots) {
      const c = card(r);
      order.push(c.el);
      if (r.map_version && r.map_version !== c.version) {
        try {
          const m = await api.mapLatest(r.id);
          if (!ctx.alive) return;
          c.version = m.version;
          c.walls = (m.segments || []).length;
          c.pose = m.pose;
          c.el.dataset.drawn = String(drawThumbnail(c.canvas, m));
        } catch (e) {
          c.error = e.detail;
        }
      }
      c.el.dataset.version = String(c.version ?? 0);
      mount(c.info,
        h("div", { class: "fleet-title" }, h("strong", null, r.name), " ", badge(r.online ? "online" : "offline")),
        h("div", { "data-testid": "fleet-summary" }, c.version ? `map v${c.version} · ${c.walls} walls` : "no map yet"),
        h("div", { class: "muted", "data-testid": "fleet-pose" }, poseText(c.pose)),
        c.error ? h("div", { class: "text-red" }, c.error) : null);
    }
    mount(grid, order.length ? order : h("p", { class: "muted" }, "No robots yet."));
    status.textContent = `${robots.length} robot${robots.length === 1 ? "" : "s"} · ${robots.filter((r) => r.online).length} online · updated ${new Date().toLocaleTimeString()}`;
  };
  refresh();
  ctx.interval(refresh, REFRESH_MS);
}
