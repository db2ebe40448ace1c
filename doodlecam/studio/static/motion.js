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
      x: r.t.filter((_, j) => r.axes[n][k][j] !== null), y: r.axes[n][k].filter((v) => v !== null), color: COLORS[i % 4], label: n })) });
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
