// The live map's controls and readouts around the canvas: the HUD (version, walls, link latency, the
// robot's pose), the tools (Fit, Follow, zoom, Measure, Download), the legend whose items switch layers
// on and off, and the measurement readout. MapView owns the state; this module only builds and updates
// the DOM and calls back.

import { h, mount } from "./dom.js";
import { FORMATS } from "./downloads.js";

/** The layers a user can switch; all but those marked off shown at first. */
export const LAYERS = [
  { key: "walls", label: "walls" },
  { key: "centroids", label: "centroids" },
  { key: "trajectory", label: "trajectory" },
  { key: "keyframes", label: "keyframes" }, // the pose graph's (with loop closure on)
  { key: "loopClosures", label: "loop closures" },
  { key: "robot", label: "robot" },
  { key: "occupancy", label: "occupancy grid", off: true }, // fetched from the server when switched on
];

/** The pose readout: "x 1.23 m · y −4.56 m · heading 90.0°" ("—" without a pose). */
export function poseText(pose) {
  if (!pose || !Number.isFinite(pose[0]) || !Number.isFinite(pose[1])) return "—";
  let head = Number.isFinite(pose[2]) ? (pose[2] * 180) / Math.PI : null;
  if (head !== null) head = ((head % 360) + 360) % 360;
  return `x ${pose[0].toFixed(2)} m · y ${pose[1].toFixed(2)} m · heading ${head === null ? "—" : `${head.toFixed(1)}°`}`;
}

export class MapOverlay {
  /** cb: {fit(), zoomBy(f), setFollow(on), setLayer(key, on), setMeasuring(on), clearMeasure(), download(key)} */
  constructor(cb) {
    this.version = h("span", { "data-testid": "map-version" }, "—");
    this.walls = h("span", { "data-testid": "map-walls" }, "0");
    this.latency = h("span", { "data-testid": "map-latency" }, "—");
    this.pose = h("span", { "data-testid": "map-pose" }, "—");
    this.sigma = h("div", { class: "hud-sigma", "data-testid": "map-pose-sigma", hidden: true,
      title: "1 standard deviation of the pose (the robot's pose graph); the ring at the robot is its 95 % ellipse" });
    this.status = h("span", { class: "hud-status", "data-testid": "map-status" }, "connecting…");
    this.far = h("div", { class: "hud-far", "data-testid": "map-far", hidden: true });
    this.scaleText = h("span", { class: "map-scale-text" });
    this.scaleBar = h("div", { class: "map-scale", "data-testid": "map-scale" }, this.scaleText);
    this.followBox = h("input", { type: "checkbox", "data-testid": "map-follow", onchange: (e) => cb.setFollow(e.target.checked) });
    this.measureBtn = h("button", { type: "button", "data-testid": "map-measure", "aria-pressed": "false",
      title: "Measure: click points on the map (two: a distance; three: an angle). Esc or click again to stop.",
      onclick: () => cb.setMeasuring(this.measureBtn.getAttribute("aria-pressed") !== "true") }, "Measure");
    this.measureOut = h("div", { class: "map-measure", "data-testid": "map-measure-readout", hidden: true },
      h("span", { "data-testid": "map-measure-text" }),
      h("button", { type: "button", class: "link", "data-testid": "map-measure-clear", onclick: () => cb.clearMeasure() }, "clear"));
    this.downloadNote = h("div", { class: "map-download-note small", "data-testid": "map-download-note", hidden: true });
    this.downloadMenu = h("details", { class: "map-download" },
      h("summary", { "data-testid": "map-download" }, "Download"),
      h("div", { class: "map-download-list" },
        FORMATS.map((f) => h("button", { type: "button", "data-testid": `map-download-${f.key}`,
          title: "The map as shown (its version), as a file",
          onclick: () => { this.downloadMenu.open = false; cb.download(f.key); } }, f.label))));
    this.layerBoxes = {};
    const legend = LAYERS.map((l) => {
      const box = h("input", { type: "checkbox", checked: !l.off, "data-testid": `map-layer-${l.key}`,
        onchange: (e) => cb.setLayer(l.key, e.target.checked) });
      this.layerBoxes[l.key] = box;
      return h("label", { class: `legend-item legend-${l.key.replace(/s$/, "")}`, title: `Show or hide the ${l.label}` },
        box, h("i"), l.label);
    });
    this.el = [
      h("div", { class: "map-hud" },
        h("div", null, "map v", this.version, " · ", this.walls, " walls"),
        h("div", null, "pose ", this.pose),
        this.sigma,
        h("div", null, "link latency ", this.latency),
        this.far,
        this.status),
      h("div", { class: "map-tools" },
        h("button", { type: "button", "data-testid": "map-fit", title: "Fit the whole map (double-click the map too)", onclick: () => cb.fit() }, "Fit"),
        h("label", { class: "map-follow", title: "Keep the robot in the centre" }, this.followBox, " Follow robot"),
        h("button", { type: "button", title: "Zoom in", onclick: () => cb.zoomBy(1.5) }, "+"),
        h("button", { type: "button", title: "Zoom out", onclick: () => cb.zoomBy(1 / 1.5) }, "−"),
        this.measureBtn,
        this.downloadMenu),
      h("div", { class: "map-notes" }, this.measureOut, this.downloadNote),
      this.scaleBar,
      h("div", { class: "map-legend" }, legend),
    ];
  }

  setStatus(text) {
    this.status.textContent = text;
    this.status.hidden = !text;
  }

  setMeasuring(on, text) {
    this.measureBtn.setAttribute("aria-pressed", on ? "true" : "false");
    this.measureBtn.classList.toggle("active", on);
    this.measureOut.hidden = !on;
    if (text !== undefined) this.measureOut.firstChild.textContent = text;
  }

  showDownload(text, isError = false) {
    this.downloadNote.hidden = !text;
    this.downloadNote.classList.toggle("error", isError);
    mount(this.downloadNote, text || "");
  }
}
