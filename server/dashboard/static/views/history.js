// History page: the audit log (newest first, "Older" paging) and the acknowledgements of all robots.

import { h, mount, when, badge, trunc } from "../dom.js";
import { api } from "../api.js";

const PAGE = 100;

export function renderHistory(root, ctx) {
  const auditBody = h("tbody");
  const auditStatus = h("div", { class: "muted small" });
  const olderBtn = h("button", { type: "button", "data-testid": "audit-older", hidden: true, onclick: () => loadAudit(true) }, "Older");
  const acksBody = h("tbody");
  const acksStatus = h("div", { class: "muted small" });
  let audit = [];

  const loadAudit = async (older) => {
    try {
      const before = older && audit.length ? Math.min(...audit.map((a) => a.id)) : undefined;
      const page = await api.audit(PAGE, before);
      if (!ctx.alive) return;
      if (older) audit = audit.concat(page);
      else {
        // Refresh: newest page merged with anything older already loaded.
        const seen = new Set(page.map((a) => a.id));
        audit = page.concat(audit.filter((a) => !seen.has(a.id) && a.id < Math.min(...page.map((p) => p.id))));
      }
      audit.sort((a, b) => b.id - a.id);
      if (older || audit.length === page.length) olderBtn.hidden = page.length < PAGE;
      auditStatus.textContent = `${audit.length} entr${audit.length === 1 ? "y" : "ies"} shown`;
      mount(auditBody, audit.length ? audit.map(auditRow) : h("tr", null, h("td", { colspan: 5, class: "empty" }, "Nothing yet.")));
    } catch (e) {
      auditStatus.textContent = `Could not load the audit log: ${e.detail}`;
    }
  };

  const loadAcks = async () => {
    try {
      const robots = await api.robots();
      const lists = await Promise.all(robots.map(async (r) => {
        const res = await api.messages(r.id, Math.max(0, (r.last_seq || 0) - PAGE), PAGE);
        return res.messages.map((m) => ({ ...m, robot: r }));
      }));
      if (!ctx.alive) return;
      const all = lists.flat().sort((a, b) => (Date.parse(b.acked_at || b.created_at) - Date.parse(a.acked_at || a.created_at)) || b.seq - a.seq);
      acksStatus.textContent = `${all.length} message${all.length === 1 ? "" : "s"} from ${robots.length} robot${robots.length === 1 ? "" : "s"} (last ${PAGE} each)`;
      mount(acksBody, all.length ? all.map(ackRow) : h("tr", null, h("td", { colspan: 5, class: "empty" }, "No control messages yet.")));
    } catch (e) {
      acksStatus.textContent = `Could not load acknowledgements: ${e.detail}`;
    }
  };

  mount(root, h("div", { class: "page" },
    h("div", { class: "page-head" }, h("h2", null, "History")),
    h("div", { class: "grid2 history" },
      h("div", { class: "card flush" },
        h("div", { class: "pad" }, h("h3", null, "Audit log"), auditStatus),
        h("table", { class: "table", "data-testid": "audit-table" },
          h("thead", null, h("tr", null, h("th", null, "When"), h("th", null, "Who"), h("th", null, "Action"), h("th", null, "Target"), h("th", null, "Detail"))),
          auditBody),
        h("div", { class: "pad" }, olderBtn)),
      h("div", { class: "card flush" },
        h("div", { class: "pad" }, h("h3", null, "Acknowledgements"), acksStatus),
        h("table", { class: "table", "data-testid": "acks-table" },
          h("thead", null, h("tr", null, h("th", null, "When"), h("th", null, "Robot"), h("th", { class: "num" }, "Seq"), h("th", null, "Status"), h("th", null, "Reason"))),
          acksBody)))));
  loadAudit(false);
  loadAcks();
  ctx.interval(() => { loadAudit(false); loadAcks(); }, 5000);
}

function auditRow(a) {
  const detail = a.detail && typeof a.detail === "object"
    ? Object.entries(a.detail).map(([k, v]) => `${k}=${v !== null && typeof v === "object" ? JSON.stringify(v) : shortHash(v)}`).join("  ")
    : String(a.detail ?? "");
  return h("tr", { "data-testid": "audit-row", "data-id": a.id, "data-action": a.action },
    h("td", { class: "small nowrap", title: `#${a.id}` }, when(a.at)),
    h("td", { class: "small" }, a.actor),
    h("td", null, h("code", null, a.action)),
    h("td", { class: "small" }, a.target),
    h("td", { class: "small mono detail" }, trunc(detail, 140)));
}

function ackRow(m) {
  return h("tr", { "data-testid": "ack-row", "data-robot-id": m.robot.id, "data-seq": m.seq, "data-status": m.status },
    h("td", { class: "small nowrap", title: `sent ${when(m.created_at)} by ${m.created_by}` }, when(m.acked_at || m.created_at)),
    h("td", null, h("a", { href: `#/robots/${m.robot.id}/messages` }, m.robot.name)),
    h("td", { class: "num" }, m.seq),
    h("td", null, badge(m.status)),
    h("td", { class: m.status === "applied" ? "small detail" : "small detail text-red" }, m.reason ? trunc(m.reason, 160) : ""));
}

/** A sha256 (64 hex digits) cut to 12 for display; anything else as it is. */
function shortHash(v) {
  return typeof v === "string" && /^[0-9a-f]{64}$/.test(v) ? `${v.slice(0, 12)}…` : v;
}
