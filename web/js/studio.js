// The studio: pick or upload a scene, orbit and relight it, paint strokes, edit the material
// and its curve, save versioned designs and publish them for the shopper viewer.
import { api, SessionStream } from "./net.js";
import { FrameView } from "./canvas.js";
import { CurveEditor, drawLobe } from "./curve.js";
import { toCurve } from "./brdf.js";
import { orbit } from "./orbit.js";
import { createLobeVisualiser, createPaintPanel, createSwatchPalette, downloadMeasurements } from "./paint.js";
import { mountCapturePanel } from "./capture.js";
import { MoveDrag, fullTransform } from "./move.js";
import { mountExportPanel } from "./export.js";

const $ = (id) => document.getElementById(id);
const status = (t) => { $("status").textContent = t; };

let session = null, stream = null, state = null, material = null, designId = null;
const saved = [];                 // design ids saved from this page (publish candidates)
const view = new FrameView($("view"), $("readout"));
const overlay = $("overlay").getContext("2d");

const srgbToLinear = (c) => (c <= 0.04045 ? c / 12.92 : ((c + 0.055) / 1.055) ** 2.4);
const hexToLinear = (hex) => [1, 3, 5].map((i) => srgbToLinear(parseInt(hex.slice(i, i + 2), 16) / 255));

// -- scenes --------------------------------------------------------------------------------------
async function listScenes(select) {
  const scenes = await api("/v1/scenes");
  const sel = $("scene-select");
  sel.innerHTML = "";
  for (const s of scenes) {
    const p = s.precomputation;
    const o = new Option(`${s.name || s.id} — ${p ? p.status : "not precomputed"}`, s.id);
    o.disabled = !p || p.status !== "done";
    sel.append(o);
  }
  const ready = scenes.find((s) => s.id === select) || scenes.find((s) => s.name === "demo" && s.precomputation?.status === "done")
    || scenes.find((s) => s.precomputation?.status === "done");
  if (ready) sel.value = ready.id;
  return { scenes, ready };
}

async function waitPrecompute(sceneId) {
  const bar = $("progress");
  bar.classList.remove("hidden");
  for (;;) {
    const s = await api(`/v1/scenes/${sceneId}`);
    const p = s.precomputation;
    if (p) {
      bar.value = p.progress;
      status(`precomputing ${s.name || s.id}: ${Math.round(100 * p.progress)}% ${p.message}`);
      if (p.status === "done") break;
      if (p.status === "failed") throw new Error(`precomputation failed: ${p.message}`);
    }
    await new Promise((r) => setTimeout(r, 700));
  }
  bar.classList.add("hidden");
}

async function upload() {
  const mesh = $("mesh-file").files[0], env = $("env-file").files[0];
  if (!mesh || !env) return status("choose a mesh and an HDRI first");
  try {
    status(`uploading ${mesh.name}…`);
    const m = await api(`/v1/assets/meshes?filename=${encodeURIComponent(mesh.name)}`, { method: "POST", raw: mesh });
    status(`uploading ${env.name}…`);
    const e = await api(`/v1/assets/envmaps?filename=${encodeURIComponent(env.name)}`, { method: "POST", raw: env });
    const [lo, hi] = m.meta.bounds;
    const c = lo.map((x, i) => (x + hi[i]) / 2), r = Math.hypot(...hi.map((x, i) => x - lo[i])) / 2;
    const scene = { version: 1, environment: { map: e.id },
      camera: { eye: [c[0], c[1] + 0.4 * r, c[2] + 2.8 * r], target: c, up: [0, 1, 0], fov_y_deg: 40, width: 640, height: 480 },
      objects: [{ name: mesh.name.replace(/\.[^.]+$/, ""), mesh: m.id, material: { model: "lambert", albedo: [0.6, 0.6, 0.6] } }],
      ground: { shadow: true } };
    const s = await api(`/v1/scenes?name=${encodeURIComponent(mesh.name)}`, { method: "POST", body: scene });
    await api(`/v1/scenes/${s.id}/precompute`, { method: "POST" });
    await waitPrecompute(s.id);
    await listScenes(s.id);
    await openScene(s.id);
  } catch (err) { status(`upload failed: ${err.message}`); }
}

async function openScene(id) {
  if (stream) stream.close();
  status("opening a session…");
  session = await api("/v1/sessions", { method: "POST", body: { scene_id: id } });
  state = session.state;
  designId = null;
  $("versions").innerHTML = "";
  const scene = await api(`/v1/scenes/${id}`);
  const objIdx = Math.max(0, scene.spec.objects.findIndex((o) => o.name === state.object));
  setMaterial(state.materials[objIdx]);
  $("shadow").checked = state.shadow ?? scene.spec.ground?.shadow ?? false;
  showMoveTool(state.movable || []);
  stream = new SessionStream(session, {
    onFrame: (f) => { $("shadow").disabled = f.header.shadow == null; view.push(f); },
    onEvent: onEvent,
    onState: (s) => status(`${state.object}: ${s}`),
  });
  view.stream = stream;
}

// the fit's figures, so a designer sees why a stroke is only partly achieved: the share of the
// requested change the fit reached, the change that spilled onto unpainted pixels, and each
// channel's specular albedo against that channel's bound
export function fitSummary(s) {
  if (!s.strokes) return "no strokes";
  const parts = [`fit: ${s.strokes} stroke(s), ${s.painted} painted px, solve ${s.ms_solve?.toFixed(1)} ms`];
  if (s.achieved != null) parts.push(`achieved ${Math.round(100 * s.achieved)}% of the change`);
  if (s.spill != null) parts.push(`spill ${Math.round(100 * s.spill)}% onto unpainted pixels`);
  if (!s.constrained) parts.push("unconstrained");
  else if (s.energy_per_channel && s.energy_bound_per_channel) {
    parts.push("specular albedo R/G/B " + s.energy_per_channel.map((e, c) =>
      `${e.toFixed(2)}≤${s.energy_bound_per_channel[c].toFixed(2)}`).join(" "));
  }
  return parts.join(", ");
}

// -- renderers: what this session's renderer lets the designer change -------------------------------
let controls = new Set(["camera", "light", "materials", "environment"]), renderers = ["cuts"], rendererKind = "cuts";
const RENDERER_NAMES = { cuts: "direct light (visibility cuts)", gi: "global illumination", paint: "car paint (prefiltered lobes)" };
function showRenderer(kind, ctl, available) {
  rendererKind = kind; controls = new Set(ctl); if (available) renderers = available;
  const fixed = !controls.has("camera");
  $("renderer-info").textContent = RENDERER_NAMES[kind] || kind;
  if (fixed) $("renderer-info").textContent += " — view and light are fixed by the precomputation; edit materials";
  document.querySelectorAll("#tool-orbit, #tool-light").forEach((e) => { e.disabled = fixed; });
  if (fixed && tool() !== "brush") $("tool-brush").checked = true;
  const other = renderers.find((k) => k !== kind);
  const sw = $("renderer-switch");
  sw.classList.toggle("hidden", !other);
  if (other) { sw.textContent = `Switch to ${RENDERER_NAMES[other] || other}`; sw.onclick = () => stream?.send("renderer", { kind: other }); }
}

// -- paint designer and lighting capture ------------------------------------------------------------
let paintPanel = null, lastPaint = null;
const lobeView = createLobeVisualiser($("paint-lobe"));
const palette = createSwatchPalette($("paint-palette"), { onSelect: (d) => paintPanel?.set(d.measurements) });
function mountPaint(object, initial) {
  $("paint-panel").innerHTML = "";
  paintPanel = createPaintPanel($("paint-panel"), { object, initial,
    // the panel numbers its own messages; the stream gives them the session's seq
    send: ({ type, seq, ...fields }) => stream?.send("paint", fields) });
}
$("paint-keep").onclick = () => {
  if (!lastPaint) return status("move a paint slider first");
  const name = $("design-name").value || "paint";
  palette.add({ name, measurements: lastPaint.measured, material: lastPaint.material });
  stream?.send("save", { name, material_id: designId });
};
$("paint-export-json").onclick = () => lastPaint && downloadMeasurements(lastPaint.measured, $("design-name").value || "paint", "json");
$("paint-export-csv").onclick = () => lastPaint && downloadMeasurements(lastPaint.measured, $("design-name").value || "paint", "csv");
mountCapturePanel($("capture-panel"), { api, onApply: (assetId) => stream?.send("environment", { asset_id: assetId }) });

let movableNames = [];   // movable objects of the scene (hello), shown when the renderer allows move

function onEvent(ev) {
  if (ev.type === "hello") {
    showRenderer(ev.renderer || "cuts", ev.controls || [], ev.renderers);
    mountPaint(ev.state.object, ev.state.paint?.[ev.state.object] || null);
    state.transforms = ev.state.transforms || state.transforms;
    movableNames = ev.state.movable || [];
    showMoveTool((ev.controls || []).includes("move") ? movableNames : []);
  } else if (ev.type === "renderer") {
    showRenderer(ev.kind, ev.controls);
    showMoveTool((ev.controls || []).includes("move") ? movableNames : []);
    status(`now drawing with ${RENDERER_NAMES[ev.kind] || ev.kind}`);
  } else if (ev.type === "paint") {
    lastPaint = ev;
    setMaterial(ev.material);
    paintPanel?.showEvent(ev);
    lobeView.update(ev.material, 45);
    status(`paint: fitted in ${ev.ms_fit.toFixed(1)} ms, error ${(100 * ev.error_l1).toFixed(1)}%`);
  } else if (ev.type === "fit") {
    setMaterial(ev.material);
    // the figures and the notes together: the notes say why a stroke fell short
    status([fitSummary(ev.stats || {}), ...(ev.notes || [])].join("; "));
  } else if (ev.type === "stroke" && ev.notes?.length) {
    status(ev.notes.join("; "));
  } else if (ev.type === "saved") {
    designId = ev.material_id;
    if (!saved.includes(designId)) saved.push(designId);
    status(`saved “${ev.name}” version ${ev.version}`);
    loadVersions();
  } else if (ev.type === "error") {
    status(`error: ${ev.message}`);
  } else if (ev.type === "note") {
    status(ev.message);
  }
}

// -- moving objects (scene objects with "movable": true) ------------------------------------------
let movable = [];
function showMoveTool(names) {
  movable = names;
  const on = movable.length > 0;
  for (const id of ["move-tool", "move-pick", "move-hint"]) $(id).classList.toggle("hidden", !on);
  const sel = $("move-object");
  if (on && [...sel.options].map((o) => o.value).join() !== movable.join()) {
    sel.innerHTML = "";
    for (const name of movable) sel.append(new Option(name, name));
  }
  if (!on && tool() === "move") $("tool-orbit").checked = true;
}
let pendingMove = null;
function sendMove(drag) {
  // one message per animation frame while dragging; the last one (drag: false) always goes out
  const name = $("move-object").value;
  const send = () => { pendingMove = null; stream?.send("move", { object: name, transform: state.transforms[name], drag }); };
  if (!drag) { pendingMove = null; return send(); }
  if (!pendingMove) pendingMove = requestAnimationFrame(send);
}

// -- camera, light, display -----------------------------------------------------------------------
let dragging = null, strokePts = [];
const tool = () => document.querySelector("input[name=tool]:checked").value;

$("view").addEventListener("pointerdown", (e) => {
  if (!stream) return;
  $("view").setPointerCapture(e.pointerId);
  const mode = tool() === "brush" ? "brush" : tool() === "move" && movable.length ? "move"
    : (e.altKey || tool() === "light" ? "light" : "orbit");
  dragging = { mode, x: e.clientX, y: e.clientY };
  if (mode === "brush") { strokePts = [view.toFrame(e, state.camera.width, state.camera.height)]; drawStroke(); }
  if (mode === "move") {
    const name = $("move-object").value;
    state.transforms = state.transforms || {};
    dragging.move = new MoveDrag(state.camera);
    dragging.turning = e.shiftKey;
    dragging.move.start(...view.toFrame(e, state.camera.width, state.camera.height), fullTransform(state.transforms[name]));
  }
});
$("view").addEventListener("pointermove", (e) => {
  if (!dragging) return;
  const dx = e.clientX - dragging.x, dy = e.clientY - dragging.y;
  if (dragging.mode === "brush") {
    strokePts.push(view.toFrame(e, state.camera.width, state.camera.height));
    drawStroke();
    return;
  }
  if (dragging.mode === "move") {
    const name = $("move-object").value, [px, py] = view.toFrame(e, state.camera.width, state.camera.height);
    if (e.shiftKey !== dragging.turning) {          // Shift pressed or released mid-drag
      dragging.turning = e.shiftKey;
      dragging.move.rebase(px, py, state.transforms[name]);
    }
    state.transforms = { ...state.transforms, [name]: dragging.move.to(px, py, dragging.turning) };
    sendMove(true);
    return;
  }
  dragging.x = e.clientX; dragging.y = e.clientY;
  if (dragging.mode === "orbit") {
    state.camera = orbit(state.camera, -dx * 0.01, dy * 0.01);
    stream.send("view", { eye: state.camera.eye, drag: true });
  } else {
    state.rotation_deg = (state.rotation_deg || 0) + dx * 0.5;
    stream.send("light", { rotation_deg: state.rotation_deg, drag: true });
  }
});
$("view").addEventListener("pointerup", () => {
  if (!dragging) return;
  const mode = dragging.mode;
  dragging = null;
  if (mode === "brush") return sendStroke();
  if (mode === "move") return sendMove(false);
  if (mode === "orbit") stream.send("view", { eye: state.camera.eye, drag: false });
  else stream.send("light", { rotation_deg: state.rotation_deg, drag: false });
});
let wheelEnd = null;
$("view").addEventListener("wheel", (e) => {
  if (!stream) return;
  e.preventDefault();
  state.camera = orbit(state.camera, 0, 0, Math.exp(e.deltaY * 0.001));
  // zooming is a drag: fast frames while the wheel turns, a still (anti-aliased) one after
  stream.send("view", { eye: state.camera.eye, drag: true });
  clearTimeout(wheelEnd);
  wheelEnd = setTimeout(() => stream?.send("view", { eye: state.camera.eye, drag: false }), 150);
}, { passive: false });
$("exposure").addEventListener("input", () => stream?.send("display", { exposure: +$("exposure").value }));
$("tone").addEventListener("change", () => stream?.send("display", { tone: $("tone").value }));
$("shadow").addEventListener("change", () => stream?.send("display", { shadow: $("shadow").checked }));

// -- brush -------------------------------------------------------------------------------------------
function drawStroke() {
  const c = $("overlay");
  overlay.clearRect(0, 0, c.width, c.height);
  if (!strokePts.length) return;
  const s = c.width / state.camera.width;
  overlay.strokeStyle = $("brush-sign").value === "1" ? "rgba(255,255,255,0.55)" : "rgba(20,20,20,0.55)";
  overlay.lineWidth = +$("brush-diameter").value * s;
  overlay.lineCap = overlay.lineJoin = "round";
  overlay.beginPath();
  strokePts.forEach(([x, y], i) => (i ? overlay.lineTo(x * s, y * s) : overlay.moveTo(x * s, y * s)));
  if (strokePts.length === 1) overlay.lineTo(strokePts[0][0] * s + 0.1, strokePts[0][1] * s);
  overlay.stroke();
}

function sendStroke() {
  const k = +$("brush-strength").value * +$("brush-sign").value;
  const color = hexToLinear($("brush-color").value).map((x) => x * k);
  stream.send("stroke", { stroke: { points: strokePts.slice(0, 10000), color, diameter: +$("brush-diameter").value,
    kappa: +$("brush-kappa").value, mode: $("brush-mode").value, scale: +$("brush-scale").value } });
  setTimeout(() => { strokePts = []; drawStroke(); }, 250);
}
$("undo").onclick = () => stream?.send("undo");
$("redo").onclick = () => stream?.send("redo");
document.addEventListener("keydown", (e) => {
  if ((e.ctrlKey || e.metaKey) && e.key.toLowerCase() === "z") { e.preventDefault(); stream?.send(e.shiftKey ? "redo" : "undo"); }
});
const sendFit = () => stream?.send("fit", { constrained: $("constrained").checked, unpainted_weight: +$("unpainted-weight").value });
$("constrained").onchange = sendFit;
$("unpainted-weight").onchange = sendFit;

// -- material panel ----------------------------------------------------------------------------------
// the models, their controls and defaults come from the server (GET /v1/models): a model added
// on the server appears here without a change to the studio
let MODELS = {};
async function loadModels() {
  const list = await api("/v1/models");
  MODELS = Object.fromEntries(list.map((m) => [m.model, m]));
  const sel = $("model");
  sel.innerHTML = "";
  for (const m of list) {
    // a curve starts from the current BRDF; other models without defaults come from elsewhere (strokes, paint)
    const o = new Option(m.creatable || m.model === "curve" ? m.label : `${m.label} (not editable here)`, m.model);
    o.disabled = !(m.creatable || m.model === "curve");
    sel.append(o);
  }
}
const toHex = (rgb) => "#" + rgb.map((c) => Math.round(255 * Math.min(1, Math.max(0, c <= 0.0031308 ? 12.92 * c : 1.055 * c ** (1 / 2.4) - 0.055))).toString(16).padStart(2, "0")).join("");

const curveEditor = new CurveEditor($("curve"), (m) => { setMaterial(m, false); queueMaterial(); });
let pendingMaterial = false;
function queueMaterial() {
  if (pendingMaterial) return;
  pendingMaterial = true;
  requestAnimationFrame(() => { pendingMaterial = false; stream?.send("material", { material }); });
}

function setMaterial(m, rebuild = true) {
  material = structuredClone(m);
  $("model").value = m.model;
  if (rebuild) buildParams();
  curveEditor.set(material);
  drawLobe($("lobe"), material, +$("lobe-angle").value);
}

function buildParams() {
  const box = $("params");
  box.innerHTML = "";
  for (const { name: key, kind, min: lo, max: hi, step } of (MODELS[material.model] || {}).controls || []) {
    const label = document.createElement("label");
    label.textContent = key;
    const input = document.createElement("input");
    input.id = `param-${key}`;
    if (kind === "color") { input.type = "color"; input.value = toHex(material[key] || [0, 0, 0]); }
    else { Object.assign(input, { type: "range", min: lo, max: hi, step, value: material[key] ?? lo }); }
    input.addEventListener("input", () => {
      material[key] = kind === "color" ? hexToLinear(input.value) : +input.value;
      curveEditor.set(material);
      drawLobe($("lobe"), material, +$("lobe-angle").value);
      queueMaterial();
    });
    label.append(input);
    box.append(label);
  }
}
$("model").addEventListener("change", () => {
  const model = $("model").value;
  // a curve starts from the current BRDF's half-angle distribution, so the look carries over
  if (model === "curve") setMaterial(toCurve(material));
  else setMaterial(structuredClone(MODELS[model].default));
  queueMaterial();
});
$("lobe-angle").addEventListener("input", () => drawLobe($("lobe"), material, +$("lobe-angle").value));

// -- designs -------------------------------------------------------------------------------------------
$("save").onclick = () => stream?.send("save", { name: $("design-name").value || "design", material_id: designId });
async function loadVersions() {
  if (!designId) return;
  const vs = await api(`/v1/materials/${designId}/versions`);
  const ul = $("versions");
  ul.innerHTML = "";
  for (const v of vs.reverse()) {
    const li = document.createElement("li");
    li.textContent = `v${v.version} · ${v.material.model} · ${new Date(v.created).toLocaleTimeString()}`;
    const b = document.createElement("button");
    b.textContent = "load";
    b.onclick = () => { setMaterial(v.material); stream.send("material", { material: v.material }); };
    li.append(b);
    ul.append(li);
  }
}
$("publish").onclick = async () => {
  if (!saved.length) return status("save a design first");
  try {
    const p = await api("/v1/publications", { method: "POST", body: { name: $("design-name").value || "designs",
      scene_id: session.scene_id, object: state.object, variants: saved.map((id) => ({ material_id: id })) } });
    const a = $("publish-link");
    a.href = p.viewer; a.textContent = `open the viewer (${p.variants.length} variant${p.variants.length > 1 ? "s" : ""})`;
    a.classList.remove("hidden");
    status(`published ${p.id}`);
  } catch (err) { status(`publish failed: ${err.message}`); }
};
mountExportPanel($("export-panel"), () => ({ sceneId: session?.scene_id, object: state?.object, designs: saved }), status);

$("open-scene").onclick = () => $("scene-select").value && openScene($("scene-select").value);
$("upload").onclick = upload;

// -- start -----------------------------------------------------------------------------------------------
// On a first start the demo scene is still being fetched and precomputed: show its progress and
// open it by itself when it is ready (no reload).
async function waitDemo() {
  const bar = $("progress");
  for (;;) {
    const { demo } = await api("/v1/status");
    if (!["fetching", "precomputing"].includes(demo.state)) { bar.classList.add("hidden"); return demo; }
    bar.classList.remove("hidden");
    bar.value = demo.progress || 0;
    status(`${demo.message} (${Math.round(100 * (demo.progress || 0))}%) — the demo opens by itself when it is ready`);
    await new Promise((r) => setTimeout(r, 700));
  }
}

(async () => {
  try {
    await loadModels();
    for (;;) {
      const { scenes, ready } = await listScenes();
      if (ready) { await openScene(ready.id); break; }
      const demo = await waitDemo();
      if (demo.state === "ready") continue;
      const pending = scenes.find((s) => s.precomputation && ["queued", "running"].includes(s.precomputation.status));
      if (pending) { await waitPrecompute(pending.id); continue; }
      status(demo.state === "failed" ? `${demo.message}; upload a mesh and an HDRI instead` : "no scene yet: upload a mesh and an HDRI");
      break;
    }
  } catch (err) { status(`error: ${err.message}`); }
})();
