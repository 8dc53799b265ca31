// Tiny DOM helpers: h() builds elements without ever parsing HTML, so server text is always escaped.

/**
 * h("div", {class: "x", "data-testid": "y", onclick: fn}, "text", child, [more children])
 * Attributes: class, style (string or object), on<event> (function), dataset (object), value/checked/
 * disabled/selected/hidden (properties), anything else via setAttribute. null/undefined/false attrs are skipped.
 */
export function h(tag, attrs, ...children) {
  const el = document.createElement(tag);
  if (attrs) {
    for (const [k, v] of Object.entries(attrs)) {
      if (v === null || v === undefined || v === false) continue;
      if (k === "class") el.className = v;
      else if (k === "style" && typeof v === "object") Object.assign(el.style, v);
      else if (k.startsWith("on") && typeof v === "function") el.addEventListener(k.slice(2), v);
      else if (k === "dataset") Object.assign(el.dataset, v);
      else if (["value", "checked", "disabled", "selected", "hidden", "multiple", "open"].includes(k)) el[k] = v;
      else el.setAttribute(k, v === true ? "" : String(v));
    }
  }
  append(el, children);
  return el;
}

function append(el, children) {
  for (const c of children) {
    if (c === null || c === undefined || c === false) continue;
    if (Array.isArray(c)) append(el, c);
    else if (c instanceof Node) el.appendChild(c);
    else el.appendChild(document.createTextNode(String(c)));
  }
}

/** Replace all children of el. */
export function mount(el, ...children) {
  el.replaceChildren();
  append(el, children);
  return el;
}

/** "3 s ago", "5 min ago", "2 h ago", "4 d ago"; "never" for null. */
export function ago(iso, now = Date.now()) {
  if (!iso) return "never";
  const t = Date.parse(iso);
  if (Number.isNaN(t)) return String(iso);
  const s = Math.max(0, Math.round((now - t) / 1000));
  if (s < 60) return `${s} s ago`;
  if (s < 3600) return `${Math.floor(s / 60)} min ago`;
  if (s < 86400) return `${Math.floor(s / 3600)} h ago`;
  return `${Math.floor(s / 86400)} d ago`;
}

/** Local date-time "2024-05-01 12:03:04". */
export function when(iso) {
  if (!iso) return "—";
  const d = new Date(iso);
  if (Number.isNaN(d.getTime())) return String(iso);
  const p = (n) => String(n).padStart(2, "0");
  return `${d.getFullYear()}-${p(d.getMonth() + 1)}-${p(d.getDate())} ${p(d.getHours())}:${p(d.getMinutes())}:${p(d.getSeconds())}`;
}

/** Text cut to n characters with an ellipsis; the full text goes into title. */
export function trunc(text, n = 60, attrs = {}) {
  const s = text == null ? "" : String(text);
  const short = s.length > n ? s.slice(0, n - 1) + "…" : s;
  return h("span", { ...attrs, title: s.length > n ? s : null }, short || "—");
}

/** Status badge: online/offline, queued/applied/rejected/rolled-back, kernel states. */
export function badge(status, attrs = {}) {
  const s = String(status ?? "unknown");
  return h("span", { ...attrs, class: `badge badge-${badgeTone(s)}`, "data-status": s }, s);
}

export function badgeTone(s) {
  if (["online", "applied", "active", "verified", "ok"].includes(s)) return "green";
  if (["rejected", "rolled-back", "failed", "error", "deleted", "revoked"].includes(s)) return "red";
  if (["queued", "pending", "downloading", "installing"].includes(s)) return "amber";
  return "grey";
}

/** Number with fixed decimals, "—" for null. */
export function num(v, digits = 1) {
  return v === null || v === undefined || Number.isNaN(Number(v)) ? "—" : Number(v).toFixed(digits);
}

/** Copy text to the clipboard (falls back to selecting a textarea). */
export async function copyText(text) {
  try {
    await navigator.clipboard.writeText(text);
    return true;
  } catch {
    const ta = h("textarea", { style: { position: "fixed", left: "-1000px" } }, text);
    document.body.appendChild(ta);
    ta.select();
    let ok = false;
    try { ok = document.execCommand("copy"); } catch { ok = false; }
    ta.remove();
    return ok;
  }
}

/** A modal dialog (native <dialog>); resolves with the returned value or null when closed. */
export function modal(title, body, buttons) {
  return new Promise((resolve) => {
    const dlg = h("dialog", { class: "modal" });
    const close = (v) => { dlg.close(); dlg.remove(); resolve(v); };
    dlg.append(
      h("h3", null, title),
      body,
      h("div", { class: "modal-buttons" },
        buttons.map((b) => h("button", { ...b.attrs, class: b.primary ? "primary" : "", type: "button",
          onclick: async () => { const v = b.value ? await b.value() : null; if (v !== undefined) close(v); } }, b.label)),
      ),
    );
    dlg.addEventListener("cancel", () => close(null));
    document.body.appendChild(dlg);
    dlg.showModal();
  });
}
