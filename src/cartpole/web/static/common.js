// Shared by every page: the header, fetching JSON, formatting, and the empty state.
"use strict";

const NAV = [
  ["/", "Runs"],
  ["/experiments", "Experiments"],
  ["/train", "Train"],
  ["/play", "Play"],
];

function renderHeader(active) {
  const header = document.createElement("header");
  header.className = "top";
  const links = NAV.map(
    ([href, label]) => `<a href="${href}" class="${label === active ? "active" : ""}">${label}</a>`
  ).join("");
  header.innerHTML = `<a class="brand" href="/">${POLE_ICON} CartPole</a><nav>${links}</nav>`;
  document.body.prepend(header);
}

const POLE_ICON =
  '<svg width="22" height="22" viewBox="0 0 22 22" aria-hidden="true"><rect x="3" y="14" width="16" height="6" rx="2" fill="#7f9cff"/>' +
  '<line x1="11" y1="15" x2="15" y2="2" stroke="#ffb347" stroke-width="3" stroke-linecap="round"/></svg>';

async function getJSON(url) {
  const response = await fetch(url, { headers: { Accept: "application/json" } });
  let body = null;
  try {
    body = await response.json();
  } catch (_) {
    body = null;
  }
  if (!response.ok) {
    const detail = body && body.detail ? body.detail : response.statusText;
    const message = typeof detail === "string" ? detail : detail.map(validationText).join("; ");
    const error = new Error(message);
    error.status = response.status;
    error.field = body && typeof body.field === "string" ? body.field : null; // the trainings API's
    throw error;
  }
  return body;
}

const TOKEN_MESSAGE =
  "Starting a training needs the server's token: open the address `cartpole serve` printed (with ?token=)";

// POST `body` as JSON. An answer that is not 2xx throws an Error with its one-line message, its
// `status` and the `field` it is about (the trainings API names the input it refuses). 401 (no token
// cookie) throws TOKEN_MESSAGE; the gate's plain-text refusals (403) throw their text.
async function postJSON(url, body) {
  const response = await fetch(url, {
    method: "POST",
    headers: { Accept: "application/json", "Content-Type": "application/json" },
    body: JSON.stringify(body ?? {}),
  });
  const text = await response.text();
  let parsed = null;
  try {
    parsed = text ? JSON.parse(text) : null;
  } catch (_) {
    parsed = null;
  }
  if (!response.ok) {
    let message;
    if (response.status === 401) message = TOKEN_MESSAGE;
    else if (parsed && parsed.detail) message = typeof parsed.detail === "string" ? parsed.detail : parsed.detail.map(validationText).join("; ");
    else message = text.trim().split("\n")[0] || response.statusText || `HTTP ${response.status}`;
    const error = new Error(message);
    error.status = response.status;
    error.field = parsed && typeof parsed.field === "string" ? parsed.field : null;
    throw error;
  }
  return parsed;
}

// One of FastAPI's validation errors as a sentence that names the field: "seed must be >= 0".
function validationText(d) {
  const field = Array.isArray(d.loc) && d.loc.length ? d.loc[d.loc.length - 1] : "value";
  const ctx = d.ctx || {};
  if (ctx.ge !== undefined) return `${field} must be >= ${ctx.ge}`;
  if (ctx.gt !== undefined) return `${field} must be > ${ctx.gt}`;
  if (ctx.le !== undefined) return `${field} must be <= ${ctx.le}`;
  if (ctx.lt !== undefined) return `${field} must be < ${ctx.lt}`;
  if (d.type === "int_parsing" || d.type === "int_from_float") return `${field} must be a whole number`;
  if (d.type === "float_parsing" || d.type === "finite_number") return `${field} must be a number`;
  return `${field}: ${d.msg}`;
}

function escapeHTML(text) {
  return String(text ?? "").replace(/[&<>"']/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;", "'": "&#39;" })[c]);
}

function fmtInt(n) {
  return n === null || n === undefined ? "–" : Number(n).toLocaleString("en-US");
}

function fmtNum(n, digits = 1) {
  return n === null || n === undefined || Number.isNaN(n) ? "–" : Number(n).toFixed(digits);
}

function fmtDate(iso) {
  if (!iso) return "–";
  const d = new Date(iso);
  return Number.isNaN(d.getTime()) ? iso : d.toLocaleString("en-GB", { dateStyle: "medium", timeStyle: "short" });
}

function stateBadge(state, problem) {
  const title = problem ? ` title="${escapeHTML(problem)}"` : "";
  return `<span class="badge ${escapeHTML(state)}"${title}>${escapeHTML(state)}</span>`;
}

function solvedBadge(run) {
  if (run.solved) {
    return `<span class="badge solved">✓ solved</span><span class="rule">${escapeHTML(run.rule || run.verdict || "")}</span>`;
  }
  if (run.state === "running") return '<span class="badge training">training</span>';
  if (run.rule) return `<span class="badge not-solved">not solved</span><span class="rule">${escapeHTML(run.rule)}</span>`;
  return '<span class="muted small">not evaluated yet</span>';
}

function emptyState(runsDir) {
  const dir = runsDir && runsDir !== "runs" ? ` --runs-dir ${escapeHTML(runsDir)}` : "";
  return `<div class="empty"><h2>No runs yet</h2>
    <p>Nothing has been trained in <code>${escapeHTML(runsDir || "runs")}</code>. Train an agent in a second terminal (about two seconds):</p>
    <pre>cartpole train cem${dir}</pre>
    <p>Or start one on the <a href="/train">Train page</a>. It appears here by itself. Meanwhile, <a href="/play">play CartPole yourself</a>.</p></div>`;
}

// Fetch `url` every `everyMs` and hand the body to `render` (only when it changed). When the server
// cannot be reached (restarted, stopped) `showError(message, seconds)` says so and it retries with
// backoff (doubling up to 30 s); the first answer after that renders again.
function poll(url, render, showError, everyMs = 3000) {
  let last = "";
  let retryMs = everyMs;
  async function tick() {
    try {
      const body = await getJSON(url);
      const text = JSON.stringify(body);
      if (text !== last) {
        last = text;
        render(body);
      }
      retryMs = everyMs;
      setTimeout(tick, everyMs);
    } catch (err) {
      if (err.status && err.status < 500) {
        showError(err.message, null); // a 4xx (an unknown name): asking again will not help
        return;
      }
      last = "";
      showError(err.message, Math.round(retryMs / 1000));
      setTimeout(tick, retryMs);
      retryMs = Math.min(30000, retryMs * 2);
    }
  }
  tick();
}

function param(name) {
  return new URLSearchParams(window.location.search).get(name);
}

window.CP = { renderHeader, getJSON, postJSON, TOKEN_MESSAGE, validationText, escapeHTML, fmtInt, fmtNum, fmtDate, stateBadge, solvedBadge, emptyState, poll, param };
