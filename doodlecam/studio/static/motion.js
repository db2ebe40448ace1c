// The motion design page (Kirecci's MOTDES): the design's points and segments as
// editable tables; every edit is solved and checked on the server and the
// position / velocity / acceleration / jerk curves redrawn.
import { linePlot } from "/static/plot.js";

const $ = (id) => document.getElementById(id);
const COLORS = ["#c30", "#093", "#06c", "#909"];
const M = { doc: null, name: "", result: null, api: null, timer: null, opened: false };
window.studioMotion = M; // for tests

export async function open(api) {
  M.api = api;
  if (M.opened) return;
  M.opened = true;
  const list = await api("/api/motion/designs");
  const sel = $("motion-sample");
  sel.innerHTML = list.map((p) => `<option>${p}</option>`).join("");
  sel.onchange = () => load(sel.value);
  $("motion-export").onclick = exportTable;
  $("m-play").onclick = animate;
  if (list.length) await load(list[0]);
  else $("motion-status").textContent = "no motion designs (*.toml with [motion]) in the studio's folders";
}

async function load(path) {
  const r = await M.api("/api/motion/open", { json: { path }, method: "POST" });
  M.doc = r.doc; M.name = r.name; M.result = r.result;
  tables(); show();
}

// Every list of rows the file format has: [[point]] / [[segment]] (X-Y input) or
// [[axis.NAME.point]] / [[axis.NAME.segment]] (axis-time input).
function lists() {
  const out = [];
  const add = (title, rows, axis, kind) => { if (Array.isArray(rows)) out.push({ title, rows, axis, kind }); };
  add("design points", M.doc.point, null, "point");
  add("segments", M.doc.segment, null, "segment");
  for (const [name, ax] of Object.entries(M.doc.axis || {})) {
    add(`axis ${name}: design points`, ax.point, name, "point");
    add(`axis ${name}: segments`, ax.segment, name, "segment");
  }
  return out;
}

function text(v) { return v === undefined ? "" : Array.isArray(v) ? JSON.stringify(v) : String(v); }
function parse(s) {
  s = s.trim();
  if (s === "") return undefined;
  if (s === "true" || s === "false") return s === "true";
  if (s.startsWith("[")) { try { return JSON.parse(s); } catch (e) { return s; } }
  const n = Number(s);
  return Number.isFinite(n) ? n : s;
}

function tables() {
  const box = $("motion-tables");
  box.innerHTML = "";
  lists().forEach((l, li) => {
    const cols = [...new Set(["t", ...l.rows.flatMap((r) => Object.keys(r))])].filter((c) => l.kind === "point" || c !== "t");
    if (l.kind === "segment" && !cols.includes("law")) cols.unshift("law");
    const table = document.createElement("table");
    table.dataset.kind = l.kind; table.dataset.list = li;
    table.innerHTML = `<caption>${l.title}</caption><tr><th>#</th>${cols.map((c) => `<th>${c}</th>`).join("")}${l.kind === "segment" ? "<th>checks</th>" : ""}</tr>`;
    l.rows.forEach((row, ri) => {
      const tr = document.createElement("tr");
      tr.innerHTML = `<td>${ri + 1}</td>`; tr.dataset.row = ri;
      for (const c of cols) {
        const td = document.createElement("td");
        let input;
        if (c === "law") {
          input = document.createElement("select");
          input.innerHTML = M.result.laws.map((n) => `<option>${n}</option>`).join("");
          input.value = row.law || "polynomial";
        } else {
          input = document.createElement("input");
          input.value = text(row[c]);
        }
        input.name = c;
        input.addEventListener("change", () => {
          const v = c === "law" ? input.value : parse(input.value);
          if (v === undefined) delete row[c]; else row[c] = v;
          clearTimeout(M.timer); M.timer = setTimeout(solve, 250);
        });
        td.append(input); tr.append(td);
      }
      if (l.kind === "segment") {
        const td = document.createElement("td");
        td.className = "checks"; td.dataset.axis = l.axis || ""; td.dataset.number = ri + 1;
        tr.append(td);
      }
      table.append(tr);
    });
    box.append(table);
  });
}

async function solve() {
  try {
    M.result = await M.api("/api/motion/solve", { method: "POST", json: { doc: M.doc, name: M.name } });
    show();
  } catch (e) { $("motion-status").textContent = "not solved: " + e.message; }
}

function show() {
  const r = M.result, names = Object.keys(r.axes);
  const titles = ["position", "velocity", "acceleration", "jerk"];
  ["m-pos", "m-vel", "m-acc", "m-jerk"].forEach((id, k) => {
    linePlot($(id), { title: titles[k], xlabel: "s", series: names.map((n, i) => ({
      x: r.t.filter((_, j) => r.axes[n][k][j] !== null), y: r.axes[n][k].filter((v) => v !== null), color: COLORS[i % 4],
      label: r.units && r.units[n] !== "mm" ? `${n} (${r.units[n]})` : n })) });
  });
  for (const td of document.querySelectorAll("td.checks")) {
    const kinds = new Set(r.segments.filter((s) => s.number === Number(td.dataset.number) && (!td.dataset.axis || s.axis === td.dataset.axis))
      .flatMap((s) => s.findings));
    td.textContent = kinds.size ? [...kinds].sort().join(", ") : "ok";
    td.className = "checks " + (kinds.size ? "flag-bad" : "flag-ok");
  }
  $("motion-findings").innerHTML = r.findings.map((f) => `<li>${f.where}: ${f.message}</li>`).join("");
  $("motion-status").textContent = r.findings.length ? `${r.findings.length} finding(s)` : "every check passed";
  document.body.dataset.motionVersion = (Number(document.body.dataset.motionVersion) || 0) + 1;
}

async function exportTable(e) {
  e.preventDefault();
  const r = await fetch("/api/motion/table", { method: "POST", headers: { "content-type": "application/json",
    "x-doodlecam-token": new URLSearchParams(location.search).get("token") || "" }, body: JSON.stringify({ doc: M.doc, name: M.name }) });
  if (!r.ok) { $("error").textContent = (await r.json()).error; $("error").hidden = false; return; }
  const a = document.createElement("a");
  a.href = URL.createObjectURL(await r.blob()); a.download = M.name.replace(/\.toml$/, "") + ".csv"; a.click();
}

// The end effector along the trajectory: with axes x and y, the pen on the X-Y plane
// (its path drawn), turned by a rotation axis (Θ: unit deg or rad) if the design has one;
// otherwise each linear axis as a slider on its own track and each rotation as a dial. Real time.
const ANGLE = { deg: Math.PI / 180, rad: 1 };
function animate() {
  const r = M.result, names = Object.keys(r.axes), t = r.t, T = t[t.length - 1] - t[0];
  const units = r.units || {}, turns = (n) => units[n] in ANGLE;
  const c = $("m-anim"), dpr = window.devicePixelRatio || 1, W = c.clientWidth, H = c.clientHeight;
  c.width = W * dpr; c.height = H * dpr;
  const g = c.getContext("2d"); g.setTransform(dpr, 0, 0, dpr, 0, 0);
  const xy = names.includes("x") && names.includes("y") && !turns("x") && !turns("y");
  const theta = names.find((n) => turns(n) && (!xy || (n !== "x" && n !== "y"))); // the tool's orientation
  const range = (a) => { const v = a.filter((x) => x !== null); return [Math.min(...v), Math.max(...v) || 1]; };
  const at = (a, s) => { // linear interpolation at time s
    let k = t.findIndex((x) => x >= s); if (k <= 0) return a[0];
    const f = (s - t[k - 1]) / (t[k] - t[k - 1]); return a[k - 1] + f * (a[k] - a[k - 1]);
  };
  const start = performance.now();
  M.frames = 0;
  const frame = (now) => {
    const s = Math.min(T, (now - start) / 1000) + t[0];
    g.clearRect(0, 0, W, H);
    M.effector = { t: s - t[0] };
    if (xy) {
      const X = r.axes.x[0], Y = r.axes.y[0], [x0, x1] = range(X), [y0, y1] = range(Y);
      const k = Math.min((W - 80) / Math.max(x1 - x0, 1e-9), (H - 80) / Math.max(y1 - y0, 1e-9)); // room for the tool
      const px = (x) => 40 + (x - x0) * k, py = (y) => H - 40 - (y - y0) * k;
      g.strokeStyle = "#999"; g.beginPath(); X.forEach((x, i) => i ? g.lineTo(px(x), py(Y[i])) : g.moveTo(px(x), py(Y[i]))); g.stroke();
      const x = at(X, s), y = at(Y, s);
      M.effector.x = x; M.effector.y = y; M.effector.screen = [px(x), py(y)];
      if (theta) { // the tool turned by Θ: a bar with a tick on its leading end, counter-clockwise positive
        const a = at(r.axes[theta][0], s);
        M.effector[theta] = a;
        const q = a * ANGLE[units[theta]], L = 22;
        g.save(); g.translate(px(x), py(y)); g.rotate(-q);
        g.fillStyle = "#d00"; g.fillRect(-L, -4, 2 * L, 8); g.fillStyle = "#fff"; g.fillRect(L - 8, -2, 6, 4);
        g.restore();
        g.fillStyle = "#333"; g.fillText(`${theta} ${a.toFixed(1)} ${units[theta]}`, 6, 14);
      } else {
        g.fillStyle = "#d00"; g.beginPath(); g.arc(px(x), py(y), 6, 0, 2 * Math.PI); g.fill();
      }
    } else {
      const rows = Math.max(1, names.length - 1);
      names.forEach((n, i) => {
        const P = r.axes[n][0], [p0, p1] = range(P), y = 20 + i * (H - 40) / rows, v = at(P, s);
        M.effector[n] = v;
        g.fillStyle = "#333"; g.fillText(n, 4, y + 4);
        if (turns(n)) { // a dial: the hand at the axis's angle, counter-clockwise from 3 o'clock
          const R = Math.min(16, (H - 40) / rows / 2 - 2), cx = 80, q = v * ANGLE[units[n]];
          g.strokeStyle = "#bbb"; g.beginPath(); g.arc(cx, y, R, 0, 2 * Math.PI); g.stroke();
          g.strokeStyle = COLORS[i % 4]; g.lineWidth = 3; g.beginPath(); g.moveTo(cx, y); g.lineTo(cx + R * Math.cos(q), y - R * Math.sin(q)); g.stroke();
          g.lineWidth = 1; g.fillStyle = "#333"; g.fillText(`${v.toFixed(1)} ${units[n]}`, cx + R + 6, y + 4);
          return;
        }
        const px = (p) => 60 + (p - p0) / Math.max(p1 - p0, 1e-9) * (W - 80);
        g.strokeStyle = "#bbb"; g.beginPath(); g.moveTo(px(p0), y); g.lineTo(px(p1), y); g.stroke();
        g.fillStyle = COLORS[i % 4]; g.fillRect(px(v) - 8, y - 6, 16, 12);
      });
    }
    $("m-time").textContent = `${(s - t[0]).toFixed(3)} / ${T.toFixed(3)} s`;
    M.frames++;
    if (s - t[0] < T) requestAnimationFrame(frame);
  };
  requestAnimationFrame(frame);
}
