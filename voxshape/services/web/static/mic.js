// Push-to-talk: opens the microphone while held and hands 50 ms chunks of 16 kHz int16
// audio, each with its capture time on the browser clock (ms), to onChunk.

const TARGET_RATE = 16000;
const CHUNK_MS = 50;

export class PushToTalk {
  // onChunk(pcm: ArrayBuffer, captureMs, final) for each chunk.
  constructor({ onChunk }) {
    this.onChunk = onChunk;
    this.ctx = null;
    this.node = null;
    this.stream = null;
    this.source = null;
    this.held = false;
    this.inputLatency = 0;
    this._stopped = null; // resolves when the final chunk came back
  }

  // Opens the microphone and starts the chunks; throws with a reason people can act on.
  async start() {
    this.held = true;
    if (!navigator.mediaDevices?.getUserMedia) throw new Error("this browser gives no microphone (a page on http:// needs localhost, or https)");
    if (!this.ctx) {
      this.ctx = new AudioContext({ latencyHint: "interactive" });
      await this.ctx.audioWorklet.addModule(new URL("audio-worklet.js", import.meta.url));
    }
    if (this.ctx.state !== "running") await this.ctx.resume();
    this.stream = await navigator.mediaDevices.getUserMedia({
      audio: { channelCount: 1, echoCancellation: false, noiseSuppression: false, autoGainControl: false },
    });
    const [track] = this.stream.getAudioTracks();
    this.inputLatency = track?.getSettings?.().latency ?? 0;
    this.source = this.ctx.createMediaStreamSource(this.stream);
    this.node = new AudioWorkletNode(this.ctx, "voxshape-capture", {
      numberOfInputs: 1,
      numberOfOutputs: 0,
      processorOptions: { targetRate: TARGET_RATE, chunkSamples: (TARGET_RATE * CHUNK_MS) / 1000 },
    });
    let stopped;
    this._stopped = new Promise((resolve) => (stopped = resolve));
    this.node.port.onmessage = (event) => {
      const { pcm, contextTime, final } = event.data;
      if (pcm.byteLength || final) this.onChunk(pcm, this.captureMs(contextTime), final);
      if (final) stopped();
    };
    this.source.connect(this.node);
    this.node.port.postMessage({ cmd: "start" });
  }

  // Ends the chunks (the last one partial) and closes the microphone.
  async stop() {
    this.held = false;
    if (!this.node) return;
    this.node.port.postMessage({ cmd: "stop" });
    await Promise.race([this._stopped, new Promise((r) => setTimeout(r, 500))]);
    this.source.disconnect();
    this.node.port.onmessage = null;
    for (const track of this.stream.getTracks()) track.stop();
    this.node = this.source = this.stream = null;
  }

  // Context time of a sample -> when it was captured, browser ms (performance.timeOrigin +
  // performance.now() scale). getOutputTimestamp() ties context time to performance time as
  // played out; less the output latency that is when the frame was processed, and less the
  // input and base latencies when the microphone took it.
  captureMs(contextTime) {
    const ctx = this.ctx;
    const stamp = ctx.getOutputTimestamp ? ctx.getOutputTimestamp() : null;
    let processedAt;
    if (stamp && stamp.performanceTime > 0) {
      processedAt = stamp.performanceTime + (contextTime - stamp.contextTime) * 1000 - (ctx.outputLatency || 0) * 1000;
    } else {
      processedAt = performance.now() - (ctx.currentTime - contextTime) * 1000;
    }
    const latency = (this.inputLatency + (ctx.baseLatency || 0)) * 1000;
    return performance.timeOrigin + processedAt - latency;
  }
}

// One binary frame: float64 LE capture time (browser ms), then the int16 LE samples.
export function audioFrame(pcm, captureMs) {
  const frame = new ArrayBuffer(8 + pcm.byteLength);
  new DataView(frame).setFloat64(0, captureMs, true);
  const samples = new Int16Array(pcm);
  const out = new DataView(frame, 8);
  for (let i = 0; i < samples.length; i++) out.setInt16(2 * i, samples[i], true);
  return frame;
}
