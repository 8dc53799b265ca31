// The dashboard shell: hash router, top bar, login and session handling.
// Each view is render(root, ctx, ...args); ctx collects timers and cleanups run when the route changes.

import { h, mount } from "./dom.js";
import { api, onUnauthorized } from "./api.js";
import { loadStages } from "./schema.js";
import { stats } from "./mapstats.js";
import { renderRobots } from "./views/robots.js";
import { renderRobot } from "./views/robot.js";
import { renderKernels } from "./views/kernels.js";
import { renderHistory } from "./views/history.js";
import { renderFleet } from "./views/fleet.js";
import { renderRollouts } from "./views/rollouts.js";

stats(); // window.linemapStats exists from the start

const state = { who: null, loginMessage: null, after: null };
const main = document.getElementById("main");
const topbar = document.getElementById("topbar");
let ctx = null;
// Whether this browser has logged in (the cookie itself is HttpOnly): lets a first visit go straight to
// the login page instead of asking the server and logging a 401 in the console.
const SESSION_FLAG = "linemap.session";
const flag = {
  get: () => { try { return localStorage.getItem(SESSION_FLAG) === "1"; } catch { return true; } },
  set: (on) => { try { if (on) localStorage.setItem(SESSION_FLAG, "1"); else localStorage.removeItem(SESSION_FLAG); } catch { /* private mode */ } },
};

class Context {
  constructor() {
    this.alive = true;
    this.cleanups = [];
  }
  onCleanup(fn) { this.cleanups.push(fn); }
  interval(fn, ms) {
    const id = setInterval(() => { if (this.alive) fn(); }, ms);
    this.onCleanup(() => clearInterval(id));
    return id;
  }
  timeout(fn, ms) {
    const id = setTimeout(() => { if (this.alive) fn(); }, ms);
    this.onCleanup(() => clearTimeout(id));
    return id;
  }
  dispose() {
    this.alive = false;
    for (const fn of this.cleanups.splice(0)) {
      try { fn(); } catch (e) { console.error(e); }
    }
  }
}

export function navigate(hash) {
  if (location.hash === hash) route();
  else location.hash = hash;
}

onUnauthorized((detail) => {
  if (currentPath()[0] === "login") return;
  state.who = null;
  flag.set(false);
  state.after = location.hash && !location.hash.startsWith("#/login") ? location.hash : null;
  state.loginMessage = "Your session has ended or is no longer valid: please log in again.";
  state.loginDetail = detail || null;
  navigate("#/login");
});

function currentPath() {
  const raw = location.hash.replace(/^#\/?/, "");
  return raw ? raw.split("/").map(decodeURIComponent) : [];
}

function renderTopbar(active) {
  const link = (id, label, href) =>
    h("a", { href, "data-testid": `nav-${id}`, class: active === id ? "active" : null }, label);
  mount(topbar,
    h("a", { class: "brand", href: "#/robots" }, h("span", { class: "brand-mark" }, "◢"), " linemap"),
    state.who
      ? [
        h("nav", null, link("robots", "Robots", "#/robots"), link("fleet", "Fleet", "#/fleet"),
          link("kernels", "Kernels", "#/kernels"), link("rollouts", "Rollouts", "#/rollouts"),
          link("history", "History", "#/history")),
        h("span", { class: "spacer" }),
        h("span", { class: "who", "data-testid": "operator-name", title: `${state.who.kind} #${state.who.id}` }, state.who.name),
        h("button", { type: "button", class: "logout", "data-testid": "logout", onclick: logout }, "Log out"),
      ]
      : h("span", { class: "spacer" }));
}

async function logout() {
  try { await api.logout(); } catch { /* the cookie is gone either way */ }
  state.who = null;
  flag.set(false);
  state.loginMessage = "Logged out.";
  state.loginDetail = null;
  navigate("#/login");
}

function renderLogin(root) {
  const token = h("input", { type: "password", id: "login-token", "data-testid": "login-token", autocomplete: "current-password",
    placeholder: "operator token", required: true, autofocus: true });
  const err = h("div", { class: "error", "data-testid": "login-error", role: "alert", hidden: true });
  const submit = h("button", { type: "submit", class: "primary", "data-testid": "login-submit" }, "Log in");
  const form = h("form", { class: "login-card card", onsubmit: async (e) => {
    e.preventDefault();
    err.hidden = true;
    submit.disabled = true;
    try {
      const who = await api.login(token.value.trim());
      state.who = who;
      flag.set(true);
      state.loginMessage = null;
      const next = state.after || "#/robots";
      state.after = null;
      navigate(next);
    } catch (ex) {
      err.textContent = ex.detail || String(ex);
      err.hidden = false;
      token.select();
    } finally {
      submit.disabled = false;
    }
  } },
  h("h1", null, "linemap operator"),
  state.loginMessage ? h("div", { class: "info", "data-testid": "login-message", title: state.loginDetail || null }, state.loginMessage) : null,
  h("label", { for: "login-token" }, "Operator token"),
  token, err, submit,
  h("p", { class: "hint" }, "The first operator token is printed by ", h("code", null, "linemap server"), " on its first start."));
  mount(root, h("div", { class: "login-page" }, form));
  token.focus();
}

async function route() {
  if (ctx) ctx.dispose();
  ctx = new Context();
  const c = ctx;
  const path = currentPath();
  const page = path[0] || "robots";
  if (page === "login") {
    renderTopbar(null);
    renderLogin(main);
    return;
  }
  if (!state.who && !flag.get()) {
    state.after = location.hash && !location.hash.startsWith("#/login") ? location.hash : null;
    navigate("#/login");
    return;
  }
  if (!state.who) {
    try {
      state.who = await api.whoami(false);
    } catch (e) {
      if (e.status === 401) {
        flag.set(false);
        state.after = location.hash && !location.hash.startsWith("#/login") ? location.hash : null;
        navigate("#/login");
      } else {
        mount(main, h("div", { class: "error card" }, `Cannot reach the server: ${e.detail}`));
      }
      return;
    }
    if (!c.alive) return;
    if (state.who.kind !== "operator") {
      state.who = null;
      state.loginMessage = "That is a robot token; the dashboard needs an operator token.";
      navigate("#/login");
      return;
    }
  }
  try {
    await loadStages(api);
  } catch (e) {
    mount(main, h("div", { class: "error card" }, `Cannot load the pipeline's stages: ${e.detail}`));
    return;
  }
  if (!c.alive) return;
  if (page === "robots" && path[1]) {
    renderTopbar("robots");
    renderRobot(main, c, path[1], path[2]);
  } else if (page === "kernels") {
    renderTopbar("kernels");
    renderKernels(main, c);
  } else if (page === "rollouts") {
    renderTopbar("rollouts");
    renderRollouts(main, c, path[1]);
  } else if (page === "history") {
    renderTopbar("history");
    renderHistory(main, c);
  } else if (page === "fleet") {
    renderTopbar("fleet");
    renderFleet(main, c);
  } else if (page === "robots") {
    renderTopbar("robots");
    renderRobots(main, c);
  } else {
    renderTopbar(null);
    mount(main, h("div", { class: "card" }, "No such page. ", h("a", { href: "#/robots" }, "Robots")));
  }
}

window.addEventListener("hashchange", route);
route();
