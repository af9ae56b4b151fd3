// The viewer's live mode (publications published with "live": true): a read-only streaming
// session on a worker, with a free camera. The bundle player steps aside; swatches and the
// lighting menu then drive the session. Shoppers see no frame-rate or timing figures.
import { api, SessionStream } from "./net.js";
import { FrameView } from "./canvas.js";
import { orbit } from "./orbit.js";

export async function startLive(pubId, player, ui) {
  const session = await api(`/v1/publications/${pubId}/sessions`, { method: "POST" });
  let state = session.state;
  player.stop();
  const view = new FrameView(ui.canvas, null);
  const stream = new SessionStream(session, { onFrame: (f) => view.push(f), onEvent: (e) => {
    if (e.type === "error") { ui.status.classList.remove("hidden"); ui.status.textContent = e.message; }
  } });
  view.stream = stream;
  ui.canvas.dataset.mode = "live";
  // the session shows variant 0 and preset 0: make it show what the shopper picked
  stream.send("variant", { index: player.v });
  stream.send("environment", { index: player.e });
  ui.swatches.querySelectorAll(".swatch").forEach((b, i) => {
    b.onclick = () => {
      stream.send("variant", { index: i });
      ui.swatches.querySelectorAll(".swatch").forEach((x, j) => x.setAttribute("aria-pressed", String(j === i)));
    };
  });
  ui.environment.onchange = () => stream.send("environment", { index: +ui.environment.value });
  // the stage's pointer handlers belong to the player (stopped); these drive the camera
  let drag = null;
  ui.stage.addEventListener("pointerdown", (e) => { drag = { x: e.clientX, y: e.clientY }; });
  ui.stage.addEventListener("pointermove", (e) => {
    if (!drag) return;
    const dx = e.clientX - drag.x, dy = e.clientY - drag.y;
    drag = { x: e.clientX, y: e.clientY };
    state.camera = orbit(state.camera, -dx * 0.01, dy * 0.006);
    stream.send("view", { eye: state.camera.eye, drag: true });
  });
  ui.stage.addEventListener("pointerup", () => { drag = null; stream.send("view", { eye: state.camera.eye, drag: false }); });
  ui.screenshot.onclick = () => ui.canvas.toBlob((blob) => {
    const a = document.createElement("a");
    a.href = URL.createObjectURL(blob);
    a.download = "glint-live.png";
    document.body.append(a);
    a.click();
    setTimeout(() => { URL.revokeObjectURL(a.href); a.remove(); }, 1000);
  }, "image/png");
  ui.live.textContent = "Live";
}
