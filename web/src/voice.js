// The operator's voice out of the robot: the mute, and the latencies it is held back by.
// The mute is the voice node's own `muted` (the console sets it and reads it back), so the page
// shows what is in force at the robot, the same after a reconnect or on another operator's page;
// STOP stops the motion, not the voice. The three parts of the latency (graph, robot execution,
// loudspeaker), each measured or its default with why, and the resulting voice/motion offset
// come from the voice node's /diagnostics through the console's status. The browser test reads
// all of it as window.a2p.voice.
// A click not confirmed by the console's status within this long (refused: another operator has
// the floor, say; the console's reason shows as the page's error) no longer shows as pending.
const ASK_WAIT_MS = 5000;
const STALE_S = 2; // the voice node's figures older than this say how old they are
const PART_LABELS = {
  graph: 'graph', execution: 'robot execution', loudspeaker: 'loudspeaker',
};

export function createVoice({ $, send, state }) {
  // available: a voice node reports; muted: as in force at the robot (null: not known);
  // asked: the operator's click not yet confirmed (null: none); parts: graph, execution,
  // loudspeaker, each { ms, measured, why }; delayMs, offsetMs, windowMs: [early, late].
  const voice = {
    available: false, muted: null, asked: null, destination: '', parts: {},
    delayMs: null, offsetMs: null, windowMs: null, problem: '', reportedSAgo: null,
  };
  state.voice = voice;
  let connected = false;
  let askedAt = 0;

  function showButton() {
    const button = $('voice-mute');
    const muted = voice.asked !== null ? voice.asked : voice.muted === true;
    button.disabled = !connected || !voice.available;
    button.textContent = muted ? 'Unmute my voice at the robot' : 'Mute my voice at the robot';
    button.setAttribute('aria-pressed', String(muted));
    button.classList.toggle('on', muted);
  }

  function stateText() {
    if (!voice.available) return 'No voice out: the console was started without --voice-out, or its voice node does not report.';
    if (voice.problem) return `The mute could not be set: ${voice.problem}`;
    if (voice.asked !== null) return voice.asked ? 'Muting your voice at the robot…' : 'Unmuting your voice at the robot…';
    if (voice.muted === true) return `MUTED: the robot does not play your voice (${voice.destination}); it still moves with it.`;
    if (voice.muted === false) return `Your voice plays at the robot (${voice.destination}).`;
    return 'The mute is not known yet.';
  }

  function partText(name) {
    const part = voice.parts[name];
    if (!part) return `${PART_LABELS[name]}: not reported`;
    const ms = part.ms === null ? '?' : `${Math.round(part.ms)} ms`;
    return part.measured
      ? `${PART_LABELS[name]}: ${ms} (measured)`
      : `${PART_LABELS[name]}: ${ms} (default: ${part.why})`;
  }

  function offsetText() {
    if (voice.offsetMs === null) return '';
    const old = voice.reportedSAgo !== null && voice.reportedSAgo > STALE_S
      ? ` (reported ${Math.round(voice.reportedSAgo)} s ago)` : '';
    const [early, late] = voice.windowMs || [-80, 20];
    const inside = voice.offsetMs >= early && voice.offsetMs <= late;
    return `voice held back ${Math.round(voice.delayMs ?? 0)} ms: the motion reaches the joints `
      + `${voice.offsetMs >= 0 ? '+' : ''}${Math.round(voice.offsetMs)} ms from the voice `
      + `(${inside ? 'within' : 'OUTSIDE'} ${early} .. +${late} ms)${old}`;
  }

  function show() {
    showButton();
    const text = $('voice-state');
    const wanted = stateText();
    if (text.textContent !== wanted) text.textContent = wanted;
    const lines = voice.available
      ? [...Object.keys(PART_LABELS).map(partText), offsetText()].filter(Boolean)
      : [];
    const list = $('voice-latency');
    const shown = JSON.stringify(lines);
    if (list.dataset.shown !== shown) {
      list.dataset.shown = shown;
      list.replaceChildren(...lines.map((line) => {
        const li = document.createElement('li');
        li.textContent = line;
        return li;
      }));
    }
  }

  // The console's status: what is in force.
  function update(status) {
    if (!status) return;
    voice.available = Boolean(status.available);
    voice.muted = status.muted ?? null;
    voice.destination = status.destination || '';
    voice.parts = status.parts || {};
    voice.delayMs = status.delay_ms ?? null;
    voice.offsetMs = status.offset_ms ?? null;
    voice.windowMs = status.window_ms || null;
    voice.problem = status.problem || '';
    voice.reportedSAgo = status.reported_s_ago ?? null;
    const late = Date.now() - askedAt > ASK_WAIT_MS;
    if (voice.asked !== null && (voice.asked === voice.muted || voice.problem || late)) {
      voice.asked = null;
    }
    show();
  }

  function setConnected(on) {
    connected = on;
    if (!on) voice.asked = null;
    show();
  }

  $('voice-mute').addEventListener('click', () => {
    voice.asked = !(voice.asked !== null ? voice.asked : voice.muted === true);
    askedAt = Date.now();
    send({ type: 'mute', on: voice.asked });
    show();
  });
  show();
  return { update, setConnected };
}
