// The shopper viewer: a published object under an environment preset; drag to turn it, swatches
// to switch variants, a screenshot. Read-only: the session accepts nothing that edits a design.
import { api, SessionStream } from "./net.js";
import { FrameView } from "./canvas.js";
import { orbit } from "./orbit.js";
import { fitCanvases, followCanvasSize } from "./framesize.js";

// a swatch's colour: the material's own diffuse colour (a field, not an evaluation)
const albedoOf = (m) => m.albedo || m.diffuse || [0, 0, 0];

const $ = (id) => document.getElementById(id);
const pubId = location.pathname.split("/").filter(Boolean).pop();
const view = new FrameView($("view"), $("readout"));
let stream, state, pub;

const toCss = (rgb) => `rgb(${rgb.map((c) => Math.round(255 * Math.min(1, Math.max(0, c <= 0.0031308 ? 12.92 * c : 1.055 * c ** (1 / 2.4) - 0.055)))).join(",")})`;

async function start() {
  pub = await api(`/v1/publications/${pubId}`);
  document.title = `${pub.name} · Glint viewer`;
  const session = await api(`/v1/publications/${pubId}/sessions`, { method: "POST" });
  state = session.state;
  stream = new SessionStream(session, { onFrame: (f) => {
    // the toggle shows for scenes with a ground; it starts as the frames are drawn
    if (f.header.shadow != null && $("shadow-toggle").classList.contains("hidden")) {
      $("shadow-toggle").classList.remove("hidden");
      $("shadow").checked = f.header.shadow;
    }
    fitCanvases(f.header, $("view"));
    view.push(f);
  }, onEvent: (e) => {
    if (e.type === "hello") { camOk = !!e.controls?.includes("camera"); frameSize.now(); }
    if (e.type === "error") $("readout").textContent = e.message;
  } });
  view.stream = stream;
  const sw = $("swatches");
  pub.variants.forEach((v, i) => {
    const b = document.createElement("button");
    b.className = "swatch";
    b.title = v.label;
    b.setAttribute("aria-label", v.label);
    b.setAttribute("aria-pressed", String(i === 0));
    b.style.background = toCss(albedoOf(v.material).map((a, k) => a + (v.material.specular ? v.material.specular[k] * 0.3 : 0)));
    b.onclick = () => {
      stream.send("variant", { index: i });
      sw.querySelectorAll(".swatch").forEach((x, j) => x.setAttribute("aria-pressed", String(j === i)));
    };
    sw.append(b);
  });
  const env = $("environment");
  pub.environments.forEach((e, i) => env.append(new Option(e.label, i)));
  env.onchange = () => stream.send("environment", { index: +env.value });
}

// frames at the canvas's size times the device pixel ratio (the server caps the pixels)
let camOk = false;            // the renderer has a free camera (a GI publication's is fixed)
const frameSize = followCanvasSize($("view"), {
  allowed: () => !!stream && camOk,
  send: (width, height) => stream?.send("view", { width, height }),
});

let drag = null;
$("view").addEventListener("pointerdown", (e) => { drag = { x: e.clientX, y: e.clientY }; $("view").setPointerCapture(e.pointerId); });
$("view").addEventListener("pointermove", (e) => {
  if (!drag || !stream) return;
  const dx = e.clientX - drag.x, dy = e.clientY - drag.y;
  drag = { x: e.clientX, y: e.clientY };
  state.camera = orbit(state.camera, -dx * 0.01, dy * 0.006);
  stream.send("view", { eye: state.camera.eye, drag: true });
});
$("view").addEventListener("pointerup", () => { drag = null; stream?.send("view", { eye: state.camera.eye, drag: false }); });

$("shadow").onchange = () => stream?.send("display", { shadow: $("shadow").checked });

$("screenshot").onclick = () => {
  $("view").toBlob((blob) => {
    const a = document.createElement("a");
    a.href = URL.createObjectURL(blob);
    a.download = `${(pub?.name || "glint").replace(/[^\w.-]+/g, "_")}.png`;
    document.body.append(a);
    a.click();
    setTimeout(() => { URL.revokeObjectURL(a.href); a.remove(); }, 1000);
  }, "image/png");
};

start().catch((err) => { $("readout").textContent = `cannot open the viewer: ${err.message}`; });
