// Play page: a human pushes the cart; every step is simulated on the server over a WebSocket.
"use strict";

CP.renderHeader("Play");
const canvas = document.getElementById("stage");
const el = (id) => document.getElementById(id);
const BEST_KEY = "cartpole.play.best";
const STEP_MS = 20; // the env's own tau: 50 steps per second at 1x

const game = {
  socket: null,
  phase: "connecting", // connecting | ready | running | over
  state: [0, 0, 0, 0],
  seed: null,
  score: 0,
  held: null, // action of the key or button held now
  last: null, // action of the last key pressed (CartPole has no "do nothing")
  action: null,
  waiting: false, // a step was sent and its reply has not come back
  nextAt: 0,
  speed: 0.5,
  physics: {},
  info: null,
  limits: { xThreshold: 2.4, thetaThreshold: (12 * Math.PI) / 180 },
};

function best() {
  return Number(localStorage.getItem(BEST_KEY) || 0);
}

function overlay(title, text, actions) {
  el("overlay").hidden = title === null;
  el("overlay-title").textContent = title || "";
  el("overlay-text").innerHTML = text || "";
  el("overlay-actions").hidden = !actions;
}

function connect() {
  const scheme = location.protocol === "https:" ? "wss" : "ws";
  const socket = new WebSocket(`${scheme}://${location.host}/ws/play?env=CartPole-v1`);
  game.socket = socket;
  socket.onopen = () => reset();
  socket.onmessage = (event) => onReply(JSON.parse(event.data));
  socket.onclose = (event) => {
    game.phase = "connecting";
    overlay("Disconnected", `The server closed the game${event.reason ? `: ${CP.escapeHTML(event.reason)}` : ""}. Reconnecting…`);
    setTimeout(connect, 2000);
  };
}

function reset() {
  game.phase = "connecting";
  game.waiting = false;
  game.held = null;
  game.last = null;
  game.action = null;
  const message = { type: "reset" };
  if (Object.keys(game.physics).length) message.physics = game.physics;
  game.socket.send(JSON.stringify(message));
}

function onReply(message) {
  if (message.type === "error") {
    el("message").innerHTML = `<div class="error">${CP.escapeHTML(message.message)}</div>`;
    return;
  }
  game.state = message.state;
  game.score = message.return;
  game.waiting = false;
  if (message.step === 0 && game.phase === "connecting") {
    game.seed = message.seed;
    game.phase = "ready";
    overlay("Press ← or → to start", "Hold the arrow keys (or the buttons below on a touch screen) to push the cart.");
  } else if (message.terminated || message.truncated) {
    gameOver(message);
  } else {
    schedule();
  }
  updateReadout();
}

function begin(action) {
  game.held = action;
  game.last = action;
  if (game.phase !== "ready") return;
  game.phase = "running";
  overlay(null);
  game.nextAt = performance.now();
  schedule();
}

function schedule() {
  if (game.phase !== "running" || game.waiting) return;
  const delay = Math.max(0, game.nextAt - performance.now());
  setTimeout(sendStep, delay);
}

function sendStep() {
  if (game.phase !== "running" || game.waiting || game.socket.readyState !== WebSocket.OPEN) return;
  game.action = game.held ?? game.last;
  game.waiting = true;
  game.nextAt = Math.max(game.nextAt + STEP_MS / game.speed, performance.now() - STEP_MS);
  game.socket.send(JSON.stringify({ type: "step", action: game.action }));
}

function gameOver(message) {
  game.phase = "over";
  game.action = null;
  const score = message.return;
  const record = score > best();
  if (record) localStorage.setItem(BEST_KEY, String(score));
  const [x] = message.state;
  const why = message.terminated
    ? Math.abs(x) > game.limits.xThreshold ? "The cart ran off the track" : "The pole fell"
    : "You balanced it to the time limit!";
  const title = message.terminated ? `${why} after ${score} steps` : `${why} ${score} steps`;
  const text = `${record ? "<b>New best for this browser.</b> " : ""}Start state: seed ${game.seed}. How does an agent do from the same start?`;
  overlay(title, text, true);
  updateCompareLink();
  el("again").focus();
}

function updateCompareLink() {
  const link = el("compare-link");
  const run = el("agent-select").value;
  link.hidden = !run;
  if (!run) return;
  const q = new URLSearchParams({ run, checkpoint: "best", seed: String(game.seed) });
  for (const [k, v] of Object.entries(game.physics)) q.set(k, String(v));
  link.href = `/watch?${q}`;
  link.textContent = `Watch ${el("agent-select").selectedOptions[0].dataset.agent} from the same start`;
}

function updateReadout() {
  el("score").textContent = String(game.score);
  el("best").textContent = String(best());
  el("angle").textContent = `${((game.state[2] * 180) / Math.PI).toFixed(1)}°`;
  el("position").textContent = `${game.state[0].toFixed(2)} m`;
}

function draw() {
  CartPoleDraw.draw(canvas, game.state, {
    xThreshold: game.limits.xThreshold,
    thetaThreshold: game.limits.thetaThreshold,
    length: game.physics.length ?? 0.5,
    action: game.phase === "running" ? game.action : null,
    caption: game.phase === "running" ? `score ${game.score}` : "",
  });
  requestAnimationFrame(draw);
}

const KEYS = { ArrowLeft: 0, ArrowRight: 1 };

function wireInput() {
  document.addEventListener("keydown", (ev) => {
    if (ev.key in KEYS) {
      ev.preventDefault();
      if (game.phase === "over") return;
      begin(KEYS[ev.key]);
    } else if ((ev.key === "Enter" || ev.key === " ") && game.phase === "over" && ev.target.tagName !== "A") {
      ev.preventDefault();
      reset();
    }
  });
  document.addEventListener("keyup", (ev) => {
    if (ev.key in KEYS && game.held === KEYS[ev.key]) game.held = null;
  });
  for (const [id, action] of [["pad-left", 0], ["pad-right", 1]]) {
    const button = el(id);
    button.addEventListener("pointerdown", (ev) => {
      ev.preventDefault();
      button.classList.add("held");
      if (game.phase !== "over") begin(action);
    });
    for (const type of ["pointerup", "pointerleave", "pointercancel"]) {
      button.addEventListener(type, () => {
        button.classList.remove("held");
        if (game.held === action) game.held = null;
      });
    }
  }
  el("again").addEventListener("click", reset);
  el("speed").addEventListener("change", (ev) => (game.speed = Number(ev.target.value)));
  el("agent-select").addEventListener("change", updateCompareLink);
  el("physics-apply").addEventListener("click", () => {
    game.physics = PhysicsPanel.overrides(el("physics"), game.info);
    reset();
  });
  el("physics-reset").addEventListener("click", () => {
    game.physics = {};
    PhysicsPanel.render(el("physics"), game.info, {});
    reset();
  });
}

const AGENTS_POLL_MS = 5000;
let agentsText = "";

async function loadAgents() {
  const body = await CP.getJSON("/api/runs");
  const runs = body.runs.filter((r) => r.watchable && r.has_checkpoint !== false && r.state !== "unreadable" && r.state !== "incomplete");
  runs.sort((a, b) => Number(b.solved) - Number(a.solved));
  const text = JSON.stringify([body.runs_dir, runs.map((r) => [r.name, r.solved])]);
  if (text === agentsText) return; // unchanged: keep the reader's choice
  agentsText = text;
  const select = el("agent-select");
  const chosen = select.value;
  document.querySelectorAll("#no-runs .runs-dir").forEach((span) => (span.textContent = body.runs_dir || "runs"));
  el("no-runs").hidden = runs.length > 0;
  if (!runs.length) {
    select.innerHTML = '<option value="">(no runs yet)</option>';
    return;
  }
  select.innerHTML = runs.map((r) => {
    const label = `${r.agent} · seed ${r.seed}${r.solved ? " · solved" : ""} (${r.name})`;
    return `<option value="${CP.escapeHTML(r.name)}" data-agent="${CP.escapeHTML(r.agent)}">${CP.escapeHTML(label)}</option>`;
  }).join("");
  if (runs.some((r) => r.name === chosen)) select.value = chosen;
}

async function refreshAgents() {
  await loadAgents().catch(() => undefined); // the server may be restarting: try again later
  setTimeout(refreshAgents, AGENTS_POLL_MS);
}

async function start() {
  game.speed = Number(el("speed").value);
  updateReadout();
  wireInput();
  requestAnimationFrame(draw);
  const info = await CP.getJSON("/api/info");
  game.info = info.physics;
  PhysicsPanel.render(el("physics"), game.info, {});
  connect();
  refreshAgents();
}

start();
