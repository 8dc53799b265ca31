// Downloads of the robot's map from the live map (GET /robots/{id}/maps/export), pinned to the version on
// screen: asked for with ?version=N; when the server no longer holds that version it answers 410 (older than
// the history it keeps) or 409 with the current one, and the download is of that version, said so in the
// returned note (never silently). The
// occupancy map is two files (PGM and the YAML that names it), fetched for one version.

import { BASE, ApiError } from "./api.js";

export const FORMATS = [
  { key: "geojson", label: "GeoJSON" },
  { key: "svg", label: "SVG" },
  { key: "dxf", label: "DXF" },
  { key: "mcap", label: "MCAP (ROS 2, Foxglove)" },
  { key: "pgm+yaml", label: "PGM + YAML (ROS map)" },
];

function exportUrl(robotId, fmt, version) {
  const q = new URLSearchParams({ format: fmt });
  if (version !== null && version !== undefined) q.set("version", String(version));
  return `${BASE}/robots/${encodeURIComponent(robotId)}/maps/export?${q}`;
}

export async function fetchExport(robotId, fmt, version) {
  const res = await fetch(exportUrl(robotId, fmt, version), { credentials: "same-origin" });
  if (res.ok) {
    const name = /filename="([^"]+)"/.exec(res.headers.get("Content-Disposition") || "")?.[1] || `map.${fmt}`;
    return { blob: await res.blob(), name, version: Number(res.headers.get("X-Map-Version")) };
  }
  let body = null;
  try { body = await res.json(); } catch { body = null; }
  throw new ApiError(res.status, body?.error ?? null, body?.detail ?? `${res.status} ${res.statusText}`, body);
}

function save(file) {
  const url = URL.createObjectURL(file.blob);
  const a = document.createElement("a");
  a.href = url;
  a.download = file.name;
  a.dataset.testid = "map-download-link";
  document.body.appendChild(a);
  a.click();
  a.remove();
  setTimeout(() => URL.revokeObjectURL(url), 10_000);
}

/** Fetch format `key` of the map at `version` and save it; resolves to {version, files, note}. */
export async function downloadMap(robotId, key, version) {
  const first = key === "pgm+yaml" ? "pgm" : key;
  let note = null;
  let file;
  try {
    file = await fetchExport(robotId, first, version);
  } catch (e) {
    const gone = e instanceof ApiError && (e.status === 409 || e.status === 410);
    if (!gone || !Number.isInteger(e.body?.current_version)) throw e;
    file = await fetchExport(robotId, first, e.body.current_version);
    note = `map v${version} is no longer held by the server: downloaded v${file.version}, the current one`;
  }
  const files = [file];
  if (key === "pgm+yaml") files.push(await fetchExport(robotId, "yaml", file.version));
  files.forEach(save);
  return { version: file.version, files: files.map((f) => f.name), note };
}
