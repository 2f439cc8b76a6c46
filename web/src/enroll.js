// "Learn my style": with the operator's consent, the page records camera and microphone for up
// to 60 s, uploads the recording to the console (the robot's own computer: nothing leaves it)
// under a single-use ticket, and shows the console's progress; the console learns the style and
// runs it on the robot (the personal model blended in, with the style fitted to it), and either
// the personal model or the default can be chosen afterwards. Under the progress the page lists,
// part by part, what learning expects: the gain on the person's other speech with its spread,
// or that it kept the default and why (window.a2p.enroll.verdicts).
const MAX_RECORDING_MS = 60000;
const TICKET_WAIT_MS = 5000;
const MIME_TYPES = ['video/webm;codecs=vp8,opus', 'video/webm;codecs=vp9,opus', 'video/webm'];

export function createEnroll({ $, send, state, showError }) {
  const enroll = { recording: false, uploads: 0, lastUpload: null, verdicts: [], model: null };
  state.enroll = enroll;
  let recorder = null;
  let stream = null;
  let chunks = [];
  let ticket = null;
  let stopTimer = null;
  let clock = null;
  let startedAt = 0;
  let pendingBlob = null;

  function setState(text) {
    $('style-state').textContent = text;
  }

  function release() {
    clearTimeout(stopTimer);
    clearInterval(clock);
    if (stream) for (const track of stream.getTracks()) track.stop();
    stream = null;
    $('selfview').srcObject = null;
    $('selfview').hidden = true;
    $('learn-stop').hidden = true;
    $('learn').hidden = false;
    enroll.recording = false;
  }

  async function start() {
    $('consent').close();
    const mimeType = MIME_TYPES.find((type) => window.MediaRecorder?.isTypeSupported(type));
    if (!mimeType) {
      showError('This browser cannot record video (no MediaRecorder for WebM).');
      return;
    }
    try {
      stream = await navigator.mediaDevices.getUserMedia({
        video: { width: 640, height: 480 }, audio: { channelCount: 1 },
      });
    } catch (error) {
      showError(`No camera or microphone: ${error.message}`);
      return;
    }
    ticket = null;
    chunks = [];
    send({ type: 'enroll', keep: $('keep').checked });
    recorder = new MediaRecorder(stream, { mimeType, videoBitsPerSecond: 1000000 });
    recorder.ondataavailable = (event) => { if (event.data.size) chunks.push(event.data); };
    recorder.onstop = () => {
      pendingBlob = new Blob(chunks, { type: 'video/webm' });
      chunks = [];
      release();
      upload();
    };
    recorder.start(1000);
    enroll.recording = true;
    startedAt = Date.now();
    $('selfview').srcObject = stream;
    $('selfview').hidden = false;
    $('learn').hidden = true;
    $('learn-stop').hidden = false;
    clock = setInterval(() => {
      const left = Math.max(0, Math.round((MAX_RECORDING_MS - (Date.now() - startedAt)) / 1000));
      $('learn-stop').textContent = `Done (${left} s left)`;
    }, 250);
    stopTimer = setTimeout(stop, MAX_RECORDING_MS);
    setState('Recording: talk as you usually do.');
  }

  function stop() {
    if (recorder && recorder.state !== 'inactive') recorder.stop();
  }

  async function upload() {
    if (!pendingBlob) return;
    if (!ticket) {
      // the ticket may still be on its way; a refusal came as an error message meanwhile
      setTimeout(() => {
        if (pendingBlob && !ticket) {
          pendingBlob = null;
          setState('The recording was discarded: the console did not accept it.');
        }
      }, TICKET_WAIT_MS);
      return;
    }
    const body = pendingBlob;
    pendingBlob = null;
    setState('Sending the recording to the robot\u2019s computer\u2026');
    try {
      const response = await fetch(`enroll/${encodeURIComponent(ticket)}`, {
        method: 'POST', body, headers: { 'Content-Type': 'video/webm' },
      });
      enroll.lastUpload = response.status;
      if (response.status !== 202) {
        showError(`The recording was refused: ${await response.text()}`);
        return;
      }
      enroll.uploads += 1;
    } catch (error) {
      showError(`The recording could not be sent: ${error.message}`);
    } finally {
      ticket = null;
    }
  }

  function onTicket(message) {
    ticket = message.ticket;
    if (pendingBlob) upload();
  }

  // One line per part; rebuilt only when the verdicts change (a new style learned).
  let shownVerdicts = '';
  function showVerdicts(verdicts) {
    const key = JSON.stringify(verdicts);
    if (key === shownVerdicts) return;
    shownVerdicts = key;
    enroll.verdicts = verdicts.map((v) => ({
      part: v.part,
      learned: v.learned,
      text: v.learned
        ? `${v.part}: learned, expected ${v.gain.toFixed(3)} \u00b1 ${v.spread.toFixed(3)} closer `
          + 'to you than the default on speech it did not learn from'
        : `${v.part}: kept the default: ${v.reason}`,
    }));
    const list = $('style-verdicts');
    list.replaceChildren(...enroll.verdicts.map((v) => {
      const item = document.createElement('li');
      item.textContent = v.text;
      item.className = v.learned ? 'learned' : 'kept';
      return item;
    }));
  }

  function update(status) {
    const job = status.enrollment;
    if (!job) return;
    enroll.status = job;
    enroll.style = status.style;
    enroll.model = status.model_path ?? null;
    showVerdicts(job.verdicts || []);
    if (!enroll.recording) {
      const who = job.owner ? ` (${job.owner})` : '';
      const text = {
        idle: job.message || (job.personal ? 'A learned style is available.' : 'No style learned yet.'),
        waiting: `Recording a style${who}\u2026`,
        uploading: `Receiving the recording${who}\u2026`,
        learning: `Learning${who}: ${job.message}`,
        ready: job.message,
        failed: job.message,
      }[job.state] || job.message;
      setState(text);
    }
    $('style-personal').disabled = !job.personal || status.style === 'personal';
    $('style-default').disabled = status.style === 'default';
    const inUse = {
      personal: 'your personal model and style', default: 'the model and style it started with',
      adjusted: 'the style set by hand',
    }[status.style] || `the preset ${String(status.style).replaceAll('_', ' ')}`;
    $('style-in-use').textContent = `The robot moves in ${inUse}.`;
    $('style-problem').textContent = status.style_problem || '';
  }

  $('learn').addEventListener('click', () => $('consent').showModal());
  $('consent-no').addEventListener('click', () => $('consent').close());
  $('consent-yes').addEventListener('click', start);
  $('learn-stop').addEventListener('click', stop);
  $('style-personal').addEventListener('click', () => send({ type: 'style', use: 'personal' }));
  $('style-default').addEventListener('click', () => send({ type: 'style', use: 'default' }));
  return { onTicket, update };
}
