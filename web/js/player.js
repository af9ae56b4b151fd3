// The bundle player: a published object's turntable frames played in the browser. Dragging or
// swiping swaps frames that are already here (no request to any server beyond the static
// files); frames load progressively, the one on screen first, then its neighbours nearest
// first. Zoom (pinch, wheel, the +/− buttons, double tap) and high-DPI screens use the 2× set.
// The manifest format is documented in docs/guides/publishing.md. Standalone (no imports), so a
// downloaded bundle's index.html runs it from any static host.

// a 1 × 1 AVIF (Pillow, speed 10): browsers that decode it get the AVIF sets, others the JPEG frames
const AVIF_PROBE = "data:image/avif;base64,AAAAIGZ0eXBhdmlmAAAAAGF2aWZtaWYxbWlhZk1BMUIAAADrbWV0YQAAAAAAAAAhaGRscgAAAAAAAAAAcGljdAAAAAAAAAAAAAAAAAAAAAAOcGl0bQAAAAAAAQAAAB5pbG9jAAAAAEQAAAEAAQAAAAEAAAETAAAAIQAAAChpaW5mAAAAAAABAAAAGmluZmUCAAAAAAEAAGF2MDFDb2xvcgAAAABqaXBycAAAAEtpcGNvAAAAFGlzcGUAAAAAAAAAAQAAAAEAAAAQcGl4aQAAAAADCAgIAAAADGF2MUOBAAwAAAAAE2NvbHJuY2x4AAEADQAGgAAAABdpcG1hAAAAAAAAAAEAAQQBAoMEAAAAKW1kYXQSAAoIGAAGiAhoNCAyExlHh4Yhh5555oJAAJBAyRxhQr4=";
const PARALLEL = 6;          // image loads at once (a browser's per-host limit)
const MAX_ZOOM = 2.5;

function avifSupported() {
  return new Promise((resolve) => {
    const im = new Image();
    im.onload = () => resolve(im.width === 1);
    im.onerror = () => resolve(false);
    im.src = AVIF_PROBE;
  });
}

export class BundlePlayer {
  /** canvas: the stage's canvas; manifest: the bundle manifest; files: the URL prefix of its
   *  files ("/v1/bundle-files/" on the service, "files/" in a downloaded bundle). */
  constructor(canvas, manifest, files, { avif = true } = {}) {
    this.canvas = canvas;
    this.ctx = canvas.getContext("2d");
    this.m = manifest;
    this.files = files;
    this.avif = avif;
    this.v = 0; this.e = 0;
    this.el = manifest.start?.elevation ?? 0;
    this.az = manifest.start?.azimuth ?? 0;
    this.zoom = 1; this.cx = 0.5; this.cy = 0.5;     // the view centre, in frame coordinates
    this.images = new Map();                            // url -> {img, ok, failed}
    this.loading = 0;
    this.drawn = 0;
    this.shown = null;                                  // url of the frame on screen
    this.onfirst = null;
    this.active = true;
    canvas.width = 2 * manifest.width;
    canvas.height = 2 * manifest.height;
    this.pump();
  }

  get A() { return this.m.azimuths_deg.length; }
  get E() { return this.m.elevations_deg.length; }

  /** Whether the 2× set is what the screen needs: zoomed in, or a stage wider in device
   *  pixels than the 1× frame by a quarter (a high-DPI screen, a large window). */
  get hi() {
    const px = (this.canvas.clientWidth || this.m.width) * (window.devicePixelRatio || 1);
    return this.avif && (this.zoom > 1.01 || px > 1.25 * this.m.width);
  }

  entry(v, e, el, az) { return this.m.frames[v][e][el][((az % this.A) + this.A) % this.A]; }

  url(f, two) { return this.files + (two ? f.avif2 : (this.avif ? f.avif1 : f.jpeg1)); }

  /** The files to have, most wanted first: the frame on screen, its ring by azimuth distance,
   *  then the other elevations' rings; with the 2× set after its 1× frame when needed. */
  *wanted() {
    const hi = this.hi, A = this.A;
    const order = [0];
    for (let d = 1; d <= A / 2; d++) { order.push(d); if (d !== A - d) order.push(-d); }
    const els = [this.el, ...[...Array(this.E).keys()].filter((x) => x !== this.el)
      .sort((a, b) => Math.abs(a - this.el) - Math.abs(b - this.el))];
    for (const el of els) {
      for (const d of order) {
        const f = this.entry(this.v, this.e, el, this.az + d);
        yield this.url(f, false);
        if (hi && el === this.el) yield this.url(f, true);
      }
    }
  }

  pump() {
    if (!this.active) return;
    for (const u of this.wanted()) {
      if (this.loading >= PARALLEL) return;
      if (this.images.has(u)) continue;
      const rec = { img: new Image(), ok: false, failed: false };
      this.images.set(u, rec);
      this.loading++;
      rec.img.decoding = "async";
      rec.img.onload = () => { rec.ok = true; this.loading--; this.draw(); this.pump(); };
      rec.img.onerror = () => { rec.failed = true; this.loading--; this.pump(); };
      rec.img.src = u;
    }
  }

  /** The best loaded image for the current view: its 2× or 1× frame, else the nearest loaded
   *  azimuth of the same ring (so a fast drag never shows a blank). */
  pick() {
    const want2 = this.hi;
    for (let d = 0; d <= this.A / 2; d++) {
      for (const s of d ? [d, -d] : [0]) {
        const f = this.entry(this.v, this.e, this.el, this.az + s);
        for (const two of want2 ? [true, false] : [false, true]) {
          if (two && !this.avif) continue;
          const u = this.url(f, two), r = this.images.get(u);
          if (r && r.ok) return { u, img: r.img, two, exact: s === 0 };
        }
      }
    }
    return null;
  }

  draw() {
    if (!this.active) return;
    const p = this.pick();
    if (!p) return;
    const c = this.canvas, g = this.ctx, z = this.zoom;
    const iw = p.img.naturalWidth, ih = p.img.naturalHeight;
    const sw = iw / z, sh = ih / z;
    const sx = Math.min(Math.max(this.cx * iw - sw / 2, 0), iw - sw);
    const sy = Math.min(Math.max(this.cy * ih - sh / 2, 0), ih - sh);
    g.imageSmoothingEnabled = true;
    g.imageSmoothingQuality = "high";
    g.drawImage(p.img, sx, sy, sw, sh, 0, 0, c.width, c.height);
    this.shown = p.u;
    this.drawn++;
    c.dataset.set = p.two ? "2x" : "1x";
    c.dataset.azimuth = String(this.az);
    c.dataset.elevation = String(this.el);
    c.dataset.drawn = String(this.drawn);
    if (this.drawn === 1) {
      performance.mark?.("glint-first-frame");     // read by `glint bench viewer --browser`
      if (this.onfirst) this.onfirst();
    }
  }

  /** Show another view: d azimuth steps, de elevation steps (clamped), without any request
   *  beyond the static frames. */
  turn(d, de = 0) {
    this.az = ((this.az + d) % this.A + this.A) % this.A;
    this.el = Math.min(this.E - 1, Math.max(0, this.el + de));
    this.draw();
    this.pump();
  }

  setVariant(i) { this.v = i; this.draw(); this.pump(); }
  setEnvironment(i) { this.e = i; this.draw(); this.pump(); }

  setZoom(z, fx = 0.5, fy = 0.5) {
    // keep the frame point under (fx, fy) of the stage where it is
    const old = this.zoom;
    z = Math.min(MAX_ZOOM, Math.max(1, z));
    const px = this.cx + (fx - 0.5) / old, py = this.cy + (fy - 0.5) / old;
    this.zoom = z;
    this.cx = px - (fx - 0.5) / z; this.cy = py - (fy - 0.5) / z;
    this.clampCentre();
    this.draw(); this.pump();
  }

  pan(dx, dy) {              // dx, dy: fractions of the stage
    this.cx -= dx / this.zoom; this.cy -= dy / this.zoom;
    this.clampCentre();
    this.draw();
  }

  clampCentre() {
    const h = 0.5 / this.zoom;
    this.cx = Math.min(1 - h, Math.max(h, this.cx));
    this.cy = Math.min(1 - h, Math.max(h, this.cy));
  }

  /** A PNG of the current view at the 2× resolution (the 2× frame, whole, not the zoomed
   *  part), as a Blob. */
  async screenshot() {
    const f = this.entry(this.v, this.e, this.el, this.az);
    const u = this.url(f, this.avif);
    const img = await new Promise((resolve, reject) => {
      const r = this.images.get(u);
      if (r && r.ok) return resolve(r.img);
      const im = new Image();
      im.onload = () => resolve(im); im.onerror = reject; im.src = u;
    });
    const c = document.createElement("canvas");
    c.width = 2 * this.m.width; c.height = 2 * this.m.height;
    c.getContext("2d").drawImage(img, 0, 0, c.width, c.height);
    return new Promise((resolve) => c.toBlob(resolve, "image/png"));
  }

  stop() { this.active = false; }
}

/** Pointer, touch and wheel control of a player on its stage: one pointer turns (or pans when
 *  zoomed), two pinch; the wheel and a double tap zoom. */
export function attachControls(player, stage) {
  const pts = new Map();
  let pinch = null, acc = { x: 0, y: 0 };
  const rect = () => stage.getBoundingClientRect();
  stage.addEventListener("pointerdown", (ev) => {
    stage.setPointerCapture(ev.pointerId);
    pts.set(ev.pointerId, { x: ev.clientX, y: ev.clientY });
    if (pts.size === 2) {
      const [a, b] = [...pts.values()];
      pinch = { d: Math.hypot(a.x - b.x, a.y - b.y), z: player.zoom };
    }
  });
  stage.addEventListener("pointermove", (ev) => {
    const p = pts.get(ev.pointerId);
    if (!p || !player.active) return;
    const dx = ev.clientX - p.x, dy = ev.clientY - p.y;
    p.x = ev.clientX; p.y = ev.clientY;
    const r = rect();
    if (pts.size >= 2 && pinch) {
      const [a, b] = [...pts.values()];
      const d = Math.hypot(a.x - b.x, a.y - b.y);
      player.setZoom(pinch.z * d / Math.max(1, pinch.d), ((a.x + b.x) / 2 - r.left) / r.width,
        ((a.y + b.y) / 2 - r.top) / r.height);
      return;
    }
    if (player.zoom > 1.01) { player.pan(dx / r.width, dy / r.height); return; }
    // a full turn over about 1.5 stage widths; an elevation step per fifth of its height
    const step = (1.5 * r.width) / player.A, estep = r.height / 5;
    acc.x += dx; acc.y += dy;
    const n = Math.trunc(acc.x / step), ne = Math.trunc(acc.y / estep);
    if (n || ne) {
      acc.x -= n * step; acc.y -= ne * estep;
      player.turn(-n, ne);
    }
  });
  const up = (ev) => { pts.delete(ev.pointerId); if (pts.size < 2) pinch = null; if (!pts.size) acc = { x: 0, y: 0 }; };
  stage.addEventListener("pointerup", up);
  stage.addEventListener("pointercancel", up);
  stage.addEventListener("wheel", (ev) => {
    ev.preventDefault();
    const r = rect();
    player.setZoom(player.zoom * Math.exp(-ev.deltaY * 0.002), (ev.clientX - r.left) / r.width, (ev.clientY - r.top) / r.height);
  }, { passive: false });
  stage.addEventListener("dblclick", (ev) => {
    const r = rect();
    player.setZoom(player.zoom > 1.01 ? 1 : 2, (ev.clientX - r.left) / r.width, (ev.clientY - r.top) / r.height);
  });
}

/** The viewer's controls (swatches with names, lighting presets, zoom buttons, screenshot)
 *  wired to a player. ui: {swatches, environment, zoomIn, zoomOut, screenshot}; name: the
 *  screenshot's file name. */
export function buildUi(player, ui, name) {
  const m = player.m;
  ui.swatches.replaceChildren();
  m.variants.forEach((v, i) => {
    const b = document.createElement("button");
    b.className = "swatch";
    b.setAttribute("aria-pressed", String(i === player.v));
    const dot = document.createElement("span");
    dot.className = "dot";
    dot.style.background = v.swatch || "#888";
    const label = document.createElement("span");
    label.className = "swatch-label";
    label.textContent = v.label;
    b.append(dot, label);
    b.onclick = () => {
      player.setVariant(i);
      ui.swatches.querySelectorAll(".swatch").forEach((x, j) => x.setAttribute("aria-pressed", String(j === i)));
    };
    ui.swatches.append(b);
  });
  ui.environment.replaceChildren(...m.environments.map((e, i) => new Option(e.label, String(i))));
  ui.environment.closest("label")?.classList.toggle("hidden", m.environments.length < 2);
  ui.environment.onchange = () => player.setEnvironment(+ui.environment.value);
  ui.zoomIn.onclick = () => player.setZoom(player.zoom * 1.5);
  ui.zoomOut.onclick = () => player.setZoom(player.zoom / 1.5);
  modelLinks(m, player.files, ui, name);
  ui.screenshot.onclick = async () => {
    const blob = await player.screenshot();
    const a = document.createElement("a");
    a.href = URL.createObjectURL(blob);
    a.download = `${(name || "glint").replace(/[^\w.-]+/g, "_")}.png`;
    document.body.append(a);
    a.click();
    setTimeout(() => { URL.revokeObjectURL(a.href); a.remove(); }, 1000);
  };
}

/** The published object's glTF model (every variant, KHR_materials_variants), offered to any
 *  3D viewer as a download, and on Android to Google's Scene Viewer (AR), which takes the
 *  file by its absolute URL. iOS Quick Look reads USDZ only, which bundles do not carry. */
export function modelLinks(m, files, ui, name, ua = navigator.userAgent) {
  const glb = m.model && m.model.glb;
  if (!ui.model || !glb) return;
  const url = new URL(files + glb, location.href);
  ui.model.href = url.href;
  ui.model.download = `${(name || "glint").replace(/[^\w.-]+/g, "_")}.glb`;
  ui.model.classList.remove("hidden");
  if (ui.ar && /Android/i.test(ua)) {
    const q = `file=${encodeURIComponent(url.href)}&mode=ar_preferred&title=${encodeURIComponent(name || "")}`;
    ui.ar.href = `intent://arvr.google.com/scene-viewer/1.0?${q}#Intent;scheme=https;` +
      "package=com.google.android.googlequicksearchbox;action=android.intent.action.VIEW;" +
      `S.browser_fallback_url=${encodeURIComponent(url.href)};end;`;
    ui.ar.classList.remove("hidden");
  }
}

export function uiElements(doc = document) {
  const $ = (id) => doc.getElementById(id);
  return { stage: $("stage"), canvas: $("view"), swatches: $("swatches"), environment: $("environment"),
    zoomIn: $("zoom-in"), zoomOut: $("zoom-out"), screenshot: $("screenshot"), status: $("status"), live: $("live"),
    model: $("model-file"), ar: $("ar") };
}

/** Play a manifest in the page's viewer markup; returns the player. */
export async function play(manifest, files, ui = uiElements()) {
  const avif = await avifSupported();
  ui.stage.style.aspectRatio = `${manifest.width} / ${manifest.height}`;
  const player = new BundlePlayer(ui.canvas, manifest, files, { avif });
  player.onfirst = () => { ui.status.textContent = ""; ui.status.classList.add("hidden"); };
  attachControls(player, ui.stage);
  buildUi(player, ui, manifest.name);
  document.title = manifest.name;
  window.glintViewer = player;          // for scripts on the page (and the browser tests)
  return player;
}

// a downloaded bundle: index.html names its manifest and files folder
const d = document.body?.dataset;
if (d && d.manifest) {
  fetch(d.manifest).then((r) => r.json()).then((m) => play(m, d.files || "files/"))
    .catch((err) => { const s = document.getElementById("status"); if (s) s.textContent = `cannot load the bundle: ${err.message}`; });
}
