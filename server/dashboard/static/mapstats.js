// The live map's measurements in window.linemapStats (latencies, frame times, what was drawn), read by the
// dashboard tests and benchmarks/dashboard_big_map.py.

const STATS_KEEP = 1000;

export { STATS_KEEP };

export function stats() {
  if (!window.linemapStats) {
    window.linemapStats = {
      latencies_ms: [], frame_ms: [], version: null, segments: 0, drawn_at: null,
      walls_drawn: 0, walls_complete: false, walls_far: 0, first_frame_ms: null, complete_ms: null,
    };
  }
  return window.linemapStats;
}

/** Append v, keeping the last STATS_KEEP. */
export function pushCapped(arr, v) {
  arr.push(v);
  if (arr.length > STATS_KEEP) arr.splice(0, arr.length - STATS_KEEP);
}

export function median(values) {
  if (!values.length) return null;
  const s = [...values].sort((a, b) => a - b);
  const m = s.length >> 1;
  return s.length % 2 ? s[m] : (s[m - 1] + s[m]) / 2;
}
