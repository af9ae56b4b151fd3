// The shopper viewer on the service (/view/{publication}): plays the publication's static
// bundle (player.js); no session, no worker. Where the publisher allowed it, "Live view" opens
// a read-only streaming session with a free camera (viewer-live.js, loaded only then).
import { play, uiElements } from "./player.js";

const FILES = "/v1/bundle-files/";
const pubId = location.pathname.split("/").filter(Boolean).pop();
const ui = uiElements();

async function manifest() {
  // while the first build runs there is no manifest yet (409): say how far it is and wait
  for (;;) {
    const r = await fetch(`/v1/publications/${pubId}/manifest`);
    if (r.ok) return r.json();
    const body = await r.json().catch(() => ({}));
    if (r.status !== 409) throw new Error(body.detail || r.statusText);
    if (/failed/.test(body.detail || "")) throw new Error(body.detail);
    // shoppers see how far it is, not the service's message (ids, states)
    const pct = /\((\d+)%\)/.exec(body.detail || "");
    ui.status.textContent = `Preparing this product's images…${pct ? ` ${pct[1]}%` : ""}`;
    await new Promise((res) => setTimeout(res, 2000));
  }
}

async function start() {
  const m = await manifest();
  const player = await play(m, FILES, ui);
  if (m.live) {
    ui.live.classList.remove("hidden");
    ui.live.onclick = async () => {
      ui.live.disabled = true;
      const { startLive } = await import("./viewer-live.js");
      await startLive(pubId, player, ui);
    };
  }
}

start().catch((err) => {
  // the cause is for the page's developers (the console); shoppers get a sentence
  console.error("Glint viewer:", err);
  ui.status.classList.remove("hidden");
  ui.status.textContent = "This product's images cannot be shown right now.";
});
