// REST helpers and the session stream (docs/design/conventions.md, streaming protocol): JSON messages with increasing seq out,
// binary frames (4-byte big-endian header length | JSON header | JPEG) and JSON events in.

export async function api(path, { method = "GET", body, raw, headers = {} } = {}) {
  const init = { method, headers: { ...headers } };
  if (raw !== undefined) {
    init.body = raw;
    init.headers["Content-Type"] = "application/octet-stream";
  } else if (body !== undefined) {
    init.body = JSON.stringify(body);
    init.headers["Content-Type"] = "application/json";
  }
  const r = await fetch(path, init);
  const type = r.headers.get("content-type") || "";
  const data = type.includes("json") ? await r.json() : await r.blob();
  if (!r.ok) {
    const msg = data && data.detail ? data.detail : `${r.status} ${r.statusText}`;
    throw new Error(typeof msg === "string" ? msg : JSON.stringify(msg));
  }
  return data;
}

export function decodeFrame(buf) {
  const view = new DataView(buf);
  const n = view.getUint32(0, false);
  const header = JSON.parse(new TextDecoder().decode(new Uint8Array(buf, 4, n)));
  return { header, image: new Blob([new Uint8Array(buf, 4 + n)], { type: "image/jpeg" }) };
}

// One session stream. onFrame({header, bitmap}), onEvent(json), onState(text).
export class SessionStream {
  constructor(session, { onFrame, onEvent, onState } = {}) {
    this.session = session;
    this.seq = 0;
    this.onFrame = onFrame || (() => {});
    this.onEvent = onEvent || (() => {});
    this.onState = onState || (() => {});
    this.sent = new Map();          // seq -> time sent, for latency readouts
    this.latency = null;
    this.closed = false;
    this.connect();
  }

  connect() {
    const proto = location.protocol === "https:" ? "wss" : "ws";
    // the token goes in the first message, never in the URL (URLs end up in logs)
    this.ws = new WebSocket(`${proto}://${location.host}${this.session.stream}`);
    this.ws.binaryType = "arraybuffer";
    this.ws.onopen = () => {
      this.ws.send(JSON.stringify({ type: "auth", token: this.session.token }));
      this.onState("connected");
    };
    this.ws.onclose = (e) => {
      if (this.closed) return;              // the page closed it (another session): nothing to report
      this.onState(e.code >= 4400 ? `closed: ${e.code}` : "disconnected");
      // reconnect after a network drop; the server restores the session from what it stored
      if (!this.closed && e.code < 4400) setTimeout(() => this.connect(), 1000);
    };
    this.ws.onmessage = async (e) => {
      if (this.closed) return;              // closed for another session: nothing of it is shown
      if (typeof e.data === "string") {
        const ev = JSON.parse(e.data);
        // the server refuses a seq not above the session's last one: a reopened page (or a
        // reconnect) numbers on from the stored state
        if (ev.type === "hello") this.seq = Math.max(this.seq, ev.state?.last_seq ?? 0);
        this.onEvent(ev);
        return;
      }
      const { header, image } = decodeFrame(e.data);
      const t0 = this.sent.get(header.ack);
      if (t0 !== undefined) {
        this.latency = performance.now() - t0;
        for (const k of [...this.sent.keys()]) if (k <= header.ack) this.sent.delete(k);
      }
      const bitmap = await createImageBitmap(image);
      if (this.closed) { bitmap.close(); return; }
      this.onFrame({ header, bitmap });
    };
  }

  send(type, fields = {}) {
    const seq = ++this.seq;
    if (this.ws.readyState !== WebSocket.OPEN) return null;
    this.sent.set(seq, performance.now());
    this.ws.send(JSON.stringify({ seq, type, ...fields }));
    return seq;
  }

  close() {
    this.closed = true;
    this.ws.close();
  }
}
