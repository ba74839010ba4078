// AudioWorklet processor: microphone -> 16 kHz mono int16 chunks, each with the context
// time of its first sample (box-filter decimation from the context's rate).

class CaptureProcessor extends AudioWorkletProcessor {
  constructor(options) {
    super();
    const { targetRate = 16000, chunkSamples = 800 } = options.processorOptions ?? {};
    this.ratio = sampleRate / targetRate; // input samples per output sample
    this.chunk = new Int16Array(chunkSamples);
    this.filled = 0;
    this.chunkStart = 0; // input frame index of the chunk's first sample
    this.running = false;
    this.nextEdge = null; // input frame index where the current output sample ends
    this.sum = 0;
    this.count = 0;
    this.port.onmessage = (event) => {
      if (event.data.cmd === "start") {
        this.running = true;
        this.nextEdge = null;
        this.filled = 0;
        this.sum = this.count = 0;
      } else if (event.data.cmd === "stop") {
        this.running = false;
        this.flush(true);
      }
    };
  }

  flush(final) {
    const pcm = this.chunk.slice(0, this.filled);
    this.port.postMessage({ pcm: pcm.buffer, contextTime: this.chunkStart / sampleRate, final }, [pcm.buffer]);
    this.filled = 0;
  }

  process(inputs) {
    const channels = inputs[0];
    if (!this.running || !channels || !channels.length) return true;
    const n = channels[0].length;
    if (this.nextEdge === null) this.nextEdge = currentFrame + this.ratio;
    for (let j = 0; j < n; j++) {
      let v = 0;
      for (const ch of channels) v += ch[j];
      v /= channels.length;
      const frame = currentFrame + j;
      if (this.count === 0 && this.filled === 0) this.chunkStart = frame;
      this.sum += v;
      this.count++;
      if (frame + 1 >= this.nextEdge) {
        const mean = Math.max(-1, Math.min(1, this.sum / this.count));
        this.chunk[this.filled++] = Math.round(mean * 32767);
        this.sum = this.count = 0;
        this.nextEdge += this.ratio;
        if (this.filled === this.chunk.length) this.flush(false);
      }
    }
    return true;
  }
}

registerProcessor("voxshape-capture", CaptureProcessor);
