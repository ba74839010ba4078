// The robots' questions ("r1 asks: which way? stuck for 10 s"): shown in an aria-live box, a
// short chime (a WebAudio oscillator), read aloud if the teacher chose so; "answered by ana:
// left" once someone answers. Bus text only ever goes in as textContent.

const SPEAK_KEY = "voxshape.speakQuestions";

export class Questions {
  // box: the aria-live element; state: {open: {robot -> entry}, asked, answers, chimes,
  // spoken, speak, unanswered_ms, answered_ms} (window.voxshape.questions, for tests).
  // changed: called when the open questions change (the map marks where they were asked);
  // phrase(meaning): the page's phrase for a meaning, in the language it is set to.
  constructor(box, state, { changed = () => {}, phrase = (meaning) => meaning } = {}) {
    this.box = box;
    this.state = state;
    this.changed = changed;
    this.phrase = phrase;
    this.watched = null;
    this.audio = null;
    state.speak = localStorage.getItem(SPEAK_KEY) === "1";
  }

  setSpeak(on) {
    this.state.speak = on;
    localStorage.setItem(SPEAK_KEY, on ? "1" : "0");
  }

  // A page may play sound only after a gesture of the teacher's (the login, a click).
  unlockSound() {
    try {
      this.audio ??= new AudioContext();
      if (this.audio.state === "suspended") this.audio.resume();
    } catch {
      this.audio = null; // no WebAudio: questions are shown, silently
    }
  }

  ask(msg) {
    const s = this.state;
    s.open[msg.robot] = { question: msg, answer: null };
    s.asked.push(msg);
    if (s.asked.length > 50) s.asked.shift();
    this.chime();
    if (s.speak && window.speechSynthesis) {
      const words = new SpeechSynthesisUtterance(msg.text);
      words.lang = "en";
      speechSynthesis.speak(words);
      s.spoken++;
    }
    this.render();
    setTimeout(() => this.clear(msg.robot, msg.question, false), s.unanswered_ms);
  }

  answer(msg) {
    const s = this.state;
    const entry = s.open[msg.robot];
    if (entry?.question?.question === msg.question) entry.answer = msg;
    else if (!entry || entry.answer) s.open[msg.robot] = { question: null, answer: msg }; // asked before this page came
    s.answers.push(msg);
    if (s.answers.length > 50) s.answers.shift();
    this.render();
    setTimeout(() => this.clear(msg.robot, msg.question, true), s.answered_ms);
  }

  // Clears a robot's question, unless another has replaced it (or, unanswered, it was
  // answered meanwhile: its own, shorter, timer clears it then).
  clear(robot, question, answered) {
    const entry = this.state.open[robot];
    const id = entry?.question?.question ?? entry?.answer?.question;
    if (id !== question || (!answered && entry.answer)) return;
    delete this.state.open[robot];
    this.render();
  }

  watch(robot) {
    this.watched = robot;
    this.render();
  }

  render() {
    const lines = [];
    for (const [robot, { question, answer }] of Object.entries(this.state.open)) {
      const p = document.createElement("p");
      p.dataset.robot = robot;
      if (answer) {
        p.className = "answered";
        p.textContent = question ? `${question.text} · ${answer.text}` : `${robot}: ${answer.text}`;
      } else {
        p.className = "asked";
        p.textContent = question.text;
        const hint = document.createElement("span");
        hint.className = "hint";
        const [left, right, forward] = ["left", "right", "forward"].map(this.phrase);
        hint.textContent =
          robot === this.watched ? `say or click ${left}, ${right} or ${forward}` : `choose ${robot} above to answer`;
        p.append(" ", hint);
      }
      lines.push(p);
    }
    this.box.replaceChildren(...lines);
    this.changed();
  }

  chime() {
    const ctx = this.audio;
    this.state.chimes++;
    if (!ctx || ctx.state !== "running") return;
    const t = ctx.currentTime;
    const osc = ctx.createOscillator();
    const gain = ctx.createGain();
    osc.frequency.setValueAtTime(660, t);
    osc.frequency.setValueAtTime(880, t + 0.12);
    gain.gain.setValueAtTime(0.0001, t);
    gain.gain.exponentialRampToValueAtTime(0.2, t + 0.02);
    gain.gain.exponentialRampToValueAtTime(0.0001, t + 0.3);
    osc.connect(gain).connect(ctx.destination);
    osc.start(t);
    osc.stop(t + 0.32);
    this.state.played++;
  }
}
