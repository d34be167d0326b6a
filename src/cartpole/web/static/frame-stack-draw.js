// Drawing what a pixel agent sees: its stack of gray frames (shared by Watch and the notebook's player).
// An episode's view holds one frame per state (base64 of height x width uint8 gray levels); the
// agent's observation at step t is frames t-stack+1..t, the first frame standing in before step 0,
// exactly as the env stacks them (cartpole.web.agent_view.stacks_of).
"use strict";

const FrameStackDraw = (() => {
  const SCALE = 3; // backing-store pixels per frame pixel (the page scales the canvas to its width)
  const GAP = 8;
  const LABEL = 16;

  // The view's frames as Uint8Arrays, decoded once per episode.
  function decode(view) {
    return view.frames.map((text) => {
      const raw = atob(text);
      const bytes = new Uint8Array(raw.length);
      for (let i = 0; i < raw.length; i++) bytes[i] = raw.charCodeAt(i);
      return bytes;
    });
  }

  // The frame indices of the observation at step t, oldest first.
  function stackAt(t, stack) {
    const indices = [];
    for (let k = stack - 1; k >= 0; k--) indices.push(Math.max(0, t - k));
    return indices;
  }

  // One gray frame as a small canvas (putImageData cannot scale; drawImage of a canvas can).
  function frameCanvas(gray, width, height) {
    const small = document.createElement("canvas");
    small.width = width;
    small.height = height;
    const ctx = small.getContext("2d");
    const image = ctx.createImageData(width, height);
    for (let p = 0; p < gray.length; p++) {
      const o = p * 4;
      image.data[o] = image.data[o + 1] = image.data[o + 2] = gray[p];
      image.data[o + 3] = 255;
    }
    ctx.putImageData(image, 0, 0);
    return small;
  }

  // Draw the observation at step t on canvas: `columns` frames a row (default one: each frame as
  // wide as the canvas, so the pole's few pixels show), oldest first, each labelled with how many
  // steps old it is. frames = decode(view).
  function draw(canvas, view, frames, t, columns) {
    const { stack, height, width } = view;
    const cols = Math.max(1, Math.min(columns || 1, stack));
    const rows = Math.ceil(stack / cols);
    const cellW = width * SCALE;
    const cellH = height * SCALE + LABEL;
    const totalW = cols * cellW + (cols - 1) * GAP;
    const totalH = rows * cellH + (rows - 1) * GAP;
    if (canvas.width !== totalW || canvas.height !== totalH) {
      canvas.width = totalW;
      canvas.height = totalH;
    }
    const ctx = canvas.getContext("2d");
    ctx.clearRect(0, 0, totalW, totalH);
    ctx.imageSmoothingEnabled = false;
    ctx.font = "12px sans-serif";
    ctx.textBaseline = "top";
    const step = Math.max(0, Math.min(t, frames.length - 1));
    stackAt(step, stack).forEach((index, k) => {
      const x = (k % cols) * (cellW + GAP);
      const y = Math.floor(k / cols) * (cellH + GAP);
      const age = stack - 1 - k;
      ctx.fillStyle = "#5d6678";
      ctx.fillText(age === 0 ? `now (frame ${index})` : `${age} step${age > 1 ? "s" : ""} before (frame ${index})`, x, y);
      ctx.drawImage(frameCanvas(frames[index], width, height), x, y + LABEL, cellW, height * SCALE);
      ctx.strokeStyle = "#dde1ea";
      ctx.strokeRect(x + 0.5, y + LABEL + 0.5, cellW - 1, height * SCALE - 1);
    });
  }

  return { decode, stackAt, draw };
})();
