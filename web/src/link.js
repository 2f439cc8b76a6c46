// The console's WebSocket, in a dedicated Worker: the AudioWorklet's chunks come here over
// their own MessagePort and leave at once, whatever the page's main thread is busy with
// (drawing the robot in software costs tens of ms a frame). The page talks to this worker:
//   to it:   {cmd: 'connect', url, hello}, {cmd: 'send', message}, {cmd: 'audio', port}
//            (port: null stops the audio), {cmd: 'pose'} (the page is ready to draw a pose)
//   from it: {type: 'message', message} (every JSON message of the console but poses),
//            {type: 'pose', message, received} (the newest pose, once after each 'pose' asked:
//            the page draws a few to 30 a second, the console sends 50), {type: 'close',
//            code}, {type: 'level', rms, sent, dropped} (the loudest chunk of the last 100 ms
//            and the counts so far: the page shows a meter, it needs no 50 a second)

import { ClockOffset } from './clock_offset.js';

const MAGIC = [0x41, 0x32, 0x50, 0x41]; // "A2PA"
const HEADER_BYTES = 16;
const PING_PERIOD_MS = 2000;
const MAX_BUFFERED_BYTES = 32768; // more unsent audio than this: drop chunks, not add delay
const OFFSETS_KEPT = 9;
const LEVEL_PERIOD_MS = 100;

let ws = null;
let you = false; // this page holds the floor
let seq = 0;
let sent = 0;
let dropped = 0;
let chunks = null; // the MessagePort the worklet posts its chunks to
let level = 0; // the loudest chunk since the last level went to the page
let levelSentAt = 0;
const consoleClock = new ClockOffset(OFFSETS_KEPT); // console clock - this clock, from pings
const poses = { newest: null, received: 0, asked: false };

// One clock for stamps and pings: this worker's monotonic clock, in ms since the epoch.
const clock = () => performance.timeOrigin + performance.now();

function send(message) {
  if (ws && ws.readyState === WebSocket.OPEN) ws.send(JSON.stringify(message));
}

function onConsoleMessage(text) {
  const message = JSON.parse(text);
  if (message.type === 'floor') you = message.you;
  if (message.type === 'welcome') send({ type: 'ping', t: clock() });
  if (message.type === 'pong') {
    consoleClock.add(message.t, message.server, clock());
  }
  if (message.type === 'pose') {
    poses.newest = message;
    poses.received += 1;
    postPose();
  } else {
    postMessage({ type: 'message', message });
  }
}

function postPose() {
  if (!poses.asked || !poses.newest) return;
  postMessage({ type: 'pose', message: poses.newest, received: poses.received });
  poses.newest = null;
  poses.asked = false;
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
    else postMessage({ type: 'room', data: event.data, received: performance.now() }, [event.data]);
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
      header.setFloat64(8, clock() + consoleClock.value(), true);
      frame.set(new Uint8Array(pcm), HEADER_BYTES);
      ws.send(frame.buffer);
      sent += 1;
    }
  }
  level = Math.max(level, rms);
  const now = performance.now();
  if (now - levelSentAt >= LEVEL_PERIOD_MS) {
    postMessage({ type: 'level', rms: level, sent, dropped });
    level = 0;
    levelSentAt = now;
  }
}

onmessage = (event) => {
  const { cmd } = event.data;
  if (cmd === 'connect') connect(event.data.url, event.data.hello);
  else if (cmd === 'send') send(event.data.message);
  else if (cmd === 'pose') {
    poses.asked = true;
    postPose();
  }
  else if (cmd === 'audio') {
    if (chunks) chunks.onmessage = null;
    chunks = event.data.port;
    if (chunks) chunks.onmessage = (message) => onChunk(message.data);
  }
};

setInterval(() => send({ type: 'ping', t: clock() }), PING_PERIOD_MS);
