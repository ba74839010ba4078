// The teacher's page: login, then the map, the words, push-to-talk, what was understood, the
// robots' questions and the learning curve, all over one WebSocket; window.voxshape holds its
// state for tests.

import { Connection, browserNow, keepDevice, socketUrl } from "./net.js";
import { MapView } from "./mapview.js";
import { CurvePlot } from "./plot.js";
import { PushToTalk, audioFrame } from "./mic.js";
import { buildButtons, flash, meaningOfKey, phraseFor } from "./words.js";
import { Questions } from "./questions.js";

const MAX_NOTICES = 100;
const MAX_FRAMES = 5000;
const $ = (id) => document.getElementById(id);

// Everything the page knows; tests read it instead of pixels.
const state = {
  phase: "login", // login | joining | teaching | closed
  refused: null,
  closed: null,
  session: null,
  teacher: null,
  secured: null,
  welcome: null,
  device: null, // a secured session's device cookie: "kept" once the gateway set it, or why not
  robots: [],
  robot: null, // the robot this page teaches
  language: "en",
  viewer: null,
  obs: {}, // robot -> last obs (with received: performance.now())
  episodes: {}, // robot -> last episode message
  feedback: [], // newest last
  notices: [], // newest first
  stats: {}, // robot -> last stats message
  curve: {}, // robot -> [{episode, return, steps, interventions}]
  learnt: {}, // robot -> {task, episode, episodes, robot_minutes}: it has learnt its task
  said: [], // say messages sent
  framesDrawn: 0,
  frames: [], // {robot, step, stamp, wall_time, received, drawn}: received and drawn are
  // performance.now() ms, stamp (forwarded) gateway ms, wall_time (published) simulator ms
  drawn: {}, // robot -> pose last drawn {x, y, theta, step}
  marked: [], // questions marked on the map at the last draw: {robot, question, x, y}
  clock: null,
  mic: { talking: false, chunks: 0, sentMs: 0, pressMs: 0, error: null, starts: 0, stops: 0 },
  trace: { recording: false, episode: null, commands: 0, done: null },
  // the robots' questions: open (robot -> {question, answer}), the last asked and answers,
  // chimes (played: with sound), spoken aloud; how long a question stays (ms)
  questions: { open: {}, asked: [], answers: [], chimes: 0, played: 0, spoken: 0, speak: false,
    unanswered_ms: 10_000, answered_ms: 4_000 },
  errors: [],
};
window.voxshape = state;

let connection = null;
const mapView = new MapView($("map"));
const curvePlot = new CurvePlot($("curve"));
const questions = new Questions($("question"), state.questions, {
  changed: () => (dirty = true),
  phrase: (meaning) => phraseFor(state.welcome?.vocabulary, state.language, meaning),
});
mapView.questions = state.questions.open;
const pending = new Set(); // robots with an obs not drawn yet
let dirty = true;
let curveDirty = true;

// -- login -------------------------------------------------------------------------------

function initLogin() {
  const params = new URLSearchParams(location.search);
  const saved = localStorage.getItem("voxshape.services.teacher");
  $("teacher").value = params.get("teacher") ?? saved ?? `web-${Math.random().toString(16).slice(2, 6)}`;
  $("user").value = params.get("user") ?? "";
  $("login-form").addEventListener("submit", (event) => {
    event.preventDefault();
    join();
  });
  if (params.has("join")) join();
}

async function join() {
  const user = $("user").value.trim() || null;
  const teacher = $("teacher").value.trim() || user;
  const password = $("password").value || null;
  $("refused").hidden = true;
  state.phase = "joining";
  state.refused = null;
  $("login-button").disabled = true;
  questions.unlockSound(); // the click on Join lets the page chime
  connection = new Connection(socketUrl(), { onMessage: handle, onClose: closed });
  state.clock = connection.clock;
  try {
    await connection.open({ teacher, user, password });
    localStorage.setItem("voxshape.services.teacher", teacher);
  } catch (err) {
    showRefused(err.message);
  }
}

function showRefused(reason) {
  state.refused = reason;
  state.phase = "login";
  $("refused").textContent = `Refused: ${reason}`;
  $("refused").hidden = false;
  $("login").hidden = false;
  $("teach").hidden = true;
  $("login-button").disabled = false;
}

function closed(reason) {
  if (state.phase === "joining") {
    if (!state.refused) showRefused(reason);
    return;
  }
  if (state.phase !== "teaching") return;
  state.phase = "closed";
  state.closed = reason;
  $("session-line").textContent = `disconnected: ${reason}`;
  showRefused(`the connection ended (${reason}); join again`);
}

// -- messages from the gateway -------------------------------------------------------------

function handle(msg) {
  switch (msg.type) {
    case "welcome":
      return welcome(msg);
    case "refused":
      return showRefused(msg.reason ?? "no reason given");
    case "obs":
      return observation(msg);
    case "episode":
      return episode(msg);
    case "feedback":
      state.feedback.push(msg);
      if (state.feedback.length > 50) state.feedback.shift();
      return showStatus();
    case "notice":
      return notice(msg);
    case "stats":
      state.stats[msg.robot] = msg;
      return showStats();
    case "curve":
      return curve(msg);
    case "question":
      return questions.ask(msg);
    case "answer":
      return questions.answer(msg);
    case "learnt":
      return learnt(msg);
    case "error":
      state.errors.push(msg.text);
      return notice({ kind: "error", text: `the gateway refused: ${msg.text}` });
    default:
  }
}

function welcome(msg) {
  Object.assign(state, {
    phase: "teaching",
    welcome: msg,
    session: msg.session,
    teacher: msg.teacher,
    secured: msg.secured,
    language: msg.language ?? "en",
    viewer: msg.viewer ?? null,
  });
  $("login").hidden = true;
  $("teach").hidden = false;
  $("session-line").textContent = `session ${msg.session} · teacher ${msg.teacher}${msg.secured ? " · secured" : ""}`;
  if (msg.viewer) {
    $("viewer-link").href = msg.viewer;
    $("viewer-link").hidden = false;
  }
  for (const point of msg.curve ?? []) curve(point);
  for (const robot of msg.robots ?? []) addRobot(robot);
  for (const question of msg.questions ?? []) questions.ask(question);
  for (const done of msg.learnt ?? []) learnt(done);
  mapView.setMap(msg.map ?? null);
  setLanguage(state.language);
  connection.startClockSync();
  if (msg.device) keepDevice(msg.device).then((outcome) => (state.device = outcome));
  dirty = curveDirty = true;
}

function addRobot(robot) {
  if (state.robots.includes(robot)) return;
  state.robots.push(robot);
  const option = document.createElement("option");
  option.value = option.textContent = robot;
  $("robot").append(option);
  $("robot").parentElement.hidden = state.robots.length < 2;
  if (!state.robot) selectRobot(robot);
}

function selectRobot(robot) {
  state.robot = robot;
  mapView.selected = robot;
  questions.watch(robot);
  $("robot").value = robot;
  connection?.sendJson({ type: "watch", robot });
  curvePlot.clear();
  for (const point of state.curve[robot] ?? []) curvePlot.add(point);
  dirty = curveDirty = true;
  showStatus();
  showStats();
  showLearnt();
}

function observation(msg) {
  msg.received = performance.now();
  addRobot(msg.robot);
  state.obs[msg.robot] = msg;
  mapView.update(msg);
  pending.add(msg.robot);
  dirty = true;
  if (msg.robot === state.robot) {
    showStatus();
    traceProgress(msg.episode);
  }
}

function episode(msg) {
  state.episodes[msg.robot] = msg;
  if (msg.robot === state.robot && msg.kind !== "start") traceProgress(msg.episode + 1);
  showPlaced();
}

// A real robot (voxshape ros2) waits between episodes: its teachers say when it is placed.
// A simulated one starts its next episode at once, so the button shows only for a wait.
function showPlaced() {
  const e = state.episodes[state.robot];
  clearTimeout(showPlaced.timer);
  $("placed").hidden = true;
  if (e && e.kind !== "start") showPlaced.timer = setTimeout(() => ($("placed").hidden = false), 1000);
}

// A robot that has learnt its task goes on: the page says so, and what may come next.
function learnt(msg) {
  state.learnt[msg.robot] = msg;
  addRobot(msg.robot);
  showLearnt();
}

function showLearnt() {
  const done = state.learnt[state.robot];
  $("learnt").hidden = !done;
  if (!done) return;
  const episodes = `${done.episodes} episode${done.episodes === 1 ? "" : "s"}`;
  $("learnt-what").textContent =
    `${done.robot} has learnt ${done.task} in ${episodes} (${done.robot_minutes} robot minutes).`;
}

function curve(msg) {
  const point = { episode: msg.episode, return: msg.return, steps: msg.steps, interventions: msg.interventions };
  const points = (state.curve[msg.robot] ??= []);
  const i = points.findIndex((p) => p.episode === point.episode);
  if (i >= 0) points[i] = point;
  else points.push(point);
  if (msg.robot === state.robot) curveDirty = curvePlot.add(point);
}

function notice(msg) {
  state.notices.unshift({ ...msg, at: performance.now() });
  if (state.notices.length > MAX_NOTICES) state.notices.pop();
  const li = document.createElement("li");
  li.className = noticeClass(msg.kind);
  li.dataset.kind = msg.kind;
  li.textContent = msg.text; // the terminal client's line ("late answer: ..." when late)
  if (msg.late) li.classList.add("late");
  if (msg.heard) {
    const heard = document.createElement("div");
    heard.className = "heard";
    heard.textContent = `heard '${msg.heard}'`;
    li.append(heard);
  }
  $("notices").prepend(li);
  while ($("notices").children.length > MAX_NOTICES) $("notices").lastChild.remove();
}

function noticeClass(kind) {
  if (kind === "understood" || kind === "no_answer" || kind === "not_recognized") return kind;
  return "refused"; // low confidence, not understood, rate limited, unknown robot, too late
}

// -- what the page shows ------------------------------------------------------------------

function showStatus() {
  const o = state.obs[state.robot];
  if (!o) return;
  const parts = [
    `episode ${o.episode}`,
    `step ${o.episode_step}`,
    o.outcome,
    `${Number(o.goal_distance).toFixed(2)} m to the goal`,
    `last reward ${o.reward >= 0 ? "+" : ""}${o.reward}`,
  ];
  const fb = state.feedback.filter((f) => f.robot === state.robot).at(-1);
  if (fb) parts.push(`took ${fb.kind === "reward" ? `${fb.reward >= 0 ? "+" : ""}${fb.reward}` : fb.command} from ${(fb.teachers ?? []).join(", ")}`);
  $("status").textContent = parts.join(" · ");
}

function showStats() {
  const s = state.stats[state.robot];
  const dl = $("stats");
  dl.replaceChildren();
  const t = s?.teacher;
  const rows = t
    ? [
        ["words", t.utterances],
        ["understood", `${t.understood} (${t.ignored} not used)`],
        ["this episode", `${t.interventions} of ${s.interventions} words, ${s.teachers} teacher${s.teachers === 1 ? "" : "s"}`],
        ["delay", `${t.delay.toFixed(2)} ± ${(t.delay_width / 2).toFixed(2)} s (${t.delay_learned ? "learnt from you" : "not learnt yet"})`],
        ["agreement", t.agreement == null ? "nothing to compare yet" : `${Math.round(t.agreement * 100)}% of ${t.compared}`],
      ]
    : [["words", "none yet"]];
  const offset = state.clock?.offset_ms;
  if (offset != null) rows.push(["clock", `${offset >= 0 ? "+" : ""}${offset.toFixed(1)} ms (round trip ${state.clock.rtt_ms?.toFixed(1)} ms)`]);
  for (const [name, value] of rows) {
    const dt = document.createElement("dt");
    dt.textContent = name;
    const dd = document.createElement("dd");
    dd.dataset.stat = name;
    dd.textContent = value;
    dl.append(dt, dd);
  }
}

function frame() {
  if (dirty) {
    dirty = false;
    state.drawn = mapView.draw();
    state.marked = mapView.marked;
    const now = performance.now();
    state.framesDrawn++;
    for (const robot of pending) {
      const o = state.obs[robot];
      state.frames.push({ robot, step: o.step, stamp: o.stamp, wall_time: o.wall_time, received: o.received, drawn: now });
    }
    pending.clear();
    if (state.frames.length > MAX_FRAMES) state.frames.splice(0, state.frames.length - MAX_FRAMES);
  }
  if (curveDirty) {
    curveDirty = false;
    curvePlot.draw();
  }
  requestAnimationFrame(frame);
}

// -- words, keys and the microphone --------------------------------------------------------

function setLanguage(language) {
  state.language = language;
  for (const b of document.querySelectorAll(".lang button")) b.classList.toggle("on", b.dataset.lang === language);
  buildButtons($("qualifiers"), $("commands"), state.welcome?.vocabulary, language, say);
  questions.render(); // its hint names the words in this language
}

function say(meaning) {
  if (!state.robot) return noRobot();
  const text = phraseFor(state.welcome?.vocabulary, state.language, meaning);
  const msg = { type: "say", robot: state.robot, text, language: state.language, onset: browserNow() };
  if (connection?.sendJson(msg)) state.said.push({ ...msg, meaning });
  if (state.trace.recording && ["forward", "back", "left", "right"].includes(meaning)) {
    state.trace.commands++;
    traceProgress(state.obs[state.robot]?.episode);
  }
}

const mic = new PushToTalk({
  onChunk(pcm, captureMs, final) {
    if (pcm.byteLength && connection?.sendBinary(audioFrame(pcm, captureMs))) {
      state.mic.chunks++;
      state.mic.sentMs += (pcm.byteLength / 2 / 16000) * 1000;
      state.mic.pressMs += (pcm.byteLength / 2 / 16000) * 1000;
      state.mic.lastCapture = captureMs;
    }
    if (final) state.mic.final = captureMs;
  },
});

function noRobot() {
  $("mic-line").className = "hint error";
  $("mic-line").textContent = "no robot is running yet: nobody to talk to";
}

async function talkStart() {
  if (state.mic.talking) return;
  if (!state.robot) return noRobot();
  state.mic.talking = true;
  state.mic.starts++;
  state.mic.error = null;
  state.mic.pressMs = 0; // audio sent during this press
  $("talk").classList.add("on");
  $("mic-line").className = "hint";
  $("mic-line").textContent = "listening… release to send";
  connection.sendJson({ type: "talk", robot: state.robot, state: "start" });
  try {
    await mic.start();
    if (!mic.held) await mic.stop(); // released while the microphone was opening
  } catch (err) {
    state.mic.error = `${err.name ?? "Error"}: ${err.message}`;
    $("mic-line").className = "hint error";
    $("mic-line").textContent = `no microphone: ${err.message}`;
  }
}

async function talkStop() {
  if (!state.mic.talking) return;
  await mic.stop();
  connection.sendJson({ type: "talk", robot: state.robot, state: "stop" });
  state.mic.talking = false;
  state.mic.stops++;
  $("talk").classList.remove("on");
  if (!state.mic.error) $("mic-line").textContent = "sent; what was understood shows below";
}

function initControls() {
  const talk = $("talk");
  talk.addEventListener("pointerdown", (e) => {
    talk.setPointerCapture?.(e.pointerId);
    talkStart();
  });
  for (const kind of ["pointerup", "pointercancel"]) talk.addEventListener(kind, talkStop);
  document.addEventListener("keydown", (e) => {
    if (state.phase !== "teaching" || e.target.closest?.("input, select, textarea")) return;
    if (e.code === "Space") {
      e.preventDefault();
      if (!e.repeat) talkStart();
      return;
    }
    if (e.ctrlKey || e.metaKey || e.altKey) return;
    const meaning = meaningOfKey(e.key);
    if (!meaning) return;
    e.preventDefault();
    if (e.repeat) return;
    flash(document, meaning);
    say(meaning);
  });
  document.addEventListener("keyup", (e) => {
    if (e.code === "Space" && state.phase === "teaching") {
      e.preventDefault();
      talkStop();
    }
  });
  for (const b of document.querySelectorAll(".lang button")) b.addEventListener("click", () => setLanguage(b.dataset.lang));
  $("robot").addEventListener("change", () => selectRobot($("robot").value));
  $("placed").addEventListener("click", () => {
    if (connection?.sendJson({ type: "placed", robot: state.robot })) $("placed").hidden = true;
  });
  $("speak-questions").checked = state.questions.speak; // off unless chosen (remembered)
  $("speak-questions").addEventListener("change", () => questions.setSpeak($("speak-questions").checked));
  for (const kind of ["pointerdown", "keydown"]) document.addEventListener(kind, () => questions.unlockSound());
  $("trace").addEventListener("change", () => {
    const on = $("trace").checked;
    state.trace = { recording: on, episode: on ? state.obs[state.robot]?.episode ?? null : null, commands: 0, done: null };
    traceProgress(state.obs[state.robot]?.episode);
  });
}

// "Record a trace": the learner keeps any episode with commands as an initial trace; this
// only guides the teacher through one episode and says when it is over.
function traceProgress(currentEpisode) {
  const t = state.trace;
  const line = $("trace-line");
  if (!t.recording) {
    line.hidden = !t.done;
    if (t.done) line.textContent = t.done;
    return;
  }
  if (t.episode == null && currentEpisode != null) t.episode = currentEpisode;
  if (t.episode != null && currentEpisode != null && currentEpisode > t.episode) {
    t.recording = false;
    t.done = t.commands
      ? `trace recorded: episode ${t.episode}, ${t.commands} command${t.commands === 1 ? "" : "s"}`
      : `episode ${t.episode} ended without a command: no trace`;
    $("trace").checked = false;
    line.className = "hint";
    line.textContent = t.done;
    return;
  }
  line.hidden = false;
  line.className = "hint trace-on";
  line.textContent = `recording trace: episode ${t.episode ?? "(waiting for the robot)"}: steer with the arrow keys (${t.commands} command${t.commands === 1 ? "" : "s"})`;
}

initLogin();
initControls();
requestAnimationFrame(frame);
setInterval(showStats, 2000); // the clock line follows the sync
