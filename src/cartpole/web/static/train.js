// Train page: pick an env, an agent and a preset, change any setting, and start `cartpole train` on the
// server (POST /api/trainings); then off to the new run's page. Also the trainings queue, and a form
// filled from an earlier training (?from=NAME) or run (?run=NAME).
"use strict";

CP.renderHeader("Train");
const el = (id) => document.getElementById(id);

const MAX_SEEDS = 4096;
const MAX_SEED = 4294967295;
const SEEDS_HINT = "give a seed (0), a list (0,1,2), a range (0-4) or both (0-4,9)";
const FORM_FIELDS = ["agent", "env_id", "preset", "seeds", "budget"];
const ACTIVE = new Set(["queued", "running"]);

const form = {
  catalog: null, // {envs, agents, read_only, max_trainings}: what the form offers
  options: null, // the /api/training-options answer whose settings the table shows
  defaultPreset: null, // the env's preset for the agent shown (sent only when another is picked)
  blocked: "", // why the choice shown cannot train (a preset for images on a state env...), or ""
  busy: false,
  waiting: null, // the name of a queued training this page waits for
  pendingEdits: {}, // changed settings kept while a choice that does not go together shows none
};

// ------------------------------------------------------------------------------------------------
// Values: what a setting's input shows, and the JSON it sends
// ------------------------------------------------------------------------------------------------

function baseKind(kind) {
  return String(kind).split("|")[0];
}

function nullable(kind) {
  return String(kind).endsWith("|none");
}

// A JSON value as the input shows it: [64, 64], 0.004, 1.0 for a float, "" for none.
function valueText(value, kind) {
  if (value === null || value === undefined) return "";
  if (Array.isArray(value)) return `[${value.map((v) => valueText(v, "")).join(", ")}]`;
  if (typeof value === "number" && baseKind(kind) === "float" && Number.isInteger(value)) return value.toFixed(1);
  if (typeof value === "string" && kind === "") return JSON.stringify(value); // an item of a list
  return String(value);
}

// An input's text as the JSON value to send. A number that does not parse is sent as its text, so
// the server answers `cartpole train`'s message for it (lr='abc' is not a valid float ...).
function textValue(text, kind) {
  const base = baseKind(kind);
  const t = String(text).trim();
  if (nullable(kind) && (t === "" || t.toLowerCase() === "none")) return null;
  if (base === "int" || base === "float") {
    const n = Number(t);
    return t !== "" && Number.isFinite(n) ? n : String(text);
  }
  if (base === "list") {
    try {
      return JSON.parse(t);
    } catch (_) {
      return String(text);
    }
  }
  if (base === "bool") {
    if (t.toLowerCase() === "true") return true;
    if (t.toLowerCase() === "false") return false;
    return String(text);
  }
  return String(text);
}

// A value as `--set NAME=VALUE` gave it (a run's config keeps that text: "24", "false", "none").
function fromSetText(value, kind) {
  return typeof value === "string" ? textValue(value, kind) : value;
}

function sameValue(a, b) {
  return JSON.stringify(a) === JSON.stringify(b);
}

function settingInput(name) {
  return document.querySelector(`#settings-table [data-setting-input="${CSS.escape(name)}"]`);
}

function readInput(input) {
  const kind = input.dataset.kind;
  if (input.type === "checkbox") return input.checked;
  return textValue(input.value, kind);
}

function writeInput(input, value) {
  const kind = input.dataset.kind;
  if (input.type === "checkbox") input.checked = value === true;
  else if (input.tagName === "SELECT") input.value = value === null ? "none" : String(value);
  else input.value = typeof value === "string" ? value : valueText(value, kind);
}

// ------------------------------------------------------------------------------------------------
// Seeds: "0", "0,1,2", "0-4", "0-4,9" (a number alone is that seed, not a count)
// ------------------------------------------------------------------------------------------------

function parseSeeds(text) {
  const t = String(text).trim();
  if (!t) throw new Error(`seeds is empty; ${SEEDS_HINT}`);
  const seeds = [];
  for (const raw of t.split(",")) {
    const part = raw.trim();
    const range = /^(\d+)\s*-\s*(\d+)$/.exec(part);
    if (range) {
      const low = Number(range[1]);
      const high = Number(range[2]);
      if (low > high) throw new Error(`seeds range ${part} is reversed; write ${high}-${low}`);
      if (high > MAX_SEED) throw new Error(`seed ${high} is out of range; seeds are 0 to ${MAX_SEED}`);
      if (seeds.length + high - low + 1 > MAX_SEEDS) throw new Error(`more than ${MAX_SEEDS} seeds; split them into several trainings`);
      for (let s = low; s <= high; s++) seeds.push(s);
    } else if (/^\d+$/.test(part)) {
      seeds.push(Number(part));
    } else {
      const what = part === "" ? "an empty item between commas" : `${JSON.stringify(part)} is not a seed or a range`;
      throw new Error(`seeds ${JSON.stringify(t)}: ${what}; ${SEEDS_HINT}`);
    }
    if (seeds.length > MAX_SEEDS) throw new Error(`more than ${MAX_SEEDS} seeds; split them into several trainings`);
  }
  const outOfRange = seeds.find((s) => s > MAX_SEED);
  if (outOfRange !== undefined) throw new Error(`seed ${outOfRange} is out of range; seeds are 0 to ${MAX_SEED}`);
  const seen = new Set();
  for (const s of seeds) {
    if (seen.has(s)) throw new Error(`seed ${s} is listed more than once; each seed trains once`);
    seen.add(s);
  }
  return seeds;
}

// [0, 1, 2, 3, 4, 9] -> "0-4,9"
function seedsText(seeds) {
  const parts = [];
  let i = 0;
  while (i < seeds.length) {
    let j = i;
    while (j + 1 < seeds.length && seeds[j + 1] === seeds[j] + 1) j++;
    if (j - i >= 2) parts.push(`${seeds[i]}-${seeds[j]}`);
    else for (let k = i; k <= j; k++) parts.push(String(seeds[k]));
    i = j + 1;
  }
  return parts.join(",");
}

// ------------------------------------------------------------------------------------------------
// Budgets: a run's {env_steps|episodes|iterations|seconds: n} as --budget text, and back
// ------------------------------------------------------------------------------------------------

const BUDGET_UNITS = [["env_steps", ""], ["episodes", "ep"], ["iterations", "gen"], ["seconds", "s"]];

function budgetText(budget) {
  if (!budget || typeof budget !== "object") return "";
  for (const [key, unit] of BUDGET_UNITS) {
    const n = budget[key];
    if (n === null || n === undefined) continue;
    if (key === "env_steps" && Number.isInteger(n) && n >= 1000 && n % 1000 === 0) return `${n / 1000}k`;
    return `${n}${unit}`;
  }
  return "";
}

// --budget text as {unit: count}, to tell whether two spellings (100k, 100000) are one budget; null
// for text this does not read (the server says what is wrong with it).
function budgetKey(text) {
  const m = /^\s*([0-9]*\.?[0-9]+(?:e[0-9]+)?)\s*(k|m|ep|gen|it|s|min)?\s*$/i.exec(String(text || ""));
  if (!m) return null;
  let n = Number(m[1]);
  const unit = (m[2] || "").toLowerCase();
  if (unit === "k") n *= 1e3;
  if (unit === "m") n *= 1e6;
  if (unit === "min") n *= 60;
  const key = { "": "env_steps", k: "env_steps", m: "env_steps", ep: "episodes", gen: "iterations", it: "iterations", s: "seconds", min: "seconds" }[unit];
  return `${key}:${n}`;
}

// ------------------------------------------------------------------------------------------------
// Messages
// ------------------------------------------------------------------------------------------------

function clearErrors() {
  for (const node of document.querySelectorAll(".field-error")) node.textContent = "";
  for (const row of document.querySelectorAll("#settings-table tr.invalid")) row.classList.remove("invalid");
  el("error-settings").innerHTML = "";
  el("message").innerHTML = readOnlyNotice();
  el("train-status").textContent = "";
}

function readOnlyNotice() {
  return form.catalog && form.catalog.read_only
    ? '<div class="notice" id="read-only">This server is read-only (<code>cartpole serve --read-only</code>): it starts no trainings. The form shows what <code>cartpole train</code> would be given.</div>'
    : "";
}

function showMessage(text, kind = "error") {
  el("message").innerHTML = `${readOnlyNotice()}<div class="${kind}" id="train-error">${CP.escapeHTML(text)}</div>`;
}

// A refusal beside the input it is about: a form field, a setting's input, or above the settings.
function showFieldError(field, text) {
  if (FORM_FIELDS.includes(field)) {
    el(`error-${field}`).textContent = text;
    return `the ${field === "env_id" ? "env" : field}`;
  }
  const input = field ? settingInput(field) : null;
  if (input) {
    const row = input.closest("tr");
    row.classList.add("invalid");
    row.querySelector(".field-error").textContent = text;
    row.scrollIntoView({ block: "center" });
    input.focus();
    return field;
  }
  el("error-settings").innerHTML = `<div class="error">${CP.escapeHTML(text)}</div>`;
  return "the settings";
}

// ------------------------------------------------------------------------------------------------
// The form: selects, and the table of the preset's settings
// ------------------------------------------------------------------------------------------------

function fillSelect(select, values, chosen, label = (v) => v) {
  const list = values.includes(chosen) || chosen === null ? values : [...values, chosen];
  select.innerHTML = list.map((v) => `<option value="${CP.escapeHTML(v)}">${CP.escapeHTML(label(v))}</option>`).join("");
  if (chosen !== null) select.value = chosen;
}

function agentPresets(agent) {
  const found = form.catalog.agents.find((a) => a.name === agent);
  return found ? found.presets : [];
}

function renderPresetSelect(agent, chosen) {
  const presets = agentPresets(agent);
  const label = (name) => {
    const p = presets.find((x) => x.name === name);
    const tags = [];
    if (name === form.defaultPreset) tags.push("the env's");
    if (p && p.for_images) tags.push("images");
    return tags.length ? `${name} (${tags.join(", ")})` : name;
  };
  fillSelect(el("preset"), presets.map((p) => p.name), chosen, label);
  const p = presets.find((x) => x.name === chosen);
  el("preset-description").textContent = p ? p.description : "";
}

// A setting's doc, its ``literals`` as code.
function docHTML(doc) {
  return CP.escapeHTML(doc).replace(/``([^`]+)``/g, "<code>$1</code>");
}

function settingRow(s) {
  const name = CP.escapeHTML(s.name);
  const kind = CP.escapeHTML(s.kind);
  const id = `set-${name}`;
  let input;
  if (s.kind === "bool") {
    input = `<input type="checkbox" id="${id}" data-setting-input="${name}" data-kind="${kind}"${s.value ? " checked" : ""}>`;
  } else if (s.kind === "bool|none") {
    const opts = ["true", "false", "none"].map((v) => `<option value="${v}">${v}</option>`).join("");
    input = `<select id="${id}" data-setting-input="${name}" data-kind="${kind}">${opts}</select>`;
  } else {
    const numeric = baseKind(s.kind) === "int" || baseKind(s.kind) === "float";
    const placeholder = nullable(s.kind) ? ' placeholder="none"' : "";
    input = `<input type="text" id="${id}" class="setting-value${numeric ? " numeric" : ""}" data-setting-input="${name}" data-kind="${kind}"` +
      ` value="${CP.escapeHTML(valueText(s.value, s.kind))}"${placeholder} autocomplete="off" spellcheck="false"${numeric ? ' inputmode="decimal"' : ""}>`;
  }
  return `<tr data-setting="${name}">
    <td class="setting-name"><label for="${id}" class="mono">${name}</label><span class="rule">${kind.replace("|none", " or none")}</span></td>
    <td class="setting-cell">${input}<div class="was small muted"></div><div class="field-error"></div></td>
    <td class="small muted setting-doc">${docHTML(s.doc)}</td></tr>`;
}

// The settings the reader changed from the preset's values: {name: JSON value}.
function changedSettings() {
  const changed = {};
  if (!form.options) return changed;
  for (const s of form.options.settings) {
    const input = settingInput(s.name);
    if (!input) continue;
    const value = readInput(input);
    if (!sameValue(value, s.value)) changed[s.name] = value;
  }
  return changed;
}

function markChanged() {
  if (!form.options) return;
  const changed = changedSettings();
  for (const s of form.options.settings) {
    const input = settingInput(s.name);
    if (!input) continue;
    const row = input.closest("tr");
    const isChanged = s.name in changed;
    row.classList.toggle("changed", isChanged);
    row.querySelector(".was").textContent = isChanged ? `preset: ${s.kind.startsWith("bool") ? String(s.value ?? "none") : valueText(s.value, s.kind) || "none"}` : "";
  }
  const names = Object.keys(changed);
  el("changed-count").textContent = names.length ? `${names.length} changed` : "";
  el("changed-summary").textContent = names.length ? `Changed from the preset: ${names.join(", ")}.` : "";
}

function renderSettings(options, edits, unknownNote) {
  const body = document.querySelector("#settings-table tbody");
  if (!options) {
    body.innerHTML = '<tr><td colspan="3" class="muted">No settings to show: pick an env, agent and preset that go together.</td></tr>';
    el("changed-count").textContent = "";
    el("changed-summary").textContent = "";
    return;
  }
  body.innerHTML = options.settings.map(settingRow).join("");
  for (const s of options.settings) {
    const input = settingInput(s.name);
    if (input.tagName === "SELECT") writeInput(input, s.value);
    if (s.name in edits) writeInput(input, edits[s.name]);
  }
  const left = Object.keys(edits).filter((name) => !options.settings.some((s) => s.name === name));
  if (left.length && unknownNote) {
    el("error-settings").innerHTML = `<div class="notice">Not settings of this preset, so left out: ${CP.escapeHTML(left.join(", "))}.</div>`;
  }
  markChanged();
}

function updateTrainButton() {
  const readOnly = form.catalog && form.catalog.read_only;
  el("train").disabled = Boolean(readOnly || form.busy || form.blocked || !form.options);
  el("train").title = readOnly ? "this server is read-only" : form.blocked || "";
}

// Show the form for (agent, env, preset), keeping `edits` ({name: value}) of settings the new preset
// has. The env's own preset is asked first (it is the default, sent only when another is picked).
async function loadOptions(agent, env, preset, edits = null, unknownNote = false) {
  const kept = edits ?? (form.options ? changedSettings() : form.pendingEdits || {});
  form.pendingEdits = kept; // kept while no settings are shown (a choice that does not go together)
  clearErrors();
  fillSelect(el("env"), form.catalog.envs, env);
  fillSelect(el("agent"), form.catalog.agents.map((a) => a.name), agent);
  form.blocked = "";
  let options = null;
  try {
    const q = new URLSearchParams({ agent, env_id: env });
    options = await CP.getJSON(`/api/training-options?${q}`);
    form.defaultPreset = options.preset;
    if (preset && preset !== options.preset) {
      q.set("preset", preset);
      options = await CP.getJSON(`/api/training-options?${q}`);
    }
  } catch (err) {
    if (err.status !== 422) throw err;
    showFieldError(err.field || "preset", err.message);
    form.blocked = err.message;
    options = null;
  }
  form.options = options;
  renderPresetSelect(agent, options ? options.preset : preset || form.defaultPreset);
  el("budget").placeholder = options ? `${options.budget} (the preset's)` : "";
  renderSettings(options, kept, unknownNote);
  updateTrainButton();
}

// ------------------------------------------------------------------------------------------------
// Starting a training
// ------------------------------------------------------------------------------------------------

function runHref(run) {
  return `/run?name=${encodeURIComponent(run)}`;
}

async function submit(event) {
  event.preventDefault();
  if (form.busy) return;
  clearErrors();
  let seeds;
  try {
    seeds = parseSeeds(el("seeds").value);
  } catch (err) {
    showFieldError("seeds", err.message);
    el("train-status").textContent = "Nothing started: see the message beside the seeds.";
    return;
  }
  const body = { agent: el("agent").value, env_id: el("env").value, seeds, settings: changedSettings() };
  if (el("preset").value && el("preset").value !== form.defaultPreset) body.preset = el("preset").value;
  const budget = el("budget").value.trim();
  if (budget) body.budget = budget;
  form.busy = true;
  updateTrainButton();
  el("train-status").textContent = "Starting…";
  try {
    const started = await CP.postJSON("/api/trainings", body);
    if (started.runs && started.runs.length) {
      el("train-status").textContent = "Started: opening its run page…";
      window.location.href = runHref(started.runs[0]);
      return;
    }
    history.replaceState(null, "", `/train?training=${encodeURIComponent(started.name)}`);
    waitFor(started.name);
  } catch (err) {
    if (err.status === 422) {
      const where = showFieldError(err.field, err.message);
      el("train-status").textContent = `Nothing started: see the message beside ${where}.`;
    } else {
      el("train-status").textContent = "";
      showMessage(err.message);
    }
  } finally {
    form.busy = false;
    updateTrainButton();
  }
}

// A training that waits in the queue: say where it stands, and open its run page once it has one.
async function waitFor(name) {
  form.waiting = name;
  const box = el("train-status");
  try {
    const rows = await CP.getJSON("/api/trainings");
    const row = rows.find((r) => r.name === name);
    if (!row) {
      showMessage(`No training named ${name} on this server.`);
      box.textContent = "";
      return;
    }
    if (row.runs.length) {
      box.textContent = "Started: opening its run page…";
      window.location.href = runHref(row.runs[0]);
      return;
    }
    if (row.state === "queued") {
      box.innerHTML = `<span class="badge queued" id="waiting-state">queued</span> ${CP.escapeHTML(name)} is number ${row.queue_position ?? "?"} in the queue; its run page opens when it starts.`;
    } else if (row.state === "running") {
      box.innerHTML = `<span class="badge running" id="waiting-state">running</span> ${CP.escapeHTML(name)} is starting; its run page opens in a moment.`;
    } else {
      const why = row.problem ? `: ${row.problem}` : "";
      showMessage(`Training ${name} is ${row.state} before it made a run${why}`);
      box.textContent = "";
      return;
    }
  } catch (err) {
    box.textContent = `Cannot read the trainings (${err.message}); trying again.`;
  }
  setTimeout(() => waitFor(name), 1000);
}

// ------------------------------------------------------------------------------------------------
// The queue
// ------------------------------------------------------------------------------------------------

function queueRow(t) {
  const title = t.runs.length
    ? `<a href="${runHref(t.runs[0])}">${CP.escapeHTML(t.name)}</a>`
    : `<span>${CP.escapeHTML(t.name)}</span>`;
  const more = t.runs.length > 1 ? ` <span class="muted small">+${t.runs.length - 1} runs</span>` : "";
  const place = t.state === "queued" && t.queue_position ? ` <span class="small muted">#${t.queue_position} in queue</span>` : "";
  const problem = t.problem ? `<span class="rule problem">${CP.escapeHTML(t.problem)}</span>` : "";
  const seeds = Array.isArray(t.seeds) ? seedsText(t.seeds) : "";
  return `<tr data-training="${CP.escapeHTML(t.name)}">
    <td class="name">${title}${more}<span class="rule">${CP.escapeHTML(t.agent ?? "?")} · ${CP.escapeHTML(t.env_id ?? "?")} · seeds ${CP.escapeHTML(seeds)}</span>${problem}</td>
    <td>${CP.stateBadge(t.state, t.problem)}${place}</td>
    <td class="num"><a class="small" href="/train?from=${encodeURIComponent(t.name)}" title="fill the form with its settings">again</a></td></tr>`;
}

function renderQueue(rows) {
  const box = el("queue");
  // Running ones first, then the queue in its order; then the latest few that ended.
  const rank = (t) => (t.state === "running" ? 0 : t.queue_position ?? 1e9);
  const active = rows.filter((t) => ACTIVE.has(t.state)).sort((a, b) => rank(a) - rank(b));
  const recent = rows.filter((t) => !ACTIVE.has(t.state)).slice(0, 5);
  if (!rows.length) {
    box.innerHTML = '<p class="muted small" id="queue-empty">None yet: the trainings started here are listed here, queued and running ones first.</p>';
    return;
  }
  const part = (list) => list.map(queueRow).join("");
  const earlier = recent.length ? `<tr class="sub"><td colspan="3" class="small muted">earlier</td></tr>${part(recent)}` : "";
  const none = active.length ? "" : '<tr class="sub"><td colspan="3" class="small muted">none queued or running</td></tr>';
  box.innerHTML = `<table id="queue-table" class="queue">${none}${part(active)}${earlier}</table>`;
}

function showQueueError(message, seconds) {
  el("queue").innerHTML = `<div class="error">Cannot read the trainings: ${CP.escapeHTML(message)}.${seconds ? ` Trying again in ${seconds} s.` : ""}</div>`;
}

// ------------------------------------------------------------------------------------------------
// Filling the form from an earlier training or run
// ------------------------------------------------------------------------------------------------

// {agent, env_id, preset, seeds, budget, settings} from ?from=TRAINING, ?training=NAME or ?run=RUN.
async function prefill() {
  const training = CP.param("from") || CP.param("training");
  if (training) {
    const rows = await CP.getJSON("/api/trainings");
    const row = rows.find((r) => r.name === training);
    if (!row) throw new Error(`No training named ${training} on this server: the form shows the defaults.`);
    const r = row.request || {};
    return {
      agent: r.agent ?? row.agent,
      env_id: r.env_id ?? row.env_id,
      preset: r.preset ?? null,
      seeds: r.seeds ?? row.seeds ?? [0],
      budget: r.budget ?? "",
      settings: r.settings || {},
      from: `training ${training}`,
      setText: false,
    };
  }
  const run = CP.param("run");
  if (run) {
    const detail = await CP.getJSON(`/api/runs/${encodeURIComponent(run)}`);
    const c = detail.config;
    if (!c) throw new Error(`Run ${run} has no readable config: the form shows the defaults.`);
    const overrides = { ...(c.overrides || {}) };
    let budget = "";
    if ("budget" in overrides) {
      budget = String(overrides.budget);
      delete overrides.budget;
    } else {
      const given = budgetText(c.budget);
      const presets = c.settings && c.settings.budget;
      budget = given && budgetKey(given) !== budgetKey(presets) ? given : "";
    }
    return {
      agent: c.agent,
      env_id: c.env_id,
      preset: c.preset ?? null,
      seeds: [c.seed ?? 0],
      budget,
      settings: overrides,
      from: `run ${run}`,
      setText: true,
    };
  }
  return null;
}

// ------------------------------------------------------------------------------------------------
// Start
// ------------------------------------------------------------------------------------------------

function wire() {
  el("train-form").addEventListener("submit", submit);
  el("env").addEventListener("change", () => loadOptions(el("agent").value, el("env").value, null).catch(fatal));
  el("agent").addEventListener("change", () => loadOptions(el("agent").value, el("env").value, null).catch(fatal));
  el("preset").addEventListener("change", () => loadOptions(el("agent").value, el("env").value, el("preset").value).catch(fatal));
  el("reset-settings").addEventListener("click", () => {
    renderSettings(form.options, {}, false);
    el("error-settings").innerHTML = "";
  });
  const table = el("settings-table");
  table.addEventListener("input", markChanged);
  table.addEventListener("change", markChanged);
  el("seeds").addEventListener("input", () => (el("error-seeds").textContent = ""));
  el("budget").addEventListener("input", () => (el("error-budget").textContent = ""));
}

function fatal(err) {
  showMessage(`Cannot load the form: ${err.message}`);
}

async function start() {
  wire();
  CP.poll("/api/trainings", renderQueue, showQueueError, 2000);
  let catalog;
  try {
    catalog = await CP.getJSON("/api/training-options");
  } catch (err) {
    fatal(err);
    return;
  }
  form.catalog = catalog;
  el("queue-note").textContent = catalog.read_only ? "" :
    catalog.max_trainings ? `At most ${catalog.max_trainings} train at once; later ones wait in the queue, in order.` : "";
  let filled = null;
  let problem = "";
  try {
    filled = await prefill();
  } catch (err) {
    problem = err.message;
  }
  if (!filled) {
    await loadOptions(catalog.agent, catalog.env_id, null, {}).catch(fatal);
    if (problem) showMessage(problem);
    return;
  }
  const env = filled.env_id || catalog.env_id;
  const agent = filled.agent || catalog.agent;
  // The settings as the new preset's kinds read them: a run's config keeps --set text ("24", "none").
  const kinds = {};
  try {
    const q = new URLSearchParams({ agent, env_id: env });
    if (filled.preset) q.set("preset", filled.preset);
    for (const s of (await CP.getJSON(`/api/training-options?${q}`)).settings) kinds[s.name] = s.kind;
  } catch (_) {
    // the form below says what is wrong with this choice
  }
  const edits = {};
  for (const [name, value] of Object.entries(filled.settings || {})) {
    edits[name] = filled.setText ? fromSetText(value, kinds[name] || "str") : value;
  }
  await loadOptions(agent, env, filled.preset, edits, true).catch(fatal);
  el("seeds").value = seedsText(Array.isArray(filled.seeds) && filled.seeds.length ? filled.seeds : [0]);
  el("budget").value = filled.budget || "";
  el("train-status").textContent = `Filled from ${filled.from}.`;
  if (CP.param("training")) waitFor(CP.param("training"));
}

start();
