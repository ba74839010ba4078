// The learning curve: return, steps and interventions per episode, three stacked panels
// sharing the episode axis, each with its labelled y axis.

const SERIES = [
  { key: "return", label: "return", colour: "#2454c5" },
  { key: "steps", label: "steps", colour: "#c2410c" },
  { key: "interventions", label: "interventions", colour: "#137a3a" },
];

export class CurvePlot {
  constructor(canvas) {
    this.canvas = canvas;
    this.ctx = canvas.getContext("2d");
    this.points = []; // {episode, return, steps, interventions}, one per ended episode
  }

  // Adds (or replaces) an episode's point; returns whether it changed the curve.
  add(point) {
    const i = this.points.findIndex((p) => p.episode === point.episode);
    if (i >= 0) this.points[i] = point;
    else this.points.push(point);
    this.points.sort((a, b) => a.episode - b.episode);
    return true;
  }

  clear() {
    this.points = [];
  }

  draw() {
    const { ctx, canvas } = this;
    const ratio = window.devicePixelRatio || 1;
    const cssWidth = canvas.clientWidth || 640;
    if (canvas.width !== Math.round(cssWidth * ratio)) {
      canvas.width = Math.round(cssWidth * ratio);
      canvas.height = Math.round(300 * ratio);
    }
    ctx.setTransform(ratio, 0, 0, ratio, 0, 0);
    const width = canvas.width / ratio;
    const height = canvas.height / ratio;
    ctx.clearRect(0, 0, width, height);
    ctx.font = "11px system-ui, sans-serif";
    const left = 56;
    const right = 12;
    const top = 8;
    const bottom = 30;
    const gap = 10;
    const panel = (height - top - bottom - gap * (SERIES.length - 1)) / SERIES.length;
    const episodes = this.points.map((p) => p.episode);
    const e0 = episodes.length ? Math.min(...episodes) : 0;
    const e1 = episodes.length ? Math.max(...episodes) : 1;
    const toX = (e) => left + ((e - e0) / Math.max(1, e1 - e0)) * (width - left - right);
    SERIES.forEach((series, k) => {
      const y0 = top + k * (panel + gap);
      const values = this.points.map((p) => p[series.key]).filter((v) => typeof v === "number");
      const [lo, hi] = niceRange(values);
      const toY = (v) => y0 + panel - ((v - lo) / (hi - lo)) * panel;
      ctx.strokeStyle = "#d9dde5";
      ctx.lineWidth = 1;
      ctx.strokeRect(left, y0, width - left - right, panel);
      ctx.fillStyle = "#6b7280";
      ctx.textAlign = "right";
      ctx.textBaseline = "middle";
      for (const v of [lo, (lo + hi) / 2, hi]) ctx.fillText(formatTick(v), left - 4, toY(v));
      ctx.save();
      ctx.translate(12, y0 + panel / 2);
      ctx.rotate(-Math.PI / 2);
      ctx.textAlign = "center";
      ctx.fillStyle = series.colour;
      ctx.fillText(series.label, 0, 0);
      ctx.restore();
      ctx.strokeStyle = series.colour;
      ctx.fillStyle = series.colour;
      ctx.lineWidth = 1.5;
      ctx.beginPath();
      let started = false;
      for (const p of this.points) {
        const v = p[series.key];
        if (typeof v !== "number") continue;
        if (started) ctx.lineTo(toX(p.episode), toY(v));
        else ctx.moveTo(toX(p.episode), toY(v));
        started = true;
      }
      ctx.stroke();
      for (const p of this.points) {
        if (typeof p[series.key] === "number") ctx.fillRect(toX(p.episode) - 1.5, toY(p[series.key]) - 1.5, 3, 3);
      }
    });
    ctx.fillStyle = "#6b7280";
    ctx.textAlign = "center";
    ctx.textBaseline = "top";
    const axisY = height - bottom + 4;
    for (const e of episodeTicks(e0, e1)) ctx.fillText(String(e), toX(e), axisY);
    ctx.fillText(this.points.length ? "episode" : "episode (none ended yet)", left + (width - left - right) / 2, axisY + 13);
  }
}

function niceRange(values) {
  if (!values.length) return [0, 1];
  let lo = Math.min(...values);
  let hi = Math.max(...values);
  if (hi - lo < 1e-9) {
    lo -= 1;
    hi += 1;
  }
  const pad = (hi - lo) * 0.05;
  return [lo - pad, hi + pad];
}

function formatTick(v) {
  const a = Math.abs(v);
  if (a >= 1000) return `${(v / 1000).toFixed(1)}k`;
  return a >= 10 ? v.toFixed(0) : v.toFixed(1);
}

function episodeTicks(e0, e1) {
  const span = Math.max(1, e1 - e0);
  const step = Math.max(1, Math.ceil(span / 8));
  const ticks = [];
  for (let e = e0; e <= e1; e += step) ticks.push(e);
  return ticks;
}
