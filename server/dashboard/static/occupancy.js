// The occupancy-grid layer of the live map: the server's ROS map (GET .../maps/export?format=pgm and the
// YAML of the same version: the same grid `linemap map --pgm` writes) drawn under the walls: free space lit,
// occupied cells red, unknown left dark. Fetched when the layer is switched on and again at most
// every REFRESH_MS while the map changes; the image is drawn with its origin and resolution from the YAML.

import { fetchExport } from "./downloads.js";

const REFRESH_MS = 5000;

/** {width, height, maxval, pixels (Uint8Array, row 0 = top)} of a binary PGM (P5, 8-bit); throws if not one. */
export function parsePgm(bytes) {
  let pos = 0;
  const token = () => {
    for (;;) {
      while (pos < bytes.length && /\s/.test(String.fromCharCode(bytes[pos]))) pos++;
      if (bytes[pos] !== 35) break; // '#': a comment to the end of the line
      while (pos < bytes.length && bytes[pos] !== 10) pos++;
    }
    const start = pos;
    while (pos < bytes.length && !/\s/.test(String.fromCharCode(bytes[pos]))) pos++;
    return String.fromCharCode(...bytes.subarray(start, pos));
  };
  if (token() !== "P5") throw new Error("not a binary PGM (P5)");
  const width = Number(token()), height = Number(token()), maxval = Number(token());
  pos++; // the single whitespace before the raster
  if (!(width > 0 && height > 0 && maxval > 0 && maxval < 256) || bytes.length - pos < width * height) {
    throw new Error("a PGM of an unexpected size or depth");
  }
  return { width, height, maxval, pixels: bytes.subarray(pos, pos + width * height) };
}

/** {resolution, origin: [x, y]} from a map_server YAML. */
export function parseMapYaml(text) {
  const res = Number(/^resolution:\s*([0-9.eE+-]+)/m.exec(text)?.[1]);
  const o = /^origin:\s*\[\s*([0-9.eE+-]+)\s*,\s*([0-9.eE+-]+)/m.exec(text);
  if (!(res > 0) || !o) throw new Error("a map YAML without resolution or origin");
  return { resolution: res, origin: [Number(o[1]), Number(o[2])] };
}

export class OccupancyLayer {
  constructor(onReady) {
    this.onReady = onReady;
    this.grid = null; // {canvas, width, height, resolution, origin, version}
    this.busy = false;
    this.fetchedAt = 0;
    this.error = null;
  }

  /** Called each frame while the layer is on: fetch the grid of `version` when due. */
  want(robotId, version) {
    if (this.busy || version === null || version === undefined) return;
    if (this.grid && (this.grid.version === version || performance.now() - this.fetchedAt < REFRESH_MS)) return;
    this.busy = true;
    this.fetchedAt = performance.now();
    this.load(robotId, version).finally(() => { this.busy = false; });
  }

  async load(robotId, version) {
    try {
      let pgm;
      try {
        pgm = await fetchExport(robotId, "pgm", version);
      } catch (e) {
        if ((e.status !== 409 && e.status !== 410) || !Number.isInteger(e.body?.current_version)) throw e;
        pgm = await fetchExport(robotId, "pgm", e.body.current_version); // that version is no longer held
      }
      const yaml = await fetchExport(robotId, "yaml", pgm.version);
      const img = parsePgm(new Uint8Array(await pgm.blob.arrayBuffer()));
      const meta = parseMapYaml(await yaml.blob.text());
      const canvas = document.createElement("canvas");
      canvas.width = img.width;
      canvas.height = img.height;
      const cctx = canvas.getContext("2d");
      const data = cctx.createImageData(img.width, img.height);
      for (let i = 0; i < img.pixels.length; i++) {
        const v = img.pixels[i] / img.maxval; // map_server trinary: 0 occupied, 205/255 unknown, 254 free
        if (v >= 0.9) data.data.set([120, 200, 255, 70], 4 * i); // free: lit, translucent
        else if (v <= 0.35) data.data.set([255, 110, 90, 200], 4 * i); // occupied
        // unknown: left transparent (the dark background)
      }
      cctx.putImageData(data, 0, 0);
      this.grid = { canvas, width: img.width, height: img.height, version: pgm.version, ...meta };
      this.error = null;
    } catch (e) {
      this.error = e.detail || e.message; // e.g. a map without walls yet (409): nothing to draw
    }
    this.onReady();
  }

  /** Draw the grid (screen = (x * scale + ox, oy - y * scale)); nothing before the first fetch. */
  draw(ctx, scale, ox, oy) {
    const g = this.grid;
    if (!g) return;
    const x = g.origin[0] * scale + ox;
    const yTop = oy - (g.origin[1] + g.height * g.resolution) * scale;
    ctx.save();
    ctx.imageSmoothingEnabled = false;
    ctx.drawImage(g.canvas, x, yTop, g.width * g.resolution * scale, g.height * g.resolution * scale);
    ctx.restore();
  }
}
