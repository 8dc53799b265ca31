// Robot page: live map on the left, side panel with tabs Status | Tune | Kernels | Maps | Messages.

import { h, mount, ago, when, badge, num, trunc } from "../dom.js";
import { api, builtinKernels } from "../api.js";
import { MapView } from "../mapview.js";
import { STAGES, configRows, showValue, isChain } from "../schema.js";
import { TuneTab } from "./tune.js";
import { RobotKernelsTab } from "./robotkernels.js";
import { RobotMapsTab } from "./robotmaps.js";

const TABS = [["status", "Status"], ["tune", "Tune"], ["kernels", "Kernels"], ["maps", "Maps"], ["messages", "Messages"]];

export function renderRobot(root, ctx, robotId, initialTab) {
  const map = new MapView();
  ctx.onCleanup(() => map.close());
  map.connect(robotId);

  const shared = { robotId, robot: null, builtins: null, uploaded: null, ctx };
  const title = h("h2", { class: "robot-title" }, `Robot #${robotId}`);
  const headBadge = h("span");
  const headSeen = h("span", { class: "muted small" });
  const loadError = h("div", { class: "error", hidden: true, "data-testid": "robot-error" });
  const tabBar = h("div", { class: "tabs", role: "tablist" });
  const body = h("div", { class: "tab-body" });
  const tabs = {};
  let active = TABS.some(([k]) => k === initialTab) ? initialTab : "status";

  const makeTab = (key) => {
    if (key === "status") return new StatusTab(shared);
    if (key === "tune") return new TuneTab(shared);
    if (key === "kernels") return new RobotKernelsTab(shared);
    if (key === "maps") return new RobotMapsTab(shared);
    return new MessagesTab(shared);
  };
  const scrolls = {};
  const select = (key) => {
    scrolls[active] = body.scrollTop;
    if (tabs[active]?.hide) tabs[active].hide();
    active = key;
    if (!tabs[key]) tabs[key] = makeTab(key);
    for (const b of tabBar.children) b.setAttribute("aria-selected", String(b.dataset.tab === key));
    mount(body, tabs[key].el); // only the active tab is in the document (test ids stay unique)
    body.scrollTop = scrolls[key] || 0;
    if (tabs[key].show) tabs[key].show();
    history.replaceState(null, "", `#/robots/${encodeURIComponent(robotId)}${key === "status" ? "" : `/${key}`}`);
  };
  for (const [key, label] of TABS) {
    tabBar.append(h("button", { type: "button", role: "tab", class: "tab", "data-tab": key, "data-testid": `tab-${key}`,
      onclick: () => select(key) }, label));
  }

  mount(root, h("div", { class: "robot-page" },
    h("section", { class: "map-pane" }, map.el),
    h("aside", { class: "side-pane" },
      h("div", { class: "side-head" }, h("a", { href: "#/robots", class: "back", title: "All robots" }, "←"), title, headBadge, headSeen),
      loadError, tabBar, body)));

  let timer = null;
  const refresh = async () => {
    try {
      const [robot, builtins] = await Promise.all([api.robot(robotId), shared.builtins || builtinKernels()]);
      if (!ctx.alive) return;
      shared.robot = robot;
      shared.builtins = builtins;
      loadError.hidden = true;
      title.textContent = robot.name;
      document.title = `${robot.name} · linemap`;
      mount(headBadge, badge(robot.online ? "online" : "offline", { "data-testid": "robot-online" }));
      headSeen.textContent = `seen ${ago(robot.last_seen_at)}`;
      for (const t of Object.values(tabs)) if (t.update) t.update(robot);
    } catch (e) {
      if (!ctx.alive) return;
      if (e.status === 404) {
        map.close(); // nothing to stream or poll
        clearInterval(timer);
        map.setStatus("no such robot");
        for (const t of Object.values(tabs)) if (t.hide) t.hide();
        mount(body, h("p", { class: "muted" }, "This robot does not exist (or was deleted). ", h("a", { href: "#/robots" }, "All robots")));
      }
      loadError.textContent = e.status === 404 ? `No robot #${robotId}.` : `Could not load the robot: ${e.detail}`;
      loadError.hidden = false;
    }
  };
  shared.refresh = refresh;
  select(active);
  refresh();
  timer = ctx.interval(refresh, 2000);
  ctx.onCleanup(() => { document.title = "linemap dashboard"; });
}

// ---- Status ---------------------------------------------------------------------------------------

class StatusTab {
  constructor(shared) {
    this.shared = shared;
    this.el = h("div", { class: "tab-status" }, h("p", { class: "muted" }, "Loading…"));
    if (shared.robot) this.update(shared.robot);
  }

  update(r) {
    const builtins = this.shared.builtins || [];
    const kv = (k, v, testid) => h("tr", null, h("th", null, k), h("td", { "data-testid": testid }, v));
    const summary = h("table", { class: "kv" }, h("tbody", null,
      kv("Status", badge(r.online ? "online" : "offline"), "status-online"),
      kv("Last seen", h("span", { title: when(r.last_seen_at) }, ago(r.last_seen_at)), "status-last-seen"),
      kv("Mode", r.mode || "—", "status-mode"),
      kv("Step time", r.step_ms == null ? "—" : `${num(r.step_ms, 1)} ms`, "status-step-ms"),
      kv("Map version", String(r.map_version ?? "—"), "status-map-version"),
      kv("Messages", `${r.pending_messages} pending · last seq ${r.last_seq}`, "status-messages"),
      // "<UTC time>: <message>" from the agent, cleared once it is healthy again; stale (muted) while offline.
      kv("Last error", r.last_error ? h("span", { class: `${r.online ? "text-red" : "muted"} pre-wrap` }, r.last_error) : "—", "status-last-error")));

    const ak = r.active_kernels || {};
    const active = h("table", { class: "kv" }, h("tbody", null,
      STAGES.map((s) => kv(s, ak[s] == null ? "—" : (Array.isArray(ak[s]) ? ak[s].join(" → ") : String(ak[s])), `active-${s}`))));

    const cfg = r.config;
    let configEl;
    if (!cfg) {
      configEl = h("p", { class: "muted", "data-testid": "config-table" }, "The robot has not reported its configuration yet.");
    } else {
      const lc = cfg.loop_closure;
      const general = [["mode", cfg.mode], ["n_smax", cfg.n_smax], ["heading_flush_deg", cfg.heading_flush_deg, "deg"],
        ["loop_closure", lc ? "on" : "off"],
        ...(lc ? [["loop search_radius_m", lc.search_radius_m, "m"], ["loop min_inlier_share", lc.min_inlier_share]] : [])]
        .filter(([, v]) => v !== undefined);
      const rows = configRows(cfg, builtins);
      const out = [];
      let lastKey = null;
      for (const row of rows) {
        const key = `${row.stage}|${row.index}|${row.kernel}`;
        if (key !== lastKey) {
          lastKey = key;
          const kernelText = row.kernel ? `${row.kernel}${row.version ? `@${row.version}` : ""}` : "none";
          out.push(h("tr", { class: "group", "data-stage": row.stage, "data-kernel": row.kernel || "", "data-index": row.index ?? null },
            h("td", { colspan: 3 }, h("span", { class: "stage-name" }, row.stage),
              row.index !== undefined && isChain(row.stage) ? h("span", { class: "muted" }, ` #${row.index + 1}`) : null,
              " ", h("b", null, kernelText))));
        }
        if (!row.param) continue;
        out.push(h("tr", {
          class: row.isDefault ? null : "non-default",
          "data-stage": row.stage, "data-kernel": row.kernel || "", "data-param": row.param, "data-index": row.index ?? null,
          title: row.isDefault ? null : "set explicitly (differs from the default)",
        },
        h("td", { class: "param" }, row.param),
        h("td", { class: "num", "data-testid": "config-value" }, showValue(row.value)),
        h("td", { class: "muted unit" }, row.unit || "")));
      }
      configEl = h("table", { class: "table config", "data-testid": "config-table" },
        h("thead", null, h("tr", null, h("th", null, "Stage → kernel → parameter"), h("th", { class: "num" }, "Value"), h("th", null, "Unit"))),
        h("tbody", null,
          h("tr", { class: "group" }, h("td", { colspan: 3 }, h("span", { class: "stage-name" }, "pipeline"))),
          general.map(([p, v, unit]) => h("tr", { "data-stage": "pipeline", "data-kernel": "", "data-param": p },
            h("td", { class: "param" }, p),
            h("td", { class: "num", "data-testid": "config-value" }, showValue(v)), h("td", { class: "muted unit" }, unit || ""))),
          out));
    }
    const schedule = cfg?.schedule && Object.keys(cfg.schedule).length
      ? h("div", null, h("h4", null, "Schedule (mixed mode)"), h("pre", { class: "xml" }, JSON.stringify(cfg.schedule, null, 2)))
      : null;

    mount(this.el,
      summary,
      h("h4", null, "Active kernels"), active,
      h("h4", null, "Configuration in force ", h("span", { class: "muted small" }, "(highlighted: differs from the kernel default)")),
      configEl, schedule);
  }
}

// ---- Messages -------------------------------------------------------------------------------------

class MessagesTab {
  constructor(shared) {
    this.shared = shared;
    this.open = new Set();
    this.list = h("div", { class: "messages" }, h("p", { class: "muted" }, "Loading…"));
    this.status = h("div", { class: "muted small" });
    this.el = h("div", { class: "tab-messages" }, this.status, this.list);
    shared.ctx.onCleanup(() => clearInterval(this.timer));
  }

  show() {
    this.load();
    clearInterval(this.timer);
    this.timer = setInterval(() => { if (this.shared.ctx.alive) this.load(); else clearInterval(this.timer); }, 2000);
  }

  hide() { clearInterval(this.timer); }

  async load() {
    const id = this.shared.robotId;
    try {
      let lastSeq = this.shared.robot?.last_seq;
      if (lastSeq === undefined) lastSeq = (await api.messages(id, 0, 1)).last_seq;
      let res = await api.messages(id, Math.max(0, lastSeq - 100), 100);
      if (res.last_seq > lastSeq + 0) res = await api.messages(id, Math.max(0, res.last_seq - 100), 100);
      this.render(res);
    } catch (e) {
      this.status.textContent = `Could not load messages: ${e.detail}`;
    }
  }

  render(res) {
    const msgs = [...res.messages].sort((a, b) => b.seq - a.seq);
    this.status.textContent = `${msgs.length} message${msgs.length === 1 ? "" : "s"} (newest first; last seq ${res.last_seq})`;
    if (!msgs.length) {
      mount(this.list, h("p", { class: "muted" }, "No messages sent to this robot yet."));
      return;
    }
    mount(this.list, msgs.map((m) => {
      const det = h("details", { open: this.open.has(m.seq) },
        h("summary", null, "XML"), h("pre", { class: "xml" }, m.xml));
      det.addEventListener("toggle", () => (det.open ? this.open.add(m.seq) : this.open.delete(m.seq)));
      return h("div", { class: "message", "data-testid": "messages-row", "data-seq": m.seq, "data-status": m.status },
        h("div", { class: "message-head" },
          h("b", null, `#${m.seq}`), badge(m.status),
          h("span", { class: "muted small", title: m.acked_at ? `acknowledged ${when(m.acked_at)}` : "not acknowledged yet" },
            `${when(m.created_at)} by ${m.created_by}${m.acked_at ? ` · acked ${ago(m.acked_at)}` : ""}`)),
        m.reason ? h("div", { class: `reason ${m.status === "applied" ? "" : "text-red"}` }, trunc(m.reason, 300)) : null,
        det);
    }));
  }
}
