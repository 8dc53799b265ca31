// Sending control messages and following their acknowledgement (the "ack" panel).

import { h, mount, badge, when } from "../dom.js";
import { api } from "../api.js";
import { isChain, stageKey } from "../schema.js";

const POLL_MS = 300;
const GIVE_UP_MS = 60000;

/**
 * An acknowledgement panel. panel.el goes into the page (one per page: data-testid "ack");
 * panel.send(robotId, xml, label) posts the XML and polls until the robot answers.
 */
export class AckPanel {
  constructor(ctx) {
    this.ctx = ctx;
    this.token = 0;
    this.el = h("div", { class: "ack", "data-testid": "ack", hidden: true, "aria-live": "polite" });
  }

  show(status, title, reason, extra) {
    this.el.hidden = false;
    this.el.dataset.status = status;
    this.el.className = `ack ack-${status}`;
    mount(this.el,
      h("div", { class: "ack-head" }, badge(status, { "data-testid": "ack-status" }), h("span", { class: "ack-title" }, title)),
      reason ? h("div", { class: "ack-reason", "data-testid": "ack-reason" }, reason) : null,
      extra || null);
  }

  error(text) {
    this.token++;
    this.el.hidden = false;
    delete this.el.dataset.status;
    this.el.className = "ack ack-error";
    mount(this.el, h("div", { class: "error", "data-testid": "ack-error" }, text));
  }

  hide() {
    this.token++;
    this.el.hidden = true;
  }

  /** Post xml to the robot; returns the final MessageOut (or null when posting failed / gave up). */
  async send(robotId, xml, label = "Message") {
    const my = ++this.token;
    this.show("queued", `${label}: sending…`);
    let msg;
    try {
      msg = await api.postXml(robotId, xml);
    } catch (e) {
      if (my === this.token) this.error(`Not sent: ${e.detail}`);
      throw e;
    }
    return this.follow(robotId, msg, label, my);
  }

  async follow(robotId, msg, label, my = ++this.token) {
    const start = performance.now();
    const details = (m) => h("div", { class: "ack-meta muted small" },
      `seq ${m.seq} · sent ${when(m.created_at)} by ${m.created_by}`,
      m.acked_at ? ` · acknowledged ${when(m.acked_at)}` : "");
    this.el.dataset.seq = msg.seq;
    while (msg.status === "queued") {
      if (my !== this.token || !this.ctx.alive) return msg;
      const waited = performance.now() - start;
      if (waited > GIVE_UP_MS) {
        this.show("queued", `${label} #${msg.seq}: no acknowledgement after 60 s`,
          "The robot has not answered yet (offline, or busy). The Messages tab shows it when it does.", details(msg));
        return msg;
      }
      this.show("queued", `${label} #${msg.seq}: queued, waiting for the robot… ${Math.floor(waited / 1000)} s`, null, details(msg));
      await sleep(POLL_MS);
      try {
        msg = await api.message(robotId, msg.seq);
      } catch (e) {
        if (e.status === 401 || e.status === 404) { this.error(`Lost track of message #${msg.seq}: ${e.detail}`); return null; }
        // transient: keep polling
      }
    }
    if (my !== this.token) return msg;
    const titles = { applied: "applied by the robot", rejected: "rejected by the robot", "rolled-back": "rolled back by the robot" };
    this.show(msg.status, `${label} #${msg.seq}: ${titles[msg.status] || msg.status}`, msg.reason, details(msg));
    return msg;
  }
}

const sleep = (ms) => new Promise((r) => setTimeout(r, ms));

/**
 * Build a message from a JSON draft (POST /control/xml) and send it to the robot, showing the ack.
 * onXml(xml) is called with the generated XML (e.g. to show it).
 */
export async function sendDraft(panel, robotId, draft, label, onXml) {
  panel.show("queued", `${label}: preparing…`);
  let xml;
  try {
    ({ xml } = await api.controlXml(draft));
  } catch (e) {
    panel.error(`Not sent: ${e.detail}`);
    throw e;
  }
  if (onXml) onXml(xml);
  return panel.send(robotId, xml, label);
}

/** Draft that installs an uploaded kernel and selects it for its stage (config: the robot's, or null;
 * builtins: GET /kernels/builtin, to send built-in chain members with version null). */
export function installDraft(kernel, config, builtins = []) {
  const op = { kind: "install", stage: kernel.stage, name: kernel.name, version: kernel.version, sha256: kernel.sha256 };
  const choice = { name: kernel.name, version: kernel.version, params: {} };
  const draft = { operations: [op] };
  const key = stageKey(kernel.stage);
  if (isChain(kernel.stage)) {
    const chain = Array.isArray(config?.[key]) ? config[key] : [];
    const i = chain.findIndex((c) => c.name === kernel.name);
    draft[key] = i >= 0
      ? chain.map((c, j) => (j === i ? choice : { name: c.name, version: draftVersion(builtins, kernel.stage, c), params: c.params || {} }))
      : [choice];
  } else {
    draft[key] = choice;
  }
  return draft;
}

export function rollbackDraft(stage, name, version) {
  // The operator's explicit override of the robot's anti-rollback floor (recorded in the audit log).
  return { operations: [{ kind: "rollback", stage, name, version, below_floor: true }] };
}

/** Version to put in a draft for a configured kernel: null for a built-in one. */
export function draftVersion(builtins, stage, choice) {
  const b = builtins.find((k) => k.stage === stage && k.name === choice.name);
  return b && (!choice.version || choice.version === b.version) ? null : (choice.version ?? null);
}
