// Tune tab: a form generated from the kernels' parameter schemas, pre-filled from the robot's
// configuration; Preview XML / Send (POST /control/xml, then the XML to the robot) with the ack panel;
// and a Raw XML area for messages like the paper's Listing 1.

import { h, mount } from "../dom.js";
import { api, uploadedKernels } from "../api.js";
import { STAGES, MODES, stageKey, configBlocks, isChain, isOptional } from "../schema.js";
import { KernelEditor, kernelOptions, NONE } from "./kernelform.js";
import { AckPanel } from "./ack.js";

// The paper's Listing 1 (as in tests/shared/control/fixtures/listing1.xml).
export const LISTING_1 = `<?xml version="1.0"?>
<xml>
  <message>
    <mode>
      online
    </mode>
    <noise-removal>
      <dbscan>
        <minpts>
          15
        </minpts>
        <epsilon>
          5
        </epsilon>
      </dbscan>
      <erosion>
        <kernel-name>
          PLUSx4
        </kernel-name>
      </erosion>
    </noise-removal>
    <clustering>
      <kmeans>
        <cluster-no>
          2
        </cluster-no>
      </kmeans>
    </clustering>
    <straight-line-method>
      Hough
    </straight-line-method>
  </message>
</xml>
`;

export class TuneTab {
  constructor(shared) {
    this.shared = shared;
    this.ack = new AckPanel(shared.ctx);
    this.formBox = h("div", { class: "tune-form" }, h("p", { class: "muted" }, "Loading kernels…"));
    this.formError = h("div", { class: "error", "data-testid": "form-error", role: "alert", hidden: true });
    this.xmlPreview = h("pre", { class: "xml", "data-testid": "xml-preview", hidden: true });
    this.previewBtn = h("button", { type: "button", "data-testid": "tune-preview", onclick: () => this.preview() }, "Preview XML");
    this.sendBtn = h("button", { type: "button", class: "primary", "data-testid": "tune-send", onclick: () => this.send() }, "Send");
    this.resetBtn = h("button", { type: "button", "data-testid": "tune-reset", title: "Back to the configuration in force",
      onclick: () => this.build(true) }, "Reset");
    this.touchedNote = h("span", { class: "muted small" });
    this.raw = h("textarea", { class: "raw-xml", "data-testid": "raw-xml", rows: 10, spellcheck: "false",
      placeholder: "<?xml version=\"1.0\"?>\n<xml><message>…</message></xml>" });
    this.el = h("div", { class: "tab-tune" },
      this.formBox,
      this.xmlPreview,
      h("div", { class: "tune-footer" },
        h("div", { class: "button-row" }, this.previewBtn, this.sendBtn, this.resetBtn, this.touchedNote),
        this.formError, this.ack.el),
      h("section", { class: "raw-section" },
        h("h4", null, "Raw XML"),
        h("p", { class: "muted small" }, "Paste a control message (e.g. the paper's Listing 1) and send it as it is."),
        this.raw,
        h("div", { class: "button-row" },
          h("button", { type: "button", "data-testid": "raw-listing1", onclick: () => { this.raw.value = LISTING_1; } }, "Paste Listing 1"),
          h("button", { type: "button", class: "primary", "data-testid": "raw-send", onclick: () => this.sendRaw() }, "Send raw XML"))));
    this.built = false;
    this.update(shared.robot);
  }

  async update(robot) {
    if (!robot || !this.shared.builtins || this.loading) return;
    const cfgJson = JSON.stringify(robot.config);
    if (this.built && (this.anyTouched() || cfgJson === this.prefilledFrom)) return;
    this.loading = true;
    try {
      this.uploaded = await uploadedKernels(this.shared);
    } catch (e) {
      this.uploaded = [];
      this.showError(`Could not list uploaded kernels: ${e.detail}`);
    } finally {
      this.loading = false;
    }
    if (this.built && this.anyTouched()) return;
    this.build(false);
  }

  build(reset) {
    const robot = this.shared.robot;
    if (!robot) return;
    const builtins = this.shared.builtins || [];
    const uploaded = this.uploaded || [];
    const cfg = robot.config;
    this.prefilledFrom = JSON.stringify(cfg);
    this.touched = new Set();
    this.updateTouched();
    if (reset) this.hideError();
    const touch = (what) => () => { this.touched.add(what); this.updateTouched(); };

    this.mode = h("select", { "data-testid": "tune-mode", onchange: touch("mode") },
      MODES.map((m) => h("option", { value: m }, m)));
    this.mode.value = cfg?.mode || robot.mode || "online";
    this.nsmax = h("input", { type: "number", min: 1, step: 1, "data-testid": "tune-nsmax", oninput: touch("n_smax"),
      value: cfg?.n_smax ?? "", placeholder: "N_smax" });

    this.editors = {};
    const fieldsets = STAGES.map((stage) => {
      const blocks = configBlocks(cfg, stage);
      if (isChain(stage)) return this.chainFieldset(stage, blocks, builtins, uploaded, touch(stage));
      const options = kernelOptions(stage, builtins, uploaded, blocks[0]);
      const ed = new KernelEditor({ stage, options, choice: blocks[0] || null, allowNone: isOptional(stage),
        onTouch: touch(stage) });
      this.editors[stage] = ed;
      return h("fieldset", { class: "stage", "data-stage": stage }, h("legend", null, stage), ed.el);
    });
    mount(this.formBox,
      cfg ? null : h("p", { class: "info small" }, "The robot has not reported its configuration yet: fields show the kernel defaults."),
      h("div", { class: "row2" },
        h("label", { class: "field" }, h("span", { class: "field-label" }, "Mode"), this.mode),
        h("label", { class: "field" }, h("span", { class: "field-label" }, "N", h("sub", null, "smax")), this.nsmax,
          h("span", { class: "field-hint muted" }, "scans per batch, integer ≥ 1"))),
      fieldsets,
      this.loopFieldset(cfg?.loop_closure || null, touch("loop-closure")));
    this.built = true;
  }

  // Loop closure: on/off, search radius (m), minimum inlier share; the robot's other loop-closure settings
  // are sent as they are (the element states loop closure whole).
  loopFieldset(lc, onTouch) {
    this.loopSettings = lc;
    this.loopOn = h("input", { type: "checkbox", "data-testid": "tune-loop-enabled", onchange: onTouch });
    this.loopOn.checked = !!lc;
    this.loopRadius = h("input", { type: "number", min: 0, max: 100, step: "any", "data-testid": "tune-loop-radius",
      oninput: onTouch, value: lc ? lc.search_radius_m : 4, placeholder: "m" });
    this.loopInliers = h("input", { type: "number", min: 0, max: 1, step: "any", "data-testid": "tune-loop-inliers",
      oninput: onTouch, value: lc ? lc.min_inlier_share : 0.5 });
    return h("fieldset", { class: "stage", "data-stage": "loop-closure" },
      h("legend", null, "loop closure ", h("span", { class: "muted small" }, "(pose graph: walls redrawn when a loop closes)")),
      h("label", { class: "field" }, this.loopOn, h("span", null, " on")),
      h("div", { class: "row2" },
        h("label", { class: "field" }, h("span", { class: "field-label" }, "Search radius"), this.loopRadius,
          h("span", { class: "field-hint muted" }, "m, earlier places this near are tried")),
        h("label", { class: "field" }, h("span", { class: "field-label" }, "Minimum inlier share"), this.loopInliers,
          h("span", { class: "field-hint muted" }, "0 to 1, of the scan's returns"))));
  }

  loopDraft() {
    if (!this.loopOn.checked) return { block: { enabled: false } };
    const radius = Number(this.loopRadius.value);
    const share = Number(this.loopInliers.value);
    if (this.loopRadius.value === "" || !Number.isFinite(radius)) return { error: `loop closure: search radius '${this.loopRadius.value}' must be a number of metres` };
    if (this.loopInliers.value === "" || !Number.isFinite(share)) return { error: `loop closure: minimum inlier share '${this.loopInliers.value}' must be a number from 0 to 1` };
    const params = {};
    for (const [k, v] of Object.entries(this.loopSettings || {})) {
      if (!["enabled", "search_radius_m", "min_inlier_share"].includes(k)) params[k] = v;
    }
    return { block: { enabled: true, search_radius_m: radius, min_inlier_share: share, params } };
  }

  chainFieldset(stage, blocks, builtins, uploaded, onTouch) {
    const list = h("div", { class: "chain" });
    const chain = [];
    this.chain = chain;
    const make = (choice) => new KernelEditor({ stage, options: kernelOptions(stage, builtins, uploaded, choice),
      choice, index: chain.length, onTouch });
    const redraw = () => {
      chain.forEach((ed, i) => ed.setIndex(i));
      mount(list, chain.length ? chain.map((ed, i) => h("div", { class: "chain-item", "data-index": i },
        h("div", { class: "chain-head" }, h("b", null, `${i + 1}.`),
          h("span", { class: "spacer" }),
          h("button", { type: "button", class: "small", title: "Move up", disabled: i === 0, "data-testid": `noise-up-${i}`,
            onclick: () => { [chain[i - 1], chain[i]] = [chain[i], chain[i - 1]]; onTouch(); redraw(); } }, "↑"),
          h("button", { type: "button", class: "small", title: "Move down", disabled: i === chain.length - 1, "data-testid": `noise-down-${i}`,
            onclick: () => { [chain[i + 1], chain[i]] = [chain[i], chain[i + 1]]; onTouch(); redraw(); } }, "↓"),
          h("button", { type: "button", class: "small danger", title: "Remove from the chain", "data-testid": `noise-remove-${i}`,
            onclick: () => { chain.splice(i, 1); onTouch(); redraw(); } }, "✕")),
        ed.el)) : h("p", { class: "muted small" }, "Empty chain: no noise removal."));
    };
    for (const b of blocks) chain.push(make(b));
    redraw();
    return h("fieldset", { class: "stage", "data-stage": stage },
      h("legend", null, `${stage} `, h("span", { class: "muted small" }, "(a chain, applied in order)")),
      list,
      h("button", { type: "button", class: "small", "data-testid": "noise-add",
        onclick: () => { chain.push(make(null)); onTouch(); redraw(); } }, "+ Add kernel"));
  }

  anyTouched() { return this.touched && this.touched.size > 0; }

  updateTouched() {
    const t = [...(this.touched || [])];
    this.touchedNote.textContent = t.length ? `will send: ${t.join(", ")}` : "nothing changed yet";
  }

  /** {draft} from the touched parts of the form, or {error}. */
  draft() {
    const builtins = this.shared.builtins || [];
    const d = {};
    if (this.touched.has("mode")) d.mode = this.mode.value;
    if (this.touched.has("n_smax")) {
      const n = Number(this.nsmax.value);
      if (!Number.isInteger(n) || n < 1) return { error: `N_smax: '${this.nsmax.value}' must be an integer ≥ 1` };
      d.n_smax = n;
    }
    for (const stage of STAGES) {
      if (!this.touched.has(stage)) continue;
      if (isChain(stage)) {
        const list = [];
        for (const ed of this.chain) {
          const r = ed.block(builtins);
          if (r.error) return r;
          list.push(r.block);
        }
        d[stageKey(stage)] = list;
      } else {
        const r = this.editors[stage].block(builtins);
        if (r.error) return r;
        if (r.block === NONE && !isOptional(stage)) return { error: `${stage}: choose a kernel` };
        d[stageKey(stage)] = r.block;
      }
    }
    if (this.touched.has("loop-closure")) {
      const r = this.loopDraft();
      if (r.error) return r;
      d.loop_closure = r.block;
    }
    return { draft: d };
  }

  showError(text) {
    this.formError.textContent = text;
    this.formError.hidden = false;
    this.ack.hide(); // the panel is about an earlier message: under this error it would look like its answer
  }

  hideError() { this.formError.hidden = true; }

  async makeXml() {
    this.hideError();
    if (!this.built) { this.showError("The form is not loaded yet."); return null; }
    const r = this.draft();
    if (r.error) { this.showError(r.error); return null; }
    try {
      const { xml } = await api.controlXml(r.draft);
      this.xmlPreview.textContent = xml;
      this.xmlPreview.hidden = false;
      this.xmlPreview.scrollIntoView({ block: "nearest" });
      return { xml, draft: r.draft };
    } catch (e) {
      this.showError(e.detail);
      return null;
    }
  }

  async preview() {
    this.previewBtn.disabled = true;
    try { await this.makeXml(); } finally { this.previewBtn.disabled = false; }
  }

  async send() {
    if (!this.anyTouched()) { this.showError("Nothing to send: change a field first."); return; }
    this.sendBtn.disabled = true;
    try {
      const made = await this.makeXml();
      if (!made) return;
      const msg = await this.ack.send(this.shared.robotId, made.xml, "Tuning");
      if (msg && msg.status === "applied") {
        this.touched.clear(); // the form follows the robot's next reported configuration
        this.updateTouched();
        this.shared.refresh?.();
      }
    } catch (e) {
      this.showError(e.detail || String(e));
    } finally {
      this.sendBtn.disabled = false;
    }
  }

  async sendRaw() {
    this.hideError();
    this.xmlPreview.hidden = true; // the form's preview is not what is sent here
    const xml = this.raw.value;
    if (!xml.trim()) { this.showError("Raw XML: paste a message first."); return; }
    try {
      const msg = await this.ack.send(this.shared.robotId, xml, "Raw XML");
      if (msg && msg.status === "applied") this.shared.refresh?.();
    } catch (e) {
      this.showError(`Raw XML: ${e.detail || String(e)}`);
    }
  }
}
