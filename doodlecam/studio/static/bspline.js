// Clamped uniform B-splines (doodlecam.model.Spline): degree + 1 knots at 0 and
// at 1, interior knots evenly spaced, so the control points alone define the curve.

export function knots(n, degree) {
  const inner = n - degree; // spans
  const t = new Float64Array(n + degree + 1);
  for (let i = 0; i <= degree; i++) { t[i] = 0; t[n + i] = 1; }
  for (let i = 1; i < inner; i++) t[degree + i] = i / inner;
  return t;
}

// Points of the curve at `count` evenly spaced u in [0, 1] (de Boor's algorithm),
// written into `out` (Float64Array of 2 * count): x0, y0, x1, y1, ...
export function evaluate(control, degree, count, out) {
  const n = control.length;
  const spans = n - degree;
  const d = new Float64Array(2 * (degree + 1));
  out = out || new Float64Array(2 * count);
  for (let s = 0; s < count; s++) {
    const u = count === 1 ? 0 : s / (count - 1);
    const k = Math.min(Math.floor(u * spans), spans - 1); // span index: u in [k, k + 1) / spans
    const mu = k + degree; // knot index of the span's left end
    for (let j = 0; j <= degree; j++) {
      const p = control[k + j];
      d[2 * j] = p[0]; d[2 * j + 1] = p[1];
    }
    for (let r = 1; r <= degree; r++) {
      for (let j = degree; j >= r; j--) {
        const i = mu - degree + j;
        const left = knotAt(i, n, degree), right = knotAt(i + degree - r + 1, n, degree);
        const a = right === left ? 0 : (u - left) / (right - left);
        d[2 * j] = (1 - a) * d[2 * (j - 1)] + a * d[2 * j];
        d[2 * j + 1] = (1 - a) * d[2 * (j - 1) + 1] + a * d[2 * j + 1];
      }
    }
    out[2 * s] = d[2 * degree]; out[2 * s + 1] = d[2 * degree + 1];
  }
  return out;
}

function knotAt(i, n, degree) {
  if (i <= degree) return 0;
  if (i >= n) return 1;
  return (i - degree) / (n - degree);
}
