// Play page: a human plays CartPole (or Gymnasium's Acrobot-v1 or MountainCar-v0); every step is
// simulated on the server over a WebSocket.
"use strict";

CP.renderHeader("Play");
const canvas = document.getElementById("stage");
const el = (id) => document.getElementById(id);
const ENVS = {
  "CartPole-v1": {
    scene: "cartpole",
    title: "Play CartPole yourself",
    keys: { ArrowLeft: 0, ArrowRight: 1 },
    idle: null, // CartPole has no "do nothing": the last key's push goes on
    pad: [0, 1],
  },
  "Acrobot-v1": {
    scene: "acrobot",
    title: "Play Acrobot yourself",
    help: "Swing the free end above the green line: hold ← or → to apply torque at the middle joint " +
      "(no key: no torque). Each step costs 1; the episode ends at 500 steps.",
    keys: { ArrowLeft: 0, ArrowRight: 2 },
    idle: 1,
    pad: [0, 2],
  },
  "MountainCar-v0": {
    scene: "mountaincar",
    title: "Play MountainCar yourself",
    help: "Drive the car up to the flag: its engine is too weak to climb straight, so rock it with ← and → " +
      "(no key: no push). Each step costs 1; the episode ends at 200 steps.",
    keys: { ArrowLeft: 0, ArrowRight: 2 },
    idle: 1,
    pad: [0, 2],
  },
};
const envId = ENVS[CP.param("env")] ? CP.param("env") : "CartPole-v1";
const ENV = ENVS[envId];
const BEST_KEY = envId === "CartPole-v1" ? "cartpole.play.best" : `cartpole.play.best.${envId}`;
let STEP_MS = 20; // the env's own time step (CartPole's tau): set from the server's limits

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

// The best return this browser has played here (null before the first game: returns can be negative).
function best() {
  const stored = localStorage.getItem(BEST_KEY);
  return stored === null ? null : Number(stored);
}

function overlay(title, text, actions) {
  el("overlay").hidden = title === null;
  el("overlay-title").textContent = title || "";
  el("overlay-text").innerHTML = text || "";
  el("overlay-actions").hidden = !actions;
}

function connect() {
  const scheme = location.protocol === "https:" ? "wss" : "ws";
  const socket = new WebSocket(`${scheme}://${location.host}/ws/play?env=${encodeURIComponent(envId)}`);
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
  if (message.limits) {
    game.sceneLimits = message.limits;
    STEP_MS = 1000 / (message.limits.fps || 50);
  }
  if (message.step === 0 && game.phase === "connecting") {
    game.seed = message.seed;
    game.phase = "ready";
    const what = { cartpole: "push the cart", acrobot: "apply torque at the middle joint", mountaincar: "push the car" };
    overlay("Press ← or → to start", `Hold the arrow keys (or the buttons below on a touch screen) to ${what[ENV.scene]}.`);
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
  game.action = game.held ?? (ENV.idle === null ? game.last : ENV.idle);
  game.waiting = true;
  game.nextAt = Math.max(game.nextAt + STEP_MS / game.speed, performance.now() - STEP_MS);
  game.socket.send(JSON.stringify({ type: "step", action: game.action }));
}

function gameOver(message) {
  game.phase = "over";
  game.action = null;
  const score = message.return;
  const record = best() === null || score > best();
  if (record) localStorage.setItem(BEST_KEY, String(score));
  el("best").textContent = String(best());
  let title;
  if (ENV.scene === "cartpole") {
    const [x] = message.state;
    const why = message.terminated
      ? Math.abs(x) > game.limits.xThreshold ? "The cart ran off the track" : "The pole fell"
      : "You balanced it to the time limit!";
    title = message.terminated ? `${why} after ${score} steps` : `${why} ${score} steps`;
  } else {
    const goal = ENV.scene === "acrobot" ? "The free end swung above the line" : "The car reached the flag";
    const missed = ENV.scene === "acrobot" ? "The free end never reached the line" : "The car never reached the flag";
    title = message.terminated
      ? `${goal} in ${message.step} steps (return ${score})`
      : `${missed} in ${message.step} steps (return ${score})`;
  }
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
  if (ENV.scene === "cartpole") for (const [k, v] of Object.entries(game.physics)) q.set(k, String(v));
  link.href = `/watch?${q}`;
  link.textContent = `Watch ${el("agent-select").selectedOptions[0].dataset.agent} from the same start`;
}

function updateReadout() {
  el("score").textContent = String(game.score);
  el("best").textContent = best() === null ? "–" : String(best());
  const s = game.state;
  if (!s.length) return;
  if (ENV.scene === "cartpole") {
    el("angle").textContent = `${((s[2] * 180) / Math.PI).toFixed(1)}°`;
    el("position").textContent = `${s[0].toFixed(2)} m`;
  } else if (ENV.scene === "acrobot") {
    el("angle").textContent = `${((s[0] * 180) / Math.PI).toFixed(0)}°, ${((s[1] * 180) / Math.PI).toFixed(0)}°`;
    el("position").textContent = (-Math.cos(s[0]) - Math.cos(s[0] + s[1])).toFixed(2);
  } else {
    el("angle").textContent = s[0].toFixed(3);
    el("position").textContent = s[1].toFixed(4);
  }
}

function draw() {
  const action = game.phase === "running" ? game.action : null;
  const caption = game.phase === "running" ? `score ${game.score}` : "";
  if (ENV.scene === "cartpole") {
    CartPoleDraw.draw(canvas, game.state, {
      xThreshold: game.limits.xThreshold,
      thetaThreshold: game.limits.thetaThreshold,
      length: game.physics.length ?? 0.5,
      action,
      caption,
    });
  } else if (game.state.length && game.sceneLimits) {
    SceneDraw[ENV.scene](canvas, game.state, { limits: game.sceneLimits, action, caption });
  }
  requestAnimationFrame(draw);
}

const KEYS = ENV.keys;

// The page for the chosen env: its title, help, keys and readouts; CartPole's physics only for CartPole.
function describeEnv() {
  el("env-select").value = envId;
  el("title").textContent = ENV.title;
  document.title = `Play · ${envId}`;
  if (ENV.scene === "cartpole") return;
  el("subtitle").textContent = ENV.help;
  el("keys").innerHTML = "keys: <kbd>←</kbd> torque/push left, <kbd>→</kbd> right, none: nothing";
  el("readout-a").textContent = ENV.scene === "acrobot" ? "link angles" : "position";
  el("readout-b").textContent = ENV.scene === "acrobot" ? "tip height" : "velocity";
  el("speed-note").textContent = "Slow motion gives you time to react; 1× is the env's own frame rate.";
  el("physics-panel").hidden = true;
  canvas.setAttribute("aria-label", ENV.scene === "acrobot" ? "the acrobot's two links" : "the car on the hill");
  el("pad-left").setAttribute("aria-label", ENV.scene === "acrobot" ? "torque left" : "push left");
  el("pad-right").setAttribute("aria-label", ENV.scene === "acrobot" ? "torque right" : "push right");
}

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
  for (const [id, action] of [["pad-left", ENV.pad[0]], ["pad-right", ENV.pad[1]]]) {
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
  el("env-select").addEventListener("change", (ev) => {
    location.href = `/play?env=${encodeURIComponent(ev.target.value)}`;
  });
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
  const sameEnv = (r) => (ENV.scene === "cartpole" ? /CartPole-v[01]$/.test(r.env_id || "") : r.env_id === envId);
  const runs = body.runs.filter((r) => r.watchable && sameEnv(r) && r.has_checkpoint !== false && r.state !== "unreadable" && r.state !== "incomplete");
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
    if (game.phase === "over") updateCompareLink();
    return;
  }
  select.innerHTML = runs.map((r) => {
    const label = `${r.agent} · seed ${r.seed}${r.solved ? " · solved" : ""} (${r.name})`;
    return `<option value="${CP.escapeHTML(r.name)}" data-agent="${CP.escapeHTML(r.agent)}">${CP.escapeHTML(label)}</option>`;
  }).join("");
  if (runs.some((r) => r.name === chosen)) select.value = chosen;
  if (game.phase === "over") updateCompareLink(); // the list may arrive after the game ended
}

async function refreshAgents() {
  await loadAgents().catch(() => undefined); // the server may be restarting: try again later
  setTimeout(refreshAgents, AGENTS_POLL_MS);
}

async function start() {
  describeEnv();
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
