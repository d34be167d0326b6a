"""Numba kernel behind :mod:`cartpole.envs.pixels` (imported lazily, on first use).

:func:`render_frames` draws a batch of cart-pole states straight at the output size: for every output
pixel it computes the area of the pixel that each of Gymnasium's shapes covers (cart, pole, axle,
track line) and mixes their gray levels by those areas. Nothing is drawn at 600x400, so a frame
costs what its few hundred pixels near the cart and pole cost; the rest is a copy of the background.

Coordinates are those of the final (flipped) 600x400 image with pixel ``(row, col)`` covering
``[row, row + 1) x [col, col + 1)``: ``X`` grows to the right, ``Y`` downwards. Output pixel
``(i, j)`` covers ``X in [j * s, (j + 1) * s)`` and ``Y in [top + i * s, top + (i + 1) * s)``.

How pygame draws, and how it is modelled here (measured against pygame 2.6; the tests hold as well for
pygame-ce 2.5, which the lock installs):

- ``gfxdraw`` truncates vertex coordinates to integers and fills every pixel from the first vertex
  pixel to the last, both included; an axis-aligned rectangle with integer corners ``a..b`` covers
  ``[a, b + 1)``. The cart is such a rectangle, and its coverage is exact and separable.
- The pole is a rotated rectangle: ``filled_polygon`` plus ``aapolygon``'s anti-aliased outline. It
  is modelled as the quadrilateral through the centres of its truncated vertex pixels, each edge
  pushed outwards by a dilation (about half a pixel: the outline's width). The area of a square
  pixel on the inside of one edge is exact (the projection of a square on the edge's normal has a
  trapezoidal density, integrated in closed form); the pole's coverage is (sides) x (ends), where
  each pair of nearly parallel edges gives ``F_1 + F_2 - 1``. Only at the pole's four corners is
  that product an approximation.
- The axle is a fixed 11x11 alpha mask (pygame's ``aacircle`` + ``filled_circle`` of radius 5 at an
  integer centre), spread over the output pixels by area, each of its screen pixels marked as on
  the pole or not (its centre inside the pole's dilated edges).
- Painter's order (cart, pole, axle, line) is kept by adding areas: the pole hides the cart where it
  crosses it, the axle hides what of the pole lies under it, the line lies on the cart; the pole and
  the axle never reach the line's row (they end 1.5 px above it), nor leave the cart's columns.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numba import njit
from numpy.typing import NDArray

# Layout of the geometry vector (built by cartpole.envs.pixels.PixelRenderer).
SCALE, CENTER_X, CART_HALF_WIDTH, POLE_HALF_WIDTH, POLE_LENGTH, PIVOT_Y = 0, 1, 2, 3, 4, 5
PIXEL, TOP, SIDE_DILATION, END_DILATION, GRAY_POLE, GRAY_AXLE, SCREEN_HEIGHT = 6, 7, 8, 9, 10, 11, 12
N_GEOMETRY = 13

_JIT: dict[str, Any] = {"cache": True, "nogil": True, "error_model": "numpy"}

# Positions beyond this many screen pixels are off the screen whatever the pole does; clamping keeps
# the integer conversions below finite for any finite state.
_FAR = 1.0e5

# Round halves up, and values within 1e-6 of a half as halves: as cartpole.envs.pixels does.
_HALF = 0.5 + 1e-6


@njit(**_JIT)
def _overlap(a0: float, a1: float, b0: float, b1: float) -> float:
    """Length of the intersection of [a0, a1) and [b0, b1)."""
    return max(0.0, min(a1, b1) - max(a0, b0))


@njit(**_JIT)
def _inside(t: float, h1: float, h2: float, inv_a: float, inv_2ab: float) -> float:
    """Area fraction of a square pixel on the inside of a line, its centre ``t`` inside it.

    The pixel's projection on the line's normal is the sum of two uniform variables of widths ``a``
    and ``b`` (``a >= b``; ``h1 = (a + b) / 2``, ``h2 = (a - b) / 2``): a trapezoid, whose
    cumulative distribution this is.
    """
    if t <= -h1:
        return 0.0
    if t >= h1:
        return 1.0
    if t < -h2:
        u = t + h1
        return u * u * inv_2ab
    if t > h2:
        u = h1 - t
        return 1.0 - u * u * inv_2ab
    return 0.5 + t * inv_a


@njit(**_JIT)
def render_frames(
    states: NDArray[np.float64],
    g: NDArray[np.float64],
    cart_rows: NDArray[np.float64],
    line_rows: NDArray[np.float64],
    cart_line_rows: NDArray[np.float64],
    axle_mask: NDArray[np.float64],
    axle_y0: float,
    axle_row0: int,
    axle_rows: NDArray[np.float64],
    background: NDArray[np.uint8],
    out: NDArray[np.uint8],
) -> None:
    """Draw ``states`` (N, 4) into ``out`` (N, H, W): one gray frame per state.

    ``cart_rows[i]``, ``line_rows[i]``, ``cart_line_rows[i]``: the fraction of output row ``i``'s
    height inside the cart's rows, the track line's row, and both. ``axle_mask`` (m, m): the axle's
    alpha per screen pixel, its first row at screen row ``axle_y0``; ``axle_rows[r, q]``: the
    fraction of output row ``axle_row0 + r``'s height in mask row ``q``. ``background`` (H, W): the
    frame without cart, pole or axle.
    """
    n = states.shape[0]
    height, width = background.shape
    s = g[PIXEL]
    inv_s = 1.0 / s
    top = g[TOP]
    scale = g[SCALE]
    gray_pole = g[GRAY_POLE]
    gray_axle = g[GRAY_AXLE]
    half_w = g[POLE_HALF_WIDTH]
    pole_top = g[POLE_LENGTH] - half_w
    pivot_y = g[PIVOT_Y]
    screen_h = g[SCREEN_HEIGHT]
    side_dil = g[SIDE_DILATION]
    end_dil = g[END_DILATION]
    n_axle_rows = axle_rows.shape[0]
    n_mask = axle_mask.shape[0]
    axle_half = n_mask // 2
    n_axle_cols = int(n_mask * inv_s) + 2  # output columns the mask can touch
    axle = np.empty((n_axle_rows, n_axle_cols))  # its area per output pixel near the pivot
    axle_on_pole = np.empty((n_axle_rows, n_axle_cols))  # the pole's area under it

    # Cart rows, fixed for every frame: the output rows it touches.
    cart_i0, cart_i1 = height, 0
    for i in range(height):
        if cart_rows[i] > 0.0:
            cart_i0 = min(cart_i0, i)
            cart_i1 = max(cart_i1, i + 1)

    vx = np.empty(4)
    vy = np.empty(4)
    normal_x = np.empty(4)
    normal_y = np.empty(4)
    offset = np.empty(4)
    h1 = np.empty(4)
    h2 = np.empty(4)
    inv_a = np.empty(4)
    inv_2ab = np.empty(4)

    for f in range(n):
        frame = out[f]
        for i in range(height):  # plain loops: slice assignment costs seconds of compilation
            for j in range(width):
                frame[i, j] = background[i, j]
        cx = min(max(states[f, 0] * scale + g[CENTER_X], -_FAR), _FAR)
        theta = states[f, 2]
        sin_t, cos_t = math.sin(theta), math.cos(theta)

        # Cart: columns [trunc(cx - 25), trunc(cx + 25) + 1), as gfxdraw fills them.
        cart_x0 = float(math.trunc(cx - g[CART_HALF_WIDTH]))
        cart_x1 = float(math.trunc(cx + g[CART_HALF_WIDTH])) + 1.0

        # Pole: Gymnasium's corners (l, b), (l, t), (r, t), (r, b) rotated by -theta about the
        # pivot, truncated, moved to their pixel's centre and flipped to image rows.
        for k in range(4):
            px = -half_w if k < 2 else half_w
            py = -half_w if (k == 0 or k == 3) else pole_top
            x_pre = px * cos_t + py * sin_t + cx
            y_pre = -px * sin_t + py * cos_t + pivot_y
            vx[k] = float(math.trunc(x_pre)) + 0.5
            vy[k] = screen_h - (float(math.trunc(y_pre)) + 0.5)
        mid_x = 0.25 * (vx[0] + vx[1] + vx[2] + vx[3])
        mid_y = 0.25 * (vy[0] + vy[1] + vy[2] + vy[3])
        for k in range(4):  # edge k joins vertex k and k + 1: 0 and 2 are the sides, 1 and 3 the ends
            ex = vx[(k + 1) % 4] - vx[k]
            ey = vy[(k + 1) % 4] - vy[k]
            norm = math.sqrt(ex * ex + ey * ey)
            nx, ny = ey / norm, -ex / norm
            if nx * (mid_x - vx[k]) + ny * (mid_y - vy[k]) > 0.0:
                nx, ny = -nx, -ny  # outwards
            normal_x[k], normal_y[k] = nx, ny
            offset[k] = nx * vx[k] + ny * vy[k] + (side_dil if k % 2 == 0 else end_dil)
            a, b = s * abs(nx), s * abs(ny)
            if a < b:
                a, b = b, a
            h1[k], h2[k] = 0.5 * (a + b), 0.5 * (a - b)
            inv_a[k] = 1.0 / a
            inv_2ab[k] = 0.5 / (a * b) if b > 0.0 else 0.0
        margin = max(side_dil, end_dil) + 0.5
        pole_y0 = min(min(vy[0], vy[1]), min(vy[2], vy[3])) - margin
        pole_y1 = max(max(vy[0], vy[1]), max(vy[2], vy[3])) + margin
        pole_i0 = max(0, math.floor((pole_y0 - top) * inv_s))
        pole_i1 = min(height, math.floor((pole_y1 - top) * inv_s) + 1)

        # Axle: its mask spread over output pixels by area, with the part of it that covers the pole.
        axle_x0 = float(math.trunc(cx)) - axle_half
        axle_j0 = math.floor(axle_x0 * inv_s)
        for r in range(n_axle_rows):
            for c in range(n_axle_cols):
                axle[r, c] = 0.0
                axle_on_pole[r, c] = 0.0
        for q in range(n_mask):
            # The pole's span on this screen row: pixel centres inside all four (dilated) edges.
            yc = axle_y0 + q + 0.5
            lo, hi = -math.inf, math.inf
            for e in range(4):
                room = offset[e] - normal_y[e] * yc  # inside where normal_x * x <= room
                if normal_x[e] > 0.0:
                    hi = min(hi, room / normal_x[e])
                elif normal_x[e] < 0.0:
                    lo = max(lo, room / normal_x[e])
                elif room < 0.0:
                    hi = -math.inf
            for k in range(n_mask):
                alpha = axle_mask[q, k]
                if alpha == 0.0:
                    continue
                x0 = axle_x0 + k
                on_pole = 1.0 if lo <= x0 + 0.5 <= hi else 0.0
                j = math.floor(x0 * inv_s)
                for jj in range(j, j + 2):
                    w = _overlap(x0, x0 + 1.0, jj * s, (jj + 1) * s) * inv_s * alpha
                    if w == 0.0:
                        continue
                    for r in range(n_axle_rows):
                        a = axle_rows[r, q] * w
                        axle[r, jj - axle_j0] += a
                        axle_on_pole[r, jj - axle_j0] += a * on_pole

        # Row by row: the cart's columns on its rows, and the pole's span on the row (the part of its
        # quadrilateral within `margin` of the row, widened by `margin`); nothing else changes.
        cart_j0 = max(0, math.floor(cart_x0 * inv_s))
        cart_j1 = min(width, math.floor(cart_x1 * inv_s) + 1)
        for i in range(min(pole_i0, cart_i0), max(pole_i1, cart_i1)):
            row0 = top + i * s
            yc = row0 + 0.5 * s
            lo_j, hi_j = (cart_j0, cart_j1) if cart_rows[i] > 0.0 else (width, 0)
            pole_lo, pole_hi = width, 0
            if pole_i0 <= i < pole_i1:
                band0, band1 = row0 - margin, row0 + s + margin
                x_lo, x_hi = math.inf, -math.inf
                for e in range(4):
                    ax, ay = vx[e], vy[e]
                    bx, by = vx[(e + 1) % 4], vy[(e + 1) % 4]
                    if ay == by:
                        t_lo, t_hi = (0.0, 1.0) if band0 <= ay <= band1 else (1.0, 0.0)
                    else:
                        t0, t1 = (band0 - ay) / (by - ay), (band1 - ay) / (by - ay)
                        t_lo, t_hi = max(0.0, min(t0, t1)), min(1.0, max(t0, t1))
                    if t_lo <= t_hi:
                        xa, xb = ax + t_lo * (bx - ax), ax + t_hi * (bx - ax)
                        x_lo, x_hi = min(x_lo, min(xa, xb)), max(x_hi, max(xa, xb))
                if x_lo <= x_hi:
                    pole_lo = max(0, math.floor((x_lo - margin) * inv_s))
                    pole_hi = min(width, math.floor((x_hi + margin) * inv_s) + 1)
                    lo_j, hi_j = min(lo_j, pole_lo), max(hi_j, pole_hi)
            r = i - axle_row0
            for j in range(lo_j, hi_j):
                col0 = j * s
                cover_x = _overlap(cart_x0, cart_x1, col0, col0 + s) * inv_s
                covered = cover_x * cart_rows[i] + line_rows[i] - cover_x * cart_line_rows[i]
                pole = 0.0
                if pole_lo <= j < pole_hi:
                    xc = col0 + 0.5 * s
                    in0 = _inside(
                        offset[0] - (normal_x[0] * xc + normal_y[0] * yc), h1[0], h2[0], inv_a[0], inv_2ab[0]
                    )
                    in2 = _inside(
                        offset[2] - (normal_x[2] * xc + normal_y[2] * yc), h1[2], h2[2], inv_a[2], inv_2ab[2]
                    )
                    across = in0 + in2 - 1.0
                    if across > 0.0:
                        in1 = _inside(
                            offset[1] - (normal_x[1] * xc + normal_y[1] * yc),
                            h1[1],
                            h2[1],
                            inv_a[1],
                            inv_2ab[1],
                        )
                        in3 = _inside(
                            offset[3] - (normal_x[3] * xc + normal_y[3] * yc),
                            h1[3],
                            h2[3],
                            inv_a[3],
                            inv_2ab[3],
                        )
                        pole = min(across, 1.0) * min(max(in1 + in3 - 1.0, 0.0), 1.0)
                        covered += pole * (1.0 - cart_rows[i])  # where the pole crosses the cart, once
                value = 255.0 * (1.0 - covered) + gray_pole * pole
                if 0 <= r < n_axle_rows and 0 <= j - axle_j0 < n_axle_cols:
                    value += gray_axle * axle[r, j - axle_j0] - gray_pole * axle_on_pole[r, j - axle_j0]
                frame[i, j] = np.uint8(min(max(value + _HALF, 0.0), 255.0))


@njit(**_JIT)
def gray_blocks(
    picture: NDArray[np.uint8], top: int, pixel: int, weights: NDArray[np.int64], out: NDArray[np.uint8]
) -> None:
    """``out[i, j]``: the gray level of the ``pixel`` x ``pixel`` block of ``picture`` [rows, cols, 3]
    (C-contiguous) whose top-left screen pixel is ``(top + i * pixel, j * pixel)``, rounded half up.

    In whole numbers (gray levels times ``sum(weights)``, e.g. 299 R + 587 G + 114 B), so it is
    :func:`~cartpole.envs.pixels.preprocess_frames`' general area average exactly, where an output
    pixel covers whole screen pixels. Each band of ``pixel`` screen rows is summed column by column
    first (one pass along contiguous memory, in int32: at most 1000 x 255 x 25 rows), then in blocks
    of ``pixel`` columns."""
    height, width = out.shape
    columns = width * pixel
    denominator = (weights[0] + weights[1] + weights[2]) * pixel * pixel
    w0, w1, w2 = np.int32(weights[0]), np.int32(weights[1]), np.int32(weights[2])
    band = np.empty(columns, dtype=np.int32)
    for i in range(height):
        band[:] = 0
        for row in range(top + i * pixel, top + (i + 1) * pixel):
            rgb = picture[row].reshape(-1)  # R, G, B of each column in turn
            for col in range(columns):
                red, green, blue = rgb[3 * col], rgb[3 * col + 1], rgb[3 * col + 2]
                band[col] += w0 * np.int32(red) + w1 * np.int32(green) + w2 * np.int32(blue)
        for j in range(width):
            total = 0
            for col in range(j * pixel, (j + 1) * pixel):
                total += band[col]
            out[i, j] = min(255, (2 * total + denominator) // (2 * denominator))
