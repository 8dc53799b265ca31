// Robot page, Maps tab: the robot's maps, one per mapping session (the current one and those a new
// session replaced, kept on the server), and what happened to its identity: new sessions and why,
// agents that took over or were refused, message numbering re-synchronised after a server restore.

import { api } from "../api.js";
import { h, mount, ago, when, badge } from "../dom.js";

// Audit actions about a robot's identity, and how each reads.
const EVENTS = {
  "map.session.start": (d) =>
    `New map session ${short(d.session)} from version ${d.first_version}` +
    (d.previous_session !== undefined && d.previous_version ? ` (replaces ${short(d.previous_session)} at version ${d.previous_version})` : "") +
    (d.reason ? `: ${d.reason}` : ""),
  "agent.takeover": (d) => `Agent ${short(d.instance)} took over from agent ${short(d.previous_instance)} (the agent restarted, or another one with this robot's token)`,
  "agent.refused": (d) => `Agent ${short(d.instance)} refused: agent ${short(d.current_instance)} took over at ${d.since}`,
  "messages.resync": (d) =>
    `Message numbering re-synchronised: the robot had applied up to ${d.robot_applied}, the server was at ${d.server_last_seq}` +
    (d.renumbered && d.renumbered.length ? `; renumbered ${d.renumbered.map(([a, b]) => `${a}→${b}`).join(", ")}` : ""),
};

function short(id) {
  return id ? String(id).slice(0, 8) : "(none)";
}

export class RobotMapsTab {
  constructor(shared) {
    this.shared = shared;
    this.maps = h("div", { "data-testid": "robot-maps" }, h("p", { class: "muted" }, "Loading…"));
    this.events = h("div", { "data-testid": "robot-events" }, h("p", { class: "muted" }, "Loading…"));
    this.error = h("div", { class: "error", hidden: true, "data-testid": "maps-error" });
    this.el = h("div", { class: "tab-maps" },
      h("h4", null, "Maps ", h("span", { class: "muted small" }, "(one per mapping session; replaced maps are kept)")),
      this.error, this.maps,
      h("h4", null, "Identity events"), this.events);
    this.lastKey = null;
  }

  show() { this.reload(); }

  update() { this.reload(); }

  async reload() {
    const id = this.shared.robotId;
    let maps, events;
    try {
      [maps, events] = await Promise.all([api.robotMaps(id), api.robotEvents(id)]);
    } catch (e) {
      if (!this.shared.ctx.alive) return;
      this.error.textContent = `Could not load the robot's maps: ${e.detail}`;
      this.error.hidden = false;
      return;
    }
    if (!this.shared.ctx.alive) return;
    this.error.hidden = true;
    events = events.filter((e) => EVENTS[e.action]);
    const key = JSON.stringify([maps, events.map((e) => e.id)]);
    if (key === this.lastKey) return;
    this.lastKey = key;
    this.renderMaps(maps);
    this.renderEvents(events);
  }

  renderMaps(maps) {
    if (!maps.length) {
      mount(this.maps, h("p", { class: "muted" }, "No map uploaded yet."));
      return;
    }
    const row = (m) => h("tr", { "data-testid": "map-session", "data-session": m.map_session || "", "data-current": String(m.current) },
      h("td", { title: m.map_session || "a map from before map sessions" },
        h("code", null, short(m.map_session)), " ", m.current ? badge("current") : null,
        m.reason ? h("div", { class: "muted small" }, m.reason) : null),
      h("td", { class: "num" }, m.first_version == null ? "" : `${m.first_version}–`,
        h("span", { "data-testid": "session-last-version" }, String(m.last_version ?? "—"))),
      h("td", { class: "num", "data-testid": "session-walls" }, String(m.wall_count)),
      h("td", { title: `started ${when(m.started_at)}, last upload ${when(m.last_upload_at)}` },
        m.last_upload_at ? ago(m.last_upload_at) : "—"),
      h("td", null, m.current ? "" : h("a", {
        href: `/api/v1/robots/${encodeURIComponent(this.shared.robotId)}/maps/export?format=svg&session=${encodeURIComponent(m.map_session || "")}`,
        target: "_blank", rel: "noopener", title: "This map as it was when it was replaced",
      }, "SVG")));
    mount(this.maps, h("table", { class: "table" },
      h("thead", null, h("tr", null, ...["Session", "Versions", "Walls", "Last upload", ""].map((t) => h("th", null, t)))),
      h("tbody", null, maps.map(row))));
  }

  renderEvents(events) {
    if (!events.length) {
      mount(this.events, h("p", { class: "muted" }, "Nothing yet."));
      return;
    }
    mount(this.events, h("ul", { class: "events" }, events.map((e) =>
      h("li", { "data-testid": "robot-event", "data-action": e.action },
        h("span", { class: "muted small", title: when(e.at) }, ago(e.at)), " ", EVENTS[e.action](e.detail || {})))));
  }
}
