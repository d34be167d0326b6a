// Drawing Acrobot-v1 and MountainCar-v0 states on a canvas (Watch, Play); CartPole has cartpole-draw.js,
// which must load first.
// The server simulates with Gymnasium's own envs; this only draws the env's own state.
"use strict";

const SceneDraw = (() => {
  const COLORS = {
    skyTop: "#f4f7ff",
    skyBottom: "#e8eefc",
    ground: "#d7dceb",
    link: "#263a7a",
    joint: "#e08a1e",
    goal: "#17804a",
    car: "#263a7a",
    left: "#d9534f",
    none: "#8a93a8",
    right: "#2f7ed8",
  };

  const fit = CartPoleDraw.fit; // the same canvas sizing (cartpole-draw.js loads first)

  function background(ctx, width, height) {
    const sky = ctx.createLinearGradient(0, 0, 0, height);
    sky.addColorStop(0, COLORS.skyTop);
    sky.addColorStop(1, COLORS.skyBottom);
    ctx.fillStyle = sky;
    ctx.fillRect(0, 0, width, height);
  }

  function caption(ctx, text) {
    if (!text) return;
    ctx.fillStyle = "#3b4357";
    ctx.font = "600 14px system-ui, sans-serif";
    ctx.textAlign = "left";
    ctx.fillText(text, 12, 22);
  }

  // An arrow for the action: -1 left/negative, 0 none, +1 right/positive, at (x, y).
  function actionArrow(ctx, x, y, direction) {
    if (direction === null || direction === undefined) return;
    ctx.fillStyle = direction < 0 ? COLORS.left : direction > 0 ? COLORS.right : COLORS.none;
    ctx.beginPath();
    if (direction === 0) {
      ctx.arc(x, y, 6, 0, 2 * Math.PI);
    } else {
      ctx.moveTo(x + direction * 14, y);
      ctx.lineTo(x - direction * 8, y - 10);
      ctx.lineTo(x - direction * 8, y + 10);
      ctx.closePath();
    }
    ctx.fill();
  }

  // Acrobot: state = [theta1, theta2, dtheta1, dtheta2]; theta1 = 0 hangs straight down. The episode
  // ends when the free end rises above the line one link above the pivot.
  function acrobot(canvas, state, opts) {
    const { ctx, width, height } = fit(canvas);
    background(ctx, width, height);
    const l1 = opts.limits.link_length_1 ?? 1;
    const l2 = opts.limits.link_length_2 ?? 1;
    const scale = (Math.min(width, height) * 0.42) / (l1 + l2);
    const px = width / 2;
    const py = height / 2;
    const [t1, t2] = state;
    const x1 = px + Math.sin(t1) * l1 * scale;
    const y1 = py + Math.cos(t1) * l1 * scale;
    const x2 = x1 + Math.sin(t1 + t2) * l2 * scale;
    const y2 = y1 + Math.cos(t1 + t2) * l2 * scale;
    const goalY = py - l1 * scale;
    ctx.strokeStyle = COLORS.goal;
    ctx.lineWidth = 2;
    ctx.setLineDash([6, 5]);
    ctx.beginPath();
    ctx.moveTo(px - (l1 + l2) * scale, goalY);
    ctx.lineTo(px + (l1 + l2) * scale, goalY);
    ctx.stroke();
    ctx.setLineDash([]);
    ctx.strokeStyle = COLORS.link;
    ctx.lineCap = "round";
    ctx.lineWidth = Math.max(8, 0.12 * scale);
    ctx.beginPath();
    ctx.moveTo(px, py);
    ctx.lineTo(x1, y1);
    ctx.lineTo(x2, y2);
    ctx.stroke();
    ctx.lineCap = "butt";
    for (const [x, y] of [[px, py], [x1, y1]]) {
      ctx.fillStyle = COLORS.joint;
      ctx.beginPath();
      ctx.arc(x, y, 6, 0, 2 * Math.PI);
      ctx.fill();
    }
    // The torque acts at the second joint: its sign as an arrow beside it.
    actionArrow(ctx, x1, y1 - 24, opts.action === null ? null : opts.action - 1);
    caption(ctx, opts.caption);
  }

  // MountainCar: state = [position, velocity]; the track is y = sin(3x); the flag stands at the goal.
  function mountaincar(canvas, state, opts) {
    const { ctx, width, height } = fit(canvas);
    background(ctx, width, height);
    const lo = opts.limits.min_position ?? -1.2;
    const hi = opts.limits.max_position ?? 0.6;
    const goal = opts.limits.goal_position ?? 0.5;
    const margin = 30;
    const sx = (x) => margin + ((x - lo) / (hi - lo)) * (width - 2 * margin);
    const sy = (x) => height - margin - ((Math.sin(3 * x) + 1) / 2) * (height * 0.62);
    ctx.fillStyle = COLORS.ground;
    ctx.beginPath();
    ctx.moveTo(sx(lo), height);
    for (let i = 0; i <= 120; i++) {
      const x = lo + ((hi - lo) * i) / 120;
      ctx.lineTo(sx(x), sy(x));
    }
    ctx.lineTo(sx(hi), height);
    ctx.closePath();
    ctx.fill();
    ctx.strokeStyle = "#7b8499";
    ctx.lineWidth = 2;
    ctx.stroke();
    const fx = sx(goal);
    const fy = sy(goal);
    ctx.strokeStyle = "#3b4357";
    ctx.beginPath();
    ctx.moveTo(fx, fy);
    ctx.lineTo(fx, fy - 40);
    ctx.stroke();
    ctx.fillStyle = COLORS.goal;
    ctx.beginPath();
    ctx.moveTo(fx, fy - 40);
    ctx.lineTo(fx + 22, fy - 33);
    ctx.lineTo(fx, fy - 26);
    ctx.closePath();
    ctx.fill();
    const x = state[0];
    const cx = sx(x);
    const cy = sy(x);
    const slope = Math.atan2(sy(x + 0.01) - cy, sx(x + 0.01) - cx);
    ctx.save();
    ctx.translate(cx, cy);
    ctx.rotate(slope);
    ctx.fillStyle = COLORS.car;
    ctx.fillRect(-20, -22, 40, 16);
    ctx.fillStyle = "#1d2433";
    for (const dx of [-12, 12]) {
      ctx.beginPath();
      ctx.arc(dx, -5, 5, 0, 2 * Math.PI);
      ctx.fill();
    }
    actionArrow(ctx, 0, -36, opts.action === null ? null : opts.action - 1);
    ctx.restore();
    caption(ctx, opts.caption);
  }

  return { acrobot, mountaincar, COLORS };
})();
