// Sweep page: one `cartpole sweep` study: its trials (values, states, settings), best.toml, optuna-dashboard.
"use strict";

CP.renderHeader("Experiments");
const name = CP.param("name") || "";
const STATE_BADGE = { COMPLETE: "finished", PRUNED: "interrupted", FAIL: "failed", RUNNING: "running", WAITING: "unknown" };

function value(v, digits = 0) {
  if (v === null || v === undefined) return "–";
  if (typeof v === "number") {
    if (Number.isInteger(v)) return v.toLocaleString("en-US");
    return Math.abs(v) < 0.01 || Math.abs(v) >= 1e6 ? v.toExponential(3) : v.toLocaleString("en-US", { maximumFractionDigits: Math.max(digits, 4) });
  }
  return CP.escapeHTML(String(v));
}

function duration(seconds) {
  if (seconds === null || seconds === undefined) return "–";
  return seconds < 120 ? `${seconds.toFixed(0)} s` : `${(seconds / 60).toFixed(1)} min`;
}

function trialRow(t, paramNames, best) {
  const params = paramNames.map((p) => `<td class="num">${value(t.params[p])}</td>`).join("");
  const costs = t.seed_costs.map((c) => value(c)).join(", ") || "–";
  const mark = t.number === best ? ' <span class="badge solved">best</span>' : "";
  return `<tr data-trial="${t.number}" class="${t.number === best ? "best" : ""}">
    <td class="num">${t.number}${mark}</td>
    <td><span class="badge ${STATE_BADGE[t.state] || "unknown"}">${CP.escapeHTML(t.state.toLowerCase())}</span></td>
    <td class="num"><b>${value(t.value)}</b></td>
    <td class="num small">${costs}</td>
    ${params}
    <td class="num small muted">${duration(t.seconds)}</td>
  </tr>`;
}

function renderTrials(d) {
  const box = document.getElementById("trials");
  const counts = Object.entries(d.counts).map(([state, n]) => `${n} ${state.toLowerCase()}`).join(" · ");
  const asked = d.trials_asked ? ` of ${d.trials_asked} asked` : "";
  document.getElementById("counts").textContent = counts ? `${counts}${asked}` : "";
  if (!d.trials.length) {
    box.innerHTML = '<p class="muted">No trials to show.</p>';
    return;
  }
  const paramNames = [...new Set(d.trials.flatMap((t) => Object.keys(t.params)))].sort();
  const head = paramNames.map((p) => `<th class="num">${CP.escapeHTML(p)}</th>`).join("");
  const trials = [...d.trials].sort((a, b) => a.number - b.number);
  box.innerHTML = `<table id="trials-table"><thead><tr><th class="num">trial</th><th>state</th><th class="num">value</th>
      <th class="num">per seed</th>${head}<th class="num">took</th></tr></thead>
    <tbody>${trials.map((t) => trialRow(t, paramNames, d.best)).join("")}</tbody></table>`;
}

function renderBest(d) {
  const box = document.getElementById("best");
  if (!d.best_toml) {
    box.innerHTML = '<p class="muted">No best.toml yet: it is written once a trial completes.</p>';
    return;
  }
  const file = `${runsDir}/sweeps/${d.name}/best.toml`;
  box.innerHTML = `<p class="small">Trial ${d.best ?? "?"} as a complete preset file (<a id="best-link" href="/api/sweeps/${encodeURIComponent(d.name)}/best.toml">best.toml</a>). Train with it, then judge it on fresh seeds:</p>
    <pre class="mono small wrap">cartpole train ${CP.escapeHTML(d.agent ?? "AGENT")} --preset ${CP.escapeHTML(file)}
cartpole compare ${CP.escapeHTML(d.agent ?? "AGENT")} ${CP.escapeHTML(d.agent ?? "AGENT")}:${CP.escapeHTML(file)} --seeds 10 --first-seed 1000</pre>
    <pre class="mono small wrap" id="best-toml">${CP.escapeHTML(d.best_toml)}</pre>`;
}

function renderDashboard(d) {
  document.getElementById("dashboard").innerHTML = `<p class="small">Optuna's dashboard shows the study live (history, parameter importances, slices):</p>
    <pre class="mono small wrap" id="dashboard-command">pip install optuna-dashboard
${CP.escapeHTML(d.dashboard)}</pre>
    <p class="small muted">Run it from the folder that holds <code>${CP.escapeHTML(runsDir)}</code>; it serves on 127.0.0.1:8080.</p>`;
  const space = d.space ? Object.entries(d.space) : [];
  document.getElementById("space").innerHTML = space.length
    ? `<table class="kv">${space.map(([k, v]) => `<tr><td>${CP.escapeHTML(k)}</td><td class="mono small">${CP.escapeHTML(JSON.stringify(v))}</td></tr>`).join("")}</table>`
    : '<p class="muted small">Not recorded.</p>';
}

let runsDir = "runs";

function render(d) {
  document.getElementById("error").innerHTML = "";
  document.title = `${d.name} · CartPole`;
  document.getElementById("title").textContent = `Sweep ${d.name}`;
  const parts = [
    `${CP.escapeHTML(d.agent ?? "?")} on ${CP.escapeHTML(d.env_id ?? "?")}`,
    d.preset ? `from preset <code>${CP.escapeHTML(d.preset)}</code>` : "",
    d.seeds_per_trial ? `${d.seeds_per_trial} seeds per trial` : "",
    `budget: ${CP.escapeHTML(d.budget ?? "the preset's own")}`,
  ];
  document.getElementById("subtitle").innerHTML = parts.filter(Boolean).join(" · ");
  document.getElementById("problem").innerHTML = d.problem ? `<div class="notice" id="sweep-problem">${CP.escapeHTML(d.problem)}</div>` : "";
  renderTrials(d);
  renderBest(d);
  renderDashboard(d);
}

function showError(message, seconds) {
  if (message === "Not Found") message = `No sweep named "${name}" in this runs folder`;
  const retry = seconds === null ? ' See <a href="/experiments">all experiments</a>.' : ` Is <code>cartpole serve</code> still running? Trying again in ${seconds} s.`;
  document.getElementById("error").innerHTML = `<div class="error" id="load-error">${CP.escapeHTML(message)}.${retry}</div>`;
  if (seconds === null) document.getElementById("trials").innerHTML = "";
}

async function start() {
  if (!name) {
    document.querySelector("main").innerHTML = '<div class="error">No sweep named in the address. Pick one on the <a href="/experiments">experiments page</a>.</div>';
    return;
  }
  try {
    runsDir = (await CP.getJSON("/api/info")).runs_dir;
  } catch (_) {
    // the poll below retries and says what is wrong
  }
  CP.poll(`/api/sweeps/${encodeURIComponent(name)}`, render, showError, 5000);
}

start();
