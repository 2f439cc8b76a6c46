// Runs the console's capture AudioWorklet processor (a2p-capture of web/src/worklet.js) outside a
// browser: one second of a sine of FREQ Hz at RATE Hz, in the 128-frame blocks of Web Audio, two equal channels.
// Prints the chunks it posted as JSON. Usage: node console_worklet_harness.mjs FILE RATE FREQ
const [file, rate, freq] = process.argv.slice(2);
globalThis.sampleRate = Number(rate);
globalThis.AudioWorkletProcessor = class { constructor() { this.port = { postMessage: (m) => chunks.push(m) }; } };
let Processor = null;
globalThis.registerProcessor = (name, cls) => { if (name === 'a2p-capture') Processor = cls; };
const chunks = [];
await import(file);
const p = new Processor({ processorOptions: { chunkSamples: 320 } });
const n = Number(rate); // one second
for (let start = 0; start < n; start += 128) {
  const block = new Float32Array(128);
  for (let i = 0; i < 128; i++) block[i] = 0.5 * Math.sin(2 * Math.PI * Number(freq) * (start + i) / n);
  p.process([[block, block]]);
}
const samples = [];
for (const c of chunks) samples.push(...new Int16Array(c.pcm));
console.log(JSON.stringify({ chunks: chunks.length, sizes: [...new Set(chunks.map((c) => new Int16Array(c.pcm).length))], samples }));
