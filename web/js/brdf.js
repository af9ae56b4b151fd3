// BRDF evaluation for the plots (the renderer's models of DESIGN.md §3, worker/core/brdf.py).
// Directions are local (z = normal). Values are 1/sr, RGB arrays.

const PI = Math.PI;
const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
const norm = (a) => { const l = Math.hypot(a[0], a[1], a[2]) || 1; return [a[0] / l, a[1] / l, a[2] / l]; };

function schlick(f0, c) { const m = Math.min(1, Math.max(0, 1 - c)); return f0 + (1 - f0) * m ** 5; }

function ggxD(ch, a) {
  if (ch <= 0) return 0;
  const a2 = a * a, d = ch * ch * (a2 - 1) + 1;
  return a2 / (PI * d * d);
}

function ggxG1(c, a) {
  const c2 = Math.max(c * c, 1e-12), t2 = Math.max(0, 1 - c2) / c2;
  return 2 / (1 + Math.sqrt(1 + a * a * t2));
}

// p(h) of the quotient models (srbf, curve)
function distribution(m, h) {
  if (m.model === "curve") {
    const k = m.values.length;
    const th = Math.acos(Math.min(1, Math.max(0, h[2])));
    return m.values[Math.min(k - 1, Math.floor(th * 2 * k / PI))];
  }
  const out = [0, 0, 0];
  for (let j = 0; j < m.centers.length; j++) {
    const c = norm(m.centers[j]);
    const g = Math.exp(m.bandwidth * (dot(h, c) - 1));
    if (g < 1e-7) continue;
    for (let k = 0; k < 3; k++) out[k] += m.coefficients[j][k] * g;
  }
  return out;
}

export function albedoOf(m) {
  return m.albedo || m.diffuse || [0, 0, 0];
}

export function evalBRDF(m, wi, wo) {
  const ci = wi[2], co = wo[2];
  if (ci <= 0 || co <= 0) return [0, 0, 0];
  const a = albedoOf(m);
  const f = [a[0] / PI, a[1] / PI, a[2] / PI];
  const h = norm([wi[0] + wo[0], wi[1] + wo[1], wi[2] + wo[2]]);
  let s = null;
  if (m.model === "ggx") {
    const v = ggxD(h[2], m.alpha) * ggxG1(ci, m.alpha) * ggxG1(co, m.alpha) / (4 * ci * co);
    s = m.specular.map((x) => x * v);
  } else if (m.model === "blinn-phong") {
    const v = (m.exponent + 8) / (8 * PI) * Math.max(0, h[2]) ** m.exponent;
    s = m.specular.map((x) => x * v);
  } else if (m.model === "lobes") {
    const rv = Math.min(1, Math.max(0, 2 * ci * co - dot(wi, wo)));
    s = [0, 0, 0];
    m.exponents.forEach((e, i) => {
      const v = (e + 2) / (2 * PI) * rv ** e;
      for (let k = 0; k < 3; k++) s[k] += v * (m.gloss[i] + m.directional_diffuse[i][k]);
    });
  } else if (m.model === "srbf" || m.model === "curve") {
    const q = schlick(m.fresnel_f0 ?? 1, dot(wi, h)) / Math.max(ci + co - ci * co, 1e-12);
    s = distribution(m, h).map((x) => x * q);
  }
  if (s) for (let k = 0; k < 3; k++) f[k] += s[k];
  return f;
}

// The 1D half-angle distribution to plot: the specular part at ωo = n, ωi at 2θh (so the
// quotient models show p(θh) itself), averaged over φh for srbf. Returns {theta, values}.
export function halfAngleCurve(m, n = 90) {
  const theta = [], values = [];
  for (let i = 0; i < n; i++) {
    const th = (i + 0.5) * (PI / 2) / n;
    theta.push(th * 180 / PI);
    if (m.model === "srbf" || m.model === "curve") {
      const acc = [0, 0, 0], K = m.model === "srbf" ? 16 : 1;
      for (let k = 0; k < K; k++) {
        const ph = 2 * PI * k / K;
        const p = distribution(m, [Math.sin(th) * Math.cos(ph), Math.sin(th) * Math.sin(ph), Math.cos(th)]);
        for (let c = 0; c < 3; c++) acc[c] += p[c] / K;
      }
      values.push(acc);
    } else {
      const wi = [Math.sin(2 * th), 0, Math.cos(2 * th)];
      const f = evalBRDF(m, wi, [0, 0, 1]);
      const a = albedoOf(m);
      values.push(f.map((x, c) => Math.max(0, x - a[c] / PI)));
    }
  }
  return { theta, values };
}

// A curve material that reproduces m's half-angle distribution on K bins (for editing).
export function toCurve(m, K = 24) {
  if (m.model === "curve") return structuredClone(m);
  const c = halfAngleCurve(m, K);
  return { model: "curve", values: c.values.map((v) => v.map((x) => Math.max(x, 0))),
           fresnel_f0: m.fresnel_f0 ?? 1, albedo: albedoOf(m).slice() };
}
