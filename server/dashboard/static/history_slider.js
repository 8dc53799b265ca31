// The map history slider under the live map: replays the versions of the robot's current mapping session
// that the server can rebuild (GET /robots/{id}/maps/history, then /maps/latest?version=N). Drag or step
// to a version, play them in order at a chosen speed, or go back to "Live". While a past version is shown
// the stream keeps being received (the live map stays current underneath) but does not overwrite the view;
// downloads are of the version shown. The view (mapview.js) is told through showVersion(m) and goLive().

import { h } from "./dom.js";
import { request } from "./api.js";

/** Replay speeds, versions per second. */
export const SPEEDS = [1, 2, 5, 10];
const TRAJECTORY_KEEP = 5000;

export class HistorySlider {
  /** view: {showVersion(map), goLive(), liveVersion()} */
  constructor(view) {
    this.view = view;
    this.robotId = null;
    this.versions = []; // [{version, stamp_s}], oldest first, from the server
    this.older = "";
    this.listedAt = null; // the live version when the list was read
    this.shown = null; // the version shown, null when live
    this.seq = 0; // the latest version request: older answers are dropped
    this.timer = 0;
    this.range = h("input", { type: "range", min: 0, max: 0, value: 0, step: 1, "data-testid": "history-range",
      "aria-label": "Map version", oninput: () => this.seekIndex(Number(this.range.value)) });
    this.range.addEventListener("pointerdown", () => this.refresh());
    this.back = h("button", { type: "button", title: "The version before", "data-testid": "history-back",
      onclick: () => this.step(-1) }, "◀");
    this.forward = h("button", { type: "button", title: "The version after", "data-testid": "history-forward",
      onclick: () => this.step(1) }, "▶");
    this.play = h("button", { type: "button", "data-testid": "history-play", "aria-pressed": "false",
      title: "Replay the versions in order", onclick: () => (this.timer ? this.pause() : this.start()) }, "Play");
    this.speed = h("select", { "data-testid": "history-speed", title: "Replay speed (versions per second)" },
      SPEEDS.map((s) => h("option", { value: String(s), selected: s === 2 }, `${s}×/s`)));
    this.speed.addEventListener("change", () => { if (this.timer) { this.pause(); this.start(); } });
    this.live = h("button", { type: "button", class: "history-live active", "data-testid": "history-live",
      title: "Follow the live stream again", onclick: () => this.goLive() }, "Live");
    this.label = h("span", { class: "history-label", "data-testid": "history-label" }, "live");
    this.el = h("div", { class: "map-history", "data-testid": "map-history" },
      h("span", { class: "history-title" }, "History"),
      this.back, this.range, this.forward, this.play, this.speed, this.live, this.label);
  }

  connect(robotId) {
    this.robotId = robotId;
    this.refresh();
  }

  close() {
    this.pause();
    this.seq += 1;
  }

  /** A live version arrived: the slider's end moves with it while live. */
  onLive(version) {
    if (this.shown !== null) return;
    const last = this.versions[this.versions.length - 1];
    if (!last || version > last.version) this.versions.push({ version, stamp_s: null });
    this.place(this.versions.length - 1);
    this.setLabel(`live · v${version}`);
  }

  /** Read the replayable versions anew (the live map moved since, or a version was refused). */
  async refresh() {
    if (this.robotId === null) return;
    const live = this.view.liveVersion();
    if (this.listedAt !== null && this.listedAt === live && this.versions.length) return;
    try {
      const got = await request("GET", `/robots/${encodeURIComponent(this.robotId)}/maps/history`);
      this.versions = got.versions;
      this.older = got.older;
      this.listedAt = got.current_version;
      this.range.title = `Versions ${got.first_version}..${got.current_version}: ${got.older}`;
      const at = this.shown === null ? this.versions.length - 1 : this.indexOf(this.shown);
      this.place(at < 0 ? this.versions.length - 1 : at);
      if (this.shown === null) this.setLabel(`live · v${got.current_version}`);
    } catch (e) {
      this.setLabel(`history unavailable: ${e.detail || e.message}`, true);
    }
  }

  indexOf(version) {
    return this.versions.findIndex((v) => v.version === version);
  }

  place(index) {
    this.range.max = String(Math.max(0, this.versions.length - 1));
    this.range.value = String(Math.max(0, index));
    this.back.disabled = index <= 0;
    this.forward.disabled = this.shown === null;
  }

  setLabel(text, isError = false) {
    this.label.textContent = text;
    this.label.classList.toggle("error", isError);
  }

  step(delta) {
    this.pause();
    const at = this.shown === null ? this.versions.length - 1 : this.indexOf(this.shown);
    this.seekIndex(Math.min(this.versions.length - 1, Math.max(0, at + delta)));
  }

  /** Show the version at `index` of the list (the last one while live is the live map itself). */
  async seekIndex(index) {
    const entry = this.versions[index];
    if (!entry) return;
    if (entry.version === this.view.liveVersion() && index === this.versions.length - 1 && !this.timer) {
      this.goLive();
      return;
    }
    const seq = ++this.seq;
    this.shown = entry.version;
    this.live.classList.remove("active");
    this.place(index);
    this.setLabel(`v${entry.version} … loading`);
    try {
      const q = new URLSearchParams({ version: String(entry.version), trajectory: String(TRAJECTORY_KEEP) });
      const m = await request("GET", `/robots/${encodeURIComponent(this.robotId)}/maps/latest?${q}`);
      if (seq !== this.seq) return;
      this.view.showVersion(m);
      const of = `${this.versions[0].version}..${this.versions[this.versions.length - 1].version}`;
      const stamp = Number.isFinite(m.stamp_s) ? ` · scan ${m.stamp_s.toFixed(1)} s` : "";
      this.setLabel(`v${m.version} of ${of}${stamp}`);
    } catch (e) {
      if (seq !== this.seq) return;
      this.pause();
      this.setLabel(`v${entry.version}: ${e.detail || e.message}`, true);
      this.listedAt = null;
      this.refresh();
    }
  }

  start() {
    if (this.shown === null || this.indexOf(this.shown) >= this.versions.length - 1) this.seekIndex(0);
    this.play.textContent = "Pause";
    this.play.setAttribute("aria-pressed", "true");
    this.timer = setInterval(() => this.tick(), 1000 / Number(this.speed.value));
  }

  pause() {
    clearInterval(this.timer);
    this.timer = 0;
    this.play.textContent = "Play";
    this.play.setAttribute("aria-pressed", "false");
  }

  async tick() {
    const at = this.indexOf(this.shown);
    if (at >= this.versions.length - 1) {
      this.pause();
      this.goLive();
      return;
    }
    this.seekIndex(at + 1);
  }

  /** Back to the live stream: the view shows the live map again, the slider at its end. */
  goLive() {
    this.pause();
    this.seq += 1;
    this.shown = null;
    this.view.goLive();
    this.live.classList.add("active");
    this.listedAt = null;
    this.setLabel(`live · v${this.view.liveVersion() ?? "—"}`);
    this.place(this.versions.length - 1);
    this.refresh();
  }
}
