// The studio: pick or upload a scene, orbit and relight it, paint strokes, edit the material
// and its curve, save versioned designs and publish them for the shopper viewer.
import { api, SessionStream } from "./net.js";
import { FrameView } from "./canvas.js";
import { CurveEditor, drawLobe } from "./curve.js";
import { orbit } from "./orbit.js";
import { createLobeVisualiser, createPaintPanel, createSwatchPalette, downloadMeasurements } from "./paint.js";
import { mountCapturePanel } from "./capture.js";
import { MoveDrag, fullTransform } from "./move.js";
import { applyPeer, forget, lastSession, remember, reopen, sessionOf, setUrl, urlState } from "./persist.js";
import { mountDesigns } from "./designs.js";
import { createStatus, packPanels } from "./layout.js";
import { imageFraction, isClick, mountObjects } from "./objects.js";
import { fitCanvases, followCanvasSize } from "./framesize.js";
import { mountSceneCreate } from "./scenecreate.js";
import { mountExportPanel } from "./export.js";

const $ = (id) => document.getElementById(id);
const status = createStatus($("status"), $("status-panel"));
packPanels(document.querySelector("main.studio aside"));

let session = null, stream = null, state = null, material = null;
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

// a precomputation's first look (GET …/preview), drawn once while it runs
let previewShown = null;
async function showPreview(url) {
  if (!url || previewShown === url) return;
  previewShown = url;
  try { await view.showPreview(await api(url)); } catch (err) { console.warn("no preview:", err.message); }
}

async function waitPrecompute(sceneId) {
  const bar = $("progress");
  bar.classList.remove("hidden");
  for (;;) {
    const s = await api(`/v1/scenes/${sceneId}`);
    const p = s.precomputation;
    if (p) {
      bar.value = p.progress;
      if (p.stats?.preview) await showPreview(`/v1/precomputations/${p.id}/preview`);
      status(`precomputing ${s.name || s.id}: ${Math.round(100 * p.progress)}% ${p.message}` +
             (p.stats?.preview ? " (a first look is shown; the final image follows)" : ""));
      if (p.status === "done") break;
      if (p.status === "failed") throw new Error(`precomputation failed: ${p.message}`);
    }
    await new Promise((r) => setTimeout(r, 700));
  }
  bar.classList.add("hidden");
}

// a new session of scene ``id`` (the URL names it from now on; design: a design to put on it)
async function openScene(id, design = null, version = null) {
  if (stream) stream.close();
  status("opening a session…");
  const s = await api("/v1/sessions", { method: "POST", body: { scene_id: id } });
  remember(s);
  setUrl({ session: s.id, scene: id, design: null, version: null });
  await startSession(s);
  await designs.start(design, version, true);
}

// stream session ``s`` (new, or reopened with what the server stored)
async function startSession(s) {
  if (stream) stream.close();
  view.reset();
  session = s;
  state = session.state;
  const id = session.scene_id;
  const scene = await api(`/v1/scenes/${id}`);
  sceneSpec = scene.spec;
  const objIdx = Math.max(0, scene.spec.objects.findIndex((o) => o.name === state.object));
  setMaterial(state.materials[objIdx], true, null);         // its curve comes from the worker
  objects.show(state.objects, state.object);
  $("shadow").checked = state.shadow ?? scene.spec.ground?.shadow ?? false;
  $("exposure").value = state.exposure ?? 0;
  showMoveTool(state.movable || []);
  stream = new SessionStream(session, {
    onFrame: (f) => {
      showShadowToggle(f.header.shadow != null);
      // a full frame sets the canvases' pixels and the camera's size the strokes are drawn in
      if (fitCanvases(f.header, $("view"), $("overlay")) && controls.has("camera")) {
        state.camera = { ...state.camera, width: f.header.width, height: f.header.height };
      }
      view.push(f);
    },
    onEvent: onEvent,
    onState: (s) => {
      status(`${state.object}: ${s}`);
      // the server closed it, or cannot draw it: "/" opens a new one
      if (s.startsWith("closed: 4404") || s.startsWith("closed: 4409")) forget(session.id);
    },
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
  if (s.painting) parts.push(`region “${s.painting}”`);
  // a region fit short of the change is fitted again in parts after its frame (a second fit event)
  if (s.refined_in_parts) parts.push(`in ${s.parts} parts (one BRDF each)`);
  else if (s.parts_later) parts.push("fitting it in parts…");
  if (s.spill != null) parts.push(`spill ${Math.round(100 * s.spill)}% onto unpainted pixels`);
  if (s.spill_far != null) parts.push(`${Math.round(100 * s.spill_far)}% beyond one brush diameter`);
  if (!s.constrained) parts.push("unconstrained");
  else if (s.energy_per_channel && s.energy_bound_per_channel) {
    parts.push("specular albedo R/G/B " + s.energy_per_channel.map((e, c) =>
      `${e.toFixed(2)}≤${s.energy_bound_per_channel[c].toFixed(2)}`).join(" "));
  }
  return parts.join(", ");
}

// the ground shadow toggle: off, with the reason, when the frame has no ground shadow to show
let sceneSpec = null;
const SHADOW_TITLE = $("shadow").closest("label").title;
function showShadowToggle(on) {
  $("shadow").disabled = !on;
  const why = rendererKind !== "cuts" ? `${RENDERER_NAMES[rendererKind] || rendererKind} draws none`
    : !sceneSpec?.ground ? "this scene has no ground (a \"ground\" in its scene file)"
    : movableNames.length ? "scenes with movable objects have none yet (it would change as they move)" : "none was precomputed";
  $("shadow").closest("label").title = on ? SHADOW_TITLE : `no ground shadow: ${why}`;
}

// -- renderers: what this session's renderer lets the designer change -------------------------------
let controls = new Set(["camera", "light", "materials", "environment"]), renderers = ["cuts"], rendererKind = "cuts";
const RENDERER_NAMES = { cuts: "direct light (visibility cuts)", gi: "global illumination", paint: "car paint (prefiltered lobes)" };
// each tool and the control it needs: a renderer without it turns the tool off, with its reason
const TOOL_NEEDS = { "tool-orbit": "camera", "tool-light": "light", "tool-brush": "strokes", "tool-move": "move" };
function showRenderer(kind, ctl, available, off = {}) {
  rendererKind = kind; controls = new Set(ctl); if (available) renderers = available;
  $("renderer-info").textContent = RENDERER_NAMES[kind] || kind;
  for (const [id, need] of Object.entries(TOOL_NEEDS)) {
    const input = $(id), on = controls.has(need);
    input.disabled = !on;
    input.closest("label").title = on ? "" : off[need] || `not available with ${RENDERER_NAMES[kind] || kind}`;
    input.closest("label").classList.toggle("off", !on);
  }
  // never leave a tool selected that the renderer rejects: the first one it offers, else none
  // (a click still picks an object)
  if (document.querySelector("input[name=tool]:checked")?.disabled) {
    const first = [...document.querySelectorAll("input[name=tool]")].find((e) => !e.disabled);
    document.querySelectorAll("input[name=tool]").forEach((e) => { e.checked = e === first; });
  }
  const ul = $("renderer-off");
  ul.innerHTML = "";
  for (const [what, why] of Object.entries(off)) {
    const li = document.createElement("li");
    li.textContent = `${what}: ${why}`;
    ul.append(li);
  }
  const other = renderers.find((k) => k !== kind);
  const sw = $("renderer-switch");
  sw.classList.toggle("hidden", !other);
  if (other) { sw.textContent = `Switch to ${RENDERER_NAMES[other] || other}`; sw.onclick = () => stream?.send("renderer", { kind: other }); }
}

const objects = mountObjects($("object-select"), { send: (t, f) => stream?.send(t, f), status });
const frameSize = followCanvasSize($("view"), {
  allowed: () => !!stream && controls.has("camera"),
  send: (width, height) => stream?.send("view", { width, height }),
});

// -- paint designer and lighting capture ------------------------------------------------------------
let paintPanel = null, lastPaint = null;
const lobeView = createLobeVisualiser($("paint-lobe"));
const palette = createSwatchPalette($("paint-palette"), { onSelect: (d) => paintPanel?.set(d.measurements) });
function mountPaint(object, initial) {
  $("paint-panel").innerHTML = "";
  paintPanel = createPaintPanel($("paint-panel"), { object, initial,
    // the panel numbers its own messages; the stream gives them the session's seq
    send: ({ type, seq, ...fields }) => { stream?.send("paint", fields); designs.edited(); } });
}
$("paint-keep").onclick = () => {
  if (!lastPaint) return status("move a paint slider first");
  const name = $("design-name").value || "paint";
  palette.add({ name, measurements: lastPaint.measured, material: lastPaint.material, swatch: lastPaint.swatch });
  stream?.send("save", { name, material_id: designs.current() });
};
$("paint-export-json").onclick = () => lastPaint && downloadMeasurements(lastPaint.measured, $("design-name").value || "paint", "json");
$("paint-export-csv").onclick = () => lastPaint && downloadMeasurements(lastPaint.measured, $("design-name").value || "paint", "csv");
mountCapturePanel($("capture-panel"), { api, onApply: (assetId) => stream?.send("environment", { asset_id: assetId }) });

let movableNames = [];   // movable objects of the scene (hello), shown when the renderer allows move

function onEvent(ev) {
  if (ev.type === "hello") {
    hideGuidance();                    // a new session: an earlier stroke's offers are not its own
    // what the server stored (a reopened session: the camera, light and material left there)
    Object.assign(state, ev.state);
    const i = state.objects ? state.objects.indexOf(state.object) : -1;
    if (i >= 0 && state.materials?.[i]) setMaterial(state.materials[i]);
    if (state.exposure != null) $("exposure").value = state.exposure;
    if (state.tone) $("tone").value = state.tone;
    if (ev.strokes || ev.streams > 1) {
      // the worker replays the strokes (their fit views) before the session's first frame
      status(`${state.object}: ${ev.strokes} stroke(s) restored` + (ev.streams > 1 ? `; ${ev.streams} tabs share this session` : "")
             + (view.drawn ? "" : " (its first frame follows)"));
    }
    showRenderer(ev.renderer || "cuts", ev.controls || [], ev.renderers, ev.off || {});
    // a reopened session's regions are listed at once (not after its next fit)
    if (i >= 0 && state.materials?.[i]) showRegions(state.materials[i], state.region ?? null);
    objects.show(state.objects, state.object);     // the menu names the object the session edits
    mountPaint(ev.state.object, ev.state.paint?.[ev.state.object] || null);
    state.transforms = ev.state.transforms || state.transforms;
    movableNames = ev.state.movable || [];
    showMoveTool((ev.controls || []).includes("move") ? movableNames : []);
    frameSize.now();          // the stream is open: frames at the canvas's size from now on
  } else if (ev.type === "renderer") {
    showRenderer(ev.kind, ev.controls, null, ev.off || {});
    frameSize.now();
    showMoveTool((ev.controls || []).includes("move") ? movableNames : []);
    status(`now drawing with ${RENDERER_NAMES[ev.kind] || ev.kind}`);
  } else if (ev.type === "peer") {
    applyPeer(ev.message, { state, setMaterial, editedObject: () => state.object,
      setControl: (id, v) => { if (id === "shadow") $(id).checked = v; else $(id).value = v; } });
  } else if (ev.type === "paint") {
    lastPaint = ev;
    setMaterial(ev.material);
    paintPanel?.showEvent(ev);          // its lobe plot follows with the curve event
    status(`paint: fitted in ${ev.ms_fit.toFixed(1)} ms, error ${(100 * ev.error_l1).toFixed(1)}%` +
      (ev.warning ? ` — ${ev.warning}` : ""));
  } else if (ev.type === "curve") {
    if (ev.object === state.object) { curveEditor.set(material, ev.curve); curveData = ev.curve; drawLobePlot(); }
  } else if (ev.type === "converted") {
    if (ev.object === state.object) setMaterial(ev.material, true, ev.curve);
    status(`${ev.object}: now ${MODELS[ev.material.model]?.label || ev.material.model}, fitted to the old look ` +
      `(its colour in this view kept; albedo within ${(100 * ev.albedo_error).toFixed(1)}%)`);
  } else if (ev.type === "object") {
    state.object = ev.object;
    objects.selected(ev.object);
    setMaterial(ev.material, true, ev.curve);
    showRegions(ev.material);                      // the list is the edited object's
    mountPaint(ev.object, state.paint?.[ev.object] || null);
    status(`editing ${ev.object}` + (ev.strokes ? ` (${ev.strokes} stroke${ev.strokes > 1 ? "s" : ""} of its own)` : ""));
  } else if (ev.type === "exposure") {
    state.exposure = ev.exposure;
    $("exposure").value = ev.exposure;
    status(`exposure ${ev.exposure >= 0 ? "+" : ""}${ev.exposure.toFixed(2)} EV: ${ev.reason}`);
  } else if (ev.type === "picked") {
    objects.picked(ev);
  } else if (ev.type === "fit") {
    if (ev.object !== state.object) return;
    setMaterial(ev.material, true, ev.curve);
    showRegions(ev.material, ev.stats?.painting);
    // the figures and the notes together: the notes say why a stroke fell short
    status([fitSummary(ev.stats || {}), ...(ev.notes || [])].join("; "));
  } else if (ev.type === "guidance") {
    if (ev.object === state.object) showGuidance(ev);
  } else if (ev.type === "stroke" && ev.notes?.length) {
    status(ev.notes.join("; "));
  } else if (ev.type === "saved") {
    designs.onSaved(ev);
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
// A gesture keeps the frame size it started in (strokeSize, the Move tool's camera): a frame of a
// new size can arrive mid-gesture (the canvas was resized, or the first full frame after opening),
// and points in two sizes would draw a broken stroke or make a dragged object jump. The server
// rescales a stroke from its ``frame`` size to the camera's.
let dragging = null, strokePts = [], strokeSize = null, pressed = null;
const tool = () => document.querySelector("input[name=tool]:checked")?.value || "none";

$("view").addEventListener("pointerdown", (e) => {
  if (!stream) return;
  $("view").setPointerCapture(e.pointerId);
  const mode = tool() === "brush" ? "brush" : tool() === "move" && movable.length ? "move"
    : !controls.has("camera") ? "fixed" : (e.altKey || tool() === "light" ? "light" : "orbit");
  dragging = { mode, x: e.clientX, y: e.clientY };
  pressed = { x: e.clientX, y: e.clientY, t: performance.now() };
  if (mode === "brush") {
    strokeSize = [state.camera.width, state.camera.height];
    strokePts = [view.toFrame(e, ...strokeSize)];
    drawStroke();
  }
  if (mode === "move") {
    const name = $("move-object").value;
    state.transforms = state.transforms || {};
    const cam = { ...state.camera };
    dragging.move = new MoveDrag(cam, { cssPerFramePx: $("view").getBoundingClientRect().width / cam.width });
    dragging.turning = e.shiftKey;
    dragging.move.start(...view.toFrame(e, cam.width, cam.height), fullTransform(state.transforms[name]));
  }
});
$("view").addEventListener("pointermove", (e) => {
  if (!dragging) return;
  const dx = e.clientX - dragging.x, dy = e.clientY - dragging.y;
  if (dragging.mode === "brush") {
    strokePts.push(view.toFrame(e, ...strokeSize));
    drawStroke();
    return;
  }
  if (dragging.mode === "move") {
    const cam = dragging.move.cam, name = $("move-object").value, [px, py] = view.toFrame(e, cam.width, cam.height);
    if (e.shiftKey !== dragging.turning) {          // Shift pressed or released mid-drag
      dragging.turning = e.shiftKey;
      dragging.move.rebase(px, py, state.transforms[name]);
    }
    state.transforms = { ...state.transforms, [name]: dragging.move.to(px, py, dragging.turning) };
    sendMove(true);
    return;
  }
  if (dragging.mode === "fixed") return;          // a fixed view: a click picks, a drag does nothing
  dragging.x = e.clientX; dragging.y = e.clientY;
  if (dragging.mode === "orbit") {
    state.camera = orbit(state.camera, -dx * 0.01, dy * 0.01);
    stream.send("view", { eye: state.camera.eye, drag: true });
  } else {
    state.rotation_deg = (state.rotation_deg || 0) + dx * 0.5;
    stream.send("light", { rotation_deg: state.rotation_deg, drag: true });
  }
});
$("view").addEventListener("pointerup", (e) => {
  if (!dragging) return;
  const mode = dragging.mode;
  dragging = null;
  // a click (no drag) outside the brush picks the object under it
  if (mode !== "brush" && isClick(pressed, e)) { stream.send("pick", imageFraction($("view"), e)); if (mode !== "move") return; }
  if (mode === "brush") return sendStroke();
  if (mode === "move") return sendMove(false);
  if (mode === "fixed") return;
  if (mode === "orbit") stream.send("view", { eye: state.camera.eye, drag: false });
  else stream.send("light", { rotation_deg: state.rotation_deg, drag: false });
});
let wheelEnd = null;
$("view").addEventListener("wheel", (e) => {
  if (!stream || !controls.has("camera")) return;
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
  // the stroke's pixels to the overlay's (same vertical field of view: scaled about the centre)
  const [w, h] = strokeSize || [state.camera.width, state.camera.height], s = c.height / h;
  const X = (x) => c.width / 2 + (x - w / 2) * s;
  overlay.strokeStyle = $("brush-sign").value === "1" ? "rgba(255,255,255,0.55)" : "rgba(20,20,20,0.55)";
  overlay.lineWidth = +$("brush-diameter").value * s;
  overlay.lineCap = overlay.lineJoin = "round";
  overlay.beginPath();
  strokePts.forEach(([x, y], i) => (i ? overlay.lineTo(X(x), y * s) : overlay.moveTo(X(x), y * s)));
  if (strokePts.length === 1) overlay.lineTo(X(strokePts[0][0]) + 0.1, strokePts[0][1] * s);
  overlay.stroke();
}

function sendStroke() {
  hideGuidance();
  const k = +$("brush-strength").value * +$("brush-sign").value;
  const color = hexToLinear($("brush-color").value).map((x) => x * k);
  stream.send("stroke", { stroke: { points: strokePts.slice(0, 10000), color, diameter: +$("brush-diameter").value,
    kappa: +$("brush-kappa").value, mode: $("brush-mode").value, scale: +$("brush-scale").value },
    frame: strokeSize || [state.camera.width, state.camera.height] });
  setTimeout(() => { strokePts = []; drawStroke(); }, 250);
  designs.edited();
}
// (edits made in this tab mark the design edited, for autosave; another tab's, in that tab)
const undoRedo = (kind) => { hideGuidance(); stream?.send(kind); designs.edited(); };
$("undo").onclick = () => undoRedo("undo");
$("redo").onclick = () => undoRedo("redo");
document.addEventListener("keydown", (e) => {
  if ((e.ctrlKey || e.metaKey) && e.key.toLowerCase() === "z") { e.preventDefault(); undoRedo(e.shiftKey ? "redo" : "undo"); }
});
// -- guidance (docs/guides/regions.md): a highlight the light cannot give, and what would -------------
// the offers a guidance event makes: a rotation of the environment that puts more light near the
// painted pixels' mirror directions (10 points more of the highlight, as the note says), and a
// painted region when the stroke fitted one BRDF for the whole object
const hideGuidance = () => $("guidance").classList.add("hidden");
function showGuidance(ev) {
  $("guidance-text").textContent = ev.message;
  const rot = $("guidance-rotate"), turn = ev.covered_at_rotation != null && ev.covered_at_rotation > ev.covered + 0.1;
  rot.classList.toggle("hidden", !turn || !controls.has("light"));
  rot.textContent = `Rotate the light to ${Math.round(ev.rotate_to_deg)}°`;
  rot.onclick = () => {
    state.rotation_deg = ev.rotate_to_deg;
    stream?.send("light", { rotation_deg: state.rotation_deg, drag: false });
    status(`light turned to ${Math.round(ev.rotate_to_deg)}°: paint the highlight again`);
    hideGuidance();
  };
  const reg = $("guidance-region");
  reg.classList.toggle("hidden", !ev.region || $("region-paint").checked);
  reg.onclick = () => {
    $("region-paint").checked = true;
    $("region-paint").onchange();
    hideGuidance();
  };
  $("guidance").classList.remove("hidden");
}
$("guidance-close").onclick = hideGuidance;
// -- painted regions under GI traced into the light transport (docs/guides/regions.md): a new scene,
// this one with the objects' materials as the session has them and the edited object's regions in
// gi.painted, precomputed, then opened (the regions then light the rest of the scene as painted)
$("region-trace").onclick = async () => {
  const obj = state.object, btn = $("region-trace");
  btn.disabled = true;
  try {
    const [sc, ses] = await Promise.all([api(`/v1/scenes/${session.scene_id}`),
      api(`/v1/sessions/${session.id}`, { headers: { "X-Session-Token": session.token } })]);
    const spec = structuredClone(sc.spec);
    spec.objects.forEach((o, k) => { if (ses.state.materials?.[k]) o.material = ses.state.materials[k]; });
    // shown as the designer sees it now, not exposed anew
    if (typeof ses.state.exposure === "number") spec.exposure = ses.state.exposure;
    const i = spec.objects.findIndex((o) => o.name === obj);
    spec.objects[i].material = material;
    spec.gi = { ...(spec.gi || {}),
      painted: [...(spec.gi?.painted || []).filter((p) => p.object !== obj), { object: obj, material }] };
    const name = `${(sc.name || sc.id).replace(/ · regions traced$/, "")} · regions traced`;
    status(`tracing the regions of ${obj}: a new scene, "${name}"…`);
    const s = await api(`/v1/scenes?name=${encodeURIComponent(name)}`, { method: "POST", body: spec });
    await api(`/v1/scenes/${s.id}/precompute`, { method: "POST" });
    await waitPrecompute(s.id);
    await listScenes(s.id);
    await openScene(s.id);
  } catch (err) {
    status(`tracing the regions failed: ${err.message}`);
  } finally {
    btn.disabled = false;
  }
};
// -- painted regions (docs/guides/regions.md): strokes make or extend the named region ---------------
const regionName = () => $("region-name").value.trim().replaceAll("/", " ") || "region 1";
$("region-paint").onchange = () => {
  stream?.send("region", $("region-paint").checked ? { action: "paint", name: regionName() } : { action: "stop" });
  designs.edited();
};
function showRegions(material, painting) {
  const names = [...new Set((material?.model === "regions" ? material.regions : []).map((r) => r.name.split("/")[0]))];
  $("region-trace").classList.toggle("hidden", !(rendererKind === "gi" && names.length > 0));
  if (painting !== undefined) $("region-paint").checked = painting != null;
  const list = $("region-list");
  list.replaceChildren(...names.map((n) => {
    const li = document.createElement("li");
    li.dataset.region = n;
    const pick = document.createElement("a");
    pick.textContent = n + (n === painting ? " (painting)" : "");
    pick.onclick = () => { $("region-name").value = n; $("region-paint").checked = true; stream?.send("region", { action: "paint", name: n }); };
    // a region step: sent, and the design marked edited
    const step = (text, action, fields, title = "") => {
      const b = Object.assign(document.createElement("button"), { textContent: text, className: `region-${action}`, title });
      b.onclick = () => { stream?.send("region", { action, name: n, ...fields() }); designs.edited(); };
      return b;
    };
    const rename = step("Rename", "rename", () => ({ new_name: regionName() }));
    const erase = step("Erase", "erase", () => ({}));
    const merge = step("Merge", "merge", () => ({ new_name: regionName() }),
                       "merge this region into the region named above (its material, both footprints)");
    const pickMaterial = document.createElement("select");
    pickMaterial.className = "region-material";
    pickMaterial.title = "give this region a material: a model's defaults, or a saved design from the library";
    pickMaterial.append(new Option("material…", ""));
    fillRegionMaterials(pickMaterial);
    pickMaterial.onchange = () => {
      const m = regionMaterials.get(pickMaterial.value);
      pickMaterial.value = "";
      if (!m) return;
      stream?.send("region", { action: "material", name: n, material: m });
      designs.edited();
    };
    li.append(pick, " ", rename, erase, merge, pickMaterial);
    return li;
  }));
}
// the materials a region can take (undo takes the step back): every creatable model's defaults
// and the saved designs of the library (GET /v1/materials; a design with regions gives its base)
const regionMaterials = new Map();
async function fillRegionMaterials(sel) {
  for (const m of Object.values(MODELS)) {
    if (!m.default) continue;
    regionMaterials.set(`model:${m.model}`, m.default);
    sel.append(new Option(`${m.label} (defaults)`, `model:${m.model}`));
  }
  let lib = [];
  try { lib = await api("/v1/materials"); } catch { return; }
  for (const d of lib) {
    if (!d.material) continue;
    regionMaterials.set(`design:${d.id}`, d.material.model === "regions" ? d.material.base : d.material);
    sel.append(new Option(`${d.name} (design, v${d.version})`, `design:${d.id}`));
  }
}
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

// the curve editor draws the worker's curve of the material; a drag on another model asks the
// worker to convert the look to a curve first
const curveEditor = new CurveEditor($("curve"), {
  onChange: (m) => { setMaterial(m, false); queueMaterial(); },
  onNeedCurve: () => { status("converting to a curve…"); stream?.send("convert", { model: "curve" }); },
});
let curveData = null;             // the worker's curve of the edited object's material
// both lobe plots draw the worker's lobe of the material its curve was evaluated for
const drawLobePlot = () => {
  drawLobe($("lobe"), curveData?.lobe, +$("lobe-angle").value);
  lobeView.update(curveData?.lobe || null, curveEditor.base);
};
let pendingMaterial = false;
function queueMaterial() {
  if (pendingMaterial) return;
  pendingMaterial = true;
  requestAnimationFrame(() => { pendingMaterial = false; stream?.send("material", { material }); });
  designs.edited();
}

// curve: the worker's curve of m (undefined: not known yet, the last one stays until it comes)
function setMaterial(m, rebuild = true, curve) {
  material = structuredClone(m);
  $("model").value = m.model;
  if (rebuild) buildParams();
  curveEditor.set(material, curve);
  if (curve !== undefined) curveData = curve;
  drawLobePlot();
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
      curveEditor.set(material);          // its curve follows from the worker (a curve event)
      queueMaterial();
    });
    label.append(input);
    box.append(label);
  }
}
$("model").addEventListener("change", () => {
  // the worker fits the new model to the current look (a converted event), never a reset
  const model = $("model").value;
  $("model").value = material.model;        // until the converted material arrives
  status(`converting to ${MODELS[model]?.label || model}…`);
  stream?.send("convert", { model });
});
$("lobe-angle").addEventListener("input", drawLobePlot);

// -- designs (designs.js) -------------------------------------------------------------------------------
const designs = mountDesigns({ status, send: (type, f) => stream?.send(type, f), session: () => session, state: () => state,
  applyMaterial: (m) => { setMaterial(m); stream?.send("material", { material: m }); } });
mountExportPanel($("export-panel"), () => ({ sceneId: session?.scene_id, object: state?.object, designs: designs.chosen() }), status);

// Open: the session this browser last edited on that scene, with its strokes, undo history and
// design (a designer who looks at another scene and comes back finds their work); else a new one
$("open-scene").onclick = async () => {
  const id = $("scene-select").value;
  if (!id) return;
  const prev = sessionOf(id);
  if (prev && prev.session !== session?.id) {
    if (stream) { stream.close(); stream = null; }
    const { session: s } = await reopen(prev.session);
    if (s) {
      setUrl({ session: s.id, scene: id, design: prev.design, version: prev.version });
      await startSession(s);
      await designs.start(prev.design, prev.version, false);
      return;
    }
  }
  await openScene(id);
};
mountSceneCreate($("scene-panel"), { api, status, waitPrecompute,
  onCreated: async (id) => { await listScenes(id); await openScene(id); } });

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
    if (demo.preview) await showPreview(demo.preview);
    status(`${demo.message} (${Math.round(100 * (demo.progress || 0))}%) — ` +
           (demo.preview ? "a first look is shown; the demo opens by itself when it is ready" : "the demo opens by itself when it is ready"));
    await new Promise((r) => setTimeout(r, 700));
  }
}

// the session the URL names (else the last one this browser edited), reopened with what the server
// stored; else a new session of a ready scene (with the design the URL names, if any)
async function resume() {
  const url = urlState();
  const want = url.session ? url : (url.design ? null : lastSession());
  if (want?.session) {
    const { session: s, why } = await reopen(want.session);
    if (s) {
      setUrl({ session: s.id, scene: s.scene_id, design: want.design, version: want.version });
      await listScenes(s.scene_id);
      await startSession(s);
      await designs.start(want.design, want.version, false);
      return true;
    }
    if (url.session) status(`${why}; opening a new session` + (url.scene && !url.design ? " of the same scene" : ""));
    setUrl({ session: null });
  }
  if (url.design) {
    try {
      const d = await api(`/v1/materials/${url.design}`);
      if (await openIfReady(d.scene_id, d.id, url.version)) return true;
    } catch (err) { status(`design ${url.design}: ${err.message}`); }
  }
  // a session this browser cannot reopen: a new one of the scene it was on, not whichever
  // scene is the default
  if (url.scene && await openIfReady(url.scene)) return true;
  return false;
}

// a new session of scene ``id`` if it is precomputed (with a design on it); false if not
async function openIfReady(id, design = null, version = null) {
  const { ready } = await listScenes(id);
  if (ready?.id !== id || ready.precomputation?.status !== "done") return false;
  await openScene(id, design, version);
  return true;
}

(async () => {
  try {
    await loadModels();
    if (await resume()) return;
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
