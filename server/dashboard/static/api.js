// The server API (/api/v1) over fetch with the session cookie. Errors become ApiError with the
// server's `detail`; any 401 sends the browser to the login page with a message.
// Every state-changing request carries the session's CSRF token in X-Linemap-CSRF (the server refuses
// it without; see docs/reliability/csrf.md): the token comes with the login, or from GET /session after
// a reload, and is fetched again once if the server says it no longer matches (a login in another tab).

export const BASE = "/api/v1";
export const CSRF_HEADER = "X-Linemap-CSRF";
const SAFE = new Set(["GET", "HEAD", "OPTIONS"]);
let csrfToken = null;

/** Forget the CSRF token (logged out, or the session changed). */
export function clearCsrf() {
  csrfToken = null;
}

async function refreshCsrf(auth401) {
  const s = await request("GET", "/session", { auth401 });
  csrfToken = s && s.csrf_token ? s.csrf_token : null;
  return csrfToken;
}

export class ApiError extends Error {
  constructor(status, code, detail, body) {
    super(detail || code || `HTTP ${status}`);
    this.status = status;
    this.code = code;
    this.detail = detail || code || `HTTP ${status}`;
    this.body = body;
  }
}

let unauthorizedHandler = () => {};
/** Called with a message whenever the server answers 401 (set by app.js). */
export function onUnauthorized(fn) {
  unauthorizedHandler = fn;
}

/**
 * request("GET", "/robots") → parsed JSON (or null for 204).
 * opts: {json, body, headers, auth401: false to not redirect on 401}
 */
export async function request(method, path, opts = {}) {
  const headers = { Accept: "application/json", ...(opts.headers || {}) };
  let body = opts.body;
  if (opts.json !== undefined) {
    headers["Content-Type"] = "application/json";
    body = JSON.stringify(opts.json);
  }
  // Logging in needs no token (there is no session yet); every other change does.
  const needsToken = !SAFE.has(method.toUpperCase()) && !(method.toUpperCase() === "POST" && path === "/session");
  if (needsToken) {
    if (csrfToken === null) await refreshCsrf(opts.auth401);
    if (csrfToken !== null) headers[CSRF_HEADER] = csrfToken;
  }
  let res;
  try {
    res = await fetch(BASE + path, { method, headers, body, credentials: "same-origin" });
  } catch (e) {
    throw new ApiError(0, "network", `cannot reach the server (${e.message})`);
  }
  const text = await res.text();
  let data = null;
  if (text) {
    try { data = JSON.parse(text); } catch { data = text; }
  }
  if (res.status === 403 && needsToken && !opts.csrfRetried && data && data.reason === "csrf") {
    await refreshCsrf(opts.auth401); // the session changed (e.g. a login in another tab): once more
    return request(method, path, { ...opts, csrfRetried: true });
  }
  if (!res.ok) {
    const code = data && typeof data === "object" ? data.error : null;
    let detail = data && typeof data === "object" ? data.detail : (typeof data === "string" ? data.slice(0, 300) : null);
    if (detail && typeof detail !== "string") detail = JSON.stringify(detail);
    const err = new ApiError(res.status, code, detail || `${res.status} ${res.statusText}`, data);
    if (res.status === 401 && opts.auth401 !== false) unauthorizedHandler(err.detail);
    throw err;
  }
  return data;
}

const q = (params) => {
  const u = new URLSearchParams();
  for (const [k, v] of Object.entries(params)) if (v !== undefined && v !== null && v !== "") u.set(k, v);
  const s = u.toString();
  return s ? `?${s}` : "";
};

export const api = {
  login: async (token) => {
    const who = await request("POST", "/session", { json: { token }, auth401: false });
    csrfToken = who && who.csrf_token ? who.csrf_token : null;
    return who;
  },
  logout: async () => {
    try {
      await request("DELETE", "/session", { auth401: false });
    } finally {
      csrfToken = null;
    }
  },
  whoami: (auth401 = true) => request("GET", "/whoami", { auth401 }),

  robots: () => request("GET", "/robots"),
  robot: (id) => request("GET", `/robots/${encodeURIComponent(id)}`),
  registerRobot: (name) => request("POST", "/robots", { json: { name } }),
  deleteRobot: (id) => request("DELETE", `/robots/${encodeURIComponent(id)}`),

  messages: (id, after, limit = 100) => request("GET", `/robots/${encodeURIComponent(id)}/messages${q({ after, limit })}`),
  message: (id, seq) => request("GET", `/robots/${encodeURIComponent(id)}/messages/${encodeURIComponent(seq)}`),
  postXml: (id, xml) =>
    request("POST", `/robots/${encodeURIComponent(id)}/messages`, {
      body: new Blob([xml], { type: "application/xml" }),
      headers: { "Content-Type": "application/xml; charset=utf-8" },
    }),
  controlXml: (draft) => request("POST", "/control/xml", { json: draft }),

  builtinKernels: () => request("GET", "/kernels/builtin"),
  stages: () => request("GET", "/kernels/stages"),
  kernels: (params = {}) => request("GET", `/kernels${q(params)}`),
  uploadKernel: (form) => request("POST", "/kernels", { body: form }),
  deleteKernel: (name, version) =>
    request("DELETE", `/kernels/${encodeURIComponent(name)}/${encodeURIComponent(version)}`),

  keys: () => request("GET", "/keys"),
  addKey: (name, public_key) => request("POST", "/keys", { json: { name, public_key } }),
  revokeKey: (kid) => request("DELETE", `/keys/${encodeURIComponent(kid)}`),

  audit: (limit = 100, before) => request("GET", `/audit${q({ limit, before })}`),
  robotEvents: (id, limit = 50) => request("GET", `/audit${q({ limit, target: `robot:${id}` })}`),
  robotMaps: (id) => request("GET", `/robots/${encodeURIComponent(id)}/maps`),

  mapLatest: (id, trajectory = 300) =>
    request("GET", `/robots/${encodeURIComponent(id)}/maps/latest?trajectory=${trajectory}`),
  streamUrl: (id, trajectory = 5000) =>
    `${BASE}/robots/${encodeURIComponent(id)}/maps/stream?trajectory=${trajectory}`,
};

// Built-in kernel descriptions change only with a server upgrade: fetch once per page load.
let builtinCache = null;
export function builtinKernels() {
  if (!builtinCache) builtinCache = api.builtinKernels().catch((e) => { builtinCache = null; throw e; });
  return builtinCache;
}

/** Uploaded kernels (GET /kernels), cached for a few seconds across tabs (in a view's shared state). */
export async function uploadedKernels(shared, maxAgeMs = 5000) {
  if (!shared.uploaded || performance.now() - shared.uploadedAt > maxAgeMs) {
    shared.uploaded = await api.kernels();
    shared.uploadedAt = performance.now();
  }
  return shared.uploaded;
}
