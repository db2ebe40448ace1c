// Small line plots on a canvas: the plan view's figures (no third-party code).

export function linePlot(canvas, { title, xlabel, series, limits = [] }) {
  const dpr = window.devicePixelRatio || 1;
  const W = canvas.clientWidth, H = canvas.clientHeight;
  canvas.width = W * dpr; canvas.height = H * dpr;
  const g = canvas.getContext("2d");
  g.setTransform(dpr, 0, 0, dpr, 0, 0);
  g.clearRect(0, 0, W, H);
  const L = 46, R = 8, T = 18, B = 22;
  let x0 = Infinity, x1 = -Infinity, y0 = Infinity, y1 = -Infinity;
  for (const s of series) for (let i = 0; i < s.x.length; i++) {
    x0 = Math.min(x0, s.x[i]); x1 = Math.max(x1, s.x[i]);
    y0 = Math.min(y0, s.y[i]); y1 = Math.max(y1, s.y[i]);
  }
  for (const l of limits) { y0 = Math.min(y0, l.y); y1 = Math.max(y1, l.y); }
  if (!isFinite(x0)) { x0 = 0; x1 = 1; y0 = 0; y1 = 1; }
  if (x1 === x0) x1 = x0 + 1;
  if (y1 === y0) { y1 += 1; y0 -= 1; }
  const pad = 0.05 * (y1 - y0); y0 -= pad; y1 += pad;
  const X = (x) => L + (x - x0) / (x1 - x0) * (W - L - R);
  const Y = (y) => H - B - (y - y0) / (y1 - y0) * (H - T - B);
  g.strokeStyle = "#999"; g.lineWidth = 1; g.strokeRect(L, T, W - L - R, H - T - B);
  g.fillStyle = "#333"; g.font = "11px sans-serif";
  g.fillText(title, L, 12);
  g.fillText(fmt(y1), 2, T + 8); g.fillText(fmt(y0), 2, H - B);
  g.fillText(fmt(x0), L, H - 6); g.fillText(`${fmt(x1)} ${xlabel}`, W - R - 70, H - 6);
  for (const l of limits) {
    g.strokeStyle = l.color || "#c00"; g.setLineDash([4, 3]);
    g.beginPath(); g.moveTo(L, Y(l.y)); g.lineTo(W - R, Y(l.y)); g.stroke();
  }
  g.setLineDash([]);
  let lx = L + g.measureText(title).width + 14;
  for (const s of series) {
    g.strokeStyle = s.color; g.lineWidth = 1.5; g.beginPath();
    for (let i = 0; i < s.x.length; i++) {
      if (s.step && i > 0) g.lineTo(X(s.x[i]), Y(s.y[i - 1]));
      i ? g.lineTo(X(s.x[i]), Y(s.y[i])) : g.moveTo(X(s.x[i]), Y(s.y[i]));
    }
    g.stroke();
    g.fillStyle = s.color; g.fillText(s.label, lx, 12); lx += g.measureText(s.label).width + 12;
  }
}

function fmt(v) {
  const a = Math.abs(v);
  return a >= 100 ? v.toFixed(0) : a >= 1 ? v.toFixed(1) : v.toPrecision(2);
}
