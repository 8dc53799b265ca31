// Rollouts page: start a rollout of an uploaded kernel version to chosen robots (canaries first, then
// waves), list the rollouts, and watch one: each robot's state with the reason; pause, resume, abort.
// The server decides everything (server/rolloutplan.py); this page only asks and shows.

import { h, mount, when, trunc } from "../dom.js";
import { api, request } from "../api.js";

const rollouts = {
  list: () => request("GET", "/rollouts"),
  get: (id) => request("GET", `/rollouts/${encodeURIComponent(id)}`),
  start: (body) => request("POST", "/rollouts", { json: body }),
  act: (id, action) => request("POST", `/rollouts/${encodeURIComponent(id)}/${action}`),
};

// Robot and rollout states -> badge colour (dom.js's badge knows the message states only).
const TONE = {
  installed: "green", completed: "green", running: "green",
  failed: "red", "rolled-back": "red", "timed-out": "red", stopped: "red", aborted: "red",
  sent: "amber", applied: "amber", pending: "amber", paused: "amber",
  skipped: "grey",
};

function stateBadge(s, attrs = {}) {
  return h("span", { ...attrs, class: `badge badge-${TONE[s] || "grey"}`, "data-status": s }, s);
}

const pct = (share) => `${Math.round(share * 1000) / 10} %`;

export function renderRollouts(root, ctx, id) {
  if (id) renderOne(root, ctx, id);
  else renderList(root, ctx);
}

function renderList(root, ctx) {
  const listBox = h("div", null, h("p", { class: "muted pad" }, "Loading…"));
  const formBox = h("div", null, h("p", { class: "muted" }, "Loading…"));
  mount(root, h("div", { class: "page" },
    h("div", { class: "page-head" }, h("h2", null, "Rollouts")),
    h("div", { class: "card" }, h("h3", null, "Start a rollout"), formBox),
    h("div", { class: "card flush" }, h("h3", { class: "pad" }, "Rollouts"), listBox)));

  const refresh = async () => {
    try {
      const list = await rollouts.list();
      if (ctx.alive) drawList(listBox, list);
    } catch (e) {
      if (ctx.alive) mount(listBox, h("div", { class: "error pad" }, `Could not list rollouts: ${e.detail}`));
    }
  };
  Promise.all([api.kernels(), api.robots()])
    .then(([kernels, robots]) => { if (ctx.alive) mount(formBox, startForm(kernels, robots)); })
    .catch((e) => mount(formBox, h("div", { class: "error" }, `Could not load kernels and robots: ${e.detail}`)));
  refresh();
  ctx.interval(refresh, 2000);
}

function drawList(box, list) {
  if (!list.length) {
    mount(box, h("p", { class: "muted pad", "data-testid": "rollouts-empty" }, "No rollouts yet."));
    return;
  }
  mount(box, h("table", { class: "table", "data-testid": "rollouts-table" },
    h("thead", null, h("tr", null, ["#", "Kernel", "State", "Robots", "Started", "By", "Why it stopped"].map((t) => h("th", null, t)))),
    h("tbody", null, list.map((r) => h("tr", { "data-testid": "rollout-row", "data-rollout-id": r.id },
      h("td", null, h("a", { href: `#/rollouts/${r.id}`, "data-testid": "rollout-link" }, `#${r.id}`)),
      h("td", null, h("code", null, `${r.name}@${r.version}`), h("span", { class: "muted small" }, ` ${r.stage}`)),
      h("td", null, stateBadge(r.state)),
      h("td", { class: "small" }, Object.entries(r.counts).map(([s, n]) => `${n} ${s}`).join(", ")),
      h("td", null, when(r.created_at)),
      h("td", { class: "small" }, r.created_by),
      h("td", { class: "small" }, r.stop_reason ? trunc(r.stop_reason, 70) : "—"))))));
}

function numberField(label, attrs, hint) {
  const input = h("input", { type: "number", required: true, ...attrs });
  return [input, h("label", { class: "field" }, h("span", { class: "field-label" }, label), input,
    hint ? h("span", { class: "field-hint muted" }, hint) : null)];
}

function startForm(kernels, robots) {
  const live = kernels.filter((k) => !k.deleted);
  if (!live.length) return h("p", { class: "muted", "data-testid": "rollout-no-kernels" }, "Upload a kernel version first (Kernels page).");
  if (!robots.length) return h("p", { class: "muted" }, "Register robots first (Robots page).");
  const kernel = h("select", { "data-testid": "rollout-kernel" },
    live.map((k, i) => h("option", { value: String(i) }, `${k.name}@${k.version} (${k.stage})`)));
  const boxes = robots.map((r) => h("input", { type: "checkbox", value: String(r.id), checked: true, "data-testid": `rollout-robot-${r.id}` }));
  const robotList = h("div", { class: "rollout-robots" }, robots.map((r, i) => h("label", { class: "check" }, boxes[i],
    ` ${r.name} `, h("span", { class: "muted small" }, `#${r.id} ${(r.active_kernels && Object.values(r.active_kernels).join(", ")) || ""}`))));
  const [canaries, canariesField] = numberField("Canaries", { value: 1, min: 1, step: 1, "data-testid": "rollout-canaries" }, "first, alone; any failure stops");
  const [wave, waveField] = numberField("Wave size", { value: 5, min: 1, step: 1, "data-testid": "rollout-wave-size" });
  const [share, shareField] = numberField("Max failures (%)", { value: 20, min: 0, max: 100, step: "any", "data-testid": "rollout-max-failures" }, "of the robots tried");
  const [windowS, windowField] = numberField("Commit window (s)", { value: 60, min: 0.1, step: "any", "data-testid": "rollout-window" }, "healthy this long to commit");
  const [timeout, timeoutField] = numberField("Acknowledge within (s)", { value: 300, min: 0.1, step: "any", "data-testid": "rollout-ack-timeout" });
  const [watch, watchField] = numberField("Watch late answers (s)", { value: 3600, min: 0.1, step: "any", "data-testid": "rollout-watch-timeout" }, "after sending; then its rollback is queued");
  const [ratio, ratioField] = numberField("Max step-time ratio", { value: 2, min: 1.01, step: "any", "data-testid": "rollout-step-ratio" }, "x the robot's time before");
  const err = h("div", { class: "error", role: "alert", hidden: true, "data-testid": "rollout-error" });
  const submit = h("button", { type: "submit", class: "primary", "data-testid": "rollout-start" }, "Start rollout");
  return h("form", { class: "stack", onsubmit: async (e) => {
    e.preventDefault();
    err.hidden = true;
    const k = live[Number(kernel.value)];
    const chosen = boxes.filter((b) => b.checked).map((b) => Number(b.value));
    if (!chosen.length) { err.textContent = "Choose at least one robot."; err.hidden = false; return; }
    submit.disabled = true;
    try {
      const r = await rollouts.start({
        stage: k.stage, name: k.name, version: k.version, sha256: k.sha256, robots: chosen,
        canaries: Number(canaries.value), wave_size: Number(wave.value), max_failure_share: Number(share.value) / 100,
        commit_window_s: Number(windowS.value), ack_timeout_s: Number(timeout.value),
        watch_timeout_s: Number(watch.value), max_step_ratio: Number(ratio.value),
      });
      location.hash = `#/rollouts/${r.id}`;
    } catch (ex) {
      err.textContent = ex.detail;
      err.hidden = false;
    } finally {
      submit.disabled = false;
    }
  } },
  h("label", { class: "field" }, h("span", { class: "field-label" }, "Kernel version"), kernel),
  h("div", { class: "field" }, h("span", { class: "field-label" }, "Robots, in rollout order (the first are the canaries)"), robotList),
  h("div", { class: "row2" }, canariesField, waveField, shareField, windowField, timeoutField, watchField, ratioField),
  h("div", { class: "button-row" }, submit), err);
}

function renderOne(root, ctx, id) {
  const head = h("div", null, h("p", { class: "muted" }, "Loading…"));
  const body = h("div");
  const err = h("div", { class: "error", role: "alert", hidden: true, "data-testid": "rollout-action-error" });
  mount(root, h("div", { class: "page" },
    h("div", { class: "page-head" }, h("h2", null, `Rollout #${id}`), h("a", { href: "#/rollouts" }, "All rollouts")),
    h("div", { class: "card" }, head, err),
    h("div", { class: "card flush" }, h("h3", { class: "pad" }, "Robots"), body)));

  const act = async (action) => {
    err.hidden = true;
    try {
      draw(await rollouts.act(id, action));
    } catch (e) {
      err.textContent = e.detail;
      err.hidden = false;
    }
  };
  const draw = (r) => {
    if (!ctx.alive) return;
    const button = (action, label, cls) => h("button", { type: "button", class: cls, "data-testid": `rollout-${action}`, onclick: () => act(action) }, label);
    mount(head,
      h("div", { class: "button-row" },
        h("code", null, `${r.stage} / ${r.name}@${r.version}`), stateBadge(r.state, { "data-testid": "rollout-state" }),
        r.active && !["running", "paused"].includes(r.state) ? h("span", { class: "muted small" }, "(watching robots still to answer)") : null,
        h("span", { class: "spacer" }),
        r.state === "running" ? button("pause", "Pause") : null,
        r.state === "paused" ? button("resume", "Resume", "primary") : null,
        ["running", "paused"].includes(r.state) ? button("abort", "Abort and roll back", "danger") : null),
      h("p", { class: "small muted" },
        `${r.canaries} canar${r.canaries === 1 ? "y" : "ies"}, waves of ${r.wave_size}, stop above ${pct(r.max_failure_share)} failed, `
        + `commit window ${r.commit_window_s} s, acknowledge within ${r.ack_timeout_s} s, `
        + `watch a timed-out robot ${r.watch_timeout_s} s`
        + (r.max_step_ratio ? `, step time at most ${r.max_step_ratio} x` : "")
        + ` · started ${when(r.created_at)} by ${r.created_by}`),
      r.stop_reason ? h("div", { class: "error", "data-testid": "rollout-stop-reason" }, r.stop_reason) : null);
    mount(body, h("table", { class: "table", "data-testid": "rollout-robots" },
      h("thead", null, h("tr", null, ["Robot", "Wave", "State", "Reason", "Before", "Sent", "Done"].map((t) => h("th", null, t)))),
      h("tbody", null, r.robots.map((x) => h("tr", { "data-testid": "rollout-robot-row", "data-robot-id": x.robot_id, "data-state": x.state, "data-watched": String(x.watched) },
        h("td", null, h("a", { href: `#/robots/${x.robot_id}` }, x.robot_name), h("span", { class: "muted small" }, ` #${x.robot_id}`)),
        h("td", null, x.wave === 0 ? "canary" : String(x.wave)),
        h("td", null, stateBadge(x.state),
          x.watched ? h("span", { class: "muted small", "data-testid": "rollout-robot-watched" }, " watching for a late answer") : null),
        h("td", { class: "small", "data-testid": "rollout-robot-reason" }, x.reason ? trunc(x.reason, 160) : "—"),
        h("td", { class: "small" }, x.previous || "—"),
        h("td", { class: "small" }, x.sent_at ? when(x.sent_at) : "—"),
        h("td", { class: "small" }, x.finished_at ? when(x.finished_at) : "—"))))));
  };
  const refresh = async () => {
    try {
      draw(await rollouts.get(id));
    } catch (e) {
      if (ctx.alive) mount(head, h("div", { class: "error" }, `Could not read rollout ${id}: ${e.detail}`));
    }
  };
  refresh();
  ctx.interval(refresh, 1000);
}
