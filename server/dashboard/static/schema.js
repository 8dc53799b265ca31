// Stages (GET /kernels/stages), robot configuration and kernel parameter schemas (JSON Schema from
// GET /kernels/builtin).

/** The pipeline's stages in order, and each stage's description {stage, paper, field, element, result,
 * chain, optional, scheduled}, as the server states them; filled by loadStages() before any view renders. */
export let STAGES = [];
export let STAGE_INFO = {};
export const MODES = ["online", "offline", "mixed"];

/** Fetch the stage descriptions once (api.stages: GET /kernels/stages). */
export async function loadStages(api) {
  if (STAGES.length) return;
  const list = await api.stages();
  STAGE_INFO = Object.fromEntries(list.map((s) => [s.stage, s]));
  STAGES = list.map((s) => s.stage);
}

/** Configuration / draft key of a stage: "noise-removal" -> "noise_removal". */
export const stageKey = (stage) => STAGE_INFO[stage]?.field ?? stage.replaceAll("-", "_");

/** Whether a stage runs a chain of kernels (noise removal), and whether it may be switched off. */
export const isChain = (stage) => Boolean(STAGE_INFO[stage]?.chain);
export const isOptional = (stage) => Boolean(STAGE_INFO[stage]?.optional);

/** The kernel blocks of a stage in a robot config: a list (noise-removal may have several, others 0 or 1). */
export function configBlocks(config, stage) {
  if (!config) return [];
  const v = config[stageKey(stage)];
  if (v === null || v === undefined || v === "none") return [];
  return Array.isArray(v) ? v : [v];
}

/** The built-in kernel description {stage, name, version, summary, parameters} or undefined. */
export function findBuiltin(builtins, stage, name) {
  return builtins.find((k) => k.stage === stage && k.name === name);
}

/** [[param, propSchema], ...] of a kernel description (empty for unknown kernels). */
export function paramList(desc) {
  const props = desc?.parameters?.properties;
  return props ? Object.entries(props) : [];
}

/** The scalar type of a property: number | integer | boolean | string | json (arrays, unions...). */
export function propType(prop) {
  if (["number", "integer", "boolean", "string"].includes(prop.type)) return prop.type;
  if (Array.isArray(prop.enum)) return "string";
  return "json";
}

/** "0 < x ≤ 10 m"-style range hint for a property (null when unbounded). */
export function rangeHint(name, prop) {
  const unit = prop.unit ? ` ${prop.unit}` : "";
  let lo = null;
  let hi = null;
  if (prop.minimum !== undefined) lo = `${prop.minimum} ≤ `;
  if (prop.exclusiveMinimum !== undefined) lo = `${prop.exclusiveMinimum} < `;
  if (prop.maximum !== undefined) hi = ` ≤ ${prop.maximum}`;
  if (prop.exclusiveMaximum !== undefined) hi = ` < ${prop.exclusiveMaximum}`;
  if (Array.isArray(prop.enum)) return `one of ${prop.enum.join(", ")}`;
  if (lo === null && hi === null) return null;
  return `${lo ?? ""}${name}${hi ?? ""}${unit}`;
}

/** Display form of a value ("—" for null/undefined; JSON for arrays/objects). */
export function showValue(v) {
  if (v === null || v === undefined) return "—";
  if (typeof v === "object") return JSON.stringify(v);
  return String(v);
}

/**
 * Parse and check raw input text against a property schema.
 * Returns {value} (value undefined for an empty field) or {error: "message naming the param and range"}.
 */
export function checkValue(name, prop, raw, label = name) {
  const type = propType(prop);
  const text = typeof raw === "string" ? raw.trim() : raw;
  if (text === "" || text === null || text === undefined) return { value: undefined };
  const range = rangeHint(name, prop);
  const fail = (why) => ({ error: `${label}: ${why}${range ? ` (allowed: ${range})` : ""}` });
  if (type === "boolean") {
    if (text === true || text === "true") return { value: true };
    if (text === false || text === "false") return { value: false };
    return fail(`'${text}' is not true or false`);
  }
  if (type === "string") {
    if (Array.isArray(prop.enum) && !prop.enum.includes(text)) return fail(`'${text}' is not allowed`);
    return { value: text };
  }
  if (type === "json") {
    try {
      return { value: JSON.parse(text) };
    } catch {
      return fail(`'${text}' is not valid JSON (e.g. [1, 1, 0] or null)`);
    }
  }
  const n = Number(text);
  if (!Number.isFinite(n)) return fail(`'${text}' is not a number`);
  if (type === "integer" && !Number.isInteger(n)) return fail(`${text} is not an integer`);
  if (prop.minimum !== undefined && n < prop.minimum) return fail(`${text} is below the minimum ${prop.minimum}`);
  if (prop.exclusiveMinimum !== undefined && n <= prop.exclusiveMinimum)
    return fail(`${text} must be greater than ${prop.exclusiveMinimum}`);
  if (prop.maximum !== undefined && n > prop.maximum) return fail(`${text} is above the maximum ${prop.maximum}`);
  if (prop.exclusiveMaximum !== undefined && n >= prop.exclusiveMaximum)
    return fail(`${text} must be less than ${prop.exclusiveMaximum}`);
  return { value: n };
}

/** Whether two parameter values are equal (numbers by value, others by JSON). */
export function sameValue(a, b) {
  if (typeof a === "number" && typeof b === "number") return Math.abs(a - b) <= 1e-12 * Math.max(1, Math.abs(a));
  return JSON.stringify(a) === JSON.stringify(b);
}

/**
 * Rows of the configuration in force: [{stage, kernel, version, param, value, unit, isDefault}], the
 * robot's explicit params merged over the built-in schema defaults. A kernel without a known schema lists
 * only its explicit params (or one row with param null when it has none).
 */
export function configRows(config, builtins) {
  const rows = [];
  for (const stage of STAGES) {
    const blocks = configBlocks(config, stage);
    if (!blocks.length) {
      rows.push({ stage, kernel: null, version: null, param: null, value: null, unit: null, isDefault: true });
      continue;
    }
    blocks.forEach((b, index) => {
      const desc = findBuiltin(builtins, stage, b.name);
      const given = b.params || {};
      const names = new Set([...paramList(desc).map(([p]) => p), ...Object.keys(given)]);
      if (!names.size) rows.push({ stage, index, kernel: b.name, version: b.version, param: null });
      for (const p of names) {
        const prop = desc?.parameters?.properties?.[p] || {};
        const explicit = Object.hasOwn(given, p);
        rows.push({
          stage, index, kernel: b.name, version: b.version, param: p,
          value: explicit ? given[p] : prop.default,
          unit: prop.unit || null,
          isDefault: !explicit || sameValue(given[p], prop.default),
        });
      }
    });
  }
  return rows;
}

/** Compare semantic versions "1.2.3" (negative if a < b). */
export function cmpVersion(a, b) {
  const pa = String(a).split(".").map(Number);
  const pb = String(b).split(".").map(Number);
  for (let i = 0; i < Math.max(pa.length, pb.length); i++) {
    const d = (pa[i] || 0) - (pb[i] || 0);
    if (d) return d;
  }
  return 0;
}
