// The BRDF curve editor: the current BRDF's 1D half-angle distribution on a log scale; the
// designer drags points to set a `curve` material's values (onChange gets the new material).
// And the lobe visualiser: the BRDF in the plane of incidence for a chosen incident angle.
import { evalBRDF, halfAngleCurve, toCurve } from "./brdf.js";

const LUM = [0.2126, 0.7152, 0.0722];
const lum = (v) => v[0] * LUM[0] + v[1] * LUM[1] + v[2] * LUM[2];

export class CurveEditor {
  constructor(canvas, onChange) {
    this.canvas = canvas;
    this.ctx = canvas.getContext("2d");
    this.onChange = onChange;
    this.material = null;
    this.drag = -1;
    this.lo = -3; this.hi = 2;             // log10 range shown
    canvas.addEventListener("pointerdown", (e) => this.down(e));
    canvas.addEventListener("pointermove", (e) => this.move(e));
    canvas.addEventListener("pointerup", () => { this.drag = -1; });
    canvas.addEventListener("pointerleave", () => { this.drag = -1; });
  }

  set(material) {
    this.material = material;
    this.draw();
  }

  points() {
    if (!this.material) return [];
    const c = this.material.model === "curve" ? this.material : toCurve(this.material);
    const K = c.values.length;
    return c.values.map((v, i) => ({ x: (i + 0.5) / K * 90, y: Math.log10(Math.max(lum(v), 1e-4)) }));
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
    if (!this.material) return;
    const c = halfAngleCurve(this.material, 90);
    ["#d33", "#3a3", "#36d"].forEach((col, k) => {
      ctx.strokeStyle = col; ctx.beginPath();
      c.theta.forEach((t, i) => {
        const [x, y] = this.px(t, Math.max(this.lo, Math.log10(Math.max(c.values[i][k], 1e-6))));
        i ? ctx.lineTo(x, y) : ctx.moveTo(x, y);
      });
      ctx.stroke();
    });
    ctx.fillStyle = "#111";
    const where = [];
    for (const p of this.points()) {
      const [x, y] = this.px(p.x, Math.max(this.lo, p.y));
      ctx.beginPath(); ctx.arc(x, y, 3.5, 0, 2 * Math.PI); ctx.fill();
      where.push([+(x / this.canvas.width).toFixed(4), +(y / this.canvas.height).toFixed(4)]);
    }
    // the draggable points, as fractions of the canvas (for assistive tools and tests)
    this.canvas.dataset.points = JSON.stringify(where);
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
    this.drag = best;
    if (best >= 0) this.canvas.setPointerCapture(e.pointerId);
  }

  move(e) {
    if (this.drag < 0 || !this.material) return;
    const { my } = this.hit(e);
    const H = this.canvas.height;
    const r = this.canvas.getBoundingClientRect();
    const y = this.lo + (1 - ((my) - 10) / (H - 30)) * (this.hi - this.lo);
    const m = toCurve(this.material);
    const v = m.values[this.drag];
    const target = 10 ** Math.min(this.hi, Math.max(this.lo, y));
    const cur = Math.max(lum(v), 1e-6);
    m.values[this.drag] = lum(v) > 1e-6 ? v.map((x) => x * target / cur) : [target, target, target];
    this.material = m;
    this.draw();
    this.onChange(m);
  }
}

// Polar plot of f(ωi, ωo)·cosθo in the plane of incidence, ωi at thetaDeg on the −x side.
export function drawLobe(canvas, material, thetaDeg) {
  const ctx = canvas.getContext("2d");
  const { width: W, height: H } = canvas;
  ctx.clearRect(0, 0, W, H);
  const cx = W / 2, cy = H - 12, R = Math.min(W / 2, H) - 16;
  ctx.strokeStyle = "#ccc";
  ctx.beginPath(); ctx.arc(cx, cy, R, Math.PI, 2 * Math.PI); ctx.stroke();
  ctx.beginPath(); ctx.moveTo(cx - R, cy); ctx.lineTo(cx + R, cy); ctx.stroke();
  if (!material) return;
  const ti = thetaDeg * Math.PI / 180;
  const wi = [-Math.sin(ti), 0, Math.cos(ti)];
  ctx.strokeStyle = "#e90"; ctx.beginPath(); ctx.moveTo(cx, cy);
  ctx.lineTo(cx - R * Math.sin(ti), cy - R * Math.cos(ti)); ctx.stroke();
  const samples = [];
  for (let i = 0; i <= 180; i++) {
    const to = (i / 180) * Math.PI - Math.PI / 2;
    const wo = [Math.sin(to), 0, Math.cos(to)];
    samples.push([to, lum(evalBRDF(material, wi, wo)) * Math.cos(to)]);
  }
  const mx = Math.max(...samples.map((s) => s[1]), 1e-9);
  ctx.strokeStyle = "#227"; ctx.lineWidth = 1.5; ctx.beginPath();
  samples.forEach(([to, v], i) => {
    const r = R * v / mx, x = cx + r * Math.sin(to), y = cy - r * Math.cos(to);
    i ? ctx.lineTo(x, y) : ctx.moveTo(x, y);
  });
  ctx.stroke(); ctx.lineWidth = 1;
}
