// The WebSocket to the gateway: login, JSON and audio frames, and the clock sync.

export const browserNow = () => performance.timeOrigin + performance.now();

const CLOCK_PROBES_AT_START = 5;
const CLOCK_EVERY_MS = 30_000;

export class Connection {
  // onMessage(msg) gets every JSON message; onClose(reason) once the socket is gone.
  constructor(url, { onMessage, onClose }) {
    this.url = url;
    this.onMessage = onMessage;
    this.onClose = onClose;
    this.socket = null;
    this.clock = { offset_ms: null, rtt_ms: null, probes: 0, replies: 0, own: null };
    this._clockTimer = null;
  }

  // Opens the socket and sends the login; resolves once it is open.
  open(login) {
    return new Promise((resolve, reject) => {
      const socket = new WebSocket(this.url);
      socket.binaryType = "arraybuffer";
      this.socket = socket;
      socket.onopen = () => {
        this.sendJson({ type: "login", ...login });
        resolve();
      };
      socket.onerror = () => reject(new Error(`cannot reach ${this.url}`));
      socket.onmessage = (event) => {
        if (typeof event.data !== "string") return;
        let msg;
        try {
          msg = JSON.parse(event.data);
        } catch {
          return;
        }
        if (msg.type === "clock") this._clockReply(msg);
        this.onMessage(msg);
      };
      socket.onclose = (event) => {
        clearInterval(this._clockTimer);
        this.onClose(event.reason || `connection closed (code ${event.code})`);
      };
    });
  }

  get open_() {
    return this.socket && this.socket.readyState === WebSocket.OPEN;
  }

  sendJson(msg) {
    if (!this.open_) return false;
    this.socket.send(JSON.stringify(msg));
    return true;
  }

  sendBinary(buffer) {
    if (!this.open_) return false;
    this.socket.send(buffer);
    return true;
  }

  close() {
    clearInterval(this._clockTimer);
    if (this.socket) this.socket.close();
  }

  // 5 probes at once after the welcome, then one every 30 s.
  startClockSync() {
    for (let i = 0; i < CLOCK_PROBES_AT_START; i++) setTimeout(() => this.probe(), i * 100);
    this._clockTimer = setInterval(() => this.probe(), CLOCK_EVERY_MS);
  }

  // A probe carries our best estimate so far, which the gateway then uses for our times.
  probe() {
    const own = this.clock.own ?? {};
    if (this.sendJson({ type: "clock", t0: browserNow(), ...own })) this.clock.probes++;
  }

  // Gateway clock minus browser clock (ms), NTP style: from the exchange with the lowest
  // round trip, t1 - (t0 + t3) / 2; the gateway's one-way bound until one came back.
  _clockReply(msg) {
    const t3 = browserNow();
    this.clock.replies++;
    if (typeof msg.t0 === "number" && typeof msg.t1 === "number") {
      const rtt = t3 - msg.t0;
      const offset = msg.t1 - (msg.t0 + t3) / 2;
      if (!this.clock.own || rtt <= this.clock.own.rtt_ms) this.clock.own = { offset_ms: offset, rtt_ms: rtt };
    }
    const best = this.clock.own ?? (typeof msg.offset_ms === "number" ? msg : null);
    if (best) {
      this.clock.offset_ms = best.offset_ms;
      this.clock.rtt_ms = best.rtt_ms ?? null;
    }
    this.clock.gateway = { offset_ms: msg.offset_ms ?? null, rtt_ms: msg.rtt_ms ?? null };
  }
}

// The WebSocket's address on the page's own origin.
export function socketUrl(path = "/ws") {
  const scheme = location.protocol === "https:" ? "wss:" : "ws:";
  return `${scheme}//${location.host}${path}`;
}

// A secured session's welcome carries a device token: the gateway turns it into this browser's
// HttpOnly cookie, sent with the next logins' handshakes, so strangers failing as this teacher
// never hold her up here (docs/web.md#security). Resolves "kept", or why not.
export async function keepDevice(token) {
  try {
    const answer = await fetch("/ws/device", {
      method: "POST",
      body: token,
      credentials: "same-origin",
      headers: { "Content-Type": "text/plain" },
    });
    return answer.ok ? "kept" : `refused (${answer.status})`;
  } catch (err) {
    return `failed (${err.message})`;
  }
}
