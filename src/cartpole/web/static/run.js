// Run page: the learning curve (live while training), checkpoints with Watch buttons, eval, config.
"use strict";

CP.renderHeader("Runs");
const runName = CP.param("name") || "";
const MA_WINDOW = 20;
const RETURN_KEYS = [
  ["train/episode_return", "episode return"],
  ["train/mean_return", "generation mean return"],
];

const state = { detail: null, rows: [], offset: 0, plot: null, socket: null, returnKey: null };

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
  renderConfig(d.config);
}

function renderCheckpoints(d) {
  const box = document.getElementById("checkpoint-list");
  if (!d.checkpoints.length) {
    box.innerHTML = '<p class="muted">No checkpoint yet: one is written as training goes.</p>';
    return;
  }
  const note = d.watchable ? "" :
    `<p class="notice">Watch draws CartPole, Acrobot-v1 and MountainCar-v0; this run trains ${CP.escapeHTML(d.env_id ?? "another env")}, so only its curves are shown.</p>`;
  const seed = d.eval && d.eval.seeds && d.eval.seeds.length ? d.eval.seeds[0] : 0;
  const rows = d.checkpoints.map((c) => {
    const href = `/watch?run=${encodeURIComponent(d.name)}&checkpoint=${encodeURIComponent(c.name)}&seed=${seed}`;
    const button = d.watchable ? `<a class="button primary" href="${href}">▶ Watch</a>` : "";
    return `<tr><td><b>${CP.escapeHTML(c.name)}</b></td><td class="muted small">${CP.fmtDate(c.modified)}</td>
      <td class="num small muted hide-narrow">${(c.bytes / 1024).toFixed(1)} KiB</td><td class="num">${button}</td></tr>`;
  });
  box.innerHTML = `${note}<table>${rows.join("")}</table>`;
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

window.addEventListener("resize", () => {
  if (!state.plot) return;
  const el = document.getElementById("chart");
  state.plot.setSize({ width: Math.max(280, el.clientWidth), height: el.clientWidth < 500 ? 260 : 340 });
});

// ------------------------------------------------------------------------------------------------
// Live updates
// ------------------------------------------------------------------------------------------------

function follow() {
  const scheme = location.protocol === "https:" ? "wss" : "ws";
  const url = `${scheme}://${location.host}/ws/runs/${encodeURIComponent(runName)}/metrics?offset=${state.offset}`;
  const socket = new WebSocket(url);
  state.socket = socket;
  let lastState = state.detail ? state.detail.state : null;
  socket.onmessage = async (event) => {
    const message = JSON.parse(event.data);
    if (message.type === "metrics") {
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
    }
  };
  socket.onclose = (event) => {
    if (event.code !== 1000 && event.code !== 1008) setTimeout(follow, 3000); // server restarted: retry
  };
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
  } catch (err) {
    document.querySelector("main").innerHTML = `<p class="small"><a href="/">← all runs</a></p><div class="error">${CP.escapeHTML(err.message)}</div>`;
  }
}

start();
