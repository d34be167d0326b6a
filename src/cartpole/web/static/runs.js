// Runs page: the table of run folders, refreshed every two seconds.
"use strict";

CP.renderHeader("Runs");
const container = document.getElementById("runs");
const POLL_MS = 2000;

function runRow(run) {
  const name = CP.escapeHTML(run.name);
  const link = `<a href="/run?name=${encodeURIComponent(run.name)}">${name}</a>`;
  const state = CP.stateBadge(run.state, run.problem);
  const problem = run.problem ? `<span class="rule">${CP.escapeHTML(run.problem)}</span>` : "";
  const watch = run.watchable && run.has_checkpoint !== false && run.state !== "unreadable" && run.state !== "incomplete"
    ? `<a class="button" href="/run?name=${encodeURIComponent(run.name)}#checkpoints">Watch</a>` : "";
  return `<tr data-run="${name}">
    <td class="name">${link}<span class="rule">${CP.fmtDate(run.created)}</span></td>
    <td data-label="agent">${CP.escapeHTML(run.agent ?? "?")}</td>
    <td data-label="env">${CP.escapeHTML(run.env_id ?? "?")}</td>
    <td data-label="seed" class="num">${run.seed ?? "–"}</td>
    <td data-label="state">${state}${problem}</td>
    <td data-label="steps" class="num">${CP.fmtInt(run.env_steps)}</td>
    <td data-label="best eval" class="num">${CP.fmtNum(run.best_eval_mean)}</td>
    <td data-label="solved?" class="solved-cell">${CP.solvedBadge(run)}</td>
    <td class="watch-cell">${watch}</td>
  </tr>`;
}

let lastText = "";

function render(body) {
  const text = JSON.stringify(body);
  if (text === lastText) return; // nothing changed: keep the DOM (and the reader's selection)
  lastText = text;
  document.getElementById("runs-dir").textContent = body.runs_dir;
  if (body.runs.length === 0) {
    container.innerHTML = CP.emptyState(body.runs_dir);
    return;
  }
  container.innerHTML = `<div class="table-wrap"><table id="runs-table">
    <thead><tr><th>run</th><th>agent</th><th>env</th><th class="num">seed</th>
      <th>state</th><th class="num">steps</th><th class="num">best eval</th><th>solved?</th><th></th></tr></thead>
    <tbody>${body.runs.map(runRow).join("")}</tbody></table></div>`;
}

const MAX_RETRY_MS = 30000;
let retryMs = POLL_MS;

async function refresh() {
  try {
    render(await CP.getJSON("/api/runs"));
    retryMs = POLL_MS;
  } catch (err) {
    lastText = ""; // whatever comes next replaces the error, even if the runs did not change
    const seconds = Math.round(retryMs / 1000);
    container.innerHTML = `<div class="error" id="runs-error">Cannot read the runs: ${CP.escapeHTML(err.message)}. Is <code>cartpole serve</code> still running? Trying again in ${seconds} s.</div>`;
    setTimeout(refresh, retryMs);
    retryMs = Math.min(MAX_RETRY_MS, retryMs * 2);
    return;
  }
  setTimeout(refresh, POLL_MS);
}

refresh();
