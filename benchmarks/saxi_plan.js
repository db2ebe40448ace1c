// Plan paths with saxi's planner (npm package saxi 0.15, dist/server/planning.js) and print its times.
// Input on stdin: {"paths": [[[x, y], ...], ...] in mm, "limits": {...}}; output: JSON on stdout.
// Run by benchmarks/bench_ebb.py with node; saxi lives only in the benchmark folder (see its docstring).
const path = require("path");
const saxiDir = process.argv[2];
const planning = require(path.join(saxiDir, "node_modules", "saxi", "dist", "server", "planning.js"));

let input = "";
process.stdin.on("data", (d) => { input += d; });
process.stdin.on("end", () => {
  const job = JSON.parse(input);
  const L = job.limits;
  // saxi's planner works in any length unit: its profiles are its defaults' form, in mm here
  const profile = {
    penDownProfile: { acceleration: L.down_accel, maximumVelocity: L.down_speed, corneringFactor: L.cornering },
    penUpProfile: { acceleration: L.up_accel, maximumVelocity: L.up_speed, corneringFactor: 0 },
    penUpPos: 12000, penDownPos: 16000,
    penDropDuration: L.pen_down_s, penLiftDuration: L.pen_up_s,
  };
  const paths = job.paths.map((p) => p.map(([x, y]) => ({ x, y })));
  const t0 = process.cpuUsage();
  const plan = planning.plan(paths, profile);
  const cpu = process.cpuUsage(t0);
  let drawS = 0, drawBlocks = 0, worst = 0, travelS = 0, penS = 0;
  const dt = job.period;
  const velocity = (m, t) => {  // the pen's velocity vector at time t of a motion
    const idx = Math.max(0, m.ts.findIndex((t0, k) => k === m.ts.length - 1 || m.ts[k + 1] > t));
    const b = m.blocks[idx];
    const d = Math.hypot(b.p2.x - b.p1.x, b.p2.y - b.p1.y) || 1;
    const v = Math.max(0, b.vInitial + b.accel * Math.min(b.duration, t - m.ts[idx]));
    return [v * (b.p2.x - b.p1.x) / d, v * (b.p2.y - b.p1.y) / d];
  };
  plan.motions.forEach((m, i) => {
    if (!m.blocks) penS += m.duration();
    else if (i % 4 !== 2) travelS += m.duration();
    // plan(): per path a pen-up move, pen down, the pen-down motion, pen up
    if (m.blocks && i % 4 === 2) {
      drawS += m.duration();
      drawBlocks += m.blocks.length;
      // the pen's mean acceleration over every sample period (what a 40 ms window sees)
      let prev = velocity(m, 0);
      for (let t = dt; t <= m.duration() + 1e-9; t += dt) {
        const v = velocity(m, t);
        worst = Math.max(worst, Math.hypot(v[0] - prev[0], v[1] - prev[1]) / dt);
        prev = v;
      }
    }
  });
  console.log(JSON.stringify({ duration: plan.duration(), draw_s: drawS, travel_s: travelS, pen_s: penS, draw_blocks: drawBlocks,
                               accel_per_period: worst, cpu_s: (cpu.user + cpu.system) / 1e6 }));
});
