// The physics sliders (gravity, pole half-length, masses, force), shared by Watch and Play.
"use strict";

const PhysicsPanel = (() => {
  const STEP = { gravity: 0.1, length: 0.05, masspole: 0.01, masscart: 0.05, force_mag: 0.5 };
  const SHOWN_MAX = { gravity: 30, length: 2.5, masspole: 2, masscart: 5, force_mag: 30 };

  // info = /api/info's "physics"; values = current overrides merged with defaults.
  function render(box, info, values) {
    box.innerHTML = Object.entries(info.labels).map(([name, label]) => {
      const [low, high] = info.limits[name];
      const max = Math.min(high, SHOWN_MAX[name] ?? high);
      const min = Math.max(low, STEP[name]);
      const value = values[name] ?? info.defaults[name];
      return `<label>${CP.escapeHTML(label)} <output id="out-${name}">${value}</output>
        <input type="range" name="${name}" min="${min}" max="${max}" step="${STEP[name] ?? 0.01}" value="${value}"></label>`;
    }).join("");
    box.querySelectorAll("input").forEach((input) => {
      input.addEventListener("input", () => {
        box.querySelector(`#out-${input.name}`).textContent = input.value;
      });
    });
  }

  // Only the values that differ from the defaults.
  function overrides(box, info) {
    const out = {};
    box.querySelectorAll("input").forEach((input) => {
      const value = Number(input.value);
      if (Math.abs(value - info.defaults[input.name]) > 1e-9) out[input.name] = value;
    });
    return out;
  }

  function fromQuery(info) {
    const params = new URLSearchParams(window.location.search);
    const out = {};
    for (const name of Object.keys(info.labels)) {
      if (params.has(name) && !Number.isNaN(Number(params.get(name)))) out[name] = Number(params.get(name));
    }
    return out;
  }

  return { render, overrides, fromQuery };
})();
