// AudioWorklet processors of the console. a2p-capture: the microphone, mixed to mono, resampled to 16 kHz
// with a windowed-sinc low-pass (Blackman window, cut-off at 95 % of 8 kHz, so nothing above
// the new Nyquist frequency folds back), converted to signed 16-bit and posted to the page in
// chunks of `chunkSamples` (320 = 20 ms), each with its RMS level, to the MessagePort the page
// hands over ({sink: port}: the WebSocket's worker), or to its own port until then.
// a2p-playback: the robot's microphones (16 kHz mono S16LE blocks posted to its port), resampled
// linearly to the context's rate and played; at most MAX_QUEUE_S waits (older sound is dropped,
// so the room is never heard later and later), and it starts after START_S has arrived.

const TARGET_RATE = 16000;
const ZERO_CROSSINGS = 8; // of the sinc on each side of the kernel

class CaptureProcessor extends AudioWorkletProcessor {
  constructor(options) {
    super();
    const opts = (options && options.processorOptions) || {};
    this.chunk = opts.chunkSamples || 320;
    this.step = sampleRate / TARGET_RATE; // input samples per output sample
    this.cut = 0.95 * Math.min(1, TARGET_RATE / sampleRate); // cut-off / (input rate / 2)
    this.half = Math.ceil(ZERO_CROSSINGS / this.cut); // kernel half-width, input samples
    this.buffer = new Float32Array(8192);
    this.length = 0;
    this.position = this.half; // where the next output sample lies, in buffer samples
    this.out = new Int16Array(this.chunk);
    this.filled = 0;
    this.energy = 0;
    this.sink = this.port;
    this.port.onmessage = (event) => {
      if (event.data && event.data.sink) this.sink = event.data.sink;
    };
  }

  kernel(distance) {
    const x = this.cut * distance;
    const sinc = x === 0 ? 1 : Math.sin(Math.PI * x) / (Math.PI * x);
    const w = 0.5 + 0.5 * (distance / this.half); // Blackman over [-half, half]
    const window = 0.42 - 0.5 * Math.cos(2 * Math.PI * w) + 0.08 * Math.cos(4 * Math.PI * w);
    return this.cut * sinc * window;
  }

  append(frames) {
    if (this.length + frames.length > this.buffer.length) {
      const bigger = new Float32Array(2 * (this.length + frames.length));
      bigger.set(this.buffer.subarray(0, this.length));
      this.buffer = bigger;
    }
    this.buffer.set(frames, this.length);
    this.length += frames.length;
  }

  emit(value) {
    const clamped = Math.max(-1, Math.min(1, value));
    this.out[this.filled++] = Math.round(clamped * 32767);
    this.energy += clamped * clamped;
    if (this.filled === this.chunk) {
      const rms = Math.sqrt(this.energy / this.chunk);
      this.sink.postMessage({ pcm: this.out.buffer, rms }, [this.out.buffer]);
      this.out = new Int16Array(this.chunk);
      this.filled = 0;
      this.energy = 0;
    }
  }

  process(inputs) {
    const input = inputs[0];
    if (!input || input.length === 0) return true;
    const n = input[0].length;
    const mono = new Float32Array(n);
    for (const channel of input) for (let i = 0; i < n; i++) mono[i] += channel[i] / input.length;
    this.append(mono);
    while (this.position + this.half < this.length) {
      const centre = Math.floor(this.position);
      let sum = 0;
      for (let k = centre - this.half + 1; k <= centre + this.half; k++) {
        sum += this.buffer[k] * this.kernel(this.position - k);
      }
      this.emit(sum);
      this.position += this.step;
    }
    const drop = Math.floor(this.position) - this.half;
    if (drop > 0) {
      this.buffer.copyWithin(0, drop, this.length);
      this.length -= drop;
      this.position -= drop;
    }
    return true;
  }
}

registerProcessor('a2p-capture', CaptureProcessor);

const MAX_QUEUE_S = 0.6;
const START_S = 0.2;

class PlaybackProcessor extends AudioWorkletProcessor {
  constructor() {
    super();
    this.queue = new Float32Array(Math.ceil(2 * MAX_QUEUE_S * TARGET_RATE));
    this.length = 0; // 16 kHz samples waiting
    this.position = 0; // where the next output sample lies, in queued samples
    this.started = false;
    this.step = TARGET_RATE / sampleRate; // queued samples per output sample
    this.dropped = 0;
    this.port.onmessage = (event) => this.push(new Int16Array(event.data));
  }

  push(pcm) {
    const keep = Math.ceil(MAX_QUEUE_S * TARGET_RATE);
    if (this.length + pcm.length > keep) { // too far behind: the oldest sound goes
      const drop = Math.min(this.length, this.length + pcm.length - keep);
      this.queue.copyWithin(0, drop, this.length);
      this.length -= drop;
      this.position = Math.max(0, this.position - drop);
      this.dropped += drop;
    }
    const samples = pcm.subarray(Math.max(0, pcm.length - keep));
    for (let i = 0; i < samples.length; i++) this.queue[this.length + i] = samples[i] / 32768;
    this.length += samples.length;
    if (this.length >= START_S * TARGET_RATE) this.started = true;
  }

  process(_inputs, outputs) {
    const out = outputs[0][0];
    if (!this.started) return true;
    for (let i = 0; i < out.length; i++) {
      const k = Math.floor(this.position);
      if (k + 1 >= this.length) { // ran dry: wait for START_S again
        this.started = false;
        break;
      }
      const frac = this.position - k;
      out[i] = this.queue[k] * (1 - frac) + this.queue[k + 1] * frac;
      this.position += this.step;
    }
    for (let c = 1; c < outputs[0].length; c++) outputs[0][c].set(out);
    const used = Math.floor(this.position);
    if (used > 0) {
      this.queue.copyWithin(0, used, this.length);
      this.length -= used;
      this.position -= used;
    }
    return true;
  }
}

registerProcessor('a2p-playback', PlaybackProcessor);
