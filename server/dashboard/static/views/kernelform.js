// One kernel choice in the Tune form: a kernel <select> and inputs generated from the kernel's
// parameter JSON Schema (built-in kernels), or a JSON object field (uploaded kernels have no schema here).

import { h, mount } from "../dom.js";
import { findBuiltin, paramList, propType, rangeHint, checkValue, sameValue, showValue } from "../schema.js";

export const NONE = "none";

/** Options of a stage's kernel select: [{value, label, builtin, name, version, desc}]. */
export function kernelOptions(stage, builtins, uploaded, extraChoice) {
  const opts = builtins.filter((k) => k.stage === stage)
    .map((k) => ({ value: k.name, label: k.name, builtin: true, name: k.name, version: null, desc: k }));
  const up = uploaded.filter((k) => k.stage === stage && !k.deleted)
    .map((k) => ({ value: `${k.name}@${k.version}`, label: `${k.name}@${k.version}`, builtin: false, name: k.name, version: k.version,
      declared: k.parameters ? { parameters: k.parameters } : null }));
  if (extraChoice && !optionFor([...opts, ...up], extraChoice)) {
    up.push({ value: `${extraChoice.name}@${extraChoice.version}`, label: `${extraChoice.name}@${extraChoice.version}`,
      builtin: false, name: extraChoice.name, version: extraChoice.version });
  }
  return [...opts, ...up];
}

/** The option matching a configured choice {name, version}: built-in when the versions agree. */
export function optionFor(options, choice) {
  if (!choice) return undefined;
  return options.find((o) => !o.builtin && o.name === choice.name && o.version === choice.version)
    || options.find((o) => o.builtin && o.name === choice.name && (!choice.version || choice.version === o.desc?.version));
}

export class KernelEditor {
  /**
   * stage; options (kernelOptions); choice: the configured {name, version, params} or null;
   * index: position in the noise-removal chain (null for other stages); allowNone: scan-matching;
   * onTouch(): called on any user edit.
   */
  constructor({ stage, options, choice, index = null, allowNone = false, onTouch }) {
    this.stage = stage;
    this.options = options;
    this.index = index;
    this.onTouch = onTouch;
    this.configured = choice; // what the robot runs here (prefill source)
    this.select = h("select", { class: "kernel-select", onchange: () => { this.renderParams(); this.onTouch(); } },
      allowNone ? h("option", { value: NONE }, "none (no scan matching)") : null,
      groups(options));
    const opt = optionFor(options, choice);
    this.select.value = opt ? opt.value : (allowNone && !choice ? NONE : options[0]?.value ?? "");
    this.summary = h("div", { class: "kernel-summary muted small" });
    this.params = h("div", { class: "params" });
    this.el = h("div", { class: "kernel-editor" }, this.select, this.summary, this.params);
    this.setIndex(index);
    this.renderParams();
  }

  builtinNamed(name) { return this.options.find((x) => x.builtin && x.name === name)?.desc; }

  get option() { return this.options.find((o) => o.value === this.select.value) || null; }

  idPart() { return this.index === null ? this.stage : `${this.stage}-${this.index}`; }

  setIndex(index) {
    this.index = index;
    this.select.dataset.testid = `tune-kernel-${this.idPart()}`;
    for (const f of this.fields || []) f.input.dataset.testid = this.fieldTestId(f.param);
  }

  fieldTestId(param) {
    const o = this.option;
    return this.index === null ? `param-${this.stage}-${o ? o.name : "none"}-${param}` : `param-${this.stage}-${this.index}-${param}`;
  }

  renderParams() {
    const o = this.option;
    this.fields = [];
    if (!o) {
      mount(this.summary);
      mount(this.params, h("p", { class: "muted small" }, "No kernel: this stage is skipped."));
      return;
    }
    // An uploaded version: the parameter schema declared at its upload, else the built-in's of the same name.
    const desc = o.builtin ? o.desc : o.declared || this.builtinNamed(o.name);
    mount(this.summary, o.builtin ? o.desc?.summary || ""
      : o.declared ? `Uploaded version ${o.version}; parameters as declared at its upload.`
        : desc ? `Uploaded version ${o.version}; parameters as the built-in ${o.name}.`
          : "Uploaded kernel without a declared parameter schema: give its parameters as a JSON object.");
    const same = this.configured && this.configured.name === o.name &&
      (o.builtin ? !this.configured.version || this.configured.version === o.desc?.version : this.configured.version === o.version);
    const given = same ? this.configured.params || {} : {};
    if (!desc) {
      const input = h("textarea", { class: "json-params", rows: 3, spellcheck: "false", placeholder: "{\"param\": value}" },
        Object.keys(given).length ? JSON.stringify(given) : "");
      this.fields.push({ param: "json", input, json: true });
      input.dataset.testid = this.fieldTestId("json");
      input.addEventListener("input", () => { input.dataset.edited = "1"; this.onTouch(); });
      mount(this.params, h("label", { class: "field wide" }, h("span", { class: "field-label" }, "Parameters (JSON object)"), input));
      return;
    }
    const rows = paramList(desc).map(([p, prop]) => this.field(p, prop, given));
    mount(this.params, rows.length ? rows : h("p", { class: "muted small" }, "This kernel has no parameters."));
  }

  field(p, prop, given) {
    const type = propType(prop);
    const explicit = Object.hasOwn(given, p);
    const value = explicit ? given[p] : prop.default;
    const label = prop.title || p;
    const tip = [prop.description, prop.paper ? `Paper: ${prop.paper}` : null, `Parameter: ${p}`].filter(Boolean).join("\n");
    let input;
    if (type === "boolean" || Array.isArray(prop.enum)) {
      const choices = type === "boolean" ? ["true", "false"] : prop.enum.map(String);
      input = h("select", null, choices.map((c) => h("option", { value: c }, c + (String(prop.default) === c ? " (default)" : ""))));
      input.value = value === undefined || value === null ? String(prop.default) : String(value);
    } else {
      input = h("input", { type: "text", inputmode: type === "json" ? "text" : "decimal", autocomplete: "off", spellcheck: "false",
        placeholder: `default ${showValue(prop.default)}`, value: value === undefined || value === null ? "" : fmt(value) });
    }
    input.title = tip;
    input.dataset.param = p;
    if (explicit) input.dataset.explicit = "1";
    const hint = rangeHint(p, prop);
    const err = h("div", { class: "field-error", hidden: true });
    const f = { param: p, prop, input, err, label };
    input.dataset.testid = this.fieldTestId(p);
    const onEdit = () => {
      input.dataset.edited = "1";
      this.check(f);
      this.onTouch();
    };
    input.addEventListener("input", onEdit);
    input.addEventListener("change", onEdit);
    this.fields.push(f);
    return h("label", { class: "field", title: tip },
      h("span", { class: "field-label" }, label, prop.unit ? h("span", { class: "unit" }, ` [${prop.unit}]`) : null),
      input,
      h("span", { class: "field-hint muted" }, hint ? `${hint}` : type, ` · default ${showValue(prop.default)}`),
      err);
  }

  check(f) {
    const r = checkValue(f.param, f.prop, f.input.value, f.param);
    f.err.hidden = !r.error;
    f.err.textContent = r.error || "";
    f.input.setAttribute("aria-invalid", r.error ? "true" : "false");
    return r;
  }

  /** {block} for the draft ("none" for no scan matching) or {error: "stage kernel: message"}. */
  block(builtins) {
    const o = this.option;
    if (!o) return { block: NONE };
    const where = `${this.stage}${this.index === null ? "" : ` #${this.index + 1}`} ${o.name}`;
    const params = {};
    for (const f of this.fields) {
      if (f.json) {
        const text = f.input.value.trim();
        if (!text) continue;
        try {
          const v = JSON.parse(text);
          if (!v || typeof v !== "object" || Array.isArray(v)) throw new Error("not an object");
          Object.assign(params, v);
        } catch {
          return { error: `${where}: parameters must be a JSON object like {"epsilon_m": 0.04}` };
        }
        continue;
      }
      const r = this.check(f);
      if (r.error) { f.input.focus(); return { error: `${where}: ${r.error}` }; }
      if (r.value === undefined) continue;
      // Send what the robot had explicitly, what the operator typed, and anything not at its default.
      if (f.input.dataset.explicit || f.input.dataset.edited || !sameValue(r.value, f.prop.default)) params[f.param] = r.value;
    }
    const builtin = o.builtin && findBuiltin(builtins, this.stage, o.name);
    return { block: { name: o.name, version: builtin ? null : o.version, params } };
  }
}

function groups(options) {
  const b = options.filter((o) => o.builtin);
  const u = options.filter((o) => !o.builtin);
  const opt = (o) => h("option", { value: o.value }, o.label);
  if (!u.length) return b.map(opt);
  return [h("optgroup", { label: "Built-in" }, b.map(opt)), h("optgroup", { label: "Uploaded" }, u.map(opt))];
}

function fmt(v) {
  if (typeof v === "number") return String(v);
  if (typeof v === "object") return JSON.stringify(v);
  return String(v);
}
