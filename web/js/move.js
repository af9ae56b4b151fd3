// The Move tool's maths (cyber-worlds §V: moving rigid objects): a drag slides the object over the
// floor plane under the pointer, Shift-drag turns it about +Y. Conventions as the server's
// (docs/design/conventions.md): +Y up, pixel (0, 0) top-left, image right = normalize(cross(forward, up)).

const sub = (a, b) => a.map((x, i) => x - b[i]);
const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
const unit = (a) => { const n = Math.hypot(...a); return a.map((x) => x / n); };

// the world ray through a frame pixel (px, py in the camera's full-resolution pixels)
export function pixelRay(cam, px, py) {
  const fwd = unit(sub(cam.target, cam.eye));
  const right = unit(cross(fwd, cam.up || [0, 1, 0]));
  const up = cross(right, fwd);
  const t = Math.tan((cam.fov_y_deg * Math.PI) / 360);
  const x = (2 * px / cam.width - 1) * t * (cam.width / cam.height);
  const y = (1 - 2 * py / cam.height) * t;
  return { origin: cam.eye, dir: unit(fwd.map((f, i) => f + x * right[i] + y * up[i])) };
}

// where a pixel's ray meets the horizontal plane y = h (null when it does not, e.g. above the horizon)
export function onPlane(cam, px, py, h) {
  const { origin, dir } = pixelRay(cam, px, py);
  if (Math.abs(dir[1]) < 1e-9) return null;
  const s = (h - origin[1]) / dir[1];
  return s > 0 ? origin.map((o, i) => o + s * dir[i]) : null;
}

// a transform as the session keeps it, with every field present
export function fullTransform(t = {}) {
  return { scale: t.scale ?? 1, rotate_deg: [...(t.rotate_deg || [0, 0, 0])], translate: [...(t.translate || [0, 0, 0])] };
}

export const TURN_DEG_PER_CSS_PX = 0.5;

// A drag of the Move tool. start(px, py, transform) then to(px, py, turning) -> the new transform:
// sliding keeps the point grabbed under the pointer on the plane through the object's origin
// (parallel to the floor); turning adds TURN_DEG_PER_CSS_PX of yaw per CSS pixel of horizontal
// motion. px, py are frame pixels, and a frame has canvas × device-pixel-ratio pixels (capped):
// cssPerFramePx (the canvas's CSS width / the frame's width) makes the turn the same on every
// screen for the same hand motion.
export class MoveDrag {
  constructor(cam, { cssPerFramePx = 1 } = {}) { this.cam = cam; this.degPerPx = TURN_DEG_PER_CSS_PX * cssPerFramePx; }

  start(px, py, transform) {
    this.t0 = fullTransform(transform);
    this.h = this.t0.translate[1];
    this.p0 = onPlane(this.cam, px, py, this.h);
    this.x0 = px;
    this.base = this.t0;
    return this.t0;
  }

  to(px, py, turning) {
    const t = fullTransform(this.base);
    if (turning) {
      t.rotate_deg[1] = this.base.rotate_deg[1] + this.degPerPx * (px - this.x0);
      return t;
    }
    const p = onPlane(this.cam, px, py, this.h);
    if (!p || !this.p0) return t;
    t.translate = [this.base.translate[0] + p[0] - this.p0[0], this.h, this.base.translate[2] + p[2] - this.p0[2]];
    return t;
  }

  // switching between sliding and turning mid-drag continues from where the object is
  rebase(px, py, transform) { this.start(px, py, transform); }
}
