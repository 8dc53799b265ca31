// Robot list (home page): a table refreshed every 2 s, and a form to register a robot.

import { h, mount, ago, trunc, badge, num, copyText } from "../dom.js";
import { api } from "../api.js";
import { STAGES } from "../schema.js";

const STAGE_SHORT = {
  segmentation: "seg", "noise-removal": "noise", clustering: "clust", "straight-line": "line", "scan-matching": "match",
};

export function renderRobots(root, ctx) {
  const tbody = h("tbody");
  const status = h("div", { class: "muted small", "data-testid": "robots-status" }, "Loading…");
  const table = h("table", { class: "table robots", "data-testid": "robots-table" },
    h("thead", null, h("tr", null,
      h("th", null, "Name"), h("th", null, "Status"), h("th", null, "Last seen"), h("th", null, "Mode"),
      h("th", null, "Active kernels"), h("th", { class: "num" }, "Map"), h("th", { class: "num" }, "Step ms"),
      h("th", null, "Last error"), h("th", { class: "num" }, "Pending"))),
    tbody);

  let robots = [];
  const draw = () => {
    const now = Date.now();
    if (!robots.length) {
      mount(tbody, h("tr", null, h("td", { colspan: 9, class: "empty" }, "No robots yet — register one below.")));
      return;
    }
    mount(tbody, robots.map((r) => {
      const open = () => { location.hash = `#/robots/${r.id}`; };
      return h("tr", { class: "clickable", "data-testid": "robot-row", "data-robot-id": r.id, tabindex: 0, onclick: open,
        onkeydown: (e) => { if (e.key === "Enter") open(); } },
      h("td", null, h("a", { href: `#/robots/${r.id}`, class: "robot-name", onclick: (e) => e.stopPropagation() }, r.name),
        h("span", { class: "muted small" }, ` #${r.id}`)),
      h("td", null, badge(r.online ? "online" : "offline", { "data-testid": "robot-online" })),
      h("td", { title: r.last_seen_at || "never", "data-testid": "robot-last-seen" }, ago(r.last_seen_at, now)),
      h("td", { "data-testid": "robot-mode" }, r.mode || "—"),
      h("td", { class: "kernels-cell" }, activeKernels(r.active_kernels)),
      h("td", { class: "num", "data-testid": "robot-map-version" }, r.map_version ?? "—"),
      h("td", { class: "num", "data-testid": "robot-step-ms" }, num(r.step_ms, 1)),
      h("td", { class: "error-cell", "data-testid": "robot-last-error" }, r.last_error
        // The agent sends "<UTC time>: <message>" and clears it once healthy; an offline robot's is as of its last contact.
        ? trunc(r.last_error.replace(/^\d{4}-\d\d-\d\dT\d\d:\d\d:\d\dZ: /, ""), 40, { class: r.online ? "text-red" : "muted" })
        : h("span", { class: "muted" }, "—")),
      h("td", { class: "num", "data-testid": "robot-pending" }, r.pending_messages ?? 0));
    }));
  };

  const refresh = async () => {
    try {
      robots = await api.robots();
      if (!ctx.alive) return;
      status.textContent = `${robots.length} robot${robots.length === 1 ? "" : "s"} · ${robots.filter((r) => r.online).length} online · updated ${new Date().toLocaleTimeString()}`;
      status.classList.remove("text-red");
      draw();
    } catch (e) {
      if (!ctx.alive) return;
      status.textContent = `Could not refresh: ${e.detail}`;
      status.classList.add("text-red");
    }
  };

  mount(root,
    h("div", { class: "page" },
      h("div", { class: "page-head" }, h("h2", null, "Robots"), status),
      h("div", { class: "card flush" }, table),
      registerForm(refresh)));
  draw();
  refresh();
  ctx.interval(refresh, 2000);
}

function activeKernels(ak) {
  const entries = ak ? STAGES.filter((s) => ak[s]).map((s) => [s, ak[s]]) : [];
  for (const [k, v] of Object.entries(ak || {})) if (!STAGES.includes(k)) entries.push([k, v]);
  if (!entries.length) return h("span", { class: "muted" }, "—");
  return h("div", { class: "chips" }, entries.map(([stage, v]) => {
    const text = Array.isArray(v) ? v.join(" → ") : String(v);
    return h("span", { class: "chip", title: `${stage}: ${text}`, "data-stage": stage },
      h("b", null, STAGE_SHORT[stage] || stage), " ", text);
  }));
}

function registerForm(refresh) {
  const name = h("input", { type: "text", name: "name", "data-testid": "register-name", placeholder: "robot name, e.g. plat-f1",
    required: true, maxlength: 100 });
  const err = h("div", { class: "error", "data-testid": "register-error", hidden: true });
  const out = h("div", { class: "token-box", hidden: true });
  const submit = h("button", { type: "submit", class: "primary", "data-testid": "register-submit" }, "Register robot");
  const form = h("form", { class: "inline-form", onsubmit: async (e) => {
    e.preventDefault();
    err.hidden = true;
    submit.disabled = true;
    try {
      const r = await api.registerRobot(name.value.trim());
      name.value = "";
      const tokenEl = h("code", { "data-testid": "register-token", class: "token" }, r.token);
      const copyBtn = h("button", { type: "button", "data-testid": "register-copy", onclick: async () => {
        copyBtn.textContent = (await copyText(r.token)) ? "Copied" : "Copy failed — select it";
      } }, "Copy");
      mount(out,
        h("div", null, "Robot ", h("b", null, r.name), ` registered with id ${r.id}. Its token is shown `, h("b", null, "only now"), ":"),
        h("div", { class: "token-line" }, tokenEl, copyBtn),
        h("div", { class: "muted small" },
          `Start the agent: linemap agent --server ${location.origin} --robot-id ${r.id} --token <token>`));
      out.hidden = false;
      refresh();
    } catch (ex) {
      err.textContent = ex.detail;
      err.hidden = false;
    } finally {
      submit.disabled = false;
    }
  } }, name, submit);
  return h("div", { class: "card" }, h("h3", null, "Register robot"), form, err, out);
}
