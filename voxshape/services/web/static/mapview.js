// The map seen from above: walls, obstacles, goal and start, then each robot's footprint,
// heading, laser points and recent trail, and where a robot asked a question not yet answered.

const ROBOT_LENGTH = 0.45; // metres, along the heading (the simulator's Pioneer footprint)
const ROBOT_WIDTH = 0.38;
const LASER_X = 0.15; // the laser sits this far ahead of the centre
const LASER_MAX = 8.0; // a beam this long hit nothing
const TRAIL = 300; // poses kept per robot
const COLOURS = ["#2454c5", "#c2410c", "#7c3aed", "#0f766e"];

export class MapView {
  constructor(canvas) {
    this.canvas = canvas;
    this.ctx = canvas.getContext("2d");
    this.map = null;
    this.robots = new Map(); // robot -> {obs, trail: [[x, y]...], colour}
    this.selected = null;
    this.questions = {}; // robot -> {question, answer} (Questions' open state)
    this.marked = []; // the questions marked at the last draw: [{robot, question, x, y}]
  }

  setMap(map) {
    this.map = map;
    const ratio = window.devicePixelRatio || 1;
    const cssWidth = this.canvas.clientWidth || 640;
    const aspect = map && map.width > 0 ? map.height / map.width : 0.75;
    this.canvas.width = Math.round(cssWidth * ratio);
    this.canvas.height = Math.round(cssWidth * aspect * ratio);
  }

  // Keeps the latest observation of a robot and its trail (cleared when an episode starts).
  update(obs) {
    let robot = this.robots.get(obs.robot);
    if (!robot) {
      robot = { obs: null, trail: [], colour: COLOURS[this.robots.size % COLOURS.length] };
      this.robots.set(obs.robot, robot);
    }
    if (robot.obs && robot.obs.episode !== obs.episode) robot.trail = [];
    robot.obs = obs;
    robot.trail.push([obs.x, obs.y]);
    if (robot.trail.length > TRAIL) robot.trail.shift();
  }

  // World (metres, y up) to canvas pixels, with a margin.
  _transform() {
    const { width, height } = this.map ?? { width: 6, height: 6 };
    const margin = 10 * (window.devicePixelRatio || 1);
    const scale = Math.min(
      (this.canvas.width - 2 * margin) / width,
      (this.canvas.height - 2 * margin) / height,
    );
    const left = (this.canvas.width - scale * width) / 2;
    const top = (this.canvas.height - scale * height) / 2;
    return { scale, toX: (x) => left + x * scale, toY: (y) => top + (height - y) * scale };
  }

  // Draws everything; returns the pose drawn for each robot.
  draw() {
    const { ctx, canvas } = this;
    ctx.clearRect(0, 0, canvas.width, canvas.height);
    const t = this._transform();
    if (this.map) this._drawMap(t);
    ctx.save();
    if (this.map) {
      ctx.beginPath();
      ctx.rect(t.toX(0), t.toY(this.map.height), this.map.width * t.scale, this.map.height * t.scale);
      ctx.clip();
    }
    this.marked = [];
    for (const [name, { question, answer }] of Object.entries(this.questions)) {
      if (!question || answer || !Number.isFinite(question.x) || !Number.isFinite(question.y)) continue;
      this._questionMark(t, question, this.robots.get(name)?.colour ?? COLOURS[0]);
      this.marked.push({ robot: name, question: question.question, x: question.x, y: question.y });
    }
    const drawn = {};
    for (const [name, robot] of this.robots) {
      if (!robot.obs) continue;
      this._drawRobot(t, robot, name === this.selected);
      drawn[name] = { x: robot.obs.x, y: robot.obs.y, theta: robot.obs.theta, step: robot.obs.step };
    }
    ctx.restore();
    return drawn;
  }

  // A dashed ring with "?" where the robot asked, under the robots.
  _questionMark(t, q, colour) {
    const { ctx } = this;
    ctx.beginPath();
    ctx.arc(t.toX(q.x), t.toY(q.y), 0.4 * t.scale, 0, 2 * Math.PI);
    ctx.fillStyle = "rgba(250, 204, 21, 0.35)";
    ctx.fill();
    ctx.lineWidth = 2;
    ctx.strokeStyle = colour;
    ctx.setLineDash([4, 3]);
    ctx.stroke();
    ctx.setLineDash([]);
    this._label(t, "?", q.x + 0.4, q.y + 0.3, colour, 20, "bold"); // beside the robot, often still there
  }

  _drawMap(t) {
    const { ctx } = this;
    const m = this.map;
    ctx.fillStyle = "#ffffff";
    ctx.fillRect(t.toX(0), t.toY(m.height), m.width * t.scale, m.height * t.scale);
    if (m.goal) {
      ctx.beginPath();
      ctx.arc(t.toX(m.goal.x), t.toY(m.goal.y), m.goal.radius * t.scale, 0, 2 * Math.PI);
      ctx.fillStyle = "rgba(19, 122, 58, 0.18)";
      ctx.fill();
      ctx.strokeStyle = "#137a3a";
      ctx.lineWidth = 2;
      ctx.stroke();
      this._label(t, "goal", m.goal.x, m.goal.y, "#137a3a");
    }
    if (m.start) {
      const theta = m.start.theta ?? 0;
      this._arrow(t, m.start.x, m.start.y, theta, 0.35, "#9aa3b2");
      this._label(t, "start", m.start.x, m.start.y - 0.3, "#6b7280");
    }
    ctx.fillStyle = "#4b5563";
    ctx.strokeStyle = "#1f2937";
    for (const shape of m.obstacles ?? []) this._shape(t, shape);
    ctx.lineCap = "square";
    ctx.lineWidth = Math.max(2, (m.wall_thickness ?? 0.1) * t.scale);
    ctx.strokeStyle = "#1f2937";
    ctx.strokeRect(t.toX(0), t.toY(m.height), m.width * t.scale, m.height * t.scale);
    for (const [x0, y0, x1, y1] of m.walls ?? []) {
      ctx.beginPath();
      ctx.moveTo(t.toX(x0), t.toY(y0));
      ctx.lineTo(t.toX(x1), t.toY(y1));
      ctx.stroke();
    }
  }

  // An obstacle: a polygon ({corners}), a circle ({x, y, r or radius} or [x, y, r]), a box
  // ({x, y, width, depth, angle}) or a segment [x0, y0, x1, y1].
  _shape(t, s) {
    const { ctx } = this;
    ctx.beginPath();
    if (Array.isArray(s) && s.length === 3) s = { x: s[0], y: s[1], radius: s[2] };
    if (Array.isArray(s) && s.length === 4) {
      ctx.lineWidth = Math.max(2, 0.1 * t.scale);
      ctx.moveTo(t.toX(s[0]), t.toY(s[1]));
      ctx.lineTo(t.toX(s[2]), t.toY(s[3]));
      ctx.stroke();
      return;
    }
    const corners = s.corners ?? s.polygon ?? (s.width !== undefined ? boxCorners(s) : null);
    if (corners) {
      corners.forEach(([x, y], i) => (i ? ctx.lineTo(t.toX(x), t.toY(y)) : ctx.moveTo(t.toX(x), t.toY(y))));
      ctx.closePath();
    } else if ((s.radius ?? s.r) !== undefined) {
      ctx.arc(t.toX(s.x), t.toY(s.y), (s.radius ?? s.r) * t.scale, 0, 2 * Math.PI);
    }
    ctx.fill();
  }

  _drawRobot(t, robot, selected) {
    const { ctx } = this;
    const o = robot.obs;
    ctx.strokeStyle = robot.colour;
    ctx.globalAlpha = 0.45;
    ctx.lineWidth = 2;
    ctx.beginPath();
    robot.trail.forEach(([x, y], i) => (i ? ctx.lineTo(t.toX(x), t.toY(y)) : ctx.moveTo(t.toX(x), t.toY(y))));
    ctx.stroke();
    ctx.globalAlpha = 1;
    this._laser(t, o);
    const corners = boxCorners({ x: o.x, y: o.y, width: ROBOT_LENGTH, depth: ROBOT_WIDTH, angle: o.theta });
    ctx.beginPath();
    corners.forEach(([x, y], i) => (i ? ctx.lineTo(t.toX(x), t.toY(y)) : ctx.moveTo(t.toX(x), t.toY(y))));
    ctx.closePath();
    ctx.fillStyle = o.collided ? "#fca5a5" : "#ffffff";
    ctx.fill();
    ctx.lineWidth = selected ? 3 : 2;
    ctx.strokeStyle = robot.colour;
    ctx.stroke();
    this._arrow(t, o.x, o.y, o.theta, ROBOT_LENGTH * 0.7, robot.colour);
    this._label(t, o.robot, o.x, o.y + 0.38, robot.colour);
  }

  // Laser hits: beams spread evenly from laser_angles[0] to [1] around the heading.
  _laser(t, o) {
    const ranges = o.laser ?? [];
    if (!ranges.length || !o.laser_angles) return;
    const [first, last] = o.laser_angles;
    const n = ranges.length;
    const step = n > 1 ? (last - first) / (n - 1) : 0;
    const lx = o.x + LASER_X * Math.cos(o.theta);
    const ly = o.y + LASER_X * Math.sin(o.theta);
    const { ctx } = this;
    ctx.fillStyle = "#dc2626";
    const size = Math.max(2, (window.devicePixelRatio || 1) * 2);
    for (let i = 0; i < n; i++) {
      const r = ranges[i];
      if (!(r < LASER_MAX - 1e-3)) continue;
      const a = o.theta + first + i * step;
      ctx.fillRect(t.toX(lx + r * Math.cos(a)) - size / 2, t.toY(ly + r * Math.sin(a)) - size / 2, size, size);
    }
  }

  _arrow(t, x, y, theta, length, colour) {
    const { ctx } = this;
    const tipX = x + length * Math.cos(theta);
    const tipY = y + length * Math.sin(theta);
    ctx.strokeStyle = colour;
    ctx.lineWidth = 2;
    ctx.beginPath();
    ctx.moveTo(t.toX(x), t.toY(y));
    ctx.lineTo(t.toX(tipX), t.toY(tipY));
    for (const side of [2.6, -2.6]) {
      ctx.moveTo(t.toX(tipX), t.toY(tipY));
      ctx.lineTo(t.toX(tipX + 0.12 * Math.cos(theta + side)), t.toY(tipY + 0.12 * Math.sin(theta + side)));
    }
    ctx.stroke();
  }

  // size: CSS pixels; weight: a CSS font weight
  _label(t, text, x, y, colour, size = 12, weight = "normal") {
    const { ctx } = this;
    ctx.fillStyle = colour;
    ctx.font = `${weight} ${size * (window.devicePixelRatio || 1)}px system-ui, sans-serif`;
    ctx.textAlign = "center";
    ctx.fillText(text, t.toX(x), t.toY(y));
  }
}

// Corners of an oriented box (angle in radians, counter-clockwise).
function boxCorners({ x, y, width, depth, angle = 0 }) {
  const c = Math.cos(angle);
  const s = Math.sin(angle);
  return [[-1, -1], [1, -1], [1, 1], [-1, 1]].map(([u, v]) => {
    const dx = (u * width) / 2;
    const dy = (v * depth) / 2;
    return [x + c * dx - s * dy, y + s * dx + c * dy];
  });
}
