// doodlecam studio: the page. Plain ES modules, no build step.
import { evaluate } from "/static/bspline.js";
import { linePlot } from "/static/plot.js";
import { follow as followLive, drawLive, clearLive } from "/static/live.js";
import { vectorPanel, meshSummary } from "/static/meshpanel.js";

const $ = (id) => document.getElementById(id);
const token = new URLSearchParams(location.search).get("token") || "";
const withToken = (url) => url + (url.includes("?") ? "&" : "?") + "token=" + encodeURIComponent(token);

// ------------------------------------------------------------------ API

let pending = 0;
async function api(path, { method = "GET", body, json } = {}) {
  const headers = { "x-doodlecam-token": token };
  // the server refuses bodies a cross-site form could send: JSON, or a file as octet-stream
  if (body !== undefined) headers["content-type"] = "application/octet-stream";
  else if (method !== "GET") { body = JSON.stringify(json === undefined ? {} : json); headers["content-type"] = "application/json"; }
  pending++; $("busy").hidden = false;
  try {
    const r = await fetch(path, { method, body, headers });
    const data = await r.json().catch(() => ({ error: `HTTP ${r.status}` }));
    if (!r.ok) {
      const e = new Error(data.error || `HTTP ${r.status}`); e.data = data;
      if (data.stale) setTimeout(refresh, 0); // another tab changed the job: show it as it is now
      throw e;
    }
    $("error").hidden = true;
    return data;
  } catch (e) {
    showError(e.message);
    throw e;
  } finally {
    if (--pending === 0) $("busy").hidden = true;
  }
}
function showError(msg) { $("error").textContent = msg; $("error").hidden = false; }

// ------------------------------------------------------------------ state

const S = {
  view: null, // /api/view
  hidden: new Set(), // layers the user hid on the paper
  selected: -1,
  point: -1, // the selected control point of the selected stroke (insert after / delete it)
  drag: null, // {point, control}
  scale: 1, ox: 0, oy: 0, // screen = (x * scale + ox, -y * scale + oy)
  fitted: false,
  base: null, // offscreen canvas with the job drawn (for the simulation)
  timeline: null,
  sim: { t: 0, playing: false, last: 0 },
};
window.studio = S; // for tests and the benchmark
window.studioPerf = { moves: [], frames: [], replan: [], replanParts: [], firstView: null };

// ------------------------------------------------------------------ drawing

const paper = $("paper");
const ctx = paper.getContext("2d");
const COLORS = 16;
const speedColor = (k) => `hsl(${240 - 240 * k / (COLORS - 1)}, 85%, 45%)`;

function resize() {
  const dpr = window.devicePixelRatio || 1;
  paper.width = paper.clientWidth * dpr; paper.height = paper.clientHeight * dpr;
  ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
  if (S.view && !S.fitted) fitView();
  draw();
}
function fitView() {
  const m = S.view.machine, W = paper.clientWidth, H = paper.clientHeight;
  S.scale = Math.min((W - 20) / m.width, (H - 20) / m.height);
  S.ox = (W - m.width * S.scale) / 2; S.oy = (H + m.height * S.scale) / 2;
  S.fitted = true;
}
const sx = (x) => x * S.scale + S.ox, sy = (y) => -y * S.scale + S.oy;
const wx = (X) => (X - S.ox) / S.scale, wy = (Y) => -(Y - S.oy) / S.scale;
window.studioScreen = (x, y) => [sx(x), sy(y)]; // mm -> canvas pixels, for tests
window.studioEvaluate = evaluate;

function draw(target = ctx, withSelection = true) {
  const g = target, W = paper.clientWidth, H = paper.clientHeight;
  g.clearRect(0, 0, W, H);
  if (!S.view) return;
  const m = S.view.machine;
  g.fillStyle = "#fff"; g.fillRect(sx(0), sy(m.height), m.width * S.scale, m.height * S.scale);
  g.strokeStyle = "#bbb"; g.setLineDash([2, 2]);
  g.strokeRect(sx(m.margin), sy(m.height - m.margin), (m.width - 2 * m.margin) * S.scale, (m.height - 2 * m.margin) * S.scale);
  // pen-up travel, dashed
  g.strokeStyle = "#999"; g.lineWidth = 0.8; g.setLineDash([4, 4]); g.beginPath();
  for (const t of S.view.travels) { g.moveTo(sx(t[0]), sy(t[1])); g.lineTo(sx(t[2]), sy(t[3])); }
  g.stroke(); g.setLineDash([]);
  if (S.view.preview) drawPreview(g);
  // pen-down strokes as executed, coloured by planned speed (one path per colour)
  const vmax = m.vmax, paths = Array.from({ length: COLORS }, () => new Path2D());
  const byPen = $("colour-by-pen").checked, penPaths = new Map(); // colour -> one path per pen
  for (const s of S.view.strokes) {
    if (S.drag && s.i === S.selected) continue;
    if (S.hidden.has(s.layer)) continue; // a layer the user hid
    if (byPen) {
      const colour = layerColour(s.layer);
      if (!penPaths.has(colour)) penPaths.set(colour, new Path2D());
      const path = penPaths.get(colour), p = s.points;
      p.forEach((q, k) => k ? path.lineTo(sx(q[0]), sy(q[1])) : path.moveTo(sx(q[0]), sy(q[1])));
      continue;
    }
    const p = s.points, v = s.speed;
    for (let k = 1; k < p.length; k++) {
      const c = Math.min(COLORS - 1, Math.round((v[k] + v[k - 1]) / 2 / vmax * (COLORS - 1)));
      paths[c].moveTo(sx(p[k - 1][0]), sy(p[k - 1][1])); paths[c].lineTo(sx(p[k][0]), sy(p[k][1]));
    }
  }
  g.lineWidth = 1.6;
  paths.forEach((p, c) => { g.strokeStyle = speedColor(c); g.stroke(p); });
  penPaths.forEach((p, colour) => { g.strokeStyle = colour; g.stroke(p); });
  if ($("show-order").checked) { // each stroke's number at its start: the order the pen draws them
    g.fillStyle = "#000"; g.font = "10px sans-serif";
    for (const s of S.view.strokes) g.fillText(String(s.i + 1), sx(s.points[0][0]) + 3, sy(s.points[0][1]) - 3);
  }
  if (withSelection) drawSelection(g);
  if (target === ctx) drawLive(g, sx, sy, W, H); // during a send: what the machine has drawn, in ink
  if (S.machinePos && target === ctx) { // where the machine's pen is during a send (PLC status / GRBL reports)
    const [x, y] = S.machinePos;
    g.strokeStyle = "#d00"; g.fillStyle = "rgba(221, 0, 0, 0.25)"; g.lineWidth = 2;
    g.beginPath(); g.arc(sx(x), sy(y), 7, 0, 2 * Math.PI); g.fill(); g.stroke();
    g.beginPath(); g.moveTo(sx(x) - 12, sy(y)); g.lineTo(sx(x) + 12, sy(y)); g.moveTo(sx(x), sy(y) - 12); g.lineTo(sx(x), sy(y) + 12); g.stroke();
  }
}

function drawSelection(g) {
  const s = S.view && S.view.strokes[S.selected];
  pointHint(s);
  if (!s || S.hidden.has(s.layer)) return; // a hidden layer's stroke is not shown, selected or not
  const control = S.drag ? S.drag.control : s.control;
  const n = Math.max(200, control.length * 12);
  S.curve = evaluate(control, s.degree, n, S.curve && S.curve.length === 2 * n ? S.curve : null);
  g.strokeStyle = "#111"; g.lineWidth = S.drag ? 2 : 3; g.globalAlpha = S.drag ? 1 : 0.35; g.beginPath();
  for (let k = 0; k < n; k++) k ? g.lineTo(sx(S.curve[2 * k]), sy(S.curve[2 * k + 1])) : g.moveTo(sx(S.curve[0]), sy(S.curve[1]));
  g.stroke(); g.globalAlpha = 1;
  g.strokeStyle = "rgba(224, 112, 0, 0.6)"; g.lineWidth = 0.6; g.beginPath();
  control.forEach((p, k) => k ? g.lineTo(sx(p[0]), sy(p[1])) : g.moveTo(sx(p[0]), sy(p[1])));
  g.stroke();
  g.fillStyle = "#e07000";
  for (const p of control) g.fillRect(sx(p[0]) - 2, sy(p[1]) - 2, 4, 4);
  markPoint(g, control);
  // the stroke order: its number at its start
  g.fillStyle = "#000"; g.font = "12px sans-serif"; g.fillText(String(s.i + 1), sx(control[0][0]) + 5, sy(control[0][1]) - 5);
}

// ------------------------------------------------------------------ the view: flat arrays, a preview while planning

// The server sends the geometry as a few flat arrays (GET /api/view?flat=1, docs/studio.md): a 10 000-stroke
// job is then one JSON parse of numbers, not 10^5 small objects. The page keeps one object per stroke
// (points as [x, y] pairs), as the rest of the page and the edits' patches use it.
async function fetchView() {
  const t0 = performance.now();
  const v = await api("/api/view?flat=1");
  const t1 = performance.now();
  const pairs = (flat, a, b) => { const out = new Array(b - a); for (let k = a; k < b; k++) out[k - a] = [flat[2 * k], flat[2 * k + 1]]; return out; };
  const g = v.geometry;
  v.strokes = [];
  if (g) {
    for (let i = 0; i < g.degree.length; i++) {
      v.strokes.push({ i, degree: g.degree[i], length: g.length[i], time: g.time[i], layer: g.layer_names[g.layer[i]],
        points: pairs(g.xy, g.offsets[i], g.offsets[i + 1]), speed: g.speed.slice(g.offsets[i], g.offsets[i + 1]),
        control: pairs(g.control, g.control_offsets[i], g.control_offsets[i + 1]) });
    }
    delete v.geometry;
    const t = v.travels; v.travels = [];
    for (let k = 0; k < t.length; k += 5) v.travels.push(t.slice(k, k + 5));
  }
  window.studioPerf.view = { request: t1 - t0, decode: performance.now() - t1 };
  document.body.dataset.preview = v.preview ? "1" : "";
  showPlanning(v.summary.planning);
  return v;
}

// A large drawing is shown as traced while the server plans it: one grey path, no selection or edits.
function drawPreview(g) {
  const { offsets, xy } = S.view.preview, path = new Path2D();
  for (let i = 0; i + 1 < offsets.length; i++) {
    for (let k = offsets[i]; k < offsets[i + 1]; k++) {
      if (k === offsets[i]) path.moveTo(sx(xy[2 * k]), sy(xy[2 * k + 1])); else path.lineTo(sx(xy[2 * k]), sy(xy[2 * k + 1]));
    }
  }
  g.strokeStyle = "#777"; g.lineWidth = 1; g.stroke(path);
}

window.studioRedraw = () => { const t = performance.now(); draw(); return performance.now() - t; }; // for the benchmark

function showPlanning(p) {
  const el = $("planning");
  el.hidden = !p;
  if (!p) return;
  el.textContent = p.error ? `planning failed: ${p.error}`
    : `planning the job: ${p.stage} ${p.done} of ${p.total} — shown as traced until it is planned; edits, export and send then`;
  el.dataset.done = p.done;
}

// ------------------------------------------------------------------ layers

const PEN_COLOURS = ["#1f4fd8", "#d81f3c", "#1b9e3a", "#8a2be2", "#e07000", "#008b8b"];
function layerColour(name) {
  const L = (S.view.layers || []).find((l) => l.name === name);
  return (L && L.colour) || PEN_COLOURS[((L ? L.pen : 1) - 1) % PEN_COLOURS.length];
}
function layersPanel() {
  const layers = S.view.layers || [];
  $("layers").innerHTML = "<tr><th></th><th>layer</th><th>pen</th><th>strokes</th></tr>" + layers.map((l, k) =>
    `<tr><td><input type="checkbox" data-layer="${k}" ${S.hidden.has(l.name) ? "" : "checked"} title="show"></td>` +
    `<td><span class="swatch" style="background:${layerColour(l.name)}"></span> ${escapeHtml(l.name || "(unnamed)")}</td>` +
    `<td>${escapeHtml(l.pen_name)}</td><td>${l.strokes}</td></tr>`).join("");
  const sel = $("send-layers"), keep = sel.value;
  sel.innerHTML = `<option value="">every layer</option>` +
    layers.map((l, k) => `<option value="${k}">layer ${escapeHtml(l.name || "(unnamed)")} only (${escapeHtml(l.pen_name)})</option>`).join("");
  sel.value = [...sel.options].some((o) => o.value === keep) ? keep : "";
}
function escapeHtml(t) { return String(t).replace(/[&<>"']/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;", "'": "&#39;" })[c]); }
$("layers").addEventListener("change", (e) => {
  const k = e.target.dataset.layer;
  if (k === undefined) return;
  const name = S.view.layers[Number(k)].name;
  if (e.target.checked) S.hidden.delete(name); else S.hidden.add(name);
  S.base = null; draw();
});
$("colour-by-pen").addEventListener("change", () => { S.base = null; draw(); });
function sendLayers() {
  const k = $("send-layers").value;
  return k === "" ? undefined : [S.view.layers[Number(k)].name];
}

function legend() {
  const c = $("legend-bar").getContext("2d");
  for (let k = 0; k < COLORS; k++) { c.fillStyle = speedColor(k); c.fillRect(k * 10, 0, 10, 10); }
  $("legend-hi").textContent = S.view ? S.view.machine.vmax.toFixed(0) : "";
}

// ------------------------------------------------------------------ job and figures

function summary(s) {
  if (!s) return;
  $("stat-strokes").textContent = s.strokes;
  $("stat-control").textContent = s.control_points;
  $("stat-ink").textContent = `${(s.pen_down_mm / 1000).toFixed(3)} m`;
  $("stat-travel").textContent = `${(s.travel_mm / 1000).toFixed(3)} m`;
  $("stat-time").textContent = s.planning ? "planning…" : `${s.job_time_s.toFixed(2)} s`;
  $("stat-ratio").textContent = `a ${s.worst_acceleration_ratio.toFixed(4)}, v ${s.worst_velocity_ratio.toFixed(4)}`;
  $("stat-made").textContent = s.tracer_made || "–";
  $("undo").disabled = !s.can_undo; $("redo").disabled = !s.can_redo;
  document.body.dataset.jobTime = s.job_time_s;
  meshSummary(s); // the STL panel says where the mesh was cut
}

async function refresh() {
  // the view and the selected stroke's figures are fetched at once
  const figs = S.selected >= 0 ? api(`/api/stroke/${S.selected}`).catch(() => null) : null;
  S.view = await fetchView();
  if (!S.fitted) fitView();
  $("machine").textContent = `machine ${S.view.machine.name} · ${S.view.summary.file}`;
  summary(S.view.summary);
  legend();
  layersPanel();
  if (S.selected >= S.view.strokes.length) S.selected = -1;
  clearLive(); // a finished send's drawing belongs to the job it drew
  if (S.timeline) { // a new or changed job: the simulation starts over on it
    S.timeline = null; S.sim.playing = false; S.sim.t = 0; $("scrub").value = 0; $("sim-time").textContent = "";
  }
  draw();
  await figures(S.selected >= 0 ? figs : null);
  document.body.dataset.strokes = S.view.strokes.length;
}

async function applyPatch(p) {
  for (const st of p.strokes) S.view.strokes[st.i] = st;
  for (const [k, row] of p.travels) S.view.travels[k] = row; // only those next to the changed strokes
  S.view.summary = p.summary;
  summary(p.summary);
  S.timeline = null; S.base = null;
  clearLive();
  draw();
  if (S.selected >= 0) await figures(S.selected === p.figures.i ? p.figures : null);
}

async function figures(fetched) {
  const i = S.selected;
  $("sel-index").textContent = i >= 0 ? `${i + 1} of ${S.view.strokes.length}` : "–";
  if (i < 0) { // nothing selected (e.g. a new job): no stale figures or plots of another stroke
    $("stroke-figures").innerHTML = "";
    for (const id of ["plot-b", "plot-v", "plot-a", "plot-d"]) { const c = $(id); c.getContext("2d").clearRect(0, 0, c.width, c.height); }
    return;
  }
  const f = (fetched && await fetched) || await api(`/api/stroke/${i}`);
  const rows = [["length", `${f.length_mm.toFixed(2)} mm`], ["control points", f.control_points], ["time", `${f.time_s.toFixed(3)} s`],
    ["worst acceleration ratio", f.worst_acceleration_ratio.toFixed(4)], ["worst velocity ratio", f.worst_velocity_ratio.toFixed(4)],
    ["off the curve between samples", `${f.max_between_samples_mm.toFixed(3)} mm`]];
  $("stroke-figures").innerHTML = rows.map(([k, v]) => `<tr><th>${k}</th><td>${v}</td></tr>`).join("");
  const p = f.plots;
  linePlot($("plot-b"), { title: "path velocity √b(u)", xlabel: "u", series: [{ x: p.u, y: p.sqrt_b, color: "#06c", label: "√b" }] });
  linePlot($("plot-v"), { title: "axis velocity, mm/s", xlabel: "s", series: [
    { x: p.t, y: p.vx, color: "#c30", label: "x" }, { x: p.t, y: p.vy, color: "#093", label: "y" }],
  limits: [{ y: p.vmax[0] }, { y: -p.vmax[0] }, { y: p.vmax[1], color: "#f88" }, { y: -p.vmax[1], color: "#f88" }] });
  linePlot($("plot-a"), { title: "axis acceleration, mm/s²", xlabel: "s", series: [
    { x: p.ta, y: p.ax, color: "#c30", label: "x", step: true }, { x: p.ta, y: p.ay, color: "#093", label: "y", step: true }],
  limits: [{ y: p.amax[0] }, { y: -p.amax[0] }, { y: p.amax[1], color: "#f88" }, { y: -p.amax[1], color: "#f88" }] });
  const ix = p.deviation.map((_, k) => k);
  linePlot($("plot-d"), { title: "executed path off the curve per period, mm", xlabel: "period", series: [
    { x: ix, y: p.deviation, color: "#606", label: "deviation", step: true }],
  limits: p.path_tolerance > 0 ? [{ y: p.path_tolerance }] : [] });
}

// ------------------------------------------------------------------ mouse: select, drag, zoom, pan

function nearestStroke(X, Y) {
  let best = -1, bd = 8 * 8;
  for (const s of S.view.strokes) for (const p of s.points) {
    const dx = sx(p[0]) - X, dy = sy(p[1]) - Y, d = dx * dx + dy * dy;
    if (d < bd) { bd = d; best = s.i; }
  }
  return best;
}
function nearestPoint(X, Y) {
  const s = S.view.strokes[S.selected];
  if (!s) return -1;
  let best = -1, bd = 8 * 8;
  s.control.forEach((p, k) => { const dx = sx(p[0]) - X, dy = sy(p[1]) - Y, d = dx * dx + dy * dy; if (d < bd) { bd = d; best = k; } });
  return best;
}

let pan = null;
paper.addEventListener("mousedown", (e) => {
  if (!S.view || e.button !== 0) return;
  const k = nearestPoint(e.offsetX, e.offsetY);
  if (k >= 0) {
    S.point = k; // a click on a point selects it; a drag moves it
    S.drag = { point: k, control: S.view.strokes[S.selected].control.map((p) => p.slice()), moved: false };
    return;
  }
  pan = { x: e.offsetX, y: e.offsetY, ox: S.ox, oy: S.oy, moved: false };
});
paper.addEventListener("mousemove", (e) => {
  if (S.drag) {
    const t0 = performance.now();
    S.drag.control[S.drag.point] = [wx(e.offsetX), wy(e.offsetY)];
    S.drag.moved = true;
    draw();
    window.studioPerf.moves.push(performance.now() - t0);
  } else if (!pan && S.view) { // hover: the stroke under the pointer and its figures, as a tooltip
    const i = nearestStroke(e.offsetX, e.offsetY), s = S.view.strokes[i];
    paper.title = s ? `stroke ${i + 1}: ${s.length.toFixed(1)} mm, ${s.control.length} control points, ${s.time.toFixed(2)} s (click for more)` : "";
  } else if (pan) {
    S.ox = pan.ox + e.offsetX - pan.x; S.oy = pan.oy + e.offsetY - pan.y;
    pan.moved = pan.moved || Math.abs(e.offsetX - pan.x) + Math.abs(e.offsetY - pan.y) > 3;
    draw();
  }
});
window.addEventListener("mouseup", async (e) => {
  if (S.drag) {
    const d = S.drag;
    if (!d.moved) { S.drag = null; draw(); return; }
    const t0 = performance.now();
    try {
      // one request: the edit answers with what it changed (the stroke, travels, summary, figures)
      const r = await api("/api/edit", { method: "POST", json: { op: "move", stroke: S.selected, control: d.control, reply: "patch", ...onJob() } });
      const t1 = performance.now();
      S.drag = null;
      if (r.strokes) await applyPatch(r); else await refresh();
      const t2 = performance.now();
      window.studioPerf.replan.push(t2 - t0);
      // where the time went: the request (server parts from its Server-Timing header) and the page's redraw
      const e = performance.getEntriesByType("resource").filter((x) => x.name.includes("/api/edit")).pop();
      const server = Object.fromEntries((e && e.serverTiming || []).map((x) => [x.name, x.duration]));
      window.studioPerf.replanParts.push({ request: t1 - t0, page: t2 - t1, ...server,
        ttfb: e ? e.responseStart - e.requestStart : null, bytes: e ? e.encodedBodySize : null });
      performance.clearResourceTimings(); // the buffer holds 250 entries: keep room for the next one
    } catch (err) { S.drag = null; draw(); }
    return;
  }
  if (pan && !pan.moved && e.target === paper) {
    S.selected = nearestStroke(e.offsetX, e.offsetY); S.point = -1;
    draw(); figures();
  }
  pan = null;
});
paper.addEventListener("wheel", (e) => {
  if (!S.view) return;
  e.preventDefault();
  const f = Math.exp(-e.deltaY * 0.0015), x = wx(e.offsetX), y = wy(e.offsetY);
  S.scale *= f; S.ox = e.offsetX - x * S.scale; S.oy = e.offsetY + y * S.scale;
  draw();
}, { passive: false });
paper.addEventListener("dblclick", () => { if (S.view) { fitView(); draw(); } });
// ------------------------------------------------------------------ control points: insert after, delete

// Explicit actions on the selected point (buttons, keys I / Insert and Delete / Backspace, the right-click menu):
// the server inserts or deletes it, re-plans only that stroke (reply=patch) and keeps the step for undo.
function pointHint(s) {
  const n = s ? s.control.length : 0, k = s && S.point < n ? S.point : -1;
  const text = !s ? "select a stroke, then click one of its control points"
    : k < 0 ? `click a control point of stroke ${s.i + 1} to select it (${n} points)`
    : `point ${k + 1} of ${n} selected: I inserts a point after it, Del deletes it, Esc deselects`;
  if ($("point-hint").textContent !== text) $("point-hint").textContent = text;
  $("insert-point").disabled = k < 0 || k >= n - 1; // after the last point there is no next one to go halfway to
  $("delete-point").disabled = k < 0 || n <= s.degree + 1; // a clamped B-spline keeps degree + 1 points
}
function markPoint(g, control) {
  const p = control[S.point];
  if (!p) return;
  g.strokeStyle = "#d00"; g.lineWidth = 2; g.strokeRect(sx(p[0]) - 5, sy(p[1]) - 5, 10, 10);
}
async function pointEdit(op) {
  const s = S.view && S.view.strokes[S.selected], k = S.point;
  $("point-menu").hidden = true;
  if (!s || k < 0 || $(op === "insert" ? "insert-point" : "delete-point").disabled) return;
  const r = await api("/api/edit", { method: "POST", json: { op, stroke: S.selected, point: k, reply: "patch", ...onJob() } });
  S.point = op === "insert" ? k + 1 : Math.min(k, s.control.length - 2); // the new point, or the one after the deleted
  if (r.strokes && Array.isArray(r.strokes)) await applyPatch(r); else await refresh();
}
for (const b of document.querySelectorAll("[data-point-op]")) b.addEventListener("click", () => pointEdit(b.dataset.pointOp).catch(() => {}));
paper.addEventListener("contextmenu", (e) => { // right-click a point: select it and offer its two actions
  if (!S.view) return;
  const k = nearestPoint(e.offsetX, e.offsetY);
  if (k < 0) return;
  e.preventDefault();
  S.point = k; draw();
  const menu = $("point-menu"), [ins, del] = menu.querySelectorAll("button");
  ins.disabled = $("insert-point").disabled; del.disabled = $("delete-point").disabled;
  menu.style.left = `${e.offsetX + 8}px`; menu.style.top = `${e.offsetY + 8}px`; menu.hidden = false;
});
window.addEventListener("mousedown", (e) => { if (!$("point-menu").contains(e.target)) $("point-menu").hidden = true; });
window.addEventListener("keydown", (e) => {
  if (e.ctrlKey || e.metaKey || e.altKey || ["INPUT", "SELECT", "TEXTAREA"].includes(e.target.tagName)) return;
  if ($("paper-tab").hidden) return; // the keys act on the paper only
  if (e.key === "Escape") { S.point = -1; $("point-menu").hidden = true; draw(); return; }
  const op = e.key === "Delete" || e.key === "Backspace" ? "delete_point" : e.key === "Insert" || e.key === "i" ? "insert" : null;
  if (op && S.point >= 0) { e.preventDefault(); pointEdit(op).catch(() => {}); }
});

// the job and version this page shows: an edit made on an older view is refused by the server
const onJob = () => ({ job: S.view.summary.job, version: S.view.summary.version });

async function edit(fields) {
  await api("/api/edit", { method: "POST", json: { stroke: S.selected, ...fields, ...onJob() } });
  await refresh();
}

$("stroke-tools").addEventListener("click", async (e) => {
  const op = e.target.dataset.op;
  if (!op || S.selected < 0) return;
  if (op === "up" || op === "down") {
    const to = S.selected + (op === "up" ? -1 : 1);
    if (to < 0 || to >= S.view.strokes.length) return;
    await edit({ op: "reorder", to }); S.selected = to; draw(); figures();
  } else if (op === "refit") { // fewer control points within the tolerance the user sets: the points become handles
    await edit({ op: "refit", tolerance: Number($("refit-tolerance").value) });
  } else if (op === "split") {
    const s = S.view.strokes[S.selected];
    await edit({ op: "split", point: Math.floor(s.control.length / 2) });
  } else {
    await edit({ op });
    if (op === "delete") { S.selected = -1; draw(); figures(); }
  }
});

async function undoRedo(which) { await api(`/api/${which}`, { method: "POST", json: onJob() }); await refresh(); }

$("undo").onclick = () => undoRedo("undo");
$("redo").onclick = () => undoRedo("redo");
window.addEventListener("keydown", (e) => {
  if (!(e.ctrlKey || e.metaKey) || e.target.tagName === "INPUT") return;
  if (e.key === "z" && !e.shiftKey) { e.preventDefault(); undoRedo("undo"); }
  if (e.key === "y" || (e.key === "Z" && e.shiftKey)) { e.preventDefault(); undoRedo("redo"); }
});

// ------------------------------------------------------------------ load and trace

async function load(file) {
  const t0 = performance.now();
  const opts = {};
  await api(`/api/load?name=${encodeURIComponent(file.name)}`, { method: "POST", body: file });
  S.fitted = false; S.selected = -1; S.traced = undefined;
  await refresh();
  await tracerPanel();
  window.studioPerf.firstView = performance.now() - t0;
}
$("file").addEventListener("change", (e) => { if (e.target.files[0]) load(e.target.files[0]).catch(() => {}); e.target.value = ""; });
$("jobfile").addEventListener("change", async (e) => {
  const f = e.target.files[0]; e.target.value = "";
  if (!f) return;
  await api(`/api/job?name=${encodeURIComponent(f.name)}`, { method: "POST", body: f });
  S.fitted = false; S.selected = -1; await refresh();
});
const wrap = $("paper-wrap");
wrap.addEventListener("dragover", (e) => { e.preventDefault(); $("drop").hidden = false; });
wrap.addEventListener("dragleave", () => { $("drop").hidden = true; });
wrap.addEventListener("drop", (e) => {
  e.preventDefault(); $("drop").hidden = true;
  if (e.dataTransfer.files[0]) load(e.dataTransfer.files[0]).catch(() => {});
});

let TRACERS = [];
async function tracerPanel() {
  if (!TRACERS.length) TRACERS = await api("/api/tracers");
  const st = await api("/api/state");
  const sel = $("tracer"), cur = st.summary ? st.summary.tracer : null;
  const ext = st.summary ? "." + st.summary.file.split(".").pop().toLowerCase() : "";
  const usable = TRACERS.filter((t) => !ext || t.extensions.includes(ext));
  sel.innerHTML = `<option value="">automatic</option>` + usable.map((t) => `<option>${t.name}</option>`).join("");
  sel.value = cur || "";
  const name = cur || (usable.find((t) => t.name === "edges") || usable[0] || {}).name;
  const tr = TRACERS.find((t) => t.name === name);
  const box = $("tracer-options");
  box.innerHTML = "";
  if (!tr) { if ($("stl-panel")) $("stl-panel").hidden = true; return; }
  const given = st.summary ? st.summary.tracer_options : {};
  for (const o of tr.options) {
    const v = o.name in given ? given[o.name] : o.default;
    let input;
    if (o.choices) {
      input = document.createElement("select");
      input.innerHTML = o.choices.map((c) => `<option>${c}</option>`).join("");
      input.value = v;
    } else if (o.type === "bool") {
      input = document.createElement("input"); input.type = "checkbox"; input.checked = !!v;
    } else {
      input = document.createElement("input");
      input.type = o.type === "float" || o.type === "int" ? "number" : "text";
      if (o.type === "float") input.step = "any";
      input.value = v;
    }
    input.name = o.name; input.dataset.type = o.type; input.title = o.help;
    const label = document.createElement("label");
    label.title = o.help; label.append(o.name, input);
    box.append(label);
    input.addEventListener("change", retraceSoon);
  }
  if (tr.name === "vector") vectorPanel(box, tr, st.summary, ext, retraceSoon); // SVG/DXF or STL options only
  else if ($("stl-panel")) $("stl-panel").hidden = true;
}
$("tracer").addEventListener("change", async () => {
  await api("/api/trace", { method: "POST", json: { tracer: $("tracer").value || null, options: {} } });
  await refresh(); await tracerPanel();
});

let retraceTimer = null;
function retraceSoon() { clearTimeout(retraceTimer); retraceTimer = setTimeout(retrace, 400); } // debounced
async function retrace() {
  const options = {};
  for (const el of $("tracer-options").querySelectorAll("input,select")) {
    options[el.name] = el.type === "checkbox" ? el.checked : el.dataset.type === "float" || el.dataset.type === "int" ? Number(el.value) : el.value;
  }
  const key = JSON.stringify([$("tracer").value, options]);
  if (key === S.traced) return; // e.g. the input's own change event on blur after a typed value
  S.traced = key;
  try {
    await api("/api/trace", { method: "POST", json: { tracer: $("tracer").value || null, options } });
    S.selected = -1; await refresh();
  } catch (e) { S.traced = undefined; /* the error is shown; the same options may be tried again */ }
}

// ------------------------------------------------------------------ simulation

function posAt(t) {
  const T = S.timeline.t, P = S.timeline.xy;
  let lo = 0, hi = T.length - 1;
  while (hi - lo > 1) { const mid = (lo + hi) >> 1; if (T[mid] <= t) lo = mid; else hi = mid; }
  const f = T[hi] > T[lo] ? Math.min(1, Math.max(0, (t - T[lo]) / (T[hi] - T[lo]))) : 0;
  return [P[lo][0] + f * (P[hi][0] - P[lo][0]), P[lo][1] + f * (P[hi][1] - P[lo][1]), S.timeline.pen[hi], lo];
}
function simFrame(now) {
  if (!S.timeline) { S.sim.frame = 0; return; } // the job changed under a pending frame
  const t0 = performance.now();
  const sim = S.sim, T = S.timeline.duration;
  if (sim.playing) { // machine time advances by the screen's time times the speed: the clock shows machine time
    sim.t = Math.min(T, sim.t + Math.max(0, now - sim.last) / 1000 * Number($("sim-speed").value));
    sim.last = Math.max(sim.last, now); // (a frame's timestamp may precede the click that started the play)
  }
  if (!S.base || S.base.width !== paper.width || S.base.key !== `${S.scale},${S.ox},${S.oy}`) {
    S.base = document.createElement("canvas"); S.base.width = paper.width; S.base.height = paper.height;
    S.base.key = `${S.scale},${S.ox},${S.oy}`;
    const g = S.base.getContext("2d"); const dpr = window.devicePixelRatio || 1; g.setTransform(dpr, 0, 0, dpr, 0, 0);
    draw(g, false);
  }
  ctx.save(); ctx.setTransform(1, 0, 0, 1, 0, 0); ctx.drawImage(S.base, 0, 0); ctx.restore();
  const [x, y, pen] = posAt(sim.t);
  ctx.fillStyle = pen ? "#d00" : "#fff"; ctx.strokeStyle = "#000"; ctx.lineWidth = 1.5;
  ctx.beginPath(); ctx.arc(sx(x), sy(y), 6, 0, 2 * Math.PI); ctx.fill(); ctx.stroke();
  $("sim-time").textContent = `${sim.t.toFixed(1)} / ${T.toFixed(1)} s (left ${(T - sim.t).toFixed(1)} s)` +
    (sim.playing && sim.t < T ? ` at ${$("sim-speed").value}×` : sim.t < T ? " paused" : "");
  $("scrub").value = Math.round(sim.t / T * 1000);
  window.studioPerf.frames.push({ at: now, script: performance.now() - t0, t: sim.t, x, y });
  sim.frame = 0;
  if (sim.playing && sim.t < T) sim.frame = requestAnimationFrame(simFrame); // one chain of frames at a time
  else { sim.playing = false; $("play").textContent = "▶ Simulate"; }
}
let timelineLoading = null; // one request for clicks that come while it is on its way
async function ensureTimeline() {
  if (S.timeline) return;
  timelineLoading = timelineLoading || api("/api/timeline").finally(() => { timelineLoading = null; });
  const tl = await timelineLoading;
  if (!S.timeline) S.timeline = tl;
}
$("play").onclick = async () => { // play / pause: the state changes at the click, whatever the network does
  if (!S.view) return;
  const sim = S.sim;
  sim.playing = !sim.playing;
  $("play").textContent = sim.playing ? "❚❚ Pause" : "▶ Simulate";
  if (!sim.playing) return;
  await ensureTimeline();
  if (!sim.playing || sim.frame) return; // paused meanwhile, or its frames already run
  if (sim.t >= S.timeline.duration) sim.t = 0;
  sim.last = performance.now();
  sim.frame = requestAnimationFrame(simFrame);
};
$("scrub").addEventListener("input", async () => {
  if (!S.view) return;
  await ensureTimeline();
  S.sim.t = $("scrub").value / 1000 * S.timeline.duration;
  if (!S.sim.playing) simFrame(performance.now());
});

// ------------------------------------------------------------------ export and send

async function posts() {
  const names = await api("/api/posts");
  $("post").innerHTML = names.map((n) => `<option>${n}</option>`).join("");
  $("post").value = names.includes("gcode") ? "gcode" : names[0];
}
$("download").addEventListener("click", (e) => { e.currentTarget.href = withToken(`/api/export/${$("post").value}`); });
$("save").addEventListener("click", (e) => { e.currentTarget.href = withToken("/api/job"); });
$("export").onclick = async () => {
  $("export-result").textContent = "";
  const req = { posts: [$("post").value], folder: $("export-folder").value };
  let r;
  try {
    r = await api("/api/export", { method: "POST", json: req });
  } catch (e) {
    if (!(e.data && e.data.confirm) || !window.confirm(e.message + "\n\nReplace it?")) return;
    r = await api("/api/export", { method: "POST", json: { ...req, overwrite: true } });
  }
  $("export-result").textContent = "wrote " + r.written.join(", ");
};
const GRBL_TARGETS = ["grbl-simulator", "serial"];
const REAL_TARGETS = ["host", "serial", "ebb-serial"]; // a real machine runs at its own speed
function sendTarget() {
  const t = $("target").value;
  return t === "host" ? $("target-host").value : t === "serial" ? "serial:" + $("target-serial").value
    : t === "ebb-serial" ? "ebb:" + ($("target-ebb").value.trim() || "auto") : t;
}
$("target").onchange = () => {
  const t = $("target").value;
  $("target-host").hidden = t !== "host"; $("target-serial").hidden = t !== "serial"; $("target-ebb").hidden = t !== "ebb-serial";
  $("machine-panel").hidden = !GRBL_TARGETS.includes(t);
  $("ebb-panel").hidden = !t.startsWith("ebb-");
  $("send-speed-label").hidden = REAL_TARGETS.includes(t);
};
function offerTargets(targets) { // the links that drive this machine (an AxiDraw: its EiBotBoard)
  for (const o of $("target").options) o.hidden = o.disabled = !targets.includes(o.value);
  if (!targets.includes($("target").value)) $("target").value = targets[0];
  $("target").onchange();
}

const ACTIVE = ["sending", "pausing", "paused", "held", "stopping", "waiting"];
let sendAgain = false; // the PLC refuses a finished job unless asked to draw it again
let sendVersion = -1; // a control's answer can arrive after a newer event: never show an older state
function showSend(s) {
  if (s.version !== undefined) { if (s.version < sendVersion) return; sendVersion = s.version; }
  $("send-progress").value = s.percent;
  const pos = s.position_mm ? ` at (${s.position_mm[0].toFixed(1)}, ${s.position_mm[1].toFixed(1)}) mm` : "";
  const what = s.transport === "grbl" ? `line ${s.line} (${s.executed} of ${s.total} answered)`
    : s.transport === "ebb" ? `command ${s.executed} of ${s.total} answered` : `command ${s.executed} of ${s.total}`;
  const grbl = s.machine_state ? `, GRBL ${s.machine_state}` : "";
  $("send-status").textContent = ACTIVE.includes(s.state)
    ? `${s.state}: ${what}, ${s.percent.toFixed(1)} %, ${s.time_left_s.toFixed(1)} s left${pos}${grbl}` + (s.message ? ` — ${s.message}` : "")
    : `${s.state}${s.message ? ": " + s.message : ""}`;
  $("send-status").dataset.state = s.state;
  // the machine's pen on the drawing while a send runs
  const at = ACTIVE.includes(s.state) && s.position_mm ? s.position_mm : null;
  if (String(at) !== String(S.machinePos)) { S.machinePos = at; document.body.dataset.machinePos = at ? at.join(",") : ""; draw(); }
  liveView(s);
  // a pen change needs the operator: a dialog they cannot miss
  const modal = $("pen-modal");
  if (s.state === "waiting") { $("pen-modal-text").textContent = s.message; if (!modal.open) modal.showModal(); }
  else if (modal.open) modal.close();
  const can = new Set(s.controls || []);
  $("send").disabled = ACTIVE.includes(s.state); $("stop").disabled = !can.has("stop");
  for (const b of ["pause", "hold", "resume", "continue"]) { $(b).hidden = !can.has(b); }
  sendAgain = s.state === "done" || (s.state === "failed" && /again/.test(s.message || ""));
  // a stopped job resumes where it stopped (the PLC holds it; GRBL's resume record names the next line)
  $("send").textContent = s.state === "stopped" ? "Resume" : sendAgain ? "Send again" : "Send";
  // where the link offers to start over or abandon (a stopped or refused job), the page has the buttons
  const offer = !ACTIVE.includes(s.state) && /Start over|Abandon/.test(s.message || "") || s.state === "stopped";
  $("start-over").hidden = $("abandon").hidden = !offer;
}
// the drawn part over the toolpath (live.js), and the last moves after every line was answered
function liveView(s) {
  if (S.view) {
    const timeline = (layers) => api("/api/timeline" + (layers ? "?layers=" + encodeURIComponent(JSON.stringify(layers)) : ""));
    followLive(s, timeline).then((changed) => changed && draw()).catch(() => {});
  }
  if (s.state === "sending" && s.total && s.executed >= s.total) { // the link waits for the machine to be idle
    $("send-status").textContent += " — the machine is finishing its last moves";
    document.body.dataset.finishing = s.version; // (for tests: the page saw it before "done")
  }
}
$("live-hide").onclick = () => { if (clearLive()) draw(); };
function follow() {
  const es = new EventSource(withToken("/api/send/events"));
  es.onmessage = (e) => { const s = JSON.parse(e.data); showSend(s); if (!ACTIVE.includes(s.state)) es.close(); };
  es.onerror = () => es.close();
}
$("send").onclick = async () => {
  const real = REAL_TARGETS.includes($("target").value); // a real machine: no simulated speed
  const speed = !real && $("send-speed").value ? Number($("send-speed").value) : null;
  showSend(await api("/api/send", { method: "POST", json: { target: sendTarget(), speed, again: sendAgain, layers: sendLayers() } }));
  follow();
};
$("pen-modal-continue").onclick = async () => { showSend(await api("/api/send/control", { method: "POST", json: { action: "continue" } })); };
$("pen-modal-stop").onclick = async () => { showSend(await api("/api/send/control", { method: "POST", json: { action: "stop" } })); };
$("start-over").onclick = async () => {
  showSend(await api("/api/send", { method: "POST", json: { target: sendTarget(), restart: true, layers: sendLayers() } }));
  follow();
};
$("abandon").onclick = async () => {
  if (!window.confirm("Abandon the stopped job? The next Send starts at the beginning.")) return;
  showSend(await api("/api/send/abandon", { method: "POST", json: { target: sendTarget() } }));
};
$("stop").onclick = async () => { showSend(await api("/api/send/control", { method: "POST", json: { action: "stop" } })); };
for (const b of ["pause", "hold", "resume", "continue"]) { // continue: a job waiting for the operator (state "waiting")
  $(b).onclick = async () => { showSend(await api("/api/send/control", { method: "POST", json: { action: b } })); };
}

async function machine(action, extra = {}) {
  const r = await api("/api/machine", { method: "POST", json: { target: sendTarget(), action, ...extra } });
  $("machine-status").textContent = (r.sent ? `sent ${r.sent}: ` : "") + r.line;
  $("machine-status").dataset.state = r.state;
  $("machine-settings").innerHTML = !r.settings ? "" : "<tr><th>setting</th><th>GRBL</th><th>the profile needs</th></tr>" +
    r.settings.map((s) => `<tr class="${s.ok ? "flag-ok" : "flag-bad"}"><td>${s.key}</td><td>${s.have ?? "–"}</td><td>${s.want}</td></tr>`).join("");
}
for (const b of document.querySelectorAll("[data-machine]")) b.onclick = () => machine(b.dataset.machine);
for (const b of document.querySelectorAll("[data-jog]")) {
  b.onclick = () => {
    const [dx, dy] = b.dataset.jog.split(",").map(Number), step = Number($("jog-step").value);
    machine("jog", { x: dx * step, y: dy * step });
  };
}

// ------------------------------------------------------------------ events: other tabs, planning, sends

// One event stream while the page is visible (GET /api/events): "job" when the job or its version changes
// (another tab loaded or edited it, or its background planning moved on or ended), "send" on every change
// of the send. A hidden tab closes it (browsers allow few open connections to a host) and catches up when shown.
let events = null, followTimer = null;
function openEvents() {
  if (events || document.hidden) return;
  events = new EventSource(withToken("/api/events"));
  events.addEventListener("job", (e) => { S.serverJob = JSON.parse(e.data); showPlanning(S.serverJob.planning); followJob(); });
  events.addEventListener("send", (e) => showSend(JSON.parse(e.data)));
}
function followJob() {
  const j = S.serverJob, v = S.view && S.view.summary;
  if (!j || !j.job || (v && j.job === v.job && j.version === v.version)) return;
  if (S.drag || pending > 0) { // this page's own request answers first; then one look again
    followTimer = followTimer || setTimeout(() => { followTimer = null; followJob(); }, 200);
    return;
  }
  const other = !v || j.job !== v.job; // another job (another file): its tracer's panel too
  if (other) S.selected = -1; // no stroke of the old job stays selected
  const t0 = performance.now();
  refresh().then(() => (other ? tracerPanel() : null))
    .then(() => { window.studioPerf.followed = (window.studioPerf.followed || 0) + 1; window.studioPerf.followMs = performance.now() - t0; })
    .catch(() => {});
}
document.addEventListener("visibilitychange", () => {
  if (!document.hidden) openEvents();
  else if (events) { events.close(); events = null; }
});

import("/static/ebbpanel.js").then((m) => m.init(api, sendTarget)); // the EiBotBoard's manual controls

// ------------------------------------------------------------------ tabs

document.querySelector(".tabs").addEventListener("click", (e) => {
  const tab = e.target.dataset.tab;
  if (!tab) return;
  for (const b of document.querySelectorAll(".tabs button")) b.classList.toggle("active", b.dataset.tab === tab);
  $("paper-tab").hidden = tab !== "paper"; $("motion-tab").hidden = tab !== "motion";
  if (tab === "motion") import("/static/motion.js").then((m) => m.open(api)).catch((err) => showError(err.message));
  else resize();
});

// ------------------------------------------------------------------ start

window.addEventListener("resize", resize);
$("show-order").addEventListener("change", () => { S.base = null; draw(); });
(async () => {
  resize(); legend();
  await posts();
  const st = await api("/api/state");
  $("machine").textContent = `machine ${st.machine}`;
  offerTargets(st.targets);
  showSend(st.send);
  if (ACTIVE.includes(st.send.state)) follow(); // a send outlives its page: pick it up
  if (st.loaded) { await refresh(); await tracerPanel(); window.studioPerf.firstView = performance.now(); }
  else await tracerPanel();
  openEvents();
  document.body.dataset.ready = "1";
})();
