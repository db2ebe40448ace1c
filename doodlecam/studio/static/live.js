// doodlecam studio: the machine on the drawing during a send. What the machine has executed is drawn in ink
// over the faded toolpath; where it is comes from the send state's position_mm (the PLC's status, GRBL's status
// reports, the EiBotBoard's step counters), matched along the job's executed motion (/api/timeline).

const ACTIVE = ["sending", "pausing", "paused", "held", "stopping", "waiting"];
const TOLERANCE_MM = 1.0; // a reported position this near the toolpath is on it (GRBL's chords, the PLC's ramps)
const WINDOW_S = 10; // matches are looked for up to this long after the time-left estimate says the machine is

// timeline: {t, xy, pen, duration}; k: the segment the machine is on; t: machine time along the job (s)
export const live = { timeline: null, layers: undefined, k: 0, t: 0, state: "idle", pos: null };
window.studioLive = live; // for tests

// Where along the timeline a reported position lies: the segments from the last match on (the machine never
// goes back), within the tolerance, the one nearest the time the link's time-left estimate gives (a path that
// crosses itself passes the same point twice). Returns [segment, time] or null.
export function locate(tl, pos, k0, hint) {
  const T = tl.t, P = tl.xy, [x, y] = pos;
  let best = null, bestGap = Infinity;
  for (let j = k0; j < T.length - 1 && T[j] <= hint + WINDOW_S; j++) {
    const ax = P[j][0], ay = P[j][1], dx = P[j + 1][0] - ax, dy = P[j + 1][1] - ay, L = dx * dx + dy * dy;
    const u = L > 0 ? Math.min(1, Math.max(0, ((x - ax) * dx + (y - ay) * dy) / L)) : 0;
    const ex = ax + u * dx - x, ey = ay + u * dy - y;
    if (ex * ex + ey * ey > TOLERANCE_MM * TOLERANCE_MM) continue;
    const t = T[j] + u * (T[j + 1] - T[j]), gap = Math.abs(t - hint);
    if (gap < bestGap) { bestGap = gap; best = [j, t]; }
  }
  return best;
}

// A send state arrived: follow it. timeline(layers) fetches /api/timeline (of the layers sent). Returns true
// when the drawing must be redrawn.
export async function follow(s, timeline) {
  const was = live.state;
  live.state = s.state;
  if (s.state === "idle") { const had = !!live.timeline; live.timeline = live.loading = null; return had; } // nothing sent
  const active = ACTIVE.includes(s.state), fresh = active && !ACTIVE.includes(was); // a new (or resumed) send
  if (!active && !live.timeline && !live.loading) return false; // a finished send's late news: nothing to show
  if (fresh || !live.timeline || String(live.layers) !== String(s.layers)) {
    live.layers = s.layers; live.timeline = null; live.k = 0; live.t = 0;
    live.loading = timeline(s.layers); // events that arrive meanwhile wait for the same answer
  }
  if (live.loading) {
    const tl = await live.loading;
    if (live.loading) { live.timeline = tl; live.loading = null; }
  }
  const tl = live.timeline;
  if (!tl) return false; // cleared while its timeline was on its way
  const D = tl.duration;
  if (s.state === "done") { live.k = tl.t.length - 1; live.t = D; } // the link reported the machine idle at the end
  else if (s.position_mm) {
    // the link's time model (GRBL's planner, the PLC's periods) need not add up to the timeline's: scale it
    const hint = s.time_total_s > 0 ? D * (1 - s.time_left_s / s.time_total_s) : 0;
    const m = locate(tl, s.position_mm, live.k, Math.max(hint, live.t));
    if (m && m[1] >= live.t) { live.k = m[0]; live.t = m[1]; }
  }
  live.pos = s.position_mm;
  document.body.dataset.liveT = live.t.toFixed(3);
  return true;
}

// The job changed, or the user hid the view: a finished send's drawing goes (a running one's stays).
export function clearLive() {
  if (ACTIVE.includes(live.state) || !live.timeline) return false;
  live.timeline = live.loading = null;
  return true;
}

// The executed part in ink over the veiled job (on the page's canvas only, not the simulation's base).
export function drawLive(g, sx, sy, W, H) {
  const tl = live.timeline;
  document.getElementById("live-legend").hidden = !tl;
  if (!tl) return;
  g.fillStyle = "rgba(244, 244, 250, 0.72)"; g.fillRect(0, 0, W, H); // what remains: faded
  const T = tl.t, P = tl.xy, pen = tl.pen, k = Math.min(live.k, T.length - 1);
  const path = new Path2D();
  let down = false;
  for (let j = 0; j < k; j++) {
    if (pen[j] && pen[j + 1]) {
      if (!down) path.moveTo(sx(P[j][0]), sy(P[j][1]));
      path.lineTo(sx(P[j + 1][0]), sy(P[j + 1][1])); down = true;
    } else down = false;
  }
  if (k < T.length - 1 && pen[k] && pen[k + 1] && T[k + 1] > T[k]) { // the part of the current segment done
    const f = Math.min(1, (live.t - T[k]) / (T[k + 1] - T[k]));
    if (!down) path.moveTo(sx(P[k][0]), sy(P[k][1]));
    path.lineTo(sx(P[k][0] + f * (P[k + 1][0] - P[k][0])), sy(P[k][1] + f * (P[k + 1][1] - P[k][1])));
  }
  g.strokeStyle = "#111"; g.lineWidth = 2; g.setLineDash([]); g.stroke(path);
  document.getElementById("live-time").textContent =
    `— the machine is at ${live.t.toFixed(1)} s of ${tl.duration.toFixed(1)} s` + (live.state === "done" ? " (done, idle)" : "");
}
