// The EiBotBoard (AxiDraw) panel: `doodlecam machine ebb`'s manual controls (pen up/down, motors off,
// jog, home to the start corner, status) on the Send target's board, through POST /api/machine.
// Its own module so that app.js only shows it and hands over the studio's api() and target.
const $ = (id) => document.getElementById(id);

export function init(api, target) {
  async function run(action, extra = {}) {
    const r = await api("/api/machine", { method: "POST", json: { target: target(), action, ...extra } });
    $("ebb-status").textContent = (r.sent ? `sent ${r.sent}: ` : "") + r.line;
    $("ebb-status").dataset.position = r.position_mm.join(",");
    $("ebb-status").dataset.action = action;
  }
  const quiet = (p) => p.catch(() => {}); // api() has shown the error on the page
  for (const b of document.querySelectorAll("[data-ebb]")) b.onclick = () => quiet(run(b.dataset.ebb));
  for (const b of document.querySelectorAll("[data-ebb-jog]")) {
    b.onclick = () => {
      const [dx, dy] = b.dataset.ebbJog.split(",").map(Number), step = Number($("ebb-jog-step").value);
      quiet(run("jog", { x: dx * step, y: dy * step })); // mm on the paper as the page shows it (y up)
    };
  }
}
