// The notebook's CartPole player (cartpole.show, Run.show): draws each step with the web app's
// CartPoleDraw, the per-action scores as bars below, and loops over the episodes. Python wraps it in
// one function with the drawing code and the episodes (DATA), and the element's id (ROOT_ID).
// A pixel agent's frames (each episode's view) are drawn beside the scene by FrameStackDraw.
"use strict";
const root = document.getElementById(ROOT_ID);
const data = DATA;
const canvas = root.querySelector("canvas.cp-scene");
const viewBox = root.querySelector(".cp-view");
const viewCanvas = viewBox.querySelector("canvas");
const viewFrames = data.episodes.map((e) => (e.view ? FrameStackDraw.decode(e.view) : null));
const bars = root.querySelector(".cp-bars");
const caption = root.querySelector(".cp-caption");
const fps = data.limits.fps || 50;
const names = ["\u2190 left", "right \u2192"];
let episode = 0, frame = 0, last = null, playing = true;
const maxScore = Math.max(1e-9, ...data.episodes.flatMap((e) => (e.scores || []).flat().map(Math.abs)));
function render() {
  const e = data.episodes[episode];
  const i = Math.min(Math.floor(frame), e.actions.length);
  const action = i < e.actions.length ? e.actions[i] : null;
  CartPoleDraw.draw(canvas, e.states[i], {
    xThreshold: data.limits.x_threshold, thetaThreshold: data.limits.theta_threshold,
    length: data.limits.length, action: action,
    caption: `episode ${episode + 1}/${data.episodes.length}  seed ${e.seed}  step ${i}  return ${i}`,
  });
  // A pixel agent's observation at this step, beside the scene (its frames, as its env stacks them).
  viewBox.style.display = e.view ? "block" : "none";
  if (e.view) FrameStackDraw.draw(viewCanvas, e.view, viewFrames[episode], i, 1);
  bars.innerHTML = "";
  if (e.scores && e.scores.length) {
    // The final state has no scores (nothing is chosen there): the last step's stay, chosen bar and all.
    const step = Math.min(i, e.scores.length - 1);
    const row = e.scores[step];
    const chosenAction = e.actions[step];
    const signed = row.some((v) => v < 0);
    row.forEach((v, a) => {
      const w = Math.min(50, (Math.abs(v) / maxScore) * 50) * (signed ? 1 : 2);
      const left = signed ? (v >= 0 ? 50 : 50 - w) : 0;
      const color = a === 1 ? CartPoleDraw.COLORS.right : CartPoleDraw.COLORS.left;
      const chosen = a === chosenAction ? "font-weight:700" : "opacity:.75";
      bars.insertAdjacentHTML("beforeend",
        `<div style="flex:1;${chosen}"><div>${names[a] || a} ${v.toFixed(2)}</div>` +
        `<div style="position:relative;height:10px;background:#e6e9f2;border-radius:5px">` +
        `<div style="position:absolute;left:${left}%;width:${w}%;height:100%;` +
        `background:${color};border-radius:5px"></div></div></div>`);
    });
  }
  const scored = data.episodes.some((x) => x.scores);
  caption.textContent =
    `${data.env_id}: ` +
    (scored ? `${data.score_label} under the cart (the agent picks the larger); ` : "") +
    `returns ${data.episodes.map((x) => x.return).join(", ")}. Click to pause.`;
}
function tick(now) {
  if (!root.isConnected) return;
  if (playing && last !== null) {
    const shown = Math.floor(frame);
    frame += ((now - last) / 1000) * fps;
    const e = data.episodes[episode];
    if (frame > e.actions.length + fps) { episode = (episode + 1) % data.episodes.length; frame = 0; }
    if (Math.floor(frame) !== shown) render();
  }
  last = now;
  requestAnimationFrame(tick);
}
canvas.addEventListener("click", () => { playing = !playing; });
render();
requestAnimationFrame(tick);
