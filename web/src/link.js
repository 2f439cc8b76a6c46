// The console's WebSocket, in a dedicated Worker: the AudioWorklet's chunks come here over
// their own MessagePort and leave at once, whatever the page's main thread is busy with
// (drawing the robot in software costs tens of ms a frame). The page talks to this worker:
//   to it:   {cmd: 'connect', url, hello}, {cmd: 'send', message}, {cmd: 'audio', port}
//            (port: null stops the audio)
//   from it: {type: 'message', message} (every JSON message of the console), {type: 'close',
//            code}, {type: 'level', rms, sent, dropped} (each chunk the microphone made)

const MAGIC = [0x41, 0x32, 0x50, 0x41]; // "A2PA"
const HEADER_BYTES = 16;
const PING_PERIOD_MS = 2000;
const MAX_BUFFERED_BYTES = 32768; // more unsent audio than this: drop chunks, not add delay
const OFFSETS_KEPT = 9;

let ws = null;
let you = false; // this page holds the floor
let seq = 0;
let sent = 0;
let dropped = 0;
let chunks = null; // the MessagePort the worklet posts its chunks to
const offsets = []; // console clock - this clock (ms), from pings

// One clock for stamps and pings: this worker's monotonic clock, in ms since the epoch.
const clock = () => performance.timeOrigin + performance.now();

function offset() {
  if (!offsets.length) return 0;
  const sorted = [...offsets].sort((a, b) => a - b);
  return sorted[Math.floor(sorted.length / 2)];
}

function send(message) {
  if (ws && ws.readyState === WebSocket.OPEN) ws.send(JSON.stringify(message));
}

function onConsoleMessage(text) {
  const message = JSON.parse(text);
  if (message.type === 'floor') you = message.you;
  if (message.type === 'welcome') send({ type: 'ping', t: clock() });
  if (message.type === 'pong') {
    offsets.push(message.server - (message.t + clock()) / 2);
    if (offsets.length > OFFSETS_KEPT) offsets.shift();
  }
  postMessage({ type: 'message', message });
}

function connect(url, hello) {
  if (ws) {
    ws.onclose = null;
    ws.close();
  }
  you = false;
  ws = new WebSocket(url);
  ws.binaryType = 'arraybuffer';
  ws.onopen = () => send(hello);
  ws.onmessage = (event) => {
    if (typeof event.data === 'string') onConsoleMessage(event.data);
  };
  ws.onclose = (event) => {
    you = false;
    postMessage({ type: 'close', code: event.code });
  };
}

// A chunk from the worklet: stamped now (its last sample was just captured) on the console's
// clock, and sent while this page holds the floor.
function onChunk({ pcm, rms }) {
  if (you && ws && ws.readyState === WebSocket.OPEN) {
    if (ws.bufferedAmount > MAX_BUFFERED_BYTES) {
      dropped += 1;
    } else {
      const frame = new Uint8Array(HEADER_BYTES + pcm.byteLength);
      const header = new DataView(frame.buffer);
      MAGIC.forEach((byte, i) => header.setUint8(i, byte));
      header.setUint32(4, seq, true);
      seq = (seq + 1) >>> 0;
      header.setFloat64(8, clock() + offset(), true);
      frame.set(new Uint8Array(pcm), HEADER_BYTES);
      ws.send(frame.buffer);
      sent += 1;
    }
  }
  postMessage({ type: 'level', rms, sent, dropped });
}

onmessage = (event) => {
  const { cmd } = event.data;
  if (cmd === 'connect') connect(event.data.url, event.data.hello);
  else if (cmd === 'send') send(event.data.message);
  else if (cmd === 'audio') {
    if (chunks) chunks.onmessage = null;
    chunks = event.data.port;
    if (chunks) chunks.onmessage = (message) => onChunk(message.data);
  }
};

setInterval(() => send({ type: 'ping', t: clock() }), PING_PERIOD_MS);
