// Watch page: an episode of a checkpoint's greedy policy, replayed at 50 frames per second.
"use strict";

CP.renderHeader("Runs");
const runName = CP.param("run") || "";
const checkpoint = CP.param("checkpoint") || "best";
const canvas = document.getElementById("stage");
const el = (id) => document.getElementById(id);

const watch = {
  info: null, // /api/info physics
  episode: null,
  frame: 0, // fractional step index into episode.states
  playing: true,
  speed: 1,
  last: null, // timestamp of the previous animation frame
  nudges: [], // [{step, change}]
  physics: {},
  seed: Number(CP.param("seed") || 0),
  viewFrames: null, // a pixel agent's frames, decoded (FrameStackDraw.decode)
};

function episodeURL() {
  const q = new URLSearchParams({ seed: String(watch.seed) });
  for (const [k, v] of Object.entries(watch.physics)) q.set(k, String(v));
  for (const n of watch.nudges) {
    q.append("nudge_at", String(n.step));
    q.append("nudge", String(n.change));
  }
  return `/api/runs/${encodeURIComponent(runName)}/checkpoints/${encodeURIComponent(checkpoint)}/episode?${q}`;
}

function syncAddress() {
  const q = new URLSearchParams({ run: runName, checkpoint, seed: String(watch.seed) });
  for (const [k, v] of Object.entries(watch.physics)) q.set(k, String(v));
  history.replaceState(null, "", `/watch?${q}`);
}

async function load(keepFrame) {
  el("loading").hidden = false;
  try {
    const episode = await CP.getJSON(episodeURL());
    watch.episode = episode;
    watch.viewFrames = episode.view ? FrameStackDraw.decode(episode.view) : null;
    el("message").innerHTML = "";
    el("timeline").max = String(episode.length);
    if (!keepFrame) watch.frame = 0;
    watch.frame = Math.min(watch.frame, episode.length);
    syncAddress();
    describeOutcome();
  } catch (err) {
    el("message").innerHTML = `<div class="error">${CP.escapeHTML(err.message)}</div>`;
  } finally {
    el("loading").hidden = true;
  }
  render();
}

// The color of action a among n: left, (none,) right.
function actionColor(a, n) {
  if (a === null) return "";
  if (n === 3 && a === 1) return SceneDraw.COLORS.none;
  return a === 0 ? CartPoleDraw.COLORS.left : CartPoleDraw.COLORS.right;
}

// Acrobot and MountainCar: Gymnasium's envs as they are (no nudges, no physics to change).
function describeOtherOutcome(e) {
  const total = e.return.toFixed(0);
  if (e.scene === "acrobot") {
    return e.terminated
      ? `the free end swung above the line at step ${e.length} (return ${total}).`
      : `the free end did not reach the line in ${e.length} steps (return ${total}).`;
  }
  return e.terminated
    ? `the car reached the flag at step ${e.length} (return ${total}).`
    : `the car did not reach the flag in ${e.length} steps (return ${total}).`;
}

function showSceneControls(e) {
  const cartpole = e.scene === "cartpole";
  if (!cartpole) canvas.setAttribute("aria-label", e.scene === "acrobot" ? "the acrobot's two links" : "the car on the hill");
  el("nudge-panel").hidden = !cartpole;
  el("physics-panel").hidden = !cartpole;
  el("readout-a").textContent = cartpole ? "pole angle" : e.scene === "acrobot" ? "link angles" : "position";
  el("readout-b").textContent = cartpole ? "cart position" : e.scene === "acrobot" ? "tip height" : "velocity";
  el("subtitle").textContent = cartpole
    ? "The greedy policy plays one episode, simulated on the server at the env's own 50 steps per second."
    : `The greedy policy plays one episode of Gymnasium's ${e.env_id} on the server, shown at its own ${e.limits.fps} frames per second.`;
}

function describeOutcome() {
  const e = watch.episode;
  showSceneControls(e);
  if (e.scene !== "cartpole") {
    el("outcome").textContent = `This episode: ${describeOtherOutcome(e)}`;
    return;
  }
  const nudged = e.nudges.length ? ` with ${e.nudges.length} nudge${e.nudges.length > 1 ? "s" : ""}` : "";
  const changed = Object.keys(watch.physics).length ? " under changed physics" : "";
  let text;
  if (e.terminated) {
    const x = e.states[e.states.length - 1][0];
    const why = Math.abs(x) > e.limits.x_threshold ? "the cart left the track" : "the pole tipped past the limit";
    text = `Episode ended at step ${e.length}: ${why}${nudged}${changed}.`;
  } else {
    text = `Balanced for all ${e.length} steps (the time limit)${nudged}${changed}.`;
  }
  el("outcome").textContent = `This episode: ${text}`;
}

function render() {
  const e = watch.episode;
  if (!e) return;
  const i = Math.min(Math.floor(watch.frame), e.length);
  const state = e.states[i];
  const action = i < e.length ? e.actions[i] : null;
  const caption = `${e.agent ?? "agent"} · ${checkpoint} · seed ${e.seed}`;
  if (e.scene === "cartpole") {
    const recentNudge = e.nudges.find((n) => i >= n.step && i < n.step + 12);
    CartPoleDraw.draw(canvas, state, {
      xThreshold: e.limits.x_threshold,
      thetaThreshold: e.limits.theta_threshold,
      length: e.physics.length,
      action,
      nudge: recentNudge ? recentNudge.theta_dot_change : 0,
      caption,
    });
    el("angle").textContent = `${((state[2] * 180) / Math.PI).toFixed(1)}°`;
    el("position").textContent = `${state[0].toFixed(2)} m`;
  } else {
    SceneDraw[e.scene](canvas, state, { limits: e.limits, action, caption });
    if (e.scene === "acrobot") {
      const degrees = (v) => `${((v * 180) / Math.PI).toFixed(0)}°`;
      el("angle").textContent = `${degrees(state[0])}, ${degrees(state[1])}`;
      el("position").textContent = (-Math.cos(state[0]) - Math.cos(state[0] + state[1])).toFixed(2);
    } else {
      el("angle").textContent = state[0].toFixed(3);
      el("position").textContent = state[1].toFixed(4);
    }
  }
  el("step").textContent = `${i} / ${e.length}`;
  el("timeline").value = String(i);
  renderView(i);
  el("action").textContent = action === null ? "–" : e.action_labels[action] ?? String(action);
  el("action").style.color = actionColor(action, e.action_labels.length);
  renderPrefs(i);
}

// A pixel agent's observation at step i (its frame stack), beside the scene; hidden for state agents.
function renderView(i) {
  const e = watch.episode;
  el("view-panel").hidden = !e.view;
  if (!e.view) return;
  FrameStackDraw.draw(el("agent-view"), e.view, watch.viewFrames, i, 1);
  const { stack, height, width } = e.view;
  el("view-note").textContent =
    `Its observation at step ${i}: the last ${stack} gray ${width}×${height} frames, drawn from the states ` +
    "on the server as its env draws them (at the start, the first frame repeated).";
}

function renderPrefs(i) {
  const e = watch.episode;
  const box = el("prefs");
  if (!e.scores) {
    box.innerHTML = '<p class="small muted">This policy does not report its preferences.</p>';
    return;
  }
  if (i >= e.length) {
    box.innerHTML = `<p class="small muted">${CP.escapeHTML(e.score_label)}: episode over.</p>`;
    return;
  }
  const row = e.scores[i];
  const scale = watch.maxScore || 1;
  const signed = row.some((v) => v < 0);
  const label = CP.escapeHTML(e.score_label);
  const bars = e.action_labels.map((side, a) => {
    return `<div class="pref ${e.actions[i] === a ? "chosen" : ""}" title="${label} of ${side}"><span>${side}</span>
      <div class="track"><div class="fill"></div></div>
      <span class="val">${row[a].toFixed(2)}</span></div>`;
  });
  box.innerHTML = `<div class="small muted">${label} (the agent picks the larger)</div>${bars.join("")}`;
  // Geometry through the CSSOM: the Content-Security-Policy forbids inline style attributes.
  box.querySelectorAll(".fill").forEach((fill, a) => {
    const v = row[a];
    const w = Math.min(50, (Math.abs(v) / scale) * 50) * (signed ? 1 : 2);
    fill.style.left = `${signed ? (v >= 0 ? 50 : 50 - w) : 0}%`;
    fill.style.width = `${w}%`;
    fill.style.background = actionColor(a, row.length);
  });
}

function tick(now) {
  const e = watch.episode;
  if (watch.playing && e && watch.last !== null) {
    const fps = e.limits.fps || 50;
    const shown = Math.floor(watch.frame);
    watch.frame += ((now - watch.last) / 1000) * fps * watch.speed;
    if (watch.frame >= e.length) {
      watch.frame = e.length;
      setPlaying(false);
    }
    // The picture only changes with the step: no redraw (bars, layout) on the display's other frames.
    if (Math.floor(watch.frame) !== shown) render();
  }
  watch.last = now;
  requestAnimationFrame(tick);
}

function setPlaying(playing) {
  watch.playing = playing;
  el("play-pause").textContent = playing ? "❚❚ Pause" : "▶ Play";
}

function scoreScale() {
  const e = watch.episode;
  watch.maxScore = e && e.scores ? Math.max(1e-9, ...e.scores.flat().map(Math.abs)) : 1;
}

async function reload(keepFrame) {
  await load(keepFrame);
  scoreScale();
  render();
}

// Why a seed typed by the reader cannot be used, or "" if it can (no silent clamping).
function seedProblem(text) {
  const value = Number(text);
  if (String(text).trim() === "" || !Number.isInteger(value)) return "seed must be a whole number";
  if (value < 0) return "seed must be >= 0";
  if (value > Number.MAX_SAFE_INTEGER) return `seed must be <= ${Number.MAX_SAFE_INTEGER}`;
  return "";
}

function nudge(direction) {
  const e = watch.episode;
  if (!e) return;
  const step = Math.floor(watch.frame);
  if (step >= e.length) {
    // The episode is over: a push now would change nothing that is shown, so none is counted.
    el("message").innerHTML = '<div class="error">The episode is over: rewind or restart to nudge.</div>';
    return;
  }
  const change = direction * Number(el("nudge-size").value);
  watch.nudges = watch.nudges.filter((n) => n.step < step);
  watch.nudges.push({ step, change });
  reload(true).then(() => setPlaying(true));
}

function wire() {
  el("play-pause").addEventListener("click", () => {
    if (!watch.playing && watch.episode && watch.frame >= watch.episode.length) watch.frame = 0;
    setPlaying(!watch.playing);
  });
  el("restart").addEventListener("click", () => {
    watch.frame = 0;
    setPlaying(true);
    render();
  });
  el("speed").addEventListener("change", (ev) => (watch.speed = Number(ev.target.value)));
  el("timeline").addEventListener("input", (ev) => {
    watch.frame = Number(ev.target.value);
    render();
  });
  el("nudge-left").addEventListener("click", () => nudge(-1));
  el("nudge-right").addEventListener("click", () => nudge(1));
  el("clear-nudges").addEventListener("click", () => {
    watch.nudges = [];
    reload(true);
  });
  el("nudge-size").addEventListener("input", (ev) => (el("nudge-size-out").textContent = ev.target.value));
  el("seed-go").addEventListener("click", () => {
    const problem = seedProblem(el("seed").value);
    if (problem) {
      el("message").innerHTML = `<div class="error">${CP.escapeHTML(problem)}</div>`;
      return;
    }
    watch.seed = Number(el("seed").value);
    watch.nudges = [];
    reload(false).then(() => setPlaying(true));
  });
  el("seed-random").addEventListener("click", () => {
    watch.seed = Math.floor(Math.random() * 2 ** 31);
    el("seed").value = String(watch.seed);
    watch.nudges = [];
    reload(false).then(() => setPlaying(true));
  });
  el("physics-apply").addEventListener("click", () => {
    watch.physics = PhysicsPanel.overrides(el("physics"), watch.info);
    reload(false).then(() => setPlaying(true));
  });
  el("physics-reset").addEventListener("click", () => {
    watch.physics = {};
    PhysicsPanel.render(el("physics"), watch.info, {});
    reload(false).then(() => setPlaying(true));
  });
  document.addEventListener("keydown", (ev) => {
    if (ev.target.tagName === "INPUT" || ev.target.tagName === "SELECT") return;
    if (ev.key === " ") {
      ev.preventDefault();
      el("play-pause").click();
    }
  });
  window.addEventListener("resize", render);
}

async function start() {
  if (!runName) {
    el("title").textContent = "Watch";
    el("message").innerHTML = '<div class="error">No run named in the address. Pick a run and a checkpoint on the <a href="/">runs page</a>.</div>';
    return;
  }
  el("back").href = `/run?name=${encodeURIComponent(runName)}`;
  el("title").textContent = `Watch ${checkpoint} of ${runName}`;
  el("seed").value = String(watch.seed);
  const info = await CP.getJSON("/api/info");
  watch.info = info.physics;
  watch.physics = PhysicsPanel.fromQuery(watch.info);
  try {
    // Physics in the address change CartPole only: a run on another env plays without them.
    const run = await CP.getJSON(`/api/runs/${encodeURIComponent(runName)}`);
    if (run.scene && run.scene !== "cartpole") {
      watch.physics = {};
      el("nudge-panel").hidden = true;
      el("physics-panel").hidden = true;
    }
  } catch (_) {
    // the episode request below says what is wrong
  }
  PhysicsPanel.render(el("physics"), watch.info, watch.physics);
  wire();
  await reload(false);
  requestAnimationFrame(tick);
}

start();
