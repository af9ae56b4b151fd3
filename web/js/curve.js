// The BRDF curve editor and the lobe plot. Both draw the server's evaluation of the material
// being rendered (the worker's `curve` data: worker/jobs/curves.py), never a BRDF of their own:
// the browser draws, the worker evaluates.
//
// The editor shows the specular part of the half-angle curve on a log scale with one point per
// bin of a `curve` material; dragging a point scales that bin's values (onChange gets the new
// material). A material of another model is converted to a curve by the worker first
// (onNeedCurve), and the drag goes on once the converted material arrives.

const LUM = [0.2126, 0.7152, 0.0722];
const lum = (v) => v[0] * LUM[0] + v[1] * LUM[1] + v[2] * LUM[2];
const BINS = 24;                     // a converted curve's bins (worker/models/convert.py CURVE_BINS)

// the server's curve at θh (degrees), linearly between its samples: plotting, not evaluating
function sampleAt(curve, key, deg) {
  const th = curve.theta_deg, v = curve[key];
  if (deg <= th[0]) return v[0];
  for (let i = 1; i < th.length; i++) {
    if (deg <= th[i]) {
      const t = (deg - th[i - 1]) / (th[i] - th[i - 1]);
      return v[i - 1].map((x, c) => x + t * (v[i][c] - x));
    }
  }
  return v[v.length - 1];
}

export class CurveEditor {
  constructor(canvas, { onChange, onNeedCurve }) {
    this.canvas = canvas;
    this.ctx = canvas.getContext("2d");
    this.onChange = onChange;
    this.onNeedCurve = onNeedCurve;
    this.material = null;
    this.curve = null;               // the server's curve of this.base
    this.base = null;                // the material the curve was evaluated for
    this.drag = -1;
    this.waiting = null;             // a drag begun on another model: {bin, y} until the curve arrives
    this.lo = -3; this.hi = 2;       // log10 range shown
    canvas.addEventListener("pointerdown", (e) => this.down(e));
    canvas.addEventListener("pointermove", (e) => this.move(e));
    // a drag released before the converted curve arrives still applies where it ended
    canvas.addEventListener("pointerup", () => { this.drag = -1; if (this.waiting) this.waiting.released = true; });
  }

  // the material and the server's curve of it (null: not evaluated yet, nothing is drawn)
  set(material, curve) {
    this.material = material;
    if (curve !== undefined) { this.curve = curve; this.base = material; }
    if (this.waiting && material?.model === "curve" && curve) {
      const { bin, y, released } = this.waiting;
      this.waiting = null;
      this.drag = bin;
      this.moveTo(y);
      if (released) this.drag = -1;
    }
    this.draw();
  }

  bins() { return this.material?.model === "curve" ? this.material.values.length : BINS; }

  // the points: one per bin, on the drawn curve (the server's specular part)
  points() {
    if (!this.curve) return [];
    const K = this.bins();
    return Array.from({ length: K }, (_, i) => {
      const x = (i + 0.5) / K * 90;
      return { x, y: Math.log10(Math.max(lum(sampleAt(this.curve, "specular", x)), 1e-4)) };
    });
  }

  px(xdeg, y) {
    const { width: W, height: H } = this.canvas;
    return [30 + (xdeg / 90) * (W - 40), 10 + (1 - (y - this.lo) / (this.hi - this.lo)) * (H - 30)];
  }

  draw() {
    const { ctx } = this;
    const { width: W, height: H } = this.canvas;
    ctx.clearRect(0, 0, W, H);
    ctx.strokeStyle = "#ccc"; ctx.fillStyle = "#666"; ctx.font = "10px system-ui";
    for (let e = this.lo; e <= this.hi; e++) {
      const [, y] = this.px(0, e);
      ctx.beginPath(); ctx.moveTo(30, y); ctx.lineTo(W - 10, y); ctx.stroke();
      ctx.fillText(`1e${e}`, 2, y + 3);
    }
    for (const d of [0, 30, 60, 90]) { const [x] = this.px(d, this.lo); ctx.fillText(`${d}°`, x - 6, H - 4); }
    const c = this.curve;
    if (!c) return;
    const drawn = [];
    ["#d33", "#3a3", "#36d"].forEach((col, k) => {
      ctx.strokeStyle = col; ctx.beginPath();
      c.theta_deg.forEach((t, i) => {
        const [x, y] = this.px(t, Math.max(this.lo, Math.log10(Math.max(c.specular[i][k], 1e-6))));
        i ? ctx.lineTo(x, y) : ctx.moveTo(x, y);
        if (k === 1) drawn.push([+(x / W).toFixed(4), +(y / H).toFixed(4)]);
      });
      ctx.stroke();
    });
    ctx.fillStyle = "#111";
    const where = [];
    for (const p of this.points()) {
      const [x, y] = this.px(p.x, Math.max(this.lo, p.y));
      ctx.beginPath(); ctx.arc(x, y, 3.5, 0, 2 * Math.PI); ctx.fill();
      where.push([+(x / W).toFixed(4), +(y / H).toFixed(4)]);
    }
    // the draggable points and the drawn green curve, as fractions of the canvas (for
    // assistive tools and tests), and the values drawn (the server's, as received)
    this.canvas.dataset.points = JSON.stringify(where);
    this.canvas.dataset.drawn = JSON.stringify(c.specular);
    this.canvas.dataset.quantity = c.quantity || "";
    this.canvas.dataset.material = JSON.stringify(this.base);
  }

  hit(e) {
    const r = this.canvas.getBoundingClientRect();
    const sx = this.canvas.width / r.width, sy = this.canvas.height / r.height;
    const mx = (e.clientX - r.left) * sx, my = (e.clientY - r.top) * sy;
    let best = -1, bd = 12;
    this.points().forEach((p, i) => {
      const [x, y] = this.px(p.x, Math.max(this.lo, p.y));
      const d = Math.hypot(x - mx, y - my);
      if (d < bd) { bd = d; best = i; }
    });
    return { best, my };
  }

  down(e) {
    const { best } = this.hit(e);
    if (best < 0) return;
    this.canvas.setPointerCapture(e.pointerId);
    if (this.material?.model !== "curve") {
      // the worker converts the look to a curve; the drag continues on it
      this.waiting = { bin: best, y: null };
      this.onNeedCurve();
      return;
    }
    this.drag = best;
  }

  move(e) {
    const { my } = this.hit(e);
    if (this.waiting) { this.waiting.y = my; return; }
    if (this.drag < 0 || !this.material) return;
    this.moveTo(my);
  }

  // scale the dragged bin so its drawn value goes to the pointer's height
  moveTo(my) {
    if (my == null || this.drag < 0 || !this.curve) return;
    const H = this.canvas.height;
    const y = this.lo + (1 - (my - 10) / (H - 30)) * (this.hi - this.lo);
    const target = 10 ** Math.min(this.hi, Math.max(this.lo, y));
    const K = this.material.values.length;
    const shown = Math.max(lum(sampleAt(this.curve, "specular", (this.drag + 0.5) / K * 90)), 1e-6);
    const m = structuredClone(this.material);
    // relative to the material the drawn curve is of (the server answers each change)
    const src = this.base?.model === "curve" && this.base.values.length === K ? this.base : this.material;
    const v = src.values[this.drag];
    m.values[this.drag] = lum(v) > 1e-6 ? v.map((x) => x * target / shown) : [target, target, target];
    this.material = m;
    this.onChange(m);
  }
}

// Polar plot of the server's f(ωi, ωo)·cosθo in the plane of incidence (luminance), ωi at the
// server's incident angle nearest thetaDeg on the −x side. lobe: the curve's `lobe` field.
export function drawLobe(canvas, lobe, thetaDeg) {
  const ctx = canvas.getContext("2d");
  const { width: W, height: H } = canvas;
  ctx.clearRect(0, 0, W, H);
  const cx = W / 2, cy = H - 12, R = Math.min(W / 2, H) - 16;
  ctx.strokeStyle = "#ccc";
  ctx.beginPath(); ctx.arc(cx, cy, R, Math.PI, 2 * Math.PI); ctx.stroke();
  ctx.beginPath(); ctx.moveTo(cx - R, cy); ctx.lineTo(cx + R, cy); ctx.stroke();
  if (!lobe) return;
  let k = 0;
  lobe.theta_i_deg.forEach((t, i) => { if (Math.abs(t - thetaDeg) < Math.abs(lobe.theta_i_deg[k] - thetaDeg)) k = i; });
  const ti = lobe.theta_i_deg[k] * Math.PI / 180;
  ctx.strokeStyle = "#e90"; ctx.beginPath(); ctx.moveTo(cx, cy);
  ctx.lineTo(cx - R * Math.sin(ti), cy - R * Math.cos(ti)); ctx.stroke();
  const vals = lobe.values[k];
  const mx = Math.max(...vals, 1e-9);
  ctx.strokeStyle = "#227"; ctx.lineWidth = 1.5; ctx.beginPath();
  lobe.theta_o_deg.forEach((d, i) => {
    const to = d * Math.PI / 180, r = R * vals[i] / mx, x = cx + r * Math.sin(to), y = cy - r * Math.cos(to);
    i ? ctx.lineTo(x, y) : ctx.moveTo(x, y);
  });
  ctx.stroke(); ctx.lineWidth = 1;
  canvas.dataset.incident = String(lobe.theta_i_deg[k]);
}
