// Drawing one cart-pole state on a canvas (shared by Watch and Play). The server simulates; this only draws.
"use strict";

const CartPoleDraw = (() => {
  const COLORS = {
    skyTop: "#f4f7ff",
    skyBottom: "#e8eefc",
    ground: "#d7dceb",
    rail: "#7b8499",
    edge: "#d9534f",
    cart: "#263a7a",
    wheel: "#1d2433",
    pole: "#e08a1e",
    poleFail: "#c0392b",
    safe: "rgba(23, 128, 74, 0.10)",
    left: "#d9534f",
    right: "#2f7ed8",
  };

  // Size the canvas backing store to its CSS width times the device pixel ratio (crisp lines).
  function fit(canvas) {
    const ratio = window.devicePixelRatio || 1;
    const width = Math.max(280, Math.round(canvas.clientWidth || canvas.parentElement.clientWidth));
    const aspect = width < 560 ? 0.72 : 0.5; // taller on a phone, so the pole stays large enough
    const height = Math.round(width * aspect);
    if (canvas.width !== Math.round(width * ratio)) {
      canvas.width = Math.round(width * ratio);
      canvas.height = Math.round(height * ratio);
    }
    const ctx = canvas.getContext("2d");
    ctx.setTransform(ratio, 0, 0, ratio, 0, 0);
    return { ctx, width, height };
  }

  // state = [x, x_dot, theta, theta_dot]; opts = {xThreshold, thetaThreshold, length, action, nudge}
  function draw(canvas, state, opts) {
    const { ctx, width, height } = fit(canvas);
    const xThr = opts.xThreshold ?? 2.4;
    const thetaThr = opts.thetaThreshold ?? 0.2094;
    const half = opts.length ?? 0.5;
    const scale = Math.min(width / (2 * xThr + 1.0), (height * 0.68) / (2 * half + 0.25));
    const groundY = height * 0.8;
    const cx = width / 2;
    const [x, , theta] = state;

    const sky = ctx.createLinearGradient(0, 0, 0, groundY);
    sky.addColorStop(0, COLORS.skyTop);
    sky.addColorStop(1, COLORS.skyBottom);
    ctx.fillStyle = sky;
    ctx.fillRect(0, 0, width, height);
    ctx.fillStyle = COLORS.ground;
    ctx.fillRect(0, groundY, width, height - groundY);

    // Track and its ends: the episode ends when the cart's centre passes them.
    ctx.strokeStyle = COLORS.rail;
    ctx.lineWidth = 3;
    ctx.beginPath();
    ctx.moveTo(cx - xThr * scale - 20, groundY);
    ctx.lineTo(cx + xThr * scale + 20, groundY);
    ctx.stroke();
    for (const side of [-1, 1]) {
      const ex = cx + side * xThr * scale;
      ctx.strokeStyle = COLORS.edge;
      ctx.lineWidth = 2;
      ctx.setLineDash([5, 4]);
      ctx.beginPath();
      ctx.moveTo(ex, groundY + 14);
      ctx.lineTo(ex, groundY - 0.45 * height);
      ctx.stroke();
      ctx.setLineDash([]);
    }
    ctx.fillStyle = "#8a93a8";
    ctx.font = "12px system-ui, sans-serif";
    ctx.textAlign = "center";
    for (let m = -Math.floor(xThr); m <= Math.floor(xThr); m++) {
      ctx.fillRect(cx + m * scale - 1, groundY + 2, 2, 7);
      ctx.fillText(`${m} m`, cx + m * scale, groundY + 22);
    }

    const cartW = Math.max(44, 0.5 * scale);
    const cartH = Math.max(24, 0.3 * scale);
    const px = cx + x * scale;
    const pivotY = groundY - cartH - 6;

    // Allowed angles: the green wedge; the pole turns red outside it.
    const poleLen = 2 * half * scale;
    ctx.fillStyle = COLORS.safe;
    ctx.beginPath();
    ctx.moveTo(px, pivotY);
    ctx.arc(px, pivotY, poleLen * 1.05, -Math.PI / 2 - thetaThr, -Math.PI / 2 + thetaThr);
    ctx.closePath();
    ctx.fill();

    // Cart and wheels.
    ctx.fillStyle = COLORS.wheel;
    for (const dx of [-cartW * 0.3, cartW * 0.3]) {
      ctx.beginPath();
      ctx.arc(px + dx, groundY - 6, 6, 0, 2 * Math.PI);
      ctx.fill();
    }
    ctx.fillStyle = COLORS.cart;
    roundRect(ctx, px - cartW / 2, groundY - cartH - 10, cartW, cartH, 6);
    ctx.fill();

    // Push arrow: the action taken this step.
    if (opts.action === 0 || opts.action === 1) {
      const dir = opts.action === 1 ? 1 : -1;
      const ax = px - dir * (cartW / 2 + 8);
      const ay = groundY - cartH / 2 - 10;
      ctx.fillStyle = dir > 0 ? COLORS.right : COLORS.left;
      ctx.beginPath();
      ctx.moveTo(ax, ay);
      ctx.lineTo(ax - dir * 22, ay - 11);
      ctx.lineTo(ax - dir * 22, ay + 11);
      ctx.closePath();
      ctx.fill();
    }

    // Pole.
    const tipX = px + Math.sin(theta) * poleLen;
    const tipY = pivotY - Math.cos(theta) * poleLen;
    ctx.strokeStyle = Math.abs(theta) > thetaThr ? COLORS.poleFail : COLORS.pole;
    ctx.lineWidth = Math.max(8, 0.07 * scale);
    ctx.lineCap = "round";
    ctx.beginPath();
    ctx.moveTo(px, pivotY);
    ctx.lineTo(tipX, tipY);
    ctx.stroke();
    ctx.lineCap = "butt";
    ctx.fillStyle = "#f5f6fa";
    ctx.beginPath();
    ctx.arc(px, pivotY, 4, 0, 2 * Math.PI);
    ctx.fill();

    if (opts.nudge) {
      ctx.fillStyle = "rgba(217, 119, 6, 0.95)";
      ctx.font = "bold 15px system-ui, sans-serif";
      ctx.fillText(opts.nudge > 0 ? "nudge →" : "← nudge", tipX, tipY - 14);
    }
    if (opts.caption) {
      ctx.fillStyle = "#3b4357";
      ctx.font = "600 14px system-ui, sans-serif";
      ctx.textAlign = "left";
      ctx.fillText(opts.caption, 12, 22);
    }
  }

  function roundRect(ctx, x, y, w, h, r) {
    ctx.beginPath();
    ctx.moveTo(x + r, y);
    ctx.arcTo(x + w, y, x + w, y + h, r);
    ctx.arcTo(x + w, y + h, x, y + h, r);
    ctx.arcTo(x, y + h, x, y, r);
    ctx.arcTo(x, y, x + w, y, r);
    ctx.closePath();
  }

  return { draw, fit, COLORS };
})();
