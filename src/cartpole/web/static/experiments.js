// Experiments page: the comparisons (`cartpole compare`) and sweeps (`cartpole sweep`) of the runs folder.
"use strict";

CP.renderHeader("Experiments");
const POLL_MS = 3000;
let runsDir = "runs";

function runsDirFlag() {
  return runsDir && runsDir !== "runs" ? ` --runs-dir ${CP.escapeHTML(runsDir)}` : "";
}

function problemLine(problem) {
  return problem ? `<span class="rule problem">${CP.escapeHTML(problem)}</span>` : "";
}

function experimentRow(e) {
  const link = `<a href="/experiment?name=${encodeURIComponent(e.name)}">${CP.escapeHTML(e.name)}</a>`;
  return `<tr data-experiment="${CP.escapeHTML(e.name)}">
    <td class="name">${link}${problemLine(e.problem)}</td>
    <td class="hide-narrow">${CP.escapeHTML(e.env_id ?? "–")}</td>
    <td>${e.entries.map((x) => `<code>${CP.escapeHTML(x)}</code>`).join(" ") || "–"}</td>
    <td class="num">${e.seeds ?? "–"}</td>
    <td class="num">${CP.fmtInt(e.runs)}</td>
    <td class="small muted hide-narrow">${CP.fmtDate(e.updated)}</td>
  </tr>`;
}

function sweepRow(s) {
  const link = `<a href="/sweep?name=${encodeURIComponent(s.name)}">${CP.escapeHTML(s.name)}</a>`;
  const best = s.has_best ? `<a href="/api/sweeps/${encodeURIComponent(s.name)}/best.toml">best.toml</a>` : '<span class="muted small">none yet</span>';
  return `<tr data-sweep="${CP.escapeHTML(s.name)}">
    <td class="name">${link}${problemLine(s.problem)}</td>
    <td>${CP.escapeHTML(s.agent ?? "?")}</td>
    <td class="hide-narrow">${CP.escapeHTML(s.env_id ?? "–")}</td>
    <td class="num">${s.trials_asked ?? "–"}</td>
    <td class="hide-narrow">${CP.escapeHTML(s.storage)}</td>
    <td>${best}</td>
    <td class="small muted hide-narrow">${CP.fmtDate(s.updated)}</td>
  </tr>`;
}

function render(body) {
  document.getElementById("error").innerHTML = "";
  const experiments = document.getElementById("experiments");
  experiments.innerHTML = body.experiments.length
    ? `<div class="table-wrap"><table id="experiments-table"><thead><tr><th>experiment</th><th class="hide-narrow">env</th><th>entries</th>
        <th class="num">seeds</th><th class="num">runs</th><th class="hide-narrow">report written</th></tr></thead>
        <tbody>${body.experiments.map(experimentRow).join("")}</tbody></table></div>`
    : `<div class="empty" id="no-experiments"><h2>No comparisons yet</h2><p>Compare agents over several seeds (each run in its own process):</p>
        <pre>cartpole compare cem dqn --seeds 5${runsDirFlag()}</pre><p>Its report appears here when the runs end.</p></div>`;
  const sweeps = document.getElementById("sweeps");
  sweeps.innerHTML = body.sweeps.length
    ? `<div class="table-wrap"><table id="sweeps-table"><thead><tr><th>sweep</th><th>agent</th><th class="hide-narrow">env</th>
        <th class="num">trials asked</th><th class="hide-narrow">storage</th><th>best preset</th><th class="hide-narrow">last change</th></tr></thead>
        <tbody>${body.sweeps.map(sweepRow).join("")}</tbody></table></div>`
    : `<div class="empty" id="no-sweeps"><h2>No sweeps yet</h2><p>Tune an agent's settings with Optuna:</p>
        <pre>cartpole sweep dqn --trials 12 --seeds-per-trial 2 --study my-sweep${runsDirFlag()}</pre></div>`;
}

function showError(message, seconds) {
  const retry = seconds === null ? "" : ` Is <code>cartpole serve</code> still running? Trying again in ${seconds} s.`;
  document.getElementById("error").innerHTML =
    `<div class="error" id="load-error">Cannot read the experiments: ${CP.escapeHTML(message)}.${retry}</div>`;
}

async function start() {
  try {
    runsDir = (await CP.getJSON("/api/info")).runs_dir;
    document.querySelectorAll(".runs-dir").forEach((el) => { el.textContent = runsDir; });
  } catch (_) {
    // the list below retries and says what is wrong
  }
  CP.poll("/api/experiments", render, showError, POLL_MS);
}

start();
