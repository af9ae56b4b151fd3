// Frames follow the canvas: its size on the page times the device pixel ratio, sent as the
// session camera's width and height (a `view` message) when it changes; the server scales it
// down to its max_frame_pixels (Settings), keeping the aspect. The canvas's own pixels follow
// the frames that arrive, so a settled frame is drawn one to one.

export function followCanvasSize(canvas, { send, allowed, delayMs = 200 }) {
  let timer = null, last = "";
  const measure = () => {
    const dpr = window.devicePixelRatio || 1;
    const w = Math.round(canvas.clientWidth * dpr), h = Math.round(canvas.clientHeight * dpr);
    if (w < 16 || h < 16 || !allowed()) return;
    const key = `${w}x${h}`;
    if (key === last) return;
    last = key;
    send(w, h);
  };
  const ro = new ResizeObserver(() => { clearTimeout(timer); timer = setTimeout(measure, delayMs); });
  ro.observe(canvas);
  return { now: () => { last = ""; measure(); } };
}

// the canvases' pixels to a full frame's size (drag frames come smaller and are scaled up)
export function fitCanvases(header, ...canvases) {
  if (header.lod) return false;
  let changed = false;
  for (const c of canvases) {
    if (c.width !== header.width || c.height !== header.height) {
      c.width = header.width; c.height = header.height; changed = true;
    }
  }
  return changed;
}
