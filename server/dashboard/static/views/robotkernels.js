// Robot page, Kernels tab: the robot's installed kernels (with Roll back to…), the uploaded kernel
// versions it could install (Install), and the acknowledgement of what was sent.

import { uploadedKernels } from "../api.js";
import { h, mount, badge, modal, when } from "../dom.js";
import { cmpVersion, STAGES, configBlocks } from "../schema.js";
import { AckPanel, sendDraft, installDraft, rollbackDraft } from "./ack.js";

export class RobotKernelsTab {
  constructor(shared) {
    this.shared = shared;
    this.ack = new AckPanel(shared.ctx);
    this.installed = h("div", null, h("p", { class: "muted" }, "Loading…"));
    this.available = h("div", null, h("p", { class: "muted" }, "Loading…"));
    this.error = h("div", { class: "error", "data-testid": "form-error", hidden: true });
    this.el = h("div", { class: "tab-kernels" },
      h("h4", null, "Installed on this robot"), this.installed,
      this.error, this.ack.el,
      h("h4", null, "Uploaded kernels ", h("span", { class: "muted small" }, "(Install downloads it, checks it and runs it for its stage)")),
      this.available);
    this.lastKey = null;
  }

  show() { this.reload(true); }

  update() { this.reload(false); }

  async reload(force) {
    const r = this.shared.robot;
    if (!r) return;
    try {
      this.uploaded = await uploadedKernels(this.shared, force ? 0 : 10000);
    } catch (e) {
      this.showError(`Could not list uploaded kernels: ${e.detail}`);
      this.uploaded = this.uploaded || [];
    }
    const key = JSON.stringify([r.kernels, r.config, this.uploaded.map((k) => [k.name, k.version, k.deleted])]);
    if (key === this.lastKey) return;
    this.lastKey = key;
    this.renderInstalled(r);
    this.renderAvailable(r);
  }

  showError(text) {
    this.error.textContent = text;
    this.error.hidden = false;
  }

  renderInstalled(r) {
    const list = r.kernels;
    if (!list) {
      mount(this.installed, h("p", { class: "muted" }, "The robot has not reported its kernel store yet."));
      return;
    }
    if (!list.length) {
      mount(this.installed, h("p", { class: "muted" }, "Only built-in kernels (nothing downloaded)."));
      return;
    }
    const inUse = new Set();
    for (const stage of STAGES) for (const b of configBlocks(r.config, stage)) inUse.add(`${stage}|${b.name}@${b.version}`);
    const rows = [...list].sort((a, b) => a.stage.localeCompare(b.stage) || a.name.localeCompare(b.name) || cmpVersion(b.version, a.version));
    mount(this.installed, h("table", { class: "table compact" },
      h("thead", null, h("tr", null, h("th", null, "Kernel"), h("th", null, "State"), h("th", null, "sha256"), h("th"))),
      h("tbody", null, rows.map((k) => {
        const lower = this.lowerVersions(k, list);
        return h("tr", { "data-testid": "robot-kernel-row", "data-name": k.name, "data-version": k.version, "data-state": k.state, "data-stage": k.stage },
          h("td", null, h("div", null, `${k.name}@${k.version}`), h("div", { class: "muted small" }, k.stage)),
          h("td", null, badge(k.state),
            inUse.has(`${k.stage}|${k.name}@${k.version}`) ? h("span", { class: "chip in-use", "data-testid": "robot-kernel-in-use", title: "in the configuration in force" }, "in use") : null),
          h("td", { class: "mono", title: k.sha256 || "" }, (k.sha256 || "").slice(0, 10)),
          h("td", { class: "actions" }, h("button", { type: "button", class: "small", "data-testid": "robot-kernel-rollback",
            disabled: !lower.length, title: lower.length ? `Run an earlier version instead (${lower.join(", ")})` : "No earlier version known",
            onclick: () => this.rollback(k, lower) }, "Roll back to…")));
      }))));
  }

  lowerVersions(k, installed) {
    const versions = new Set();
    for (const x of [...installed, ...this.uploaded, ...(this.shared.builtins || [])]) {
      if (x.name === k.name && x.stage === k.stage && cmpVersion(x.version, k.version) < 0) versions.add(x.version);
    }
    return [...versions].sort((a, b) => cmpVersion(b, a));
  }

  renderAvailable(r) {
    const ups = this.uploaded.filter((k) => !k.deleted);
    if (!ups.length) {
      mount(this.available, h("p", { class: "muted" }, "No kernels uploaded yet (see ", h("a", { href: "#/kernels" }, "Kernels"), ")."));
      return;
    }
    const have = new Map((r.kernels || []).map((k) => [`${k.name}@${k.version}`, k.state]));
    mount(this.available, h("table", { class: "table compact" },
      h("thead", null, h("tr", null, h("th", null, "Kernel"), h("th", null, "On robot"), h("th"))),
      h("tbody", null, ups.map((k) => h("tr", { "data-testid": "kernel-row", "data-name": k.name, "data-version": k.version, "data-stage": k.stage },
        h("td", { title: `sha256 ${k.sha256}\nuploaded ${when(k.uploaded_at)} by ${k.uploaded_by}` },
          h("div", null, `${k.name}@${k.version}`), h("div", { class: "muted small" }, k.stage)),
        h("td", null, have.has(`${k.name}@${k.version}`) ? badge(have.get(`${k.name}@${k.version}`)) : h("span", { class: "muted" }, "—")),
        h("td", { class: "actions" }, h("button", { type: "button", class: "small primary", "data-testid": "kernel-install",
          title: "Install on this robot and run it for its stage", onclick: (e) => this.install(k, e.target) }, "Install")))))));
  }

  async install(k, btn) {
    this.error.hidden = true;
    btn.disabled = true;
    try {
      const draft = installDraft(k, this.shared.robot?.config, this.shared.builtins || []);
      await sendDraft(this.ack, this.shared.robotId, draft, `Install ${k.name}@${k.version}`);
      this.shared.refresh?.();
    } catch (e) {
      this.showError(e.detail || String(e));
    } finally {
      btn.disabled = false;
    }
  }

  async rollback(k, lower) {
    const builtin = (this.shared.builtins || []).find((b) => b.stage === k.stage && b.name === k.name);
    const sel = h("select", { "data-testid": "rollback-version" },
      lower.map((v) => h("option", { value: v }, v === builtin?.version ? `${v} (built-in)` : v)));
    const version = await modal(`Roll back ${k.name}`,
      h("div", null,
        h("p", null, `The robot runs ${k.name}@${k.version} (${k.state}). Run this earlier version instead:`),
        h("p", { class: "hint" }, "This overrides the robot's anti-rollback floor for this version; the audit log records it."),
        h("label", { class: "field" }, h("span", { class: "field-label" }, "Version"), sel)),
      [{ label: "Cancel", value: () => null },
        { label: "Roll back", primary: true, attrs: { "data-testid": "rollback-confirm" }, value: () => sel.value }]);
    if (!version) return;
    this.error.hidden = true;
    try {
      await sendDraft(this.ack, this.shared.robotId, rollbackDraft(k.stage, k.name, version), `Roll back ${k.name} to ${version}`);
      this.shared.refresh?.();
    } catch (e) {
      this.showError(e.detail || String(e));
    }
  }
}
