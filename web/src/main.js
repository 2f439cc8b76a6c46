// The operator console's page: microphone capture (AudioWorklet, 16 kHz mono S16LE in 20 ms
// chunks), the WebSocket to console_node (in a Worker, link.js, so the chunks leave without
// waiting for this thread), a 3D view of the robot from the package's URDF (commanded pose
// solid, measured pose as a ghost), stop / enable / style (a preset, and the size and tempo of
// each part, where the hands rest and how high they go), health and the voice-to-command
// latency, the operator's voice out of the robot (voice.js: the mute and its latencies), and
// the room: the robot's camera (JPEG) and microphones (played through an AudioWorklet) with the
// age of the picture, the sound's level and how many other pages watch.
// Everything is served by the console itself.
import * as THREE from 'three';
import { OrbitControls } from 'three/examples/jsm/controls/OrbitControls.js';
import URDFLoader from 'urdf-loader';
import { createEnroll } from './enroll.js';
import { createVoice } from './voice.js';

const CHUNK_SAMPLES = 320; // 20 ms at 16 kHz
const STYLE_SEND_PERIOD_MS = 150;
// The page's names for the filter's live style parameters (their ranges come from the console).
const STYLE_LABELS = {
  head_gain: 'head size', arms_gain: 'arms size', hip_gain: 'hip size',
  head_tempo: 'head tempo', arms_tempo: 'arms tempo', hip_tempo: 'hip tempo',
  arms_rest_pitch_rad: 'hands rest lower', arms_rest_bend_rad: 'elbows bent more',
  arms_raise_limit_rad: 'arms rise at most',
};

const $ = (id) => document.getElementById(id);
// State the browser test reads (window.a2p).
const state = {
  connected: false, floor: null, you: false, talking: false, chunksSent: 0, chunksDropped: 0,
  posesReceived: 0, status: null, lastError: '', joints: [], viewReady: false,
  name: '', stopHolders: [], stopYou: false, styleHeld: false,
};
// What the page shows of the room (window.a2p.room): pictures drawn, the last one's age when
// drawn (ms), the sound's level (dBFS) and as heard before the operator's own voice was removed,
// blocks of sound received, whether it plays, pages watching (this one included), other pages
// watching (the badge), and whether the camera has stopped.
state.room = {
  framesDrawn: 0, frameAgeMs: null, levelDb: null, heardDb: null, soundBlocks: 0, playing: false,
  watchers: 0, othersWatching: 0, sequence: 0, cameraStopped: false,
};
window.a2p = state;

const link = new Worker('link.js');
let audio = null; // { context, stream, node }
let reconnectTimer = null;

// The token comes in the address's fragment (never sent to a server); it is kept for this tab
// only and taken out of the address bar, so it does not stay on screen or in bookmarks.
function token() {
  const fromHash = new URLSearchParams(location.hash.slice(1)).get('token');
  if (fromHash) {
    sessionStorage.setItem('a2p-token', fromHash);
    history.replaceState(null, '', location.pathname);
  }
  return sessionStorage.getItem('a2p-token') || '';
}

function showError(text) {
  state.lastError = text;
  $('error').textContent = text;
}

function setConnection(text, cls) {
  const pill = $('connection');
  pill.textContent = text;
  pill.className = `pill ${cls || ''}`;
}

function send(message) {
  link.postMessage({ cmd: 'send', message });
}

function setControls(enabled) {
  for (const id of ['talk', 'stop', 'release', 'enable', 'style-preset', 'learn']) {
    $(id).disabled = !enabled;
  }
  for (const slider of document.querySelectorAll('#style-sliders input')) {
    slider.disabled = !enabled;
  }
  voiceOut.setConnected(enabled);
}

function connect() {
  clearTimeout(reconnectTimer);
  const scheme = location.protocol === 'https:' ? 'wss' : 'ws';
  const name = $('name').value.trim() || localStorage.getItem('a2p-name') || '';
  setConnection('connecting…');
  link.postMessage({
    cmd: 'connect',
    url: `${scheme}://${location.host}/ws`,
    hello: { type: 'hello', token: token(), name },
  });
}

function onClose(code) {
  state.connected = false;
  state.you = false;
  showWatchers(0);
  setControls(false);
  stopAudio();
  if (code === 4401 || code === 4429) {
    setConnection('token refused', 'err');
    $('login').hidden = false;
    $('login-reason').textContent = code === 4401
      ? 'The token was refused: enter the one the console printed.'
      : 'Too many wrong tokens from this address: wait a moment, then connect again.';
    return;
  }
  setConnection('disconnected: retrying', 'err');
  reconnectTimer = setTimeout(connect, 2000);
}

link.onmessage = (event) => {
  const data = event.data;
  if (data.type === 'message') onMessage(data.message);
  else if (data.type === 'pose') applyPose(data.message, data.received);
  else if (data.type === 'close') onClose(data.code);
  else if (data.type === 'room') onRoom(data.data, data.received);
  else if (data.type === 'level') { // ten a second
    showLevel(state.talking ? Math.min(1, data.rms * 4) : 0);
    state.chunksSent = data.sent;
    state.chunksDropped = data.dropped;
  }
};

function showLevel(level) {
  $('level').firstElementChild.style.transform = `scaleX(${level.toFixed(3)})`;
}

// A page update costs a style, layout, paint and compositor commit: text and values are
// written only when they change.
function setText(element, text) {
  if (element.textContent !== text) element.textContent = text;
}

function setValue(element, value) {
  if (element.value !== value) element.value = value;
}

function onMessage(message) {
  switch (message.type) {
    case 'welcome':
      state.connected = true;
      state.joints = message.joints;
      state.neutral = message.neutral;
      if (view.commanded && !state.lastPose) setPose(view.commanded, state.neutral);
      if (view.commanded) view.commanded.visible = true;
      markViewDirty();
      $('login').hidden = true;
      state.name = message.name;
      setConnection(`connected as ${message.name}`, 'ok');
      setControls(true);
      showError('');
      break;
    case 'floor':
      state.floor = message.holder;
      state.you = message.you;
      updateFloor();
      break;
    case 'status':
      state.status = message;
      updateStatus(message);
      showWatchers(message.room_watchers);
      showStopHolders();
      break;
    case 'stop_holders':
      state.stopHolders = message.holders;
      state.stopYou = message.you;
      showStopHolders();
      holdStyle();
      break;
    case 'enroll_ticket':
      styleLearning.onTicket(message);
      break;
    case 'error':
      showError(message.message);
      break;
    default:
      break;
  }
}

// --- the room: what the robot sees and hears ---------------------------------------------

// Header of a room message (little-endian): magic A2PV (picture) or A2PS (sound), uint32
// sequence, float64 age when sent (ms), float32 levels (dBFS) of the sound sent and of the
// sound as heard before the operator's own voice was removed, then JPEG or 16 kHz S16LE.
const ROOM_HEADER_BYTES = 24;
const room = { context: null, node: null, drawing: false, pictureAt: 0, ageAtDraw: 0 };

function onRoom(buffer, received) {
  if (buffer.byteLength < ROOM_HEADER_BYTES) return;
  const view = new DataView(buffer);
  const magic = String.fromCharCode(...new Uint8Array(buffer, 0, 4));
  const ageMs = view.getFloat64(8, true);
  state.room.sequence = view.getUint32(4, true);
  const payload = buffer.slice(ROOM_HEADER_BYTES);
  if (magic === 'A2PV') drawPicture(payload, ageMs, received);
  else if (magic === 'A2PS') {
    playSound(payload, view.getFloat32(16, true), view.getFloat32(20, true));
  }
}

async function drawPicture(jpeg, ageMs, received) {
  if (room.drawing) return; // one picture at a time: a newer one comes soon
  room.drawing = true;
  try {
    const bitmap = await createImageBitmap(new Blob([jpeg], { type: 'image/jpeg' }));
    const canvas = $('room-picture');
    if (canvas.width !== bitmap.width) canvas.width = bitmap.width;
    if (canvas.height !== bitmap.height) canvas.height = bitmap.height;
    canvas.getContext('2d').drawImage(bitmap, 0, 0);
    bitmap.close();
    room.pictureAt = performance.now();
    room.ageAtDraw = ageMs + (room.pictureAt - received);
    state.room.framesDrawn += 1;
    state.room.frameAgeMs = room.ageAtDraw;
    showPictureAge();
  } catch (error) {
    showError(`A picture of the room could not be shown: ${error.message}`);
  } finally {
    room.drawing = false;
  }
}

function showPictureAge() {
  const camera = state.status && state.status.camera; // the console's word: pictures stopped
  state.room.cameraStopped = Boolean(camera && camera.stopped);
  if (state.room.cameraStopped) {
    const since = new Date(camera.last_s * 1000).toLocaleTimeString();
    const age = Math.round(camera.age_s);
    setText($('room-age'), `no picture since ${since} (${age} s): ${camera.topic} stopped`);
    return;
  }
  if (!state.room.framesDrawn) return;
  const age = room.ageAtDraw + (performance.now() - room.pictureAt);
  setText($('room-age'), `picture ${Math.round(age)} ms old (${state.room.framesDrawn} shown)`);
}
setInterval(showPictureAge, 500);

async function startRoomSound() {
  if (room.context) {
    await room.context.resume();
  } else {
    const context = new AudioContext();
    room.context = context;
    await context.audioWorklet.addModule('worklet.js');
    room.node = new AudioWorkletNode(context, 'a2p-playback', { outputChannelCount: [1] });
    room.node.connect(context.destination);
    await context.resume();
  }
  state.room.playing = room.context.state === 'running';
  $('room-listen').hidden = state.room.playing;
}

function playSound(pcm, levelDb, heardDb) {
  state.room.soundBlocks += 1;
  state.room.levelDb = levelDb;
  state.room.heardDb = heardDb;
  $('room-level').firstElementChild.style.transform =
    `scaleX(${Math.max(0, Math.min(1, (levelDb + 60) / 60)).toFixed(3)})`;
  setText($('room-sound'), heardDb - levelDb >= 1
    ? `room ${levelDb.toFixed(0)} dBFS (your voice removed: ${(heardDb - levelDb).toFixed(0)} dB)`
    : `room ${levelDb.toFixed(0)} dBFS`);
  if (!room.context) startRoomSound().catch(() => {}); // a page allowed to play starts now
  if (room.node) room.node.port.postMessage(pcm, [pcm]);
}

$('room-listen').addEventListener('click', () => {
  startRoomSound().catch((error) => showError(`The room cannot be played: ${error.message}`));
});

// The console counts every identified page, this one too: the badge says whether the room is
// shared with anyone else, and goes when the last other page leaves (or this one disconnects).
function showWatchers(watchers) {
  state.room.watchers = watchers || 0;
  const others = state.connected ? Math.max(0, state.room.watchers - 1) : 0;
  state.room.othersWatching = others;
  const pill = $('room-watched');
  pill.hidden = !others;
  setText(pill, others ? `room shared with ${others} other page${others === 1 ? '' : 's'}` : '');
}

// --- talking -------------------------------------------------------------------------------

function updateFloor() {
  const talk = $('talk');
  if (state.you) {
    $('floor').textContent = 'You have the floor: speak now.';
    talk.textContent = 'Stop talking';
    talk.classList.add('on');
  } else {
    $('floor').textContent = state.floor ? `${state.floor} is talking.` : 'Nobody is talking: press Talk.';
    talk.textContent = 'Talk';
    talk.classList.remove('on');
    if (state.talking) stopAudio();
  }
}

async function startAudio() {
  const stream = await navigator.mediaDevices.getUserMedia({
    audio: { channelCount: 1, echoCancellation: true, noiseSuppression: true, autoGainControl: true },
  });
  const context = new AudioContext();
  await context.audioWorklet.addModule('worklet.js');
  const source = context.createMediaStreamSource(stream);
  const node = new AudioWorkletNode(context, 'a2p-capture', {
    processorOptions: { chunkSamples: CHUNK_SAMPLES },
  });
  const mute = context.createGain();
  mute.gain.value = 0;
  source.connect(node).connect(mute).connect(context.destination);
  // the chunks go from the worklet straight to the WebSocket's worker
  const channel = new MessageChannel();
  node.port.postMessage({ sink: channel.port1 }, [channel.port1]);
  link.postMessage({ cmd: 'audio', port: channel.port2 }, [channel.port2]);
  audio = { context, stream, node };
}

function stopAudio() {
  state.talking = false;
  showLevel(0);
  if (!audio) return;
  link.postMessage({ cmd: 'audio', port: null });
  audio.stream.getTracks().forEach((track) => track.stop());
  audio.context.close();
  audio = null;
}

async function toggleTalk() {
  if (state.you || state.talking) {
    send({ type: 'talk', on: false });
    stopAudio();
    return;
  }
  try {
    await startAudio();
  } catch (error) {
    showError(`No microphone: ${error.message}. The page needs microphone permission (and HTTPS when not on localhost).`);
    return;
  }
  state.talking = true;
  localStorage.setItem('a2p-name', $('name').value.trim());
  send({ type: 'talk', on: true });
}

// --- controls ------------------------------------------------------------------------------

const pendingStyle = {};
let styleTimer = null;
let draggingSince = 0;
let enableToggled = 0; // the operator's own change shows until the latched value comes back
const SETTLE_MS = 1500;

function queueStyle(name, value) {
  pendingStyle[name] = value;
  draggingSince = Date.now();
  if (styleTimer) return;
  styleTimer = setTimeout(() => {
    styleTimer = null;
    send({ type: 'style_set', ...pendingStyle });
    for (const key of Object.keys(pendingStyle)) delete pendingStyle[key];
  }, STYLE_SEND_PERIOD_MS);
}

// One slider per style parameter, made once from the ranges the console sends.
function makeStyleSliders(ranges) {
  const box = $('style-sliders');
  if (box.childElementCount || !ranges) return;
  for (const [name, [min, max]] of Object.entries(ranges)) {
    const label = document.createElement('label');
    label.append(`${STYLE_LABELS[name] || name} `);
    const input = document.createElement('input');
    Object.assign(input, {
      id: `style-${name}`, type: 'range', min: String(min), max: String(max),
      step: String((max - min) / 100), disabled: !state.connected,
    });
    const output = document.createElement('output');
    input.addEventListener('input', () => {
      output.textContent = Number(input.value).toFixed(2);
      queueStyle(name, Number(input.value));
    });
    label.append(input, output);
    box.append(label);
  }
}

function updateStyle(status) {
  makeStyleSliders(status.style_ranges);
  const select = $('style-preset');
  if (status.presets && select.options.length === 1) {
    for (const name of status.presets) {
      select.add(new Option(name.replaceAll('_', ' '), name));
    }
  }
  const chosen = [...select.options].some((o) => o.value === status.style);
  if (chosen && select.value !== status.style) select.value = status.style;
  if (status.style_values && Date.now() - draggingSince > SETTLE_MS) {
    for (const [name, value] of Object.entries(status.style_values)) {
      const input = $(`style-${name}`);
      if (!input) continue;
      setValue(input, String(value));
      setText(input.nextElementSibling, value.toFixed(2));
    }
  }
}

function updateStatus(status) {
  const stopped = status.stop === true;
  document.body.classList.toggle('stopped', stopped); // no change, no restyle
  const enabled = status.enable !== false;
  if (Date.now() - enableToggled > SETTLE_MS) $('enable').checked = enabled;
  setText($('robot-state'), stopped
    ? 'STOPPED: the robot holds still until the stop is released.'
    : enabled ? 'Motion enabled.' : 'Motion disabled: the robot rests in its neutral pose.');
  updateStyle(status);
  styleLearning.update(status);
  voiceOut.update(status.voice);
  holdStyle();
  const l = status.latency || {};
  setText($('latency'), l.n
    ? `p50 ${l.p50.toFixed(1)} ms, p99 ${l.p99.toFixed(1)} ms, last ${l.last.toFixed(1)} ms ` +
      `(browser to console ${l.uplink_p50.toFixed(1)} ms, graph ${l.graph_p50.toFixed(1)} ms; ` +
      `${l.n} chunks; 20 ms chunk and 25 ms feature window come on top)`
    : 'no measurement yet: press Talk and speak');
  const health = (status.health || []).map(
    (item) => [`l${item.level}`, `${item.name}: ${item.message}`],
  );
  const shown = JSON.stringify(health);
  const list = $('health');
  if (list.dataset.shown !== shown) {
    list.dataset.shown = shown;
    list.replaceChildren(...health.map(([cls, text]) => {
      const li = document.createElement('li');
      li.className = cls;
      li.textContent = text;
      return li;
    }));
  }
  if (status.floor !== undefined && status.floor !== state.floor) {
    state.floor = status.floor;
    updateFloor();
  }
}

// --- who holds the stop --------------------------------------------------------------------

// A stop is released only by whoever pressed it; that of an operator who has left, or one set
// outside the console, only through a confirmation that names them (the console checks both).
const OUTSIDE = 'outside the console'; // audio2pose_ros/console/stop.py

function stopHolderText() {
  const holders = state.stopHolders;
  if (!holders.length) {
    return state.status && state.status.stop === true ? `Stopped ${OUTSIDE}.` : '';
  }
  const names = holders.map((h) => {
    if (!h.present) return `${h.name} (has left)`;
    return state.stopYou && h.name === state.name ? 'you' : h.name;
  });
  return `Stop held by ${names.join(', ')}.`;
}

function showStopHolders() {
  setText($('stop-holder'), stopHolderText());
}

// While the stop is latched, a style change waits for its release (the console refuses it, so
// the robot resumes in the style it stopped in): the style controls are off, and say why.
function holdStyle() {
  const held = state.stopHolders.length > 0 || (state.status !== null && state.status.stop === true);
  state.styleHeld = held;
  setText($('style-wait'), held ? 'Style changes wait until the stop is released.' : '');
  for (const input of [$('style-preset'), ...document.querySelectorAll('#style-sliders input')]) {
    input.disabled = held || !state.connected;
  }
  if (held) { // their own state comes back with the next status after the release
    $('style-personal').disabled = true;
    $('style-default').disabled = true;
  }
}

// The Release button: one's own stop at once; anyone else's needs the confirmation, which is
// offered only for someone who has left (the console refuses it for those still here).
function releaseStop() {
  if (state.stopYou) {
    send({ type: 'stop', on: false });
    return;
  }
  const absent = state.stopHolders.find((h) => !h.present);
  const stoppedOutside = !state.stopHolders.length && state.status && state.status.stop === true;
  const owner = absent ? absent.name : stoppedOutside ? OUTSIDE : null;
  if (!owner) {
    send({ type: 'stop', on: false }); // the console answers who may release it
    return;
  }
  $('release-confirm-text').textContent = absent
    ? `${owner} stopped the robot and has left. Release ${owner}'s stop only if the robot is safe to move.`
    : `The robot was stopped ${OUTSIDE}. Release that stop only if the robot is safe to move.`;
  $('release-confirm-yes').textContent = absent ? `Release ${owner}'s stop` : `Release the stop set ${OUTSIDE}`;
  $('release-confirm-yes').dataset.owner = owner;
  $('release-confirm').hidden = false;
}

function wireStopRelease() {
  $('release').addEventListener('click', releaseStop);
  $('release-confirm-yes').addEventListener('click', (event) => {
    $('release-confirm').hidden = true;
    send({ type: 'stop', on: false, confirm: event.target.dataset.owner });
  });
  $('release-confirm-no').addEventListener('click', () => { $('release-confirm').hidden = true; });
}

// --- 3D view ---------------------------------------------------------------------------------

// Frame pacing. Every frame the page makes costs its main thread script, style, paint and a
// compositor commit; with software WebGL and compositing (no GPU, as in many browsers) the
// commit after a drawing waits for it. So frames are made only when something is due (a pose to
// draw, a camera move, a resize), and the view draws at most 30 times a second and as often as
// keeps the page's frames within a quarter of its main thread's time, measured, not modelled:
// the buttons and the microphone stay responsive however slow the drawing is.
// Software drawing costs mostly in proportion to the pixels drawn (9 times the pixels took 4.5
// times as long in the browser test; one full drawing took 0.7 s on a slow machine). So the page
// fits what its drawings cost, a fixed part and a part per pixel, and draws as many pixels as
// fit in FRAME_BUDGET_MS, down to an eighth of the width and height (the browser scales the
// picture up): at a quarter of the time, 5 drawings a second before it draws less often. Where
// the fixed part alone takes the budget (slow script rather than slow drawing), fewer pixels
// would only blur the view: the pixels may then add a quarter to it. A resize takes the pixels
// that fit at once; after a drawing that cost less, the next may have a quarter more pixels.
const MIN_FRAME_MS = 1000 / 30;
const MAX_FRAME_MS = 1000; // however slow the drawing, the view shows the pose every second
const FRAME_SHARE = 0.25;
const FRAME_BUDGET_MS = 50; // a drawing's cost: at FRAME_SHARE, 5 drawings a second
const MIN_SCALE = 0.125; // of the canvas's width and height
const BUDGET_GROWTH = 1.25; // per drawing, when drawings cost less than the budget
const PIXEL_SHARE_OF_FIXED = 0.25; // the pixels' cost where the fixed cost takes the budget
const COST_MEMORY = 0.9; // weight of a drawing in the cost fit, per later drawing
const PACE_WINDOW_MS = 500;
const VSYNC_MS = 1000 / 60; // a frame comes at the display's next refresh
const WARM_UP_DRAWS = 3; // the first drawings compile shaders: they do not set the pace
const view = {
  renderer: null, scene: null, camera: null, commanded: null, measured: null, dirty: true,
  renderedAt: -Infinity, pose: null,
};
// The pace, and what set it (the browser test reads it as window.a2p.view).
const pacing = {
  requested: false, windowStart: 0, busyMs: 0,
  draws: 0, frames: 0, renderEveryMs: MIN_FRAME_MS, frameShare: 0,
  scale: 1, pixelBudget: Infinity, // the pixels a drawing may have, from the measured cost
  cost: { fixedMs: 0, msPerPixel: 0, fitted: false }, // what a drawing costs
};
// decayed sums of the drawings' pixels x and costs y, for the least-squares fit
const costSums = { n: 0, x: 0, y: 0, xx: 0, xy: 0 };
state.view = pacing;
const frameDone = new MessageChannel();

function ghostly(robot) {
  robot.traverse((object) => {
    if (object.isMesh) {
      object.material = new THREE.MeshStandardMaterial({
        color: 0x2196f3, transparent: true, opacity: 0.3, depthWrite: false,
        // drawn in front where it coincides with the commanded robot: no z-fighting speckles
        polygonOffset: true, polygonOffsetFactor: -2, polygonOffsetUnits: -2,
      });
    }
  });
  return robot;
}

async function initView() {
  const canvas = $('robot');
  try {
    view.renderer = new THREE.WebGLRenderer({ canvas, antialias: false, alpha: true });
  } catch (error) {
    $('view-problem').hidden = false;
    $('view-problem').textContent = `No 3D view: WebGL is not available in this browser (${error.message}).`;
    return;
  }
  view.scene = new THREE.Scene();
  view.camera = new THREE.PerspectiveCamera(35, 1, 0.05, 50);
  view.scene.add(new THREE.HemisphereLight(0xffffff, 0x667788, 2.2));
  const sun = new THREE.DirectionalLight(0xffffff, 1.5);
  sun.position.set(2, 4, 3);
  view.scene.add(sun);
  const grid = new THREE.GridHelper(4, 16, 0x8899aa, 0xc0c8d0);
  view.scene.add(grid);
  const text = await (await fetch('urdf/pepper.urdf')).text();
  const loader = new URDFLoader();
  const upright = (robot) => { robot.rotation.x = -Math.PI / 2; view.scene.add(robot); return robot; };
  view.commanded = upright(loader.parse(text));
  view.measured = upright(ghostly(loader.parse(text)));
  view.measured.visible = false;
  // drawn once the console said where neutral is: no made-up pose before
  view.commanded.visible = Boolean(state.neutral);
  if (state.neutral) setPose(view.commanded, state.neutral);
  const box = new THREE.Box3().setFromObject(view.commanded);
  const centre = box.getCenter(new THREE.Vector3());
  const lift = -box.min.y;
  view.commanded.position.y += lift;
  view.measured.position.y += lift;
  centre.y += lift;
  const height = box.max.y - box.min.y;
  // The robot faces +x in ROS: look at it from its front, a little from its left and above.
  view.camera.position.set(centre.x + 2.2 * height, centre.y + 0.35 * height, centre.z + 0.9 * height);
  const controls = new OrbitControls(view.camera, canvas);
  controls.target.copy(centre);
  controls.addEventListener('change', markViewDirty);
  controls.update();
  new ResizeObserver(markViewDirty).observe(canvas);
  state.viewReady = true;
  link.postMessage({ cmd: 'pose' });
  markViewDirty();
}

function markViewDirty() {
  view.dirty = true;
  requestPageFrame();
}

// Asks for one frame when the next update is due; none while nothing changes.
function requestPageFrame() {
  if (pacing.requested || !state.viewReady || !view.dirty) return;
  pacing.requested = true;
  // ask a little early: the frame waits for the display's refresh
  const wait = view.renderedAt + pacing.renderEveryMs - performance.now() - VSYNC_MS / 2;
  if (wait > 0) setTimeout(() => requestAnimationFrame(pageFrame), wait);
  else requestAnimationFrame(pageFrame);
}

function pageFrame() {
  pacing.requested = false;
  const start = performance.now();
  const pixels = drawView(start);
  pacing.frames += 1;
  // This task runs after the frame's task, so after its style, paint and commit as well.
  frameDone.port2.postMessage({ start, pixels });
  requestPageFrame();
}

// Paces the view on what the page's frames took of the main thread's time in the last window,
// and sizes its drawings on what the last one cost.
frameDone.port1.onmessage = (event) => {
  const now = performance.now();
  const { start, pixels } = event.data;
  if (pacing.draws <= WARM_UP_DRAWS) {
    pacing.windowStart = now;
    pacing.busyMs = 0;
    return;
  }
  const took = now - start;
  if (pixels > 0 && took > 0) {
    learnCost(pixels, took);
    // down at once to what fits; up by at most a quarter of what was drawn
    const fits = pixelsThatFit();
    pacing.pixelBudget = fits < pixels ? fits : Math.min(fits, pixels * BUDGET_GROWTH);
  }
  pacing.busyMs += took;
  const elapsed = now - pacing.windowStart;
  if (elapsed < PACE_WINDOW_MS) return;
  const share = pacing.busyMs / elapsed;
  const stretch = Math.min(2, Math.max(0.8, share / FRAME_SHARE)); // of the interval
  const every = pacing.renderEveryMs * stretch;
  pacing.renderEveryMs = Math.min(MAX_FRAME_MS, Math.max(MIN_FRAME_MS, every));
  pacing.frameShare = share;
  pacing.windowStart = now;
  pacing.busyMs = 0;
};

// Fits took = fixedMs + msPerPixel * pixels over the recent drawings (least squares, each older
// drawing weighing COST_MEMORY times less). Until drawings of different sizes have been seen,
// the whole cost counts as per pixel (the cautious reading); later, while the sizes stay alike,
// the last fit holds.
function learnCost(pixels, took) {
  const sums = costSums;
  sums.n = COST_MEMORY * sums.n + 1;
  sums.x = COST_MEMORY * sums.x + pixels;
  sums.y = COST_MEMORY * sums.y + took;
  sums.xx = COST_MEMORY * sums.xx + pixels * pixels;
  sums.xy = COST_MEMORY * sums.xy + pixels * took;
  const meanX = sums.x / sums.n;
  const meanY = sums.y / sums.n;
  const varianceX = sums.xx / sums.n - meanX * meanX;
  const cost = pacing.cost;
  if (varianceX > (0.1 * meanX) ** 2) {
    cost.msPerPixel = Math.max(0, (sums.xy / sums.n - meanX * meanY) / varianceX);
    cost.fitted = true;
  } else if (!cost.fitted) {
    cost.msPerPixel = meanY / meanX;
  } else {
    return;
  }
  cost.fixedMs = Math.max(0, meanY - cost.msPerPixel * meanX);
}

// The pixels a drawing may have: those that fit in the budget with the fixed cost, or, where the
// fixed cost alone takes it, those that add PIXEL_SHARE_OF_FIXED to it.
function pixelsThatFit() {
  const { fixedMs, msPerPixel } = pacing.cost;
  if (msPerPixel <= 0) return Infinity;
  return Math.max(FRAME_BUDGET_MS - fixedMs, PIXEL_SHARE_OF_FIXED * fixedMs) / msPerPixel;
}

// Draws the view if it is due: the pixels drawn, or 0.
function drawView(now) {
  if (!view.dirty || now - view.renderedAt < pacing.renderEveryMs - VSYNC_MS / 2) return 0;
  const canvas = view.renderer.domElement;
  const width = canvas.clientWidth;
  const height = canvas.clientHeight;
  const full = width * height * window.devicePixelRatio ** 2;
  const fit = full > 0 ? Math.sqrt(pacing.pixelBudget / full) : 1;
  pacing.scale = Math.min(1, Math.max(MIN_SCALE, fit));
  const ratio = window.devicePixelRatio * pacing.scale;
  if (canvas.width !== Math.floor(width * ratio) || canvas.height !== Math.floor(height * ratio)) {
    view.renderer.setPixelRatio(ratio);
    view.renderer.setSize(width, height, false);
    view.camera.aspect = width / Math.max(height, 1);
    view.camera.updateProjectionMatrix();
  }
  if (view.pose) {
    poseRobots(view.pose);
    view.pose = null;
    link.postMessage({ cmd: 'pose' });
  }
  view.renderer.render(view.scene, view.camera);
  view.dirty = false;
  view.renderedAt = now;
  pacing.draws += 1;
  return canvas.width * canvas.height;
}

function setPose(robot, pose) {
  for (const [name, angle] of Object.entries(pose)) {
    if (robot.joints[name] && Number.isFinite(angle)) robot.setJointValue(name, angle);
  }
}

// The newest pose from the console: put on the robots when the view next draws, and the
// next one asked for after that drawing (link.js keeps only the newest meanwhile).
function applyPose(message, received) {
  state.posesReceived = received;
  state.lastPose = message;
  view.pose = message;
  markViewDirty();
}

function poseRobots(message) {
  if (message.commanded) setPose(view.commanded, message.commanded);
  view.measured.visible = Boolean(message.measured);
  if (message.measured) setPose(view.measured, message.measured);
}

// --- start ---------------------------------------------------------------------------------

function wire() {
  $('name').value = localStorage.getItem('a2p-name') || '';
  $('talk').addEventListener('click', toggleTalk);
  $('stop').addEventListener('click', () => send({ type: 'stop', on: true }));
  $('enable').addEventListener('change', (event) => {
    enableToggled = Date.now();
    send({ type: 'enable', on: event.target.checked });
  });
  $('style-preset').addEventListener('change', (event) => {
    draggingSince = Date.now(); // the sliders follow once the filter has the preset
    send({ type: 'style', use: event.target.value });
  });
  $('login').addEventListener('submit', (event) => {
    event.preventDefault();
    sessionStorage.setItem('a2p-token', $('token').value);
    connect();
  });
}

wire();
wireStopRelease();
const styleLearning = createEnroll({ $, send, state, showError });
const voiceOut = createVoice({ $, send, state });
connect();
initView().catch((error) => {
  $('view-problem').hidden = false;
  $('view-problem').textContent = `No 3D view: ${error.message}`;
});
