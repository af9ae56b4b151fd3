// Orbit camera maths shared by the studio and the viewer: yaw/pitch/zoom around the target.
export function orbit(cam, dyaw, dpitch, zoom = 1) {
  const [ex, ey, ez] = cam.eye, [tx, ty, tz] = cam.target;
  let dx = ex - tx, dy = ey - ty, dz = ez - tz;
  let r = Math.hypot(dx, dy, dz) * zoom;
  let yaw = Math.atan2(dx, dz), pitch = Math.asin(Math.max(-1, Math.min(1, dy / Math.hypot(dx, dy, dz))));
  yaw += dyaw;
  pitch = Math.max(-1.45, Math.min(1.45, pitch + dpitch));   // stay off the up axis
  return { ...cam, eye: [tx + r * Math.cos(pitch) * Math.sin(yaw), ty + r * Math.sin(pitch), tz + r * Math.cos(pitch) * Math.cos(yaw)] };
}
