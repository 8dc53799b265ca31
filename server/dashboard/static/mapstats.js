// The live map's figures in window.linemapStats (read by the dashboard tests and benchmarks/): latencies,
// frame times, what is drawn. Capped lists: at most STATS_KEEP entries each.

export const STATS_KEEP = 1000;

/** window.linemapStats, made on first use. */
export function stats() {
  if (!window.linemapStats) {
    window.linemapStats = {
      latencies_ms: [], frame_ms: [], version: null, segments: 0, drawn_at: null,
      walls_drawn: 0, walls_complete: false, walls_far: 0, first_frame_ms: null, complete_ms: null,
      snapshots: 0, correction_latencies_ms: [], // snapshot events; step -> frame of each correcting delta
    };
  }
  return window.linemapStats;
}

export const pushCapped = (arr, v) => {
  arr.push(v);
  if (arr.length > STATS_KEEP) arr.splice(0, arr.length - STATS_KEEP);
};

export function median(values) {
  if (!values.length) return null;
  const s = [...values].sort((a, b) => a - b);
  const m = s.length >> 1;
  return s.length % 2 ? s[m] : (s[m - 1] + s[m]) / 2;
}
