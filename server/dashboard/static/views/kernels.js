// Kernels page: upload a kernel version, the uploaded versions (install on a robot, delete), the
// built-in kernels, and the signing keys.

import { h, mount, when, badge, modal } from "../dom.js";
import { api, builtinKernels } from "../api.js";
import { STAGES, paramList } from "../schema.js";
import { AckPanel, sendDraft, installDraft } from "./ack.js";

// shared/protocol/patterns.py VERSION_PATTERN (tests/server/test_dashboard_files.py keeps the two equal).
const VERSION_PATTERN = "(0|[1-9][0-9]{0,5})\\.(0|[1-9][0-9]{0,5})\\.(0|[1-9][0-9]{0,5})";
const VERSION_RE = new RegExp(`^${VERSION_PATTERN}$`);

export function renderKernels(root, ctx) {
  const ack = new AckPanel(ctx);
  const tableBox = h("div", null, h("p", { class: "muted" }, "Loading…"));
  const builtinBox = h("div", null, h("p", { class: "muted" }, "Loading…"));
  const keysBox = h("div", null, h("p", { class: "muted" }, "Loading…"));
  const pageError = h("div", { class: "error", "data-testid": "kernels-error", hidden: true });

  const loadKernels = async () => {
    try {
      const list = await api.kernels({ deleted: true });
      if (ctx.alive) renderTable(tableBox, list, { ack, pageError, reload: loadKernels });
    } catch (e) {
      mount(tableBox, h("div", { class: "error" }, `Could not list kernels: ${e.detail}`));
    }
  };
  const loadKeys = async () => {
    try {
      const keys = await api.keys();
      if (ctx.alive) renderKeys(keysBox, keys, loadKeys);
    } catch (e) {
      mount(keysBox, h("div", { class: "error" }, `Could not list keys: ${e.detail}`));
    }
  };

  mount(root, h("div", { class: "page" },
    h("div", { class: "page-head" }, h("h2", null, "Kernels")),
    h("div", { class: "grid2" },
      h("div", { class: "card" }, h("h3", null, "Upload a kernel version"), uploadForm(loadKernels)),
      h("div", { class: "card" }, h("h3", null, "Signing keys"), keysBox, keyForm(loadKeys))),
    h("div", { class: "card flush" }, h("h3", { class: "pad" }, "Uploaded versions"), pageError, ack.el, tableBox),
    h("div", { class: "card flush" }, h("h3", { class: "pad" }, "Built-in kernels ", h("span", { class: "muted small" }, "(every robot has them; read-only)")), builtinBox)));

  loadKernels();
  loadKeys();
  builtinKernels().then((b) => { if (ctx.alive) renderBuiltins(builtinBox, b); })
    .catch((e) => mount(builtinBox, h("div", { class: "error" }, `Could not list built-in kernels: ${e.detail}`)));
}

function uploadForm(reload) {
  const file = h("input", { type: "file", name: "file", accept: ".py,text/x-python", required: true, "data-testid": "kernel-upload-file" });
  const name = h("input", { type: "text", name: "name", required: true, placeholder: "e.g. dbscan-fast", "data-testid": "kernel-upload-name" });
  const stage = h("select", { name: "stage", "data-testid": "kernel-upload-stage" }, STAGES.map((s) => h("option", { value: s }, s)));
  const version = h("input", { type: "text", name: "version", required: true, placeholder: "MAJOR.MINOR.PATCH, e.g. 1.0.1",
    pattern: VERSION_PATTERN, "data-testid": "kernel-upload-version" });
  const sig = h("input", { type: "text", name: "signature", placeholder: "base64 Ed25519 signature", "data-testid": "kernel-upload-signature",
    spellcheck: "false", autocomplete: "off" });
  const sigFile = h("input", { type: "file", accept: ".sig,.txt", "data-testid": "kernel-upload-sigfile", onchange: async () => {
    const f = sigFile.files[0];
    if (f) sig.value = (await f.text()).trim();
  } });
  const params = h("textarea", { rows: 3, spellcheck: "false", "data-testid": "kernel-upload-parameters",
    placeholder: "optional: the JSON Schema `linemap kernels --describe module.py` prints" });
  const paramsFile = h("input", { type: "file", accept: ".json,application/json", "data-testid": "kernel-upload-parameters-file",
    onchange: async () => { const f = paramsFile.files[0]; if (f) params.value = (await f.text()).trim(); } });
  const err = h("div", { class: "error", "data-testid": "kernel-upload-error", role: "alert", hidden: true });
  const ok = h("div", { class: "ok", "data-testid": "kernel-upload-ok", hidden: true });
  const submit = h("button", { type: "submit", class: "primary", "data-testid": "kernel-upload-submit" }, "Upload");
  file.addEventListener("change", async () => {
    const f = file.files[0];
    if (!f) return;
    const guess = guessKernel(f.name, await f.text().catch(() => ""));
    if (guess.name && !name.value) name.value = guess.name;
    if (guess.version && !version.value) version.value = guess.version;
    if (guess.stage) stage.value = guess.stage;
  });
  const form = h("form", { class: "stack", onsubmit: async (e) => {
    e.preventDefault();
    err.hidden = true;
    ok.hidden = true;
    if (!file.files[0]) { err.textContent = "Choose the kernel's .py file."; err.hidden = false; return; }
    if (!VERSION_RE.test(version.value.trim())) {
      err.textContent = `Version '${version.value}' must be MAJOR.MINOR.PATCH without leading zeros (e.g. 1.0.1).`;
      err.hidden = false;
      return;
    }
    const fd = new FormData();
    fd.append("file", file.files[0]);
    fd.append("name", name.value.trim());
    fd.append("stage", stage.value);
    fd.append("version", version.value.trim());
    fd.append("signature", sig.value.trim());
    if (params.value.trim()) fd.append("parameters", params.value.trim());
    submit.disabled = true;
    try {
      const k = await api.uploadKernel(fd);
      ok.textContent = `Uploaded ${k.name}@${k.version} (${k.stage}), sha256 ${k.sha256.slice(0, 12)}…, signed by ${k.key_id}.`;
      ok.hidden = false;
      file.value = "";
      sigFile.value = "";
      sig.value = "";
      params.value = "";
      paramsFile.value = "";
      version.value = "";
      reload();
    } catch (ex) {
      err.textContent = ex.detail;
      err.hidden = false;
    } finally {
      submit.disabled = false;
    }
  } },
  h("label", { class: "field" }, h("span", { class: "field-label" }, "Module (.py)"), file),
  h("div", { class: "row2" },
    h("label", { class: "field" }, h("span", { class: "field-label" }, "Name"), name),
    h("label", { class: "field" }, h("span", { class: "field-label" }, "Version"), version)),
  h("label", { class: "field" }, h("span", { class: "field-label" }, "Stage"), stage),
  h("label", { class: "field" }, h("span", { class: "field-label" }, "Signature (base64)"), sig),
  h("label", { class: "field" }, h("span", { class: "field-label" }, "…or the .sig file"), sigFile),
  h("label", { class: "field", title: "With it, messages choosing this kernel are checked before they are queued, and the Tune form shows its parameters as fields" },
    h("span", { class: "field-label" }, "Parameter schema (JSON, optional)"), params),
  h("label", { class: "field" }, h("span", { class: "field-label" }, "…or its .json file"), paramsFile),
  h("div", { class: "button-row" }, submit),
  err, ok,
  h("p", { class: "hint" }, "Sign with ", h("code", null, "linemap keys sign --key linemap-signing.pem module.py"),
    " (prints the sha256 and the signature); make a key pair with ", h("code", null, "linemap keys generate"),
    " and add its public key under Signing keys; ", h("code", null, "linemap kernels --describe module.py"),
    " prints its parameter schema."));
  return form;
}

const PACKAGE_STAGE = {
  segmentation: "segmentation", noise: "noise-removal", clustering: "clustering", lines: "straight-line", matching: "scan-matching",
};

/** Name, version and stage of a kernel module, guessed from its class attributes, its base class's
 * package (shared.kernels.noise -> noise-removal) and its file name (dbscan_1_1_0.py -> dbscan, 1.1.0). */
export function guessKernel(fileName, source) {
  const attr = (key) => source.match(new RegExp(`^\\s+${key}\\s*(?::[^=]+)?=\\s*["']([^"']+)["']`, "m"))?.[1];
  const base = fileName.replace(/\.py$/i, "");
  const fromFile = base.match(/^(.*?)[-_]v?(\d+)[._](\d+)[._](\d+)$/);
  const pkg = source.match(/from\s+shared\.kernels\.(\w+)/)?.[1];
  const stageAttr = attr("stage");
  const moduleName = source.match(/from\s+shared\.kernels\.\w+\.(\w+)\s+import/)?.[1];
  return {
    name: attr("name") || (fromFile ? fromFile[1] : moduleName || base).replaceAll("_", "-").toLowerCase(),
    version: attr("version") || (fromFile ? `${fromFile[2]}.${fromFile[3]}.${fromFile[4]}` : undefined),
    stage: stageAttr && STAGES.includes(stageAttr) ? stageAttr : PACKAGE_STAGE[pkg],
  };
}

function renderTable(box, list, { ack, pageError, reload }) {
  if (!list.length) {
    mount(box, h("p", { class: "muted pad" }, "No kernels uploaded yet."));
    return;
  }
  const sorted = [...list].sort((a, b) => a.name.localeCompare(b.name) || b.version.localeCompare(a.version, undefined, { numeric: true }));
  mount(box, h("table", { class: "table" },
    h("thead", null, h("tr", null, ["Name", "Version", "Stage", "sha256", "Size", "Signed by", "Uploaded", ""].map((t) =>
      h("th", { class: t === "Size" ? "num" : null }, t)))),
    h("tbody", null, sorted.map((k) => h("tr", { "data-testid": "kernel-row", "data-name": k.name, "data-version": k.version,
      "data-stage": k.stage, class: k.deleted ? "deleted" : null },
    h("td", null, h("b", null, k.name)),
    h("td", null, k.version),
    h("td", null, k.stage),
    h("td", { class: "mono", title: k.sha256 }, k.sha256.slice(0, 12) + "…"),
    h("td", { class: "num" }, fmtSize(k.size_bytes)),
    h("td", { class: "mono", title: k.signature }, k.key_id),
    h("td", { class: "small" }, when(k.uploaded_at), h("span", { class: "muted" }, ` by ${k.uploaded_by}`)),
    h("td", { class: "actions" },
      k.deleted ? badge("deleted", { "data-testid": "kernel-deleted" }) : [
        h("button", { type: "button", class: "small primary", "data-testid": "kernel-install",
          onclick: () => installOnRobot(k, ack, pageError) }, "Install on robot…"),
        h("button", { type: "button", class: "small danger", "data-testid": "kernel-delete",
          onclick: () => deleteKernel(k, pageError, reload) }, "Delete"),
      ]))))));
}

async function installOnRobot(k, ack, pageError) {
  pageError.hidden = true;
  let robots;
  try {
    robots = await api.robots();
  } catch (e) {
    pageError.textContent = `Could not list robots: ${e.detail}`;
    pageError.hidden = false;
    return;
  }
  if (!robots.length) {
    pageError.textContent = "No robots registered yet.";
    pageError.hidden = false;
    return;
  }
  const sel = h("select", { "data-testid": "kernel-install-robot" },
    robots.map((r) => h("option", { value: r.id }, `${r.name} (#${r.id}, ${r.online ? "online" : "offline"})`)));
  const id = await modal(`Install ${k.name}@${k.version}`,
    h("div", null,
      h("p", null, `The robot downloads ${k.name}@${k.version}, checks its signature and runs it for ${k.stage}.`),
      h("label", { class: "field" }, h("span", { class: "field-label" }, "Robot"), sel)),
    [{ label: "Cancel", value: () => null },
      { label: "Install", primary: true, attrs: { "data-testid": "kernel-install-confirm" }, value: () => sel.value }]);
  if (!id) return;
  const robot = robots.find((r) => String(r.id) === String(id));
  try {
    const builtins = await builtinKernels().catch(() => []);
    await sendDraft(ack, id, installDraft(k, robot?.config, builtins), `Install ${k.name}@${k.version} on ${robot?.name ?? id}`);
  } catch (e) {
    pageError.textContent = e.detail || String(e);
    pageError.hidden = false;
  }
}

async function deleteKernel(k, pageError, reload) {
  const yes = await modal(`Delete ${k.name}@${k.version}?`,
    h("p", null, "Robots can no longer download this version. Robots that already have it keep it."),
    [{ label: "Cancel", value: () => false },
      { label: "Delete", primary: true, attrs: { "data-testid": "kernel-delete-confirm" }, value: () => true }]);
  if (!yes) return;
  try {
    await api.deleteKernel(k.name, k.version);
    reload();
  } catch (e) {
    pageError.textContent = e.detail;
    pageError.hidden = false;
  }
}

function renderBuiltins(box, list) {
  mount(box, h("table", { class: "table" },
    h("thead", null, h("tr", null, h("th", null, "Stage"), h("th", null, "Name"), h("th", null, "Version"), h("th", null, "Summary"), h("th", null, "Parameters"))),
    h("tbody", null, list.map((k) => h("tr", { "data-testid": "builtin-row", "data-name": k.name, "data-stage": k.stage },
      h("td", { class: "muted" }, k.stage), h("td", null, h("b", null, k.name)), h("td", null, k.version),
      h("td", { class: "small" }, k.summary || ""),
      h("td", { class: "small mono" }, paramList(k).map(([p, prop]) =>
        h("span", { class: "param-chip", title: prop.description || "" }, p, prop.unit ? ` [${prop.unit}]` : ""))))))));
}

function renderKeys(box, keys, reload) {
  if (!keys.length) {
    mount(box, h("p", { class: "muted" }, "No signing keys yet: uploads need a signature by a registered key."));
    return;
  }
  mount(box, h("table", { class: "table" },
    h("thead", null, h("tr", null, h("th", null, "Key id"), h("th", null, "Name"), h("th", null, "Added"), h("th"))),
    h("tbody", null, keys.map((k) => h("tr", { "data-testid": "key-row", "data-key-id": k.key_id },
      h("td", { class: "mono", title: k.public_key }, k.key_id), h("td", null, k.name),
      h("td", { class: "small" }, when(k.created_at)),
      h("td", { class: "actions" }, k.revoked ? badge("revoked") : h("button", { type: "button", class: "small danger", "data-testid": "key-revoke",
        onclick: async () => {
          const yes = await modal(`Revoke key ${k.name}?`, h("p", null, "Kernels signed only by this key can no longer be uploaded."),
            [{ label: "Cancel", value: () => false }, { label: "Revoke", primary: true, value: () => true }]);
          if (!yes) return;
          try { await api.revokeKey(k.key_id); } catch (e) { alert(e.detail); }
          reload();
        } }, "Revoke")))))));
}

function keyForm(reload) {
  const name = h("input", { type: "text", required: true, placeholder: "key name", "data-testid": "key-name" });
  const pub = h("input", { type: "text", required: true, placeholder: "public key (base64)", "data-testid": "key-public", spellcheck: "false" });
  const err = h("div", { class: "error", "data-testid": "key-error", hidden: true });
  return h("form", { class: "stack", onsubmit: async (e) => {
    e.preventDefault();
    err.hidden = true;
    try {
      await api.addKey(name.value.trim(), pub.value.trim());
      name.value = "";
      pub.value = "";
      reload();
    } catch (ex) {
      err.textContent = ex.detail;
      err.hidden = false;
    }
  } },
  h("h4", null, "Add a public key"),
  h("div", { class: "row2" }, name, pub),
  h("div", { class: "button-row" }, h("button", { type: "submit", "data-testid": "key-submit" }, "Add key")),
  err,
  h("p", { class: "hint" }, h("code", null, "linemap keys generate --out linemap-signing.pem"),
    " writes a private key and prints its public key to paste here; ", h("code", null, "linemap keys sign FILE"),
    " signs a kernel module with it."));
}

function fmtSize(n) {
  if (n == null) return "—";
  return n < 1024 ? `${n} B` : `${(n / 1024).toFixed(1)} KiB`;
}
