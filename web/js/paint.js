// The car-paint designer's studio pieces (cacad-cosine-lobes §1.1: BRDF designer, lobe
// visualiser, colour swatch palette), as self-contained ES modules. The studio wires them:
//   const panel = createPaintPanel(el, {object: "car", send: (msg) => ws.send(JSON.stringify(msg))});
//   on the session's "paint" event: panel.showEvent(ev); on its "curve" event: visualiser.update(ev.curve.lobe, m);
//   to keep it: palette.add({name, measurements: ev.measured, material: ev.material, swatch: ev.swatch}).
// Every BRDF value they show is the worker's (the curve event's lobe, the paint event's swatch):
// the browser draws, it does not evaluate.
// Measurements follow worker/paint/geometry.py: gloss in GU (ASTM D523 20°), aspecular readings
// as linear RGB reflectance factors (π·f) at 45° illumination (ASTM E2194).

export const ANGLES = ["-15", "15", "25", "45", "75", "110"];
const LUMA = [0.2126, 0.7152, 0.0722];

const srgbToLinear = (c) => (c <= 0.04045 ? c / 12.92 : ((c + 0.055) / 1.055) ** 2.4);
const linearToSrgb = (c) => (c <= 0.0031308 ? 12.92 * c : 1.055 * c ** (1 / 2.4) - 0.055);
const clamp01 = (x) => Math.min(1, Math.max(0, x));
const luma = (rgb) => rgb[0] * LUMA[0] + rgb[1] * LUMA[1] + rgb[2] * LUMA[2];

function hexToLinear(hex) {
  const v = parseInt(hex.slice(1), 16);
  return [(v >> 16) & 255, (v >> 8) & 255, v & 255].map((x) => srgbToLinear(x / 255));
}

function linearToHex(rgb) {
  const m = Math.max(...rgb, 1e-9);
  return "#" + rgb.map((x) => Math.round(255 * linearToSrgb(clamp01(x / m))).toString(16).padStart(2, "0")).join("");
}

function el(tag, attrs = {}, children = []) {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (k === "style") e.style.cssText = v;
    else if (k.startsWith("on")) e.addEventListener(k.slice(2), v);
    else e.setAttribute(k, v);
  }
  for (const c of children) e.append(c);
  return e;
}

// Paint panel: a gloss slider and, per aspecular angle, a hue (colour input) and a level
// (luminance reflectance factor, square-root slider 0…4). Every change emits a `paint` message.
export function createPaintPanel(container, { send, object = "", initial = null, angles = ANGLES } = {}) {
  let seq = 0;
  const state = initial
    ? structuredClone(initial)
    : { gloss: 85, aspecular: Object.fromEntries(angles.map((a) => [a, [0.1, 0.1, 0.1]])) };
  const root = el("div", { class: "paint-panel" });
  const status = el("div", { class: "paint-status" });
  const gl = el("input", { type: "range", min: "0", max: "100", step: "0.5", value: String(state.gloss), "aria-label": "gloss" });
  const glv = el("span", {}, [`${state.gloss} GU`]);
  gl.addEventListener("input", () => { state.gloss = +gl.value; glv.textContent = `${state.gloss} GU`; emit(); });
  root.append(el("label", { style: "display:block" }, ["Gloss (20°) ", gl, glv]));
  const rows = {};
  for (const a of angles) {
    const rgb = state.aspecular[a] || [0.1, 0.1, 0.1];
    const hue = el("input", { type: "color", value: linearToHex(rgb), "aria-label": `colour ${a}°` });
    const level = el("input", { type: "range", min: "0", max: "2", step: "0.001", value: String(Math.sqrt(luma(rgb))), "aria-label": `level ${a}°` });
    const out = el("span", { class: "paint-value" });
    const update = () => {
      const c = hexToLinear(hue.value);
      const y = (+level.value) ** 2;
      const l = Math.max(luma(c), 1e-6);
      state.aspecular[a] = c.map((x) => (x * y) / l);
      out.textContent = state.aspecular[a].map((x) => x.toFixed(3)).join(" ");
      emit();
    };
    hue.addEventListener("input", update);
    level.addEventListener("input", update);
    out.textContent = rgb.map((x) => x.toFixed(3)).join(" ");
    rows[a] = { hue, level, out };
    root.append(el("label", { class: "paint-angle", style: "display:block" }, [`${a}° `, hue, level, out]));
  }
  root.append(status);
  container.append(root);

  function message() {
    return { type: "paint", seq: ++seq, object, gloss: state.gloss, aspecular: structuredClone(state.aspecular) };
  }
  function emit() { if (send) send(message()); }

  return {
    element: root,
    get state() { return structuredClone(state); },
    // set the sliders from measurements (e.g. a swatch or a measured material) and emit once
    set(measurements, { silent = false } = {}) {
      state.gloss = measurements.gloss;
      gl.value = String(state.gloss); glv.textContent = `${(+state.gloss).toFixed(1)} GU`;
      for (const a of angles) {
        const v = measurements.aspecular[a];
        if (!v) continue;
        state.aspecular[a] = [...v];
        rows[a].hue.value = linearToHex(v);
        rows[a].level.value = String(Math.sqrt(luma(v)));
        rows[a].out.textContent = v.map((x) => x.toFixed(3)).join(" ");
      }
      if (!silent) emit();
    },
    // the session's answer: what the fitted paint measures and how far it is from the request.
    // Readings the fit cannot meet (ev.unmet, worker/paint/fit.py TOLERANCE) are named in the
    // status and marked on their row, with every reading's residual in the row's tooltip.
    showEvent(ev) {
      status.textContent = `fit ${ev.ms_fit.toFixed(2)} ms, error ${(100 * ev.error_l1).toFixed(2)}% (max ${(100 * ev.error_max).toFixed(1)}%)` +
        (ev.flop_index != null ? `, flop index ${ev.flop_index.toFixed(1)}` : "");
      const unmet = ev.unmet || [];
      status.classList.toggle("paint-warning", unmet.length > 0);
      if (ev.warning) status.textContent += ` — ${ev.warning}`;
      const res = ev.residuals?.aspecular || {};
      for (const a of angles) {
        const miss = unmet.some((u) => u.split(":")[0] === a);
        rows[a].out.classList.toggle("paint-unmet", miss);
        rows[a].out.style.color = miss ? "#f84" : "";
        rows[a].out.title = res[a] ? `fit − reading: ${res[a].map((r) => `${(100 * r).toFixed(1)}%`).join(" ")}` : "";
      }
      glv.classList.toggle("paint-unmet", unmet.includes("gloss"));
      glv.style.color = unmet.includes("gloss") ? "#f84" : "";
    },
  };
}

// Lobe visualiser: polar plot in the plane of incidence of the server's f(ωi, ωo)·cosθo (the
// `lobe` of the worker's `curve` event, worker/jobs/curves.py brdf_lobe: the BRDF the frame is
// rendered with), one curve per channel plus luminance, at the server's incident angle (of its
// rgb_theta_i_deg) nearest incidenceDeg; log radius (decades below the peak) so flakes and
// gloss both show. It draws, it does not evaluate.
export function createLobeVisualiser(canvas, { incidenceDeg = 45, decades = 4 } = {}) {
  let lobe = null, material = null;
  const ctx = canvas.getContext("2d");
  function draw() {
    const w = canvas.width, h = canvas.height, cx = w / 2, cy = h - 10, R = Math.min(w / 2, h) - 14;
    ctx.clearRect(0, 0, w, h);
    ctx.strokeStyle = "#ccc"; ctx.lineWidth = 1;        // on the studio's light plot background
    for (let d = 1; d <= decades; d++) { ctx.beginPath(); ctx.arc(cx, cy, (R * d) / decades, Math.PI, 2 * Math.PI); ctx.stroke(); }
    ctx.beginPath(); ctx.moveTo(cx - R, cy); ctx.lineTo(cx + R, cy); ctx.stroke();
    if (!lobe?.rgb) { delete canvas.dataset.drawn; return; }
    const angles = lobe.rgb_theta_i_deg;
    let k = 0;
    angles.forEach((t, i) => { if (Math.abs(t - incidenceDeg) < Math.abs(angles[k] - incidenceDeg)) k = i; });
    const ti = (angles[k] * Math.PI) / 180;
    ctx.strokeStyle = "#e90"; ctx.beginPath(); ctx.moveTo(cx, cy); ctx.lineTo(cx - R * Math.sin(ti), cy - R * Math.cos(ti)); ctx.stroke();
    const rgb = lobe.rgb[k];
    const curves = [0, 1, 2].map((c) => rgb.map((f) => f[c]));
    curves.push(rgb.map(luma));
    const vmax = Math.max(...curves[3], 1e-30);
    const colors = ["#d33", "#3a3", "#36d", "#222"];
    curves.forEach((vals, c) => {
      ctx.strokeStyle = colors[c]; ctx.lineWidth = c === 3 ? 2 : 1; ctx.beginPath();
      vals.forEach((v, i) => {
        const t = (lobe.theta_o_deg[i] * Math.PI) / 180;
        const r = (R * Math.max(0, decades + Math.log10(Math.max(v, 1e-30) / vmax))) / decades;
        const x = cx + r * Math.sin(t), y = cy - r * Math.cos(t);
        i ? ctx.lineTo(x, y) : ctx.moveTo(x, y);
      });
      ctx.stroke();
    });
    ctx.lineWidth = 1;
    // what was drawn, as received (for assistive tools and tests): the incident angle, the
    // server's RGB values at it, and the material they are of
    canvas.dataset.incident = String(angles[k]);
    canvas.dataset.drawn = JSON.stringify(rgb);
    canvas.dataset.material = JSON.stringify(material);
  }
  return {
    // lobe: a curve event's `lobe` (null: nothing evaluated yet); m: the material it is of
    update(l, m = null, inc) { lobe = l; material = m; if (inc != null) incidenceDeg = inc; draw(); },
    setIncidence(deg) { incidenceDeg = deg; draw(); },
  };
}

// Swatch palette: named collections of saved designs ({name, measurements, material, swatch}) in
// localStorage; each shown as its swatch, the worker's image of the paint on a sphere (a paint
// event's `swatch`, worker/paint/swatch.py); clicking one calls onSelect(design).
export function createSwatchPalette(container, { storageKey = "glint.paint.palette", onSelect } = {}) {
  const load = () => { try { return JSON.parse(localStorage.getItem(storageKey)) || {}; } catch { return {}; } };
  let collections = load();
  let active = Object.keys(collections)[0] || "My paints";
  const root = el("div", { class: "paint-palette" });
  const pick = el("select", { "aria-label": "collection" });
  const grid = el("div", { class: "paint-swatches", style: "display:flex;flex-wrap:wrap;gap:6px" });
  root.append(pick, grid);
  container.append(root);
  function save() { localStorage.setItem(storageKey, JSON.stringify(collections)); }
  function draw() {
    pick.replaceChildren(...Object.keys({ [active]: 1, ...collections }).map((c) => el("option", c === active ? { selected: "" } : {}, [c])));
    grid.replaceChildren();
    for (const d of collections[active] || []) {
      // a paint kept before swatches came from the worker has none: its name stands alone
      const img = d.swatch ? el("img", { src: d.swatch, width: "64", height: "64", alt: d.name, title: d.name })
        : el("div", { style: "width:64px;height:64px;border:1px dashed #888", title: d.name });
      img.addEventListener("click", () => onSelect && onSelect(d));
      grid.append(el("figure", { style: "margin:0;text-align:center" }, [img, el("figcaption", {}, [d.name])]));
    }
  }
  pick.addEventListener("change", () => { active = pick.value; draw(); });
  draw();
  return {
    element: root,
    get collections() { return structuredClone(collections); },
    useCollection(name) { active = name; draw(); },
    add(design) {                       // design: {name, measurements, material, swatch} (a paint event)
      (collections[active] ||= []).push({ name: design.name, measurements: design.measurements, material: design.material,
        swatch: design.swatch || "" });
      save(); draw();
    },
    remove(name) { collections[active] = (collections[active] || []).filter((d) => d.name !== name); save(); draw(); },
  };
}

// A design's measurements for paint formulation, as worker.paint.geometry.export_measurements.
export function exportMeasurements(m, fmt = "json") {
  const angles = Object.keys(m.aspecular).sort((a, b) => +a - +b);
  if (fmt === "csv") {
    const lines = ["geometry,angle_deg,r,g,b,value", `gloss_D523,20,,,,${m.gloss}`];
    for (const a of angles) lines.push(`aspecular_45,${a},${m.aspecular[a].join(",")},`);
    return lines.join("\n") + "\n";
  }
  return JSON.stringify({ gloss: m.gloss, aspecular: Object.fromEntries(angles.map((a) => [a, m.aspecular[a]])),
    geometry: { illumination_deg: 45, gloss: "ASTM D523 20°", aspecular: "ASTM E2194 (reflectance factor π·f, linear RGB)" } }, null, 1) + "\n";
}

export function downloadMeasurements(m, name, fmt = "json") {
  const blob = new Blob([exportMeasurements(m, fmt)], { type: fmt === "csv" ? "text/csv" : "application/json" });
  const a = el("a", { href: URL.createObjectURL(blob), download: `${name}.${fmt}` });
  a.click();
  URL.revokeObjectURL(a.href);
}
