// Sessions that survive a reload. The URL names the session being edited, its scene, and the
// design (and version) it edits: /?session=…&scene=…&design=…&v=…. The session's secret token stays in this browser
// (localStorage, never in the URL, which ends up in logs, history and shared links), so a reload,
// a second tab or the same URL opened later reopens the same session from what the server stored:
// its strokes and undo history, camera, lighting and materials. The server keeps a session without
// a stream for `session_retention_seconds` (Settings); two tabs on one session share its worker
// and see each other's changes (the server fans frames and events out, and sends each tab the
// other's messages as "peer" events).
import { api } from "./net.js";

const KEY = (sid) => `glint.session.${sid}`;
const LAST = "glint.last-session";

function read(key) {
  try { return JSON.parse(localStorage.getItem(key) || "null"); } catch { return null; }
}

// what the URL names: { session, scene, design, version } (null where it names none). The scene is
// what a browser without the session's key (another designer's, a private window) opens instead
export function urlState() {
  const q = new URLSearchParams(location.search);
  const v = q.get("v");
  return { session: q.get("session"), scene: q.get("scene"), design: q.get("design"),
           version: v && /^\d+$/.test(v) ? +v : null };
}

// change what the URL names (undefined: keep; null: drop) without a reload or a history entry
export function setUrl(parts) {
  const q = new URLSearchParams(location.search);
  for (const [k, name] of [["session", "session"], ["scene", "scene"], ["design", "design"], ["version", "v"]]) {
    if (parts[k] === undefined) continue;
    if (parts[k] === null) q.delete(name); else q.set(name, String(parts[k]));
  }
  const s = q.toString();
  history.replaceState(null, "", location.pathname + (s ? `?${s}` : "") + location.hash);
  const rec = read(KEY(q.get("session")));
  if (rec) {       // the design a session edits, for a reopen from "/" (no URL)
    rec.design = q.get("design"); rec.version = q.get("v") ? +q.get("v") : null;
    localStorage.setItem(KEY(q.get("session")), JSON.stringify(rec));
  }
}

// keep a new session's token in this browser, and make it the one "/" reopens
export function remember(session) {
  localStorage.setItem(KEY(session.id), JSON.stringify({ token: session.token, scene_id: session.scene_id,
    design: null, version: null, at: Date.now() }));
  localStorage.setItem(LAST, session.id);
}

export function forget(sid) {
  localStorage.removeItem(KEY(sid));
  if (localStorage.getItem(LAST) === sid) localStorage.removeItem(LAST);
}

// the session "/" reopens: the last one this browser opened, with the design it edited
export function lastSession() {
  const sid = localStorage.getItem(LAST);
  const rec = sid && read(KEY(sid));
  return rec ? { session: sid, design: rec.design || null, version: rec.version ?? null } : null;
}

// the session this browser last edited on scene ``sceneId`` (its id), or null: opening that scene
// again reopens it, so a look at another scene loses nothing
export function sessionOf(sceneId) {
  let best = null;
  for (let i = 0; i < localStorage.length; i++) {
    const key = localStorage.key(i);
    if (!key?.startsWith("glint.session.")) continue;
    const rec = read(key);
    if (rec?.token && rec.scene_id === sceneId && (!best || (rec.at || 0) > best.at)) {
      best = { session: key.slice("glint.session.".length), at: rec.at || 0, design: rec.design || null,
               version: rec.version ?? null };
    }
  }
  return best;
}

// the stored session, ready for a SessionStream ({id, token, stream, state, strokes, scene_id}),
// or null with the reason: this browser has no token for it, or the server closed it
export async function reopen(sid) {
  const rec = read(KEY(sid));
  if (!rec?.token) return { session: null, why: "this browser does not hold that session's key (it was opened elsewhere)" };
  try {
    const s = await api(`/v1/sessions/${sid}`, { headers: { "X-Session-Token": rec.token } });
    if (s.closed) { forget(sid); return { session: null, why: "that session was closed (unused for too long)" }; }
    localStorage.setItem(LAST, sid);
    localStorage.setItem(KEY(sid), JSON.stringify({ ...rec, at: Date.now() }));     // the one sessionOf finds
    return { session: { ...s, token: rec.token }, why: "" };
  } catch (err) {
    forget(sid);
    return { session: null, why: `that session cannot be reopened: ${err.message}` };
  }
}

// another tab's change to this session (a "peer" event): update this tab's copy of the state and
// its controls, so that its next drag or slider starts from what both see. h: { state, setMaterial,
// editedObject, setControl(id, value) }
export function applyPeer(msg, h) {
  const st = h.state;
  switch (msg.type) {
    case "view":
      for (const k of ["eye", "target", "up", "fov_y_deg"]) if (msg[k] != null) st.camera[k] = msg[k];
      break;
    case "light":
      if (msg.rotation_deg != null) st.rotation_deg = msg.rotation_deg;
      break;
    case "material":
      if (!msg.object || msg.object === h.editedObject()) h.setMaterial(msg.material);
      break;
    case "display":
      if (msg.exposure != null) h.setControl("exposure", msg.exposure);
      if (msg.tone != null) h.setControl("tone", msg.tone);
      if (msg.shadow != null) h.setControl("shadow", msg.shadow);
      break;
    case "move":
      st.transforms = { ...(st.transforms || {}), [msg.object]: msg.transform };
      break;
    default:            // strokes, undo, fits, saves: their fit and saved events reach every tab
      break;
  }
}
