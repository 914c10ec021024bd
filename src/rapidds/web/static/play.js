// The fetch game's page: draws what the server simulates and sends the player's inputs.
// No simulation happens here. window.rapidds holds the latest messages (for tests and debugging).
// A study round (rapidds study serve) serves this page with <body data-ws="/p/ID/ws"> and
// welcome.next, the study page to go on to once the round is recorded (phase "done").
"use strict";

const R = (window.rapidds = {
  connected: false, refused: null, phase: "connecting", info: null, plan: null, state: null,
  summary: null, lastRefusal: null, frames: 0, error: null,
  ended: {},  // cycle -> its last state: the next cycle replaces "over" on screen a tick later
});

const COLORS = {
  human: "#e8910c", robot: "#2f6fe4", wall: "#334155", floor: "#f8fafc", grid: "#e8edf3",
  locked: "#a3a9b3", text: "#0f172a",
};
const $ = (id) => document.getElementById(id);
const map = $("map"), mctx = map.getContext("2d");
const gantt = $("gantt"), gctx = gantt.getContext("2d");
const curve = $("curve"), cctx = curve.getContext("2d");
let ws = null, seq = 0, retry = 0, heatImage = null, heatFor = -1;
const UNIT = document.body.dataset.ws ? "round" : "cycle";  // a study plays rounds
const Unit = UNIT[0].toUpperCase() + UNIT.slice(1);

// ---------------------------------------------------------------------------- connection
function connect() {
  const proto = location.protocol === "https:" ? "wss:" : "ws:";
  ws = new WebSocket(`${proto}//${location.host}${document.body.dataset.ws || "/ws"}`);
  ws.onopen = () => { R.connected = true; retry = 0; seq = 0; setConn("on"); };
  ws.onmessage = (ev) => receive(JSON.parse(ev.data));
  ws.onclose = () => {
    R.connected = false; setConn("off");
    if (R.refused) return;  // another browser plays this run: do not fight it
    R.phase = "disconnected"; render();
    setTimeout(connect, Math.min(5000, 500 * 2 ** retry++));
  };
}
function setConn(c) { $("conn").className = "dot " + c; }
function send(obj) {
  if (!ws || ws.readyState !== WebSocket.OPEN) return;
  seq += 1;
  ws.send(JSON.stringify({ ...obj, seq }));
}

function receive(m) {
  switch (m.type) {
    case "state": R.state = m; R.frames += 1; if (m.over) R.ended[m.cycle] = m; break;
    case "welcome": R.info = m; R.refused = null; $("run").textContent = m.adapt ? `${m.run_id} · ${m.adapt} adaptation` : m.run_id; break;
    case "plan": R.plan = m; break;
    case "summary": R.summary = m; heatFor = -1; showSummary(); break;
    case "phase":
      R.phase = m.phase; R.error = m.error;
      if (m.phase === "done" && R.info && R.info.next) setTimeout(() => location.assign(R.info.next), 600);
      break;
    case "refused": R.refused = m.reason; R.phase = "refused"; break;
    case "refused-message": R.lastRefusal = m.reason; console.warn("server refused:", m.reason); break;
  }
  if (m.type !== "state") render();
}

// ---------------------------------------------------------------------------- input
const KEYS = {
  ArrowUp: [0, 1], KeyW: [0, 1], ArrowDown: [0, -1], KeyS: [0, -1],
  ArrowLeft: [-1, 0], KeyA: [-1, 0], ArrowRight: [1, 0], KeyD: [1, 0],
};
const held = new Set();
let lastMove = "0,0";
function sendMove() {
  let dx = 0, dy = 0;
  for (const k of held) { dx += KEYS[k][0]; dy += KEYS[k][1]; }
  dx = Math.sign(dx); dy = Math.sign(dy);
  const key = `${dx},${dy}`;
  if (key !== lastMove) { lastMove = key; send({ type: "move", dx, dy }); }
}
window.addEventListener("keydown", (e) => {
  if (KEYS[e.code]) { e.preventDefault(); held.add(e.code); sendMove(); }
  else if ((e.code === "Enter" || e.code === "Space") && canStart()) { e.preventDefault(); start(); }
  else if (e.code === "KeyT" && !e.repeat) { e.preventDefault(); tooClose(); }
  else if (asking() && /^Digit[1-7]$/.test(e.code)) { e.preventDefault(); send({ type: "comfort", cycle: R.state.cycle, answer: Number(e.code.at(-1)) }); }
});
window.addEventListener("keyup", (e) => { if (KEYS[e.code]) { held.delete(e.code); sendMove(); } });
window.addEventListener("blur", () => { held.clear(); sendMove(); });
map.addEventListener("pointerdown", (e) => {
  if (!R.info) return;
  const [x, y] = toWorld(e.offsetX * map.width / map.clientWidth, e.offsetY * map.height / map.clientHeight);
  send({ type: "target", x: +x.toFixed(3), y: +y.toFixed(3) });
});
$("start").addEventListener("click", () => start());
// what the person says: "too close" during a cycle (timed by the server), and after it their
// agreement with "the robot came too close to me" (1-7), asked once the cycle is over
function canSignal() { return R.phase === "playing" && R.state && R.state.started && !R.state.over; }
function tooClose() { if (canSignal()) send({ type: "too_close", cycle: R.state.cycle }); }
function asking() { return !!(R.state && R.state.ask); }
$("tooclose").addEventListener("click", () => tooClose());
for (let a = 1; a <= 7; a++) {
  const b = document.createElement("button");
  b.type = "button"; b.textContent = String(a); b.dataset.answer = String(a);
  b.addEventListener("click", () => { if (asking()) send({ type: "comfort", cycle: R.state.cycle, answer: a }); });
  $("comfort-answers").appendChild(b);
}
$("heat").addEventListener("change", () => { showHeatLegend(); drawMap(); });
function canStart() { return R.phase === "ready" && R.plan && R.state && !R.state.started; }
function start() { if (canStart()) send({ type: "start", cycle: R.plan.cycle }); }

// ---------------------------------------------------------------------------- geometry
function scale() { const [lo, hi] = R.info.scene.bounds; return map.width / (hi[0] - lo[0]); }
function toPx(x, y) {
  const [lo, hi] = R.info.scene.bounds, s = scale();
  return [(x - lo[0]) * s, (hi[1] - y) * s];
}
function toWorld(px, py) {
  const [lo, hi] = R.info.scene.bounds, s = scale();
  return [lo[0] + px / s, hi[1] - py / s];
}

// ---------------------------------------------------------------------------- drawing: map
function drawMap() {
  const c = mctx, W = map.width, H = map.height;
  c.clearRect(0, 0, W, H);
  c.fillStyle = COLORS.floor; c.fillRect(0, 0, W, H);
  if (!R.info) return;
  const sc = R.info.scene, s = scale();
  c.strokeStyle = COLORS.grid; c.lineWidth = 1;
  for (let m = 1; m < 10; m++) {
    const [x] = toPx(m, 0), [, y] = toPx(0, m);
    c.beginPath(); c.moveTo(x, 0); c.lineTo(x, H); c.moveTo(0, y); c.lineTo(W, y); c.stroke();
  }
  if ($("heat").checked && R.summary) drawHeat();
  c.fillStyle = COLORS.wall;
  for (const [x0, y0, x1, y1] of sc.walls) {
    const [a, b] = toPx(x0, y1), [d, e] = toPx(x1, y0);
    roundRect(c, a, b, d - a, e - b, 3); c.fill();
  }
  const st = R.state, plan = R.plan;
  // the robot's planned paths: the current one strong, the others faint
  if (plan) {
    for (const [task, path] of Object.entries(plan.robot_paths)) {
      const status = st && st.tasks[task];
      if (status === "done") continue;
      const cur = st && st.rcur === task;
      drawPath(path, COLORS.robot, cur ? 0.85 : 0.35, cur ? 3 : 2, [7, 6]);
    }
  }
  // homes
  for (const [agent, p] of Object.entries(sc.homes)) {
    const [x, y] = toPx(...p), r = sc.reach * s;
    c.fillStyle = agent === "human" ? "rgba(232,145,12,.13)" : "rgba(47,111,228,.12)";
    c.strokeStyle = agent === "human" ? COLORS.human : COLORS.robot;
    c.setLineDash([4, 4]); c.lineWidth = 1.5;
    c.beginPath(); c.arc(x, y, r, 0, 2 * Math.PI); c.fill(); c.stroke(); c.setLineDash([]);
    label(agent === "human" ? "your home" : "robot home", x, y + r + 13, c.strokeStyle, 11);
  }
  if (st && st.target) {
    const [x, y] = toPx(...st.target);
    c.strokeStyle = COLORS.human; c.lineWidth = 2;
    c.beginPath(); c.moveTo(x - 6, y - 6); c.lineTo(x + 6, y + 6); c.moveTo(x + 6, y - 6); c.lineTo(x - 6, y + 6); c.stroke();
  }
  // objects
  for (const [task, p] of Object.entries(sc.objects)) drawObject(task, p);
  // agents
  const rp = st ? st.r : sc.homes.robot, hp = st ? st.h : sc.homes.human;
  drawAgent(rp, ROBOT_STATE[st && st.robot] ? ROBOT_STATE[st.robot].color : COLORS.robot, "R", true);
  const why = st && st.started && !st.over ? (reacting(st) || robotWaits()) : null;
  if (why) { const [x, y] = toPx(...rp); label(why, x, y - 20, COLORS.robot, 11); }
  drawAgent(hp, COLORS.human, "you", false);
  if (st) {
    for (const [task, status] of Object.entries(st.tasks)) {
      if (status !== "carried" || !plan) continue;
      const at = ownerOf(task) === "human" ? st.h : st.r;
      const [x, y] = toPx(...at);
      objectGlyph(x + 11, y - 13, task, ownerOf(task), "carried", 0);
    }
  }
}

// ---------------------------------------------------------------------------- the reactive robot
// With --execution reactive the state says how the robot moves (speed and separation
// monitoring), who does what now (a re-plan or a task the person took) and what they may take.
const ROBOT_STATE = {
  stopped: { color: "#dc2626", text: "stopped: you are within its protective distance" },
  slowed: { color: "#d97706", text: "slowed: you are close" },
};
function ownerOf(task) {
  const st = R.state;
  return (st && st.owner && st.owner[task]) || (R.plan ? R.plan.owner[task] : null);
}
function reacting(st) { return ROBOT_STATE[st.robot] ? ROBOT_STATE[st.robot].text : null; }
function robotLine() {
  const st = R.state;
  if (!st || st.execution !== "reactive" || !st.started) return "";
  const moving = { idle: "idle", moving: "moving" }[st.robot] || reacting(st);
  const last = st.replans.length ? st.replans[st.replans.length - 1] : null;
  const why = last && { order: `you took ${last.task} first`, took: `you took its ${last.task}`, overran: `${last.task} ran long` }[last.reason];
  const next = st.robot_next.length ? ` · next: ${st.robot_next.join(" → ")}` : "";
  return `Robot ${moving}${next}` + (last ? ` · re-planned at ${last.t.toFixed(1)} s (${why})` : "");
}

// plan.items: per agent, [{task: id} | {wait: id}], structured by the server (the text of a wait
// item is rapidds.schedule's business, not the page's)
const tasksOf = (items) => items.filter((x) => x.task !== undefined).map((x) => x.task);
function waitsBefore(items, task) {
  const k = items.findIndex((x) => x.task === task);
  return items.slice(0, k).filter((x) => x.wait !== undefined).map((x) => x.wait);
}

function robotWaits() {
  // what the robot is waiting for, if it is standing still before its next task
  const st = R.state, plan = R.plan, next = st.rcur;
  if (!next || !["locked", "queued"].includes(st.tasks[next])) return null;
  const open = [...waitsBefore(plan.items.robot, next), ...plan.preceding[next]]
    .filter((t) => st.tasks[t] !== "done");
  return open.length ? `waits for ${[...new Set(open)].join(", ")}` : null;
}

function drawHeat() {
  const h = R.summary.heat, tasks = Object.keys(h.learned);
  if (!tasks.length) return;
  const [nx, ny] = h.shape;
  if (heatFor !== R.summary.cycle) {
    const img = new ImageData(nx, ny), top = Math.max(h.max, 1e-6);
    for (let i = 0; i < nx; i++) for (let j = 0; j < ny; j++) {
      let v = 0;
      for (const t of tasks) v = Math.max(v, h.learned[t][i * ny + j]);
      const u = Math.min(1, v / top), k = 4 * ((ny - 1 - j) * nx + i);
      img.data[k] = 230; img.data[k + 1] = Math.round(200 - 150 * u); img.data[k + 2] = Math.round(60 - 40 * u);
      img.data[k + 3] = Math.round(215 * u ** 1.4);
    }
    heatImage = document.createElement("canvas"); heatImage.width = nx; heatImage.height = ny;
    heatImage.getContext("2d").putImageData(img, 0, 0); heatFor = R.summary.cycle;
  }
  const lo = [h.bounds[0][0], h.bounds[1][0]], hi = [h.bounds[0][1], h.bounds[1][1]];
  const cx = (hi[0] - lo[0]) / (nx - 1), cy = (hi[1] - lo[1]) / (ny - 1);
  const [a, b] = toPx(lo[0] - cx / 2, hi[1] + cy / 2), [d, e] = toPx(hi[0] + cx / 2, lo[1] - cy / 2);
  mctx.imageSmoothingEnabled = true;
  mctx.drawImage(heatImage, a, b, d - a, e - b);
}

function drawPath(path, color, alpha, width, dash) {
  const c = mctx;
  c.save(); c.globalAlpha = alpha; c.strokeStyle = color; c.lineWidth = width; c.setLineDash(dash);
  c.beginPath();
  path.forEach(([x, y], i) => { const [a, b] = toPx(x, y); i ? c.lineTo(a, b) : c.moveTo(a, b); });
  c.stroke(); c.restore();
}

function drawAgent(p, color, text, square) {
  const c = mctx, [x, y] = toPx(...p), r = 11;
  c.fillStyle = color; c.strokeStyle = "#fff"; c.lineWidth = 2.5;
  c.beginPath();
  if (square) roundRect(c, x - r, y - r, 2 * r, 2 * r, 5); else c.arc(x, y, r, 0, 2 * Math.PI);
  c.fill(); c.stroke();
  c.fillStyle = "#fff"; c.font = "bold 9px system-ui, sans-serif"; c.textAlign = "center"; c.textBaseline = "middle";
  c.fillText(text, x, y + 0.5);
}

function orderOf(task) {
  if (!R.plan) return null;
  return tasksOf(R.plan.items[R.plan.owner[task]]).indexOf(task) + 1;
}

function drawObject(task, p) {
  const st = R.state, plan = R.plan;
  const status = st ? st.tasks[task] : "queued";
  const owner = ownerOf(task);
  if (status === "carried") return;  // drawn on its carrier
  const [x, y] = toPx(...p);
  if (status === "done") {
    objectGlyph(x, y, task, owner, "done", 0);
    return;
  }
  const open = (status === "active" && owner === "human") || (st && st.takeable && st.takeable.includes(task));
  const pulse = open ? 0.5 + 0.5 * Math.sin(performance.now() / 180) : 0;
  objectGlyph(x, y, task, owner, status, pulse);
}

function objectGlyph(x, y, task, owner, status, pulse) {
  const c = mctx, s = 10;
  const color = owner === "human" ? COLORS.human : owner === "robot" ? COLORS.robot : "#64748b";
  c.save();
  if (status === "done") c.globalAlpha = 0.28;
  if (pulse) {
    c.strokeStyle = color; c.globalAlpha = 0.35 + 0.4 * pulse; c.lineWidth = 3;
    c.beginPath(); c.arc(x, y, 18 + 5 * pulse, 0, 2 * Math.PI); c.stroke(); c.globalAlpha = 1;
  }
  c.fillStyle = status === "locked" ? COLORS.locked : color;
  c.strokeStyle = "#fff"; c.lineWidth = 2;
  roundRect(c, x - s, y - s, 2 * s, 2 * s, 4); c.fill(); c.stroke();
  c.fillStyle = "#fff"; c.font = "bold 11px system-ui, sans-serif"; c.textAlign = "center"; c.textBaseline = "middle";
  c.fillText(task, x, y + 0.5);
  if (status === "locked") {  // a padlock
    c.fillStyle = "#475569"; c.strokeStyle = "#475569"; c.lineWidth = 2;
    c.beginPath(); c.arc(x + s + 2, y - s - 2, 4, Math.PI, 0); c.stroke();
    c.fillRect(x + s - 3, y - s - 2, 10, 8);
  }
  if (status !== "done" && status !== "carried" && owner) {
    const n = orderOf(task);
    label(`${owner === "human" ? "you" : "robot"} #${n}`, x, y + s + 12, color, 11);
  }
  c.restore();
}

function label(text, x, y, color, size) {
  const c = mctx;
  c.font = `600 ${size}px system-ui, sans-serif`; c.textAlign = "center"; c.textBaseline = "middle";
  c.lineWidth = 3; c.strokeStyle = "rgba(255,255,255,.9)"; c.strokeText(text, x, y);
  c.fillStyle = color; c.fillText(text, x, y);
}

function roundRect(c, x, y, w, h, r) {
  c.beginPath(); c.moveTo(x + r, y); c.arcTo(x + w, y, x + w, y + h, r); c.arcTo(x + w, y + h, x, y + h, r);
  c.arcTo(x, y + h, x, y, r); c.arcTo(x, y, x + w, y, r); c.closePath();
}

// ---------------------------------------------------------------------------- drawing: Gantt
function drawGantt() {
  const c = gctx, W = gantt.width, H = gantt.height;
  c.clearRect(0, 0, W, H); c.fillStyle = "#fff"; c.fillRect(0, 0, W, H);
  const plan = R.plan;
  c.font = "600 12px system-ui, sans-serif"; c.textBaseline = "middle"; c.textAlign = "left";
  if (!plan) { c.fillStyle = "#64748b"; c.fillText("the plan of the coming cycle appears here", 16, H / 2); return; }
  const st = R.state, live = st && st.cycle === plan.cycle ? st : null;
  const x0 = 64, x1 = W - 14, rows = { human: 34, robot: 80 }, bh = 26;
  let end = plan.expected_makespan;
  if (live) for (const [, [s, f]] of Object.entries(live.times)) end = Math.max(end, f ?? live.t, s);
  if (live) end = Math.max(end, live.t);
  end = Math.max(4, Math.ceil((end + 0.5) / 2) * 2);
  const X = (t) => x0 + (x1 - x0) * t / end;
  c.fillStyle = "#0f172a"; c.fillText(`${UNIT} ${plan.cycle + 1} plan`, 8, 11);
  c.fillStyle = "#64748b"; c.font = "11px system-ui, sans-serif";
  c.fillText(`expected makespan ${plan.expected_makespan.toFixed(1)} s · bars: expected (light), actual (solid)`, 120, 11);
  for (let t = 0; t <= end; t += end > 20 ? 4 : 2) {
    c.strokeStyle = "#eef2f7"; c.beginPath(); c.moveTo(X(t), 22); c.lineTo(X(t), H - 14); c.stroke();
    c.fillStyle = "#94a3b8"; c.textAlign = "center"; c.fillText(`${t}s`, X(t), H - 6);
  }
  c.textAlign = "left";
  for (const [agent, y] of Object.entries(rows)) {
    c.fillStyle = agent === "human" ? COLORS.human : COLORS.robot;
    c.font = "700 12px system-ui, sans-serif"; c.fillText(agent === "human" ? "you" : "robot", 10, y + bh / 2);
    for (const item of tasksOf(plan.items[agent])) {
      const [s, f] = plan.expected[item];
      const color = agent === "human" ? COLORS.human : COLORS.robot;
      c.globalAlpha = 0.22; c.fillStyle = color; roundRect(c, X(s), y, Math.max(2, X(f) - X(s)), bh, 4); c.fill();
      c.globalAlpha = 1;
      if (live && live.times[item]) {
        const [a, b] = live.times[item], bEnd = b ?? live.t;
        c.fillStyle = color; roundRect(c, X(a), y + 5, Math.max(2, X(bEnd) - X(a)), bh - 10, 3); c.fill();
      }
      c.fillStyle = "#0f172a"; c.font = "600 11px system-ui, sans-serif"; c.textAlign = "center";
      c.fillText(item, (X(s) + X(f)) / 2, y + bh / 2); c.textAlign = "left";
    }
    // waits: where an agent stands still until the other's task is done
    let prevEnd = 0;
    for (const item of plan.items[agent]) {
      if (item.wait !== undefined) {
        const w = item.wait, until = plan.expected[w][1];
        c.strokeStyle = "#475569"; c.setLineDash([3, 3]); c.lineWidth = 1.5;
        c.beginPath(); c.moveTo(X(prevEnd), y + bh / 2); c.lineTo(X(until), y + bh / 2); c.stroke(); c.setLineDash([]);
        c.fillStyle = "#475569"; c.font = "10px system-ui, sans-serif";
        c.fillText(`waits for ${w}`, X(prevEnd) + 2, y - 5);
      } else prevEnd = plan.expected[item.task][1];
    }
  }
  if (live && live.started) {
    c.strokeStyle = "#dc2626"; c.lineWidth = 1.5;
    c.beginPath(); c.moveTo(X(live.t), 22); c.lineTo(X(live.t), H - 14); c.stroke();
  }
}

// ---------------------------------------------------------------------------- side panel
function instructions() {
  const st = R.state, plan = R.plan, n = R.info ? R.info.cycles : "?";
  if (document.body.dataset.ws) {  // a study round
    switch (R.phase) {
      case "over": return ["Round done", "Recording it…"];
      case "done": return ["Round recorded", "On to the study's next step…"];
      case "error": return ["This round was not recorded", R.error || ""];
      case "refused": return ["This round cannot be played here", R.refused];
    }
  }
  switch (R.phase) {
    case "connecting": return ["Connecting…", ""];
    case "disconnected": return ["Connection lost", "Reconnecting… The cycle in progress starts again."];
    case "refused": return ["This run is being played elsewhere", R.refused];
    case "error": return ["The planner stopped", R.error || ""];
    case "done": return ["All cycles played. Thank you!", `The run is stored; ${R.info ? R.info.run_id : ""}.`];
    case "waiting": return [R.summary ? "The robot is planning the next cycle…" : "The robot is planning cycle 1…", "This takes a moment."];
    case "over": return asking() ? ["Cycle done", "How close did the robot come? Answer with 1-7."] : ["Cycle done", "The robot is planning the next one…"];
    case "ready": return [`${Unit} ${plan.cycle + 1} of ${n}: ready`, "Look at the plan below, then press Start (or Enter)."];
  }
  if (!st || !plan) return ["", ""];
  const cur = st.cur;
  if (!cur) return st.human_done ? ["Your part is done", "The robot is finishing its tasks."] : ["", ""];
  const d = plan.descriptions[cur] || cur, s = st.tasks[cur];
  if (s === "locked" || s === "queued") {
    const open = tasksOf(plan.items.human).filter((t) => st.tasks[t] === "active").concat(st.takeable || []);
    if (open.length) return [`Fetch ${open.join(" or ")}`, `The plan's next, ${cur}, is locked; any glowing object may be fetched.`];
    const waits = lockedBy(cur);
    return [`Wait: ${cur} is locked`, waits.length ? `It unlocks when ${waits.join(" and ")} ${waits.length > 1 ? "are" : "is"} home.` : "Wait at home."];
  }
  if (s === "active") return [`Go and ${d} (${cur})`, "Walk up to it to pick it up, or to any other glowing object: any order the arrows allow" + (st.takeable && st.takeable.length ? `, the robot's ${st.takeable.join(", ")} too.` : ".")];
  if (s === "carried") return [`Bring ${cur} home`, "Back into your home circle."];
  return ["", ""];
}
function lockedBy(task) {
  const st = R.state, plan = R.plan, out = [];
  // the person's waits are the plan's advice, not a lock: only precedence locks their objects
  for (const p of plan.preceding[task]) if (st.tasks[p] !== "done") out.push(plan.owner[p] === "robot" ? `the robot's ${p}` : p);
  return out;
}

function render() {
  const plan = R.plan, st = R.state, n = R.info ? R.info.cycles : "?";
  $("cycle").textContent = plan ? `${UNIT} ${plan.cycle + 1} / ${n}` : R.phase;
  const [big, small] = instructions();
  $("instruction").textContent = big; $("detail").textContent = small || "";
  const playing = R.phase === "playing";
  const line = robotLine();
  $("robot-state").textContent = line; $("robot-state").classList.toggle("hidden", !line);
  $("robot-state").style.color = ROBOT_STATE[st && st.robot] ? ROBOT_STATE[st.robot].color : "";
  $("clock").textContent = st && plan && st.cycle === plan.cycle ? st.t.toFixed(1) : "0.0";
  $("expected").textContent = plan ? `· planned ${plan.expected_makespan.toFixed(1)} s` : "";
  // plan card
  let mine = plan ? tasksOf(plan.items.human) : [];
  if (plan && st && st.owner && st.cycle === plan.cycle) {  // reactive: who does what now
    const now = Object.keys(st.owner).filter((t) => st.owner[t] === "human");
    mine = [...mine.filter((t) => now.includes(t)), ...now.filter((t) => !mine.includes(t))];
  }
  $("plan-title").textContent = plan ? `${Unit} ${plan.cycle + 1}: your tasks, in the plan's order (any order precedence allows)` : "Your tasks";
  const ol = $("mytasks"); ol.innerHTML = "";
  for (const t of mine) {
    const li = document.createElement("li"), s = st && st.cycle === plan.cycle ? st.tasks[t] : "queued";
    const e = plan.expected[t];
    li.innerHTML = `${plan.descriptions[t]} <b>(${t})</b> <span class="tag ${s}">${s === "queued" ? "next" : s === "active" ? "open" : s}</span>` +
      `<span class="muted small"> ~${(e[1] - e[0]).toFixed(1)} s</span>`;
    ol.appendChild(li);
  }
  if (plan && !mine.length) ol.innerHTML = "<li>none this cycle: watch the robot</li>";
  $("robottasks").textContent = plan ? "Robot: " + plan.items.robot.map((x) => x.wait !== undefined ? `(waits for ${x.wait})` : `${x.task} ${plan.routes[x.task] ? "via " + plan.routes[x.task] : ""}`).join(" → ") : "";
  const btn = $("start");
  const between = ["ready", "over", "waiting", "done"].includes(R.phase) && R.summary;
  btn.classList.toggle("hidden", !(R.phase === "ready" || (between && R.phase !== "done")));
  btn.disabled = R.phase !== "ready";
  btn.textContent = R.phase === "ready" ? `Start ${UNIT} ${plan.cycle + 1} ▶` : "The robot is planning…";
  $("summary").classList.toggle("hidden", !R.summary || playing);
  $("comfort").classList.toggle("hidden", !asking());
  if (asking()) $("comfort-title").textContent = `${Unit} ${st.cycle + 1}: how close did the robot come?`;
  $("tooclose").classList.toggle("hidden", !canSignal());
  $("tooclose").textContent = st && st.signals ? `Too close! (T) · ${st.signals}` : "Too close! (T)";
  // between cycles the summary takes the status card's place (the banner says what to do)
  $("status").classList.toggle("hidden", !!R.summary && ["ready", "waiting", "over"].includes(R.phase));
  const banner = $("banner");
  banner.classList.toggle("hidden", !["ready", "waiting", "over", "done", "refused", "disconnected", "error"].includes(R.phase));
  banner.textContent = R.phase === "ready" ? `Press Enter to start ${UNIT} ${plan.cycle + 1}` : big;
}

function showHeatLegend() {
  const s = R.summary, on = $("heat").checked && s && s.human.length;
  $("heat-legend").classList.toggle("hidden", !on);
  if (on) $("heat-legend").textContent = `On the map: the spatial cost the robot has learned of your ${s.human.join(" and ")} after cycle ${s.cycle + 1}: red where it expects you, so where its paths cost most.`;
}

function showSummary() {
  const s = R.summary;
  showHeatLegend();
  $("summary-title").textContent = `Cycle ${s.cycle + 1} of ${s.cycles}: how it went`;
  $("s-makespan").textContent = `${s.makespan.toFixed(1)} s`;
  $("s-expected").textContent = `planned ${s.expected_makespan.toFixed(1)} s`;
  $("s-closest").textContent = `${s.closest.toFixed(2)} m`;
  $("s-cost").textContent = s.cost.toFixed(2);
  const rows = s.human.map((t) => {
    const yours = s.observed[t], learned = s.belief[t];
    return `<tr><td>${t}</td><td class="num">${yours.toFixed(1)} s</td><td class="num">${learned.toFixed(1)} s</td></tr>`;
  });
  $("s-tasks").innerHTML = s.human.length
    ? `<tr><th>your task</th><th class="num">your time</th><th class="num">robot now expects</th></tr>${rows.join("")}`
    : "<tr><td class='muted'>the robot did every task this cycle</td></tr>";
  drawCurve();
}

function drawCurve() {
  const c = cctx, W = curve.width, H = curve.height, pts = R.summary ? R.summary.curve : [];
  c.clearRect(0, 0, W, H); c.fillStyle = "#fff"; c.fillRect(0, 0, W, H);
  c.font = "11px system-ui, sans-serif"; c.fillStyle = "#64748b"; c.textBaseline = "middle";
  c.fillText("cost per cycle", 8, 10);
  c.fillStyle = COLORS.human; c.fillText("● cost", W - 118, 10); c.fillStyle = "#94a3b8"; c.fillText("○ makespan", W - 72, 10);
  if (!pts.length) return;
  const x0 = 34, x1 = W - 10, y0 = H - 18, y1 = 22;
  const vals = pts.flatMap((p) => [p.cost, p.makespan]);
  let lo = Math.min(...vals), hi = Math.max(...vals);
  if (hi - lo < 1) { lo -= 0.5; hi += 0.5; }
  const n = Math.max(...pts.map((p) => p.cycle)) + 1;
  const X = (k) => x0 + (x1 - x0) * (n > 1 ? k / (n - 1) : 0.5), Y = (v) => y0 - (y0 - y1) * (v - lo) / (hi - lo);
  c.strokeStyle = "#e2e8f0"; c.beginPath(); c.moveTo(x0, y0); c.lineTo(x1, y0); c.stroke();
  c.fillStyle = "#94a3b8"; c.textAlign = "right"; c.fillText(hi.toFixed(1), x0 - 4, y1); c.fillText(lo.toFixed(1), x0 - 4, y0);
  c.textAlign = "center";
  for (const p of pts) c.fillText(String(p.cycle + 1), X(p.cycle), H - 7);
  for (const [key, color, filled] of [["makespan", "#94a3b8", false], ["cost", COLORS.human, true]]) {
    c.strokeStyle = color; c.lineWidth = 2; c.beginPath();
    pts.forEach((p, i) => { i ? c.lineTo(X(p.cycle), Y(p[key])) : c.moveTo(X(p.cycle), Y(p[key])); });
    c.stroke();
    for (const p of pts) {
      c.beginPath(); c.arc(X(p.cycle), Y(p[key]), 3.2, 0, 2 * Math.PI);
      if (filled) { c.fillStyle = color; c.fill(); } else { c.fillStyle = "#fff"; c.fill(); c.stroke(); }
    }
  }
  c.textAlign = "left";
}

// ---------------------------------------------------------------------------- frame loop
let lastRender = 0;
function frame(now) {
  drawMap(); drawGantt();
  if (now - lastRender > 100) { render(); lastRender = now; }
  requestAnimationFrame(frame);
}
connect();
requestAnimationFrame(frame);
