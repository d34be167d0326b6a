// Run page: the learning curve (live while training), the newest policy playing (Now playing), the
// training that makes it (Stop, Resume), checkpoints with Watch buttons, eval, config.
"use strict";

CP.renderHeader("Runs");
const runName = CP.param("name") || "";
const MA_WINDOW = 20;
const RETURN_KEYS = [
  ["train/episode_return", "episode return"],
  ["train/mean_return", "generation mean return"],
];

const state = { detail: null, rows: [], offset: 0, plot: null, socket: null, returnKey: null, ended: false };

function setText(id, text) {
  document.getElementById(id).textContent = text;
}

// ------------------------------------------------------------------------------------------------
// Details
// ------------------------------------------------------------------------------------------------

function renderDetail(d) {
  state.detail = d;
  document.title = `${d.name} · CartPole`;
  setText("title", `${d.agent ?? "?"} on ${d.env_id ?? "?"}, seed ${d.seed ?? "?"}`);
  document.getElementById("subtitle").innerHTML =
    `<span class="mono">${CP.escapeHTML(d.name)}</span> · ${CP.stateBadge(d.state, d.problem)} ` +
    `· ${CP.fmtInt(d.env_steps)} env steps · ${CP.solvedBadge(d)}`;
  document.getElementById("problem").innerHTML = d.problem
    ? `<div class="error">This run folder is ${CP.escapeHTML(d.state)}: ${CP.escapeHTML(d.problem)}</div>` : "";
  renderCheckpoints(d);
  renderEval(d.eval);
  renderVerdict(d);
  renderConfig(d.config);
  updateNowPlaying(d);
  updateTrainAgain();
}

// The final verdict, large: written when training ends (the Evaluation panel has its numbers).
function renderVerdict(d) {
  const box = document.getElementById("verdict");
  const verdict = d.eval && d.eval.verdict;
  box.hidden = !verdict;
  if (!verdict) return;
  const solved = d.solved || String(verdict).startsWith("SOLVED");
  box.className = `verdict ${solved ? "solved" : "not-solved"}`;
  // "SOLVED: mean 500.0 ± 0.0 over ..." as the word, large, and the rule beside it.
  const text = String(verdict);
  const cut = text.indexOf(": ");
  const head = cut > 0 ? text.slice(0, cut) : text;
  const rest = cut > 0 ? text.slice(cut + 2) : "";
  box.innerHTML = `<span class="verdict-head">${CP.escapeHTML(head)}</span> <span class="verdict-rule">${CP.escapeHTML(rest)}</span>`;
  box.title = text;
}

function renderCheckpoints(d) {
  const box = document.getElementById("checkpoint-list");
  if (!d.checkpoints.length) {
    box.innerHTML = '<p class="muted">No checkpoint yet: one is written as training goes.</p>';
    return;
  }
  const note = d.watchable ? "" :
    `<p class="notice">Watch draws CartPole, Acrobot-v1 and MountainCar-v0; this run trains ${CP.escapeHTML(d.env_id ?? "another env")}: Replay shows its policy in the env's own pictures (a GIF of an episode's first steps, where the env draws them).</p><div id="replay"></div>`;
  const seed = d.eval && d.eval.seeds && d.eval.seeds.length ? d.eval.seeds[0] : 0;
  const rows = d.checkpoints.map((c) => {
    const href = `/watch?run=${encodeURIComponent(d.name)}&checkpoint=${encodeURIComponent(c.name)}&seed=${seed}`;
    const gif = `/api/runs/${encodeURIComponent(d.name)}/checkpoints/${encodeURIComponent(c.name)}/replay.gif?seed=${seed}`;
    const button = d.watchable ? `<a class="button primary" href="${href}">▶ Watch</a>` :
      `<button class="button primary replay" data-gif="${CP.escapeHTML(gif)}">▶ Replay</button>`;
    return `<tr><td><b>${CP.escapeHTML(c.name)}</b></td><td class="muted small">${CP.fmtDate(c.modified)}</td>
      <td class="num small muted hide-narrow">${(c.bytes / 1024).toFixed(1)} KiB</td><td class="num">${button}</td></tr>`;
  });
  box.innerHTML = `${note}<table>${rows.join("")}</table>`;
  box.querySelectorAll("button.replay").forEach((button) => {
    button.addEventListener("click", () => showReplay(button.dataset.gif));
  });
}

async function showReplay(url) {
  const box = document.getElementById("replay");
  box.innerHTML = '<p class="muted">Playing the episode ...</p>';
  const response = await fetch(url);
  if (!response.ok) {
    const body = await response.json().catch(() => ({}));
    box.innerHTML = `<p class="notice">${CP.escapeHTML(body.detail ?? `replay failed (${response.status})`)}</p>`;
    return;
  }
  const image = document.createElement("img");
  image.alt = "the policy's greedy episode, as the env draws it";
  image.src = URL.createObjectURL(await response.blob());
  box.replaceChildren(image);
}

function renderEval(report) {
  const box = document.getElementById("eval");
  if (!report) {
    box.innerHTML = '<p class="muted">No final evaluation yet (written when training ends).</p>';
    return;
  }
  box.innerHTML = `<p><b>${CP.escapeHTML(report.verdict)}</b></p>
    <table class="kv"><tr><td>mean ± std</td><td>${CP.fmtNum(report.mean)} ± ${CP.fmtNum(report.std)}</td></tr>
    <tr><td>min / max</td><td>${CP.fmtNum(report.min, 0)} / ${CP.fmtNum(report.max, 0)}</td></tr>
    <tr><td>episodes</td><td>${report.episodes}</td></tr>
    <tr><td>threshold</td><td>${report.threshold ?? "none registered"}</td></tr>
    <tr><td>simulator</td><td>${CP.escapeHTML(report.simulator)}</td></tr></table>`;
}

function valueText(value) {
  if (value !== null && typeof value === "object") {
    return Object.entries(value).map(([k, v]) => `<div><span class="muted">${CP.escapeHTML(k)}:</span> ${CP.escapeHTML(typeof v === "object" ? JSON.stringify(v) : String(v))}</div>`).join("");
  }
  return CP.escapeHTML(String(value));
}

// The budget the run trained under, e.g. "50 iterations" or "20,000 env steps, 60 seconds". A --budget
// given on the command line replaces the preset's, so settings.budget (the preset's) is not shown
// beside it: two budgets that disagree would leave the reader guessing which one held.
function budgetText(budget) {
  if (!budget || typeof budget !== "object") return null;
  const parts = Object.entries(budget).map(([k, v]) => `${CP.fmtInt(v)} ${k.replace(/_/g, " ")}`);
  return parts.length ? parts.join(", ") : "none";
}

function renderConfig(config) {
  const box = document.getElementById("config");
  if (!config) {
    box.innerHTML = '<p class="muted">config.json is missing or unreadable.</p>';
    return;
  }
  const rows = [];
  for (const [key, value] of Object.entries(config.config || {})) rows.push([key, value]);
  const budget = budgetText(config.budget) ?? (config.settings && config.settings.budget);
  if (budget !== undefined && budget !== null) rows.push(["budget", budget]);
  if (config.settings && typeof config.settings === "object") {
    const { budget: _presetBudget, ...settings } = config.settings;
    rows.push(["settings", settings]);
  }
  for (const key of ["preset", "device", "package_version"]) {
    if (key in config) rows.push([key, config[key]]);
  }
  const command = Array.isArray(config.command) ? `<p class="small muted">Made by</p><pre class="mono small wrap">${CP.escapeHTML(config.command.join(" "))}</pre>` : "";
  box.innerHTML = `<table class="kv">${rows.map(([k, v]) => `<tr data-key="${CP.escapeHTML(k)}"><td>${CP.escapeHTML(k)}</td><td>${valueText(v)}</td></tr>`).join("")}</table>${command}`;
}

// ------------------------------------------------------------------------------------------------
// Chart
// ------------------------------------------------------------------------------------------------

function chartData() {
  const rows = state.rows;
  if (!state.returnKey) {
    const found = RETURN_KEYS.find(([key]) => rows.some((r) => key in r));
    state.returnKey = found || null;
  }
  const key = state.returnKey ? state.returnKey[0] : null;
  const xs = [], returns = [], averages = [], evals = [], thresholds = [];
  const window = [];
  let sum = 0;
  const threshold = state.detail ? state.detail.threshold : null;
  for (const row of rows) {
    const r = key && key in row ? row[key] : null;
    const e = "eval/mean_return" in row ? row["eval/mean_return"] : null;
    if (r === null && e === null) continue;
    xs.push(row.step);
    returns.push(r);
    evals.push(e);
    if (r !== null) {
      window.push(r);
      sum += r;
      if (window.length > MA_WINDOW) sum -= window.shift();
      // Only full windows: an "average" of the first few generations would be the noise it should smooth.
      averages.push(window.length === MA_WINDOW ? sum / MA_WINDOW : null);
    } else {
      averages.push(null);
    }
    thresholds.push(threshold);
  }
  return [xs, returns, averages, evals, thresholds];
}

function makePlot() {
  const el = document.getElementById("chart");
  const data = chartData(); // also finds which return the rows carry
  const label = state.returnKey ? state.returnKey[1] : "return";
  const threshold = state.detail ? state.detail.threshold : null;
  const opts = {
    width: Math.max(280, el.clientWidth),
    height: el.clientWidth < 500 ? 260 : 340,
    // Every row at one step (a CEM run that solved in its first generation): uPlot would get an x range
    // of zero width and draw nothing; show 0 to twice that step instead.
    scales: { x: { time: false, range: (u, min, max) => (min === max ? [0, max > 0 ? 2 * max : 1] : [min, max]) } },
    axes: [
      { label: "env steps", stroke: "#5d6678", grid: { stroke: "#eef0f5" } },
      { label: "return", stroke: "#5d6678", grid: { stroke: "#eef0f5" } },
    ],
    series: [
      { label: "step", value: (u, v) => (v === null ? "–" : CP.fmtInt(v)) },
      { label, stroke: "rgba(53, 88, 212, 0.35)", width: 1, spanGaps: true,
        points: { show: (u) => u.data[0].length < 150, size: 5 } }, // few rows: show each one
      { label: `moving average (${MA_WINDOW})`, stroke: "#3558d4", width: 2.5, spanGaps: true, points: { show: false } },
      { label: "evaluation mean", stroke: "#17804a", fill: "#17804a", width: 0, paths: () => null,
        points: { show: true, size: 9, stroke: "#17804a", fill: "#dcf3e6" } },
      { label: threshold === null ? "threshold (none)" : `solved threshold ${threshold}`, stroke: "#d97706", width: 1.5, dash: [6, 5], spanGaps: true, points: { show: false } },
    ],
  };
  state.plot = new uPlot(opts, data, el);
}

function updateChart() {
  const note = document.getElementById("chart-note");
  if (!state.rows.length) {
    note.textContent = "No metrics yet: rows appear here as training logs them.";
  } else {
    const kind = state.returnKey && state.returnKey[0] === "train/mean_return" ? "Each point is a generation's mean return over its candidates. " : "";
    note.textContent = `${kind}Dark line: moving average of the last ${MA_WINDOW} points (drawn once there are ${MA_WINDOW}). Green dots: greedy evaluations. Dashed line: the env's reward_threshold. Drag to zoom, double-click to reset.`;
  }
  if (!state.plot) {
    if (!state.detail) return;
    makePlot();
    return;
  }
  state.plot.setData(chartData());
}

function resizeChart() {
  if (!state.plot) return;
  const el = document.getElementById("chart");
  state.plot.setSize({ width: Math.max(280, el.clientWidth), height: el.clientWidth < 500 ? 260 : 340 });
}

window.addEventListener("resize", () => {
  resizeChart();
  drawNowPlaying();
});

// ------------------------------------------------------------------------------------------------
// Live updates
// ------------------------------------------------------------------------------------------------

// Follow the run's metrics and status through the WebSocket until it stops. `fromStart`: ask every
// row again and replace the curve with them (a resume drops the rows logged after its checkpoint).
function follow(fromStart = false) {
  const scheme = location.protocol === "https:" ? "wss" : "ws";
  const offset = fromStart ? 0 : state.offset;
  const url = `${scheme}://${location.host}/ws/runs/${encodeURIComponent(runName)}/metrics?offset=${offset}`;
  const socket = new WebSocket(url);
  state.socket = socket;
  state.ended = false;
  let replace = fromStart;
  let lastState = state.detail ? state.detail.state : null;
  socket.onmessage = async (event) => {
    const message = JSON.parse(event.data);
    if (message.type === "metrics") {
      if (replace && message.offset === 0) {
        state.rows = [];
        state.returnKey = null;
      }
      replace = false;
      state.rows.push(...message.rows);
      state.offset = message.offset + message.rows.length;
      updateChart();
    } else if (message.type === "status") {
      setText("live", message.status.state === "running" ? "● live: following training" : "");
      if (message.status.state !== lastState || message.status.state === "running") {
        lastState = message.status.state;
        renderDetail(await CP.getJSON(`/api/runs/${encodeURIComponent(runName)}`));
      }
    } else if (message.type === "end") {
      setText("live", "");
      state.ended = true;
      // The run stopped: its last verdict and checkpoints; a training that is resumed follows it again.
      renderDetail(await CP.getJSON(`/api/runs/${encodeURIComponent(runName)}`));
      refreshTraining();
    }
  };
  socket.onclose = (event) => {
    if (state.socket === socket) state.socket = null;
    if (event.code !== 1000 && event.code !== 1008) setTimeout(() => { if (!state.socket) follow(); }, 3000); // server restarted: retry
  };
}

// ------------------------------------------------------------------------------------------------
// The training this run belongs to (started from the Train page): state, Stop, Resume
// ------------------------------------------------------------------------------------------------

const ACTIVE = new Set(["queued", "running"]);
const training = { row: null, timer: null, busy: false };

function updateTrainAgain() {
  const link = document.getElementById("train-again");
  link.hidden = false;
  link.href = training.row
    ? `/train?from=${encodeURIComponent(training.row.name)}`
    : `/train?run=${encodeURIComponent(runName)}`;
  link.title = training.row ? `the Train page, filled with training ${training.row.name}'s settings` : "the Train page, filled with this run's settings";
}

function renderTraining(row) {
  const panel = document.getElementById("training-panel");
  panel.hidden = !row;
  updateTrainAgain();
  if (!row) return;
  const badge = document.getElementById("training-state");
  badge.className = `badge ${row.state}`;
  badge.textContent = row.state;
  setText("training-queue", row.state === "queued" && row.queue_position ? `number ${row.queue_position} in the queue` : "");
  const runs = row.runs.length > 1 ? ` (${row.runs.length} runs, seeds ${row.seeds ? row.seeds.join(", ") : "?"})` : "";
  const notes = {
    queued: "It starts when a running training ends.",
    running: "Stop saves latest.pt (as Ctrl-C does); Resume goes on from it.",
    stopped: "Stopped: Resume goes on from its latest checkpoint.",
    failed: "Failed: Resume goes on from its latest checkpoint.",
    finished: "Finished.",
  };
  setText("training-note", `Training ${row.name}${runs}, started from this app. ${notes[row.state] || ""}`);
  document.getElementById("training-problem").innerHTML = row.problem
    ? `<div class="error">${CP.escapeHTML(row.problem)}</div>` : "";
  document.getElementById("stop").hidden = !ACTIVE.has(row.state);
  document.getElementById("resume").hidden = !(row.state === "stopped" || row.state === "failed");
  document.getElementById("stop").disabled = training.busy;
  document.getElementById("resume").disabled = training.busy;
}

// Ask for the run's training; every second while it is queued or running, every 5 s otherwise.
async function refreshTraining() {
  clearTimeout(training.timer);
  let wait = 5000;
  try {
    const rows = await CP.getJSON(`/api/trainings?run=${encodeURIComponent(runName)}`);
    const row = rows.length ? rows[0] : null;
    const before = training.row ? training.row.state : null;
    training.row = row;
    renderTraining(row);
    if (row && ACTIVE.has(row.state)) wait = 1000;
    // Resumed: once its process trains the run again (it has dropped any rows logged after the
    // checkpoint it goes on from), follow the run again from its first row.
    const again = row && row.state === "running" && state.ended && !state.socket;
    if (again || (row && before && before !== row.state)) {
      const detail = await CP.getJSON(`/api/runs/${encodeURIComponent(runName)}`);
      renderDetail(detail);
      if (again && detail.state === "running" && !state.socket) follow(true);
    }
  } catch (_) {
    wait = 5000; // the run page says when the server is gone; ask again later
  }
  training.timer = setTimeout(refreshTraining, wait);
}

async function act(action) {
  if (!training.row || training.busy) return;
  training.busy = true;
  renderTraining(training.row);
  const box = document.getElementById("training-message");
  box.innerHTML = "";
  try {
    const row = await CP.postJSON(`/api/trainings/${encodeURIComponent(training.row.name)}/${action}`, {});
    training.row = row;
  } catch (err) {
    const message = err.status === 401
      ? `${action === "stop" ? "Stopping" : "Resuming"} a training needs the server's token: open the address \`cartpole serve\` printed (with ?token=)`
      : err.message;
    box.innerHTML = `<div class="error">${CP.escapeHTML(message)}</div>`;
  } finally {
    training.busy = false;
    renderTraining(training.row);
  }
  refreshTraining();
}

document.getElementById("stop").addEventListener("click", () => act("stop"));
document.getElementById("resume").addEventListener("click", () => act("resume"));

// ------------------------------------------------------------------------------------------------
// Now playing: greedy episodes of the newest checkpoint while training, of the best one after
// ------------------------------------------------------------------------------------------------

const END_PAUSE_MS = 700;
const np = {
  checkpoint: null, // the checkpoint the next episode plays
  shown: null, // the checkpoint the episode on screen plays
  episode: null,
  frame: 0,
  seed: 0,
  last: null,
  endedAt: 0,
  loading: false,
  retryAt: 0,
  retryMs: 1000,
  running: false,
};

function playedCheckpoint(d) {
  const names = (d.checkpoints || []).filter((c) => c.bytes !== null).map((c) => c.name);
  const order = d.state === "finished" ? ["best", "latest"] : ["latest", "best"];
  return order.find((name) => names.includes(name)) || null;
}

function updateNowPlaying(d) {
  const checkpoint = d.watchable ? playedCheckpoint(d) : null;
  np.checkpoint = checkpoint;
  const panel = document.getElementById("now-playing-panel");
  const show = Boolean(checkpoint);
  if (panel.hidden === show) {
    panel.hidden = !show;
    document.getElementById("top-grid").classList.toggle("single", !show);
    resizeChart();
  }
  if (!show) return;
  if (!np.running) {
    np.running = true;
    requestAnimationFrame(npTick);
  }
  if (!np.episode) setText("now-playing-checkpoint", `checkpoint: ${checkpoint}`);
}

async function nextEpisode() {
  if (np.loading || !np.checkpoint) return;
  np.loading = true;
  const checkpoint = np.checkpoint;
  const note = document.getElementById("now-playing-note");
  try {
    const q = new URLSearchParams({ seed: String(np.seed) });
    const url = `/api/runs/${encodeURIComponent(runName)}/checkpoints/${encodeURIComponent(checkpoint)}/episode?${q}`;
    const episode = await CP.getJSON(url);
    np.episode = episode;
    np.shown = checkpoint;
    np.frame = 0;
    np.seed += 1;
    np.retryMs = 1000;
    setText("now-playing-checkpoint", `checkpoint: ${checkpoint}`);
    setText("now-playing-seed", String(episode.seed));
    note.textContent = checkpoint === "latest" && state.detail && state.detail.state === "running"
      ? "The newest checkpoint's greedy policy, one episode after another (each from the next seed): new checkpoints show as they are written."
      : `The ${checkpoint} checkpoint's greedy policy, one episode after another, each from the next seed.`;
    drawNowPlaying();
  } catch (err) {
    note.textContent = `Cannot play ${checkpoint}: ${err.message}. Trying again.`;
    np.retryAt = performance.now() + np.retryMs;
    np.retryMs = Math.min(15000, np.retryMs * 2);
  } finally {
    np.loading = false;
  }
}

function drawNowPlaying() {
  const e = np.episode;
  if (!e) return;
  const canvas = document.getElementById("now-playing");
  const i = Math.min(Math.floor(np.frame), e.length);
  const st = e.states[i];
  const action = i < e.length ? e.actions[i] : null;
  const caption = `${e.agent ?? "agent"} · ${np.shown} · seed ${e.seed}`;
  if (e.scene === "cartpole") {
    CartPoleDraw.draw(canvas, st, {
      xThreshold: e.limits.x_threshold,
      thetaThreshold: e.limits.theta_threshold,
      length: e.physics ? e.physics.length : undefined,
      action,
      nudge: 0,
      caption,
    });
  } else if (SceneDraw[e.scene]) {
    SceneDraw[e.scene](canvas, st, { limits: e.limits, action, caption });
  }
  setText("now-playing-step", String(i));
  setText("now-playing-length", String(e.length));
}

function npTick(now) {
  const e = np.episode;
  const dt = np.last === null ? 0 : Math.min(0.1, (now - np.last) / 1000); // a hidden tab: no jump
  np.last = now;
  if (!np.checkpoint) {
    np.running = false; // no checkpoint to play (any more): updateNowPlaying starts again
    return;
  }
  if (e && np.frame < e.length) {
    const shown = Math.floor(np.frame);
    np.frame = Math.min(e.length, np.frame + dt * (e.limits.fps || 50));
    if (np.frame >= e.length) np.endedAt = now;
    if (Math.floor(np.frame) !== shown) drawNowPlaying();
  } else if (!np.loading && now >= np.retryAt && (!e || now - np.endedAt >= END_PAUSE_MS)) {
    nextEpisode();
  }
  requestAnimationFrame(npTick);
}

async function start() {
  if (!runName) {
    document.querySelector("main").innerHTML = '<div class="error">No run named in the address. Pick one on the <a href="/">runs page</a>.</div>';
    return;
  }
  try {
    renderDetail(await CP.getJSON(`/api/runs/${encodeURIComponent(runName)}`));
    const metrics = await CP.getJSON(`/api/runs/${encodeURIComponent(runName)}/metrics`);
    state.rows = metrics.rows;
    state.offset = metrics.next_offset;
    updateChart();
    follow();
    refreshTraining();
  } catch (err) {
    document.querySelector("main").innerHTML = `<p class="small"><a href="/">← all runs</a></p><div class="error">${CP.escapeHTML(err.message)}</div>`;
  }
}

start();
