// doodlecam studio: the vector tracer's options for what was opened. A mesh (STL, OBJ, PLY, OFF) gets a panel
// for its section plane (axis, height as % of the extent or mm) or silhouette direction, written into the
// tracer's own options (mesh, plane, direction: the strings `convert --tracer-opt` takes) and shown as the
// command line that traces the same; an SVG or DXF shows only the options that apply to it.

const MESH = [".stl", ".obj", ".ply", ".off"];
const MESH_ONLY = ["mesh", "plane", "direction"], DRAWING_ONLY = ["layers"];
const $ = (id) => document.getElementById(id);
let last = null, redraw = null; // the job's summary (its mesh: extent, where it was cut) and the panel's refresh

// every new summary (after a re-trace): the panel shows where the mesh was cut
export function meshSummary(s) { last = s; if (redraw) redraw(); }

function raw(box, name) { return box.querySelector(`[name="${name}"]`); }
function show(box, names, visible) {
  for (const n of names) { const el = raw(box, n); if (el) el.closest("label").hidden = !visible; }
}

// "z=50%" -> {axis: "z", normal: "", value: 50, unit: "%"}; "0,1,1=12.5" -> custom normal, mm
export function parsePlane(text) {
  const [axis, where = "50%"] = String(text).split("=");
  const a = axis.trim().toLowerCase(), w = where.trim() || "50%";
  const pct = w.endsWith("%");
  return { axis: ["x", "y", "z"].includes(a) ? a : "custom", normal: ["x", "y", "z"].includes(a) ? "" : a,
    value: Number(pct ? w.slice(0, -1) : w), unit: pct ? "%" : "mm" };
}

export function vectorPanel(box, tracer, summary, ext, retrace) {
  let panel = $("stl-panel");
  last = summary; redraw = null;
  const mesh = MESH.includes(ext);
  if (!panel) { panel = document.createElement("div"); panel.id = "stl-panel"; box.after(panel); }
  panel.hidden = !mesh;
  if (!ext) return; // nothing opened yet: every option stays shown
  show(box, MESH_ONLY, false);
  show(box, DRAWING_ONLY, !mesh);
  if (!mesh) return;
  panel.innerHTML = `<fieldset><legend>STL: what to draw</legend>
      <label><span><input type="radio" name="stl-mode" value="section"> section, cut by a plane</span></label>
      <label><span><input type="radio" name="stl-mode" value="silhouette"> silhouette, the outline seen along a direction</span></label></fieldset>
    <fieldset id="stl-section"><legend>section plane</legend>
      <label>at right angles to <select id="stl-axis"><option>x</option><option>y</option><option>z</option><option value="custom">a normal a,b,c</option></select></label>
      <label id="stl-normal-label">normal <input id="stl-normal" placeholder="0,1,1"></label>
      <label>height <input type="range" id="stl-range" min="0" max="100" step="0.5"></label>
      <label>at <span><input type="number" id="stl-pos" step="any"> <select id="stl-unit"><option value="%">% of the extent</option><option value="mm">mm</option></select></span></label>
      <div class="small" id="stl-extent"></div></fieldset>
    <fieldset id="stl-silhouette"><legend>silhouette</legend>
      <label>seen along <select id="stl-dir"><option>x</option><option>y</option><option>z</option><option value="custom">a direction a,b,c</option></select></label>
      <label id="stl-dir-label">direction <input id="stl-dir-custom" placeholder="1,1,1"></label></fieldset>
    <div class="small">the same on the command line:</div><div id="stl-cli"></div>`;
  const info = () => (last && last.mesh) || {};
  const plane = parsePlane(raw(box, "plane").value), dir = raw(box, "direction").value.trim().toLowerCase();
  panel.querySelector(`input[value="${raw(box, "mesh").value.trim().toLowerCase() === "silhouette" ? "silhouette" : "section"}"]`).checked = true;
  $("stl-axis").value = plane.axis; $("stl-normal").value = plane.normal;
  $("stl-unit").value = plane.unit; $("stl-pos").value = plane.value;
  $("stl-dir").value = ["x", "y", "z"].includes(dir) ? dir : "custom"; $("stl-dir-custom").value = ["x", "y", "z"].includes(dir) ? "" : dir;

  // the mesh's extent along the plane's normal: its bounds for an axis, the traced span for the plane as cut
  const extent = () => {
    const b = info().bounds_mm, k = ["x", "y", "z"].indexOf($("stl-axis").value);
    if (k >= 0 && b) return [b[0][k], b[1][k]];
    const m = info();
    return m.span_mm && parsePlane(m.plane || "").normal === $("stl-normal").value.trim() ? m.span_mm : null;
  };
  const percent = () => { // the height as % of the extent, for the slider
    const v = Number($("stl-pos").value), e = extent();
    if ($("stl-unit").value === "%") return v;
    return e && e[1] > e[0] ? (v - e[0]) / (e[1] - e[0]) * 100 : 50;
  };
  const fromPercent = (p) => {
    const e = extent();
    return $("stl-unit").value === "%" || !e ? p : +(e[0] + p / 100 * (e[1] - e[0])).toFixed(3);
  };
  const options = () => {
    const axis = $("stl-axis").value === "custom" ? $("stl-normal").value.trim() : $("stl-axis").value;
    const d = $("stl-dir").value === "custom" ? $("stl-dir-custom").value.trim() : $("stl-dir").value;
    return { mesh: panel.querySelector("input[name=stl-mode]:checked").value,
      plane: `${axis}=${$("stl-pos").value}${$("stl-unit").value === "%" ? "%" : ""}`, direction: d };
  };
  const refresh = () => { // what the panel shows follows its fields; the tracer's options are written on change
    const o = options(), section = o.mesh === "section", e = extent(), m = info();
    $("stl-section").hidden = !section; $("stl-silhouette").hidden = section;
    $("stl-normal-label").hidden = $("stl-axis").value !== "custom";
    $("stl-dir-label").hidden = $("stl-dir").value !== "custom";
    $("stl-range").value = percent();
    $("stl-extent").textContent = (e ? `the mesh spans ${e[0].toFixed(2)} to ${e[1].toFixed(2)} mm along it` : "") +
      (m.level_mm !== undefined && m.plane === o.plane ? `; cut at ${m.level_mm.toFixed(2)} mm` : "");
    const set = [["mesh", o.mesh], section ? ["plane", o.plane] : ["direction", o.direction]];
    for (const opt of tracer.options) { // the other options the user changed from their defaults
      const el = raw(box, opt.name);
      if (!el || MESH_ONLY.includes(opt.name) || DRAWING_ONLY.includes(opt.name)) continue;
      const v = el.type === "checkbox" ? el.checked : el.dataset.type === "float" || el.dataset.type === "int" ? Number(el.value) : el.value;
      if (v !== opt.default) set.push([opt.name, v]);
    }
    const quote = (t) => /^[\w.,=%+-]+$/.test(t) ? t : `'${t.replace(/'/g, "'\\''")}'`;
    $("stl-cli").textContent = `doodlecam convert ${quote(last ? last.file : "FILE")} --tracer vector ` +
      set.map(([k, v]) => `--tracer-opt ${quote(`${k}=${v}`)}`).join(" ");
    return o;
  };
  const apply = () => {
    const o = refresh();
    for (const [k, v] of Object.entries(o)) raw(box, k).value = v;
    retrace();
  };
  $("stl-range").addEventListener("input", () => { $("stl-pos").value = fromPercent(Number($("stl-range").value)); refresh(); });
  $("stl-unit").addEventListener("change", () => { // the same height in the other unit
    const e = extent(), v = Number($("stl-pos").value);
    if (e && e[1] > e[0]) $("stl-pos").value = $("stl-unit").value === "%" ? +((v - e[0]) / (e[1] - e[0]) * 100).toFixed(3)
      : +(e[0] + v / 100 * (e[1] - e[0])).toFixed(3);
    refresh();
  });
  for (const el of panel.querySelectorAll("input, select")) {
    if (el.id === "stl-unit") continue; // a unit change keeps the plane where it is
    el.addEventListener("change", apply);
  }
  for (const el of box.querySelectorAll("input, select")) el.addEventListener("change", refresh);
  redraw = refresh;
  refresh();
}
