// Experiment page: one `cartpole compare` report (counts, times to solve and returns with 95% CIs) and its figures.
"use strict";

CP.renderHeader("Experiments");
const name = CP.param("name") || "";
const FIGURE_TEXT = {
  curves: "Evaluation return against env steps: per entry the mean over its runs, with a 95% bootstrap CI band.",
  solve_steps: "Each run's env steps to its first verified solve (hollow: never solved, shown at its budget); black bar: the median.",
  performance_profile: "Performance profile (rliable): per entry, the fraction of runs whose final verdict mean return is above each tau, with a 95% bootstrap CI band.",
  improvement: "Probability of improvement (rliable): for each pair, the chance that a run of X ends with a higher final verdict mean return than a run of Y (0.5: no difference), with its 95% bootstrap CI.",
};

function number(value, digits) {
  return Number(value).toLocaleString("en-US", { minimumFractionDigits: digits, maximumFractionDigits: digits });
}

// "median [CI low, high] (IQR a-b)", with ≥ where unsolved runs hold the median up.
function timeCell(stats, digits) {
  if (!stats || stats.median === null) return "–";
  const bound = stats.median_is_lower_bound ? '<abbr title="at least half the runs never solved: the true median is at least this">≥</abbr> ' : "";
  let text = `${bound}<b>${number(stats.median, digits)}</b>`;
  if (stats.ci95) text += `<span class="rule">CI [${number(stats.ci95[0], digits)}, ${number(stats.ci95[1], digits)}]</span>`;
  if (stats.iqr) text += `<span class="rule">IQR ${number(stats.iqr[0], digits)}–${number(stats.iqr[1], digits)}</span>`;
  if (stats.censored) text += `<span class="rule">${stats.censored} unsolved, at their budget</span>`;
  return text;
}

function returnCell(stats) {
  if (!stats || stats.iqm === null) return "–";
  let text = `<b>${number(stats.iqm, 1)}</b>`;
  if (stats.ci95) text += `<span class="rule">CI [${number(stats.ci95[0], 1)}, ${number(stats.ci95[1], 1)}]</span>`;
  return text + `<span class="rule">min ${number(stats.min, 1)}, max ${number(stats.max, 1)}</span>`;
}

function entryRow(e) {
  return `<tr data-entry="${CP.escapeHTML(e.entry)}">
    <td class="name"><code>${CP.escapeHTML(e.entry)}</code></td>
    <td class="num">${e.runs}</td>
    <td class="num">${e.solved} / ${e.runs}</td>
    <td class="num">${e.final_solved} / ${e.runs}</td>
    <td class="num">${timeCell(e.env_steps_to_solve, 0)}</td>
    <td class="num">${timeCell(e.cpu_seconds_to_solve, 2)}</td>
    <td class="num">${timeCell(e.wall_seconds_to_solve, 2)}</td>
    <td class="num">${returnCell(e.final_mean_return)}</td>
  </tr>`;
}

function renderReport(report) {
  const box = document.getElementById("report");
  if (!report) {
    box.innerHTML = '<p class="muted">No report to show.</p>';
    document.getElementById("method").textContent = "";
    return;
  }
  const seeds = report.seeds.length ? `seeds ${report.seeds[0]}–${report.seeds[report.seeds.length - 1]}` : "no seeds";
  document.getElementById("subtitle").innerHTML = `${CP.escapeHTML(report.env_id)} · ${report.entries.length} entries × ${report.seeds.length} seeds (${seeds}) · budget: ${CP.escapeHTML(report.budget)}`;
  const pct = Math.round(report.confidence * 100);
  box.innerHTML = `<table id="report-table"><thead><tr><th>entry</th><th class="num">runs</th>
      <th class="num">solved in training</th><th class="num">final verdict solved</th>
      <th class="num">env steps to solve</th><th class="num">CPU s to solve</th><th class="num">wall s to solve</th>
      <th class="num">final return, IQM</th></tr></thead>
    <tbody>${report.entries.map(entryRow).join("")}</tbody></table>`;
  document.getElementById("method").textContent =
    `Times: median [${pct}% CI] over runs, to the first verified solve; ≥ marks a median that unsolved runs hold up. ` +
    `Final return: interquartile mean [${pct}% CI] of each run's final verdict. Method: ${report.method}.`;
}

function renderFigures(figures) {
  const panel = document.getElementById("figures-panel");
  panel.hidden = figures.length === 0;
  document.getElementById("figures").innerHTML = figures.map((f) => {
    const src = `/api/experiments/${encodeURIComponent(name)}/figures/${encodeURIComponent(f)}.png`;
    const text = FIGURE_TEXT[f] || f;
    return `<figure class="figure"><a href="${src}"><img src="${src}" alt="${CP.escapeHTML(text)}" id="figure-${CP.escapeHTML(f)}"></a>
      <figcaption class="legend-note">${CP.escapeHTML(text)}</figcaption></figure>`;
  }).join("");
}

function renderMade(d) {
  const folder = `${runsDir}/${d.runs_folder}`;
  const command = d.command ? `<p class="small muted">Made by</p><pre class="mono small wrap">${CP.escapeHTML(d.command.join(" "))}</pre>` : "";
  document.getElementById("made").innerHTML = `${command}
    <p class="small">Re-running the same command resumes it (finished runs are kept; a larger <code>--seeds</code> adds seeds).
    Its run folders are in <code>${CP.escapeHTML(folder)}</code>; to look at them one by one:</p>
    <pre class="mono small wrap">cartpole serve --runs-dir ${CP.escapeHTML(folder)}</pre>`;
}

// A comparison shared through a database: every machine's finished runs, followed live.
function renderShared(status) {
  const box = document.getElementById("shared");
  if (!status) {
    box.innerHTML = "";
    return;
  }
  const live = status.finished < status.total ? " This page follows it as runs end." : "";
  box.innerHTML = `<div class="notice" id="shared-status">Shared through ${CP.escapeHTML(status.storage)}:
    <b>${status.finished}</b> of ${status.total} runs finished, ${status.running} running, ${status.pending} waiting.${live}</div>`;
}

function render(d) {
  document.getElementById("error").innerHTML = "";
  document.title = `${d.name} · CartPole`;
  document.getElementById("title").textContent = `Experiment ${d.name}`;
  document.getElementById("problem").innerHTML = d.problem ? `<div class="notice" id="report-problem">${CP.escapeHTML(d.problem)}</div>` : "";
  renderShared(d.shared);
  renderReport(d.report);
  renderFigures(d.figures);
  renderMade(d);
}

function showError(message, seconds) {
  if (message === "Not Found") message = `No experiment named "${name}" in this runs folder`;
  const retry = seconds === null ? ' See <a href="/experiments">all experiments</a>.' : ` Is <code>cartpole serve</code> still running? Trying again in ${seconds} s.`;
  document.getElementById("error").innerHTML = `<div class="error" id="load-error">${CP.escapeHTML(message)}.${retry}</div>`;
  if (seconds === null) document.getElementById("report").innerHTML = "";
}

let runsDir = "runs";

async function start() {
  if (!name) {
    document.querySelector("main").innerHTML = '<div class="error">No experiment named in the address. Pick one on the <a href="/experiments">experiments page</a>.</div>';
    return;
  }
  try {
    runsDir = (await CP.getJSON("/api/info")).runs_dir;
  } catch (_) {
    // the poll below retries and says what is wrong
  }
  CP.poll(`/api/experiments/${encodeURIComponent(name)}`, render, showError, 5000);
}

start();
