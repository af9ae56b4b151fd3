// Frame pacing: frames arrive when the server makes them; the newest one is drawn on the next
// animation frame and older undrawn ones are dropped. A small readout shows fps and latency.

export class FrameView {
  constructor(canvas, readout) {
    this.canvas = canvas;
    this.ctx = canvas.getContext("2d");
    this.readout = readout;
    this.pending = null;
    this.drawn = 0;
    this.dropped = 0;
    this.times = [];
    this.header = null;
    this.stream = null;
    requestAnimationFrame(() => this.tick());
  }

  push(frame) {
    if (this.pending) {
      this.pending.bitmap.close();
      this.dropped++;
    }
    this.pending = frame;
  }

  tick() {
    const f = this.pending;
    if (f) {
      this.pending = null;
      // drag frames come at half resolution: scale every frame to the canvas
      this.ctx.imageSmoothingEnabled = true;
      this.ctx.drawImage(f.bitmap, 0, 0, this.canvas.width, this.canvas.height);
      f.bitmap.close();
      this.header = f.header;
      this.drawn++;
      const now = performance.now();
      this.times.push(now);
      while (this.times.length && now - this.times[0] > 1000) this.times.shift();
      this.canvas.dataset.samples = String(f.header.samples);
      this.canvas.dataset.quick = String(!!f.header.quick);
      this.canvas.dataset.settled = String(!!f.header.settled);
      this.canvas.dataset.frame = String(f.header.frame);
      this.canvas.dataset.ack = String(f.header.ack);
      delete this.canvas.dataset.preview;
    }
    if (this.readout) {
      const lat = this.stream && this.stream.latency != null ? `${this.stream.latency.toFixed(0)} ms` : "–";
      const h = this.header;
      this.readout.textContent = `${this.times.length} fps · latency ${lat}` +
        (h ? ` · render ${h.ms_render} ms${h.lod ? " (preview)" : ""}` : "");
    }
    requestAnimationFrame(() => this.tick());
  }

  // another session starts: nothing of the last one stays on the canvas (another scene's image
  // under "strokes restored" while the reopened session replays its strokes read as lost work)
  // (a first look drawn before any session stays until the first frame replaces it)
  reset() {
    if (this.pending) { this.pending.bitmap.close(); this.pending = null; }
    if (this.drawn) {
      this.ctx.clearRect(0, 0, this.canvas.width, this.canvas.height);
      for (const k of ["samples", "quick", "settled", "frame", "ack"]) delete this.canvas.dataset[k];
    }
    this.header = null;
    this.drawn = 0;
    this.times = [];
  }

  // a precomputation's first look (an image Blob), drawn until the session's first frame comes
  async showPreview(blob) {
    const bitmap = await createImageBitmap(blob);
    if (this.drawn) { bitmap.close(); return; }      // a frame came meanwhile: it is better
    this.ctx.imageSmoothingEnabled = true;
    this.ctx.drawImage(bitmap, 0, 0, this.canvas.width, this.canvas.height);
    bitmap.close();
    this.canvas.dataset.preview = "1";
  }

  // canvas CSS pixel -> frame pixel (the session's full resolution)
  toFrame(ev, width, height) {
    const r = this.canvas.getBoundingClientRect();
    return [((ev.clientX - r.left) / r.width) * width, ((ev.clientY - r.top) / r.height) * height];
  }
}
