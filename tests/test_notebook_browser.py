"""cartpole.show's notebook output in a real headless Chromium (Playwright): the canvas player
draws, animates, pauses on a click, shows score bars, coexists with a second output, and the GIF
mode's image decodes. The HTML is loaded with ``page.set_content`` as a notebook would insert it.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

CHROMIUM = "/usr/bin/chromium"
pytestmark = [
    pytest.mark.browser,
    pytest.mark.skipif(not Path(CHROMIUM).exists(), reason=f"browser tests need Chromium at {CHROMIUM}"),
]
playwright_api = pytest.importorskip("playwright.sync_api", reason="browser tests need playwright (pip)")

import cartpole  # noqa: E402

TIMEOUT_MS = 15_000
"""How long a poll waits for the page (generous: a slow, loaded machine)."""

WEIGHTS = np.array([0.05, 0.3, 1.0, 0.3])
CART = (0x26, 0x3A, 0x7A)
"""CartPoleDraw.COLORS.cart, #263a7a."""
POLE = (0xE0, 0x8A, 0x1E)
"""CartPoleDraw.COLORS.pole, #e08a1e."""

# Records, on each canvas, the last caption CartPoleDraw wrote on it ("episode 1/2  seed 0  step 7
# return 7"): the step is drawn on the canvas, not in the DOM.
CAPTION_HOOK = """
(() => {
  const fillText = CanvasRenderingContext2D.prototype.fillText;
  CanvasRenderingContext2D.prototype.fillText = function (text, ...rest) {
    if (typeof text === "string" && text.startsWith("episode ")) this.canvas.dataset.cpCaption = text;
    return fillText.call(this, text, ...rest);
  };
})();
"""

COUNT_COLOURS = """([canvas, colours]) => {
  const { width, height } = canvas;
  if (!width || !height) return { distinct: 0, counts: colours.map(() => 0) };
  const px = canvas.getContext("2d").getImageData(0, 0, width, height).data;
  const seen = new Set();
  const counts = colours.map(() => 0);
  for (let i = 0; i < px.length; i += 4) {
    seen.add((px[i] << 24) | (px[i + 1] << 16) | (px[i + 2] << 8) | px[i + 3]);
    colours.forEach(([r, g, b], k) => {
      if (px[i] === r && px[i + 1] === g && px[i + 2] === b && px[i + 3] === 255) counts[k]++;
    });
  }
  return { distinct: seen.size, counts };
}"""


class Balancer:
    """A linear policy that balances CartPole for the 500 steps, with per-action scores."""

    def act(self, observations: np.ndarray) -> np.ndarray:
        return (np.asarray(observations) @ WEIGHTS > 0).astype(np.int64)

    def scores(self, observations: np.ndarray) -> np.ndarray:
        z = np.asarray(observations) @ WEIGHTS
        return np.stack([-z, z], axis=1)


class ActOnlyBalancer:
    """The same balancer without scores: no bars."""

    def act(self, observations: np.ndarray) -> np.ndarray:
        return (np.asarray(observations) @ WEIGHTS > 0).astype(np.int64)


class AlwaysLeft:
    """Pushes left every step: an episode ends in about ten steps."""

    def act(self, observations: np.ndarray) -> np.ndarray:
        return np.zeros(len(observations), dtype=np.int64)


@pytest.fixture(scope="module")
def balancer_html() -> str:
    animation = cartpole.show(Balancer(), episodes=1, seed=0)
    assert animation.mode == "canvas"
    assert animation.returns == [500.0], "the balancing policy should last the whole episode"
    return animation._repr_html_()


class Page:
    """A browser page that records console errors and uncaught exceptions."""

    def __init__(self, browser: object):
        self.context = browser.new_context(viewport={"width": 1000, "height": 900})  # type: ignore[attr-defined]
        self.context.add_init_script(CAPTION_HOOK)
        self.page = self.context.new_page()
        self.page.set_default_timeout(TIMEOUT_MS)
        self.errors: list[str] = []
        self.page.on("console", lambda m: self.errors.append(m.text) if m.type == "error" else None)
        self.page.on("pageerror", lambda e: self.errors.append(str(e)))

    def load(self, html: str) -> object:
        self.page.set_content(f"<!doctype html><html><body>{html}</body></html>")
        return self.page

    def canvases(self) -> list[object]:
        return self.page.query_selector_all(".cartpole-show canvas.cp-scene")

    def snapshot(self, canvas: object) -> str:
        return canvas.evaluate("c => c.toDataURL()")  # type: ignore[attr-defined]

    def caption(self, canvas: object) -> str:
        return canvas.evaluate("c => c.dataset.cpCaption || ''")  # type: ignore[attr-defined]

    def step(self, canvas: object) -> int:
        return step_of(self.caption(canvas))

    def wait_drawn(self, canvas: object) -> None:
        """Until the player has drawn a first caption on ``canvas``."""
        self.page.wait_for_function("c => !!c.dataset.cpCaption", arg=canvas)

    def wait_step_past(self, canvas: object, step: int) -> int:
        """Until ``canvas`` shows a step other than ``step``; the first such step seen, polled
        every animation frame in the page."""
        handle = self.page.wait_for_function(
            """([c, step]) => {
              const m = /step (\\d+)/.exec(c.dataset.cpCaption || "");
              return m && Number(m[1]) !== step ? Number(m[1]) : null;
            }""",
            arg=[canvas, step],
            polling="raf",
        )
        return int(handle.json_value())

    def colours(self, canvas: object, colours: list[tuple[int, int, int]]) -> dict:
        return self.page.evaluate(COUNT_COLOURS, [canvas, [list(c) for c in colours]])

    def close(self) -> None:
        self.context.close()


def step_of(caption: str) -> int:
    match = re.search(r"step (\d+)", caption)
    assert match, f"no step in the canvas caption {caption!r}"
    return int(match.group(1))


@pytest.fixture
def page(browser: object) -> Iterator[Page]:
    page = Page(browser)
    yield page
    errors = page.errors
    page.close()
    assert errors == [], f"JavaScript errors: {errors}"


def test_canvas_draws_the_scene(page: Page, balancer_html: str):
    assert 'class="cartpole-show"' in balancer_html
    page.load(balancer_html)
    (canvas,) = page.canvases()
    page.wait_drawn(canvas)
    size = canvas.evaluate("c => [c.width, c.height]")
    assert size[0] >= 280 and size[1] > 100, f"canvas backing store {size}"
    seen = page.colours(canvas, [CART, POLE])
    assert seen["distinct"] > 20, f"only {seen['distinct']} colours on the canvas: not a drawn scene"
    cart, pole = seen["counts"]
    assert cart > 300, f"the cart's colour #263a7a covers only {cart} pixels"
    assert pole > 100, f"the pole's colour #e08a1e covers only {pole} pixels"
    caption = page.page.inner_text(".cartpole-show .cp-caption")
    assert "CartPole-v1" in caption and "returns 500" in caption and "Click to pause" in caption


def test_canvas_animates(page: Page, balancer_html: str):
    page.load(balancer_html)
    (canvas,) = page.canvases()
    page.wait_drawn(canvas)
    first, step = page.snapshot(canvas), page.step(canvas)
    assert "episode 1/1" in page.caption(canvas)
    later = page.wait_step_past(canvas, step)
    assert later > step, f"the step went from {step} to {later}"
    page.page.wait_for_timeout(300)
    assert page.snapshot(canvas) != first, "the canvas did not change while the steps advanced"
    assert page.step(canvas) > later


def test_click_pauses_and_resumes(page: Page, balancer_html: str):
    page.load(balancer_html)
    (canvas,) = page.canvases()
    page.wait_drawn(canvas)
    page.wait_step_past(canvas, 0)
    canvas.click()
    paused_at, snapshot = page.step(canvas), page.snapshot(canvas)
    assert paused_at < 450, "the click came too late in the episode to tell a pause from its end"
    page.page.wait_for_timeout(300)
    assert page.snapshot(canvas) == snapshot, "the canvas changed while paused"
    page.page.wait_for_timeout(700)
    assert page.step(canvas) == paused_at, "the step advanced while paused"
    assert page.snapshot(canvas) == snapshot, "the canvas changed while paused"
    canvas.click()
    resumed = page.wait_step_past(canvas, paused_at)
    # The second of pause is not played: resuming goes on from the step it stopped at (50 steps a
    # second of play; a slow machine may still drop a few frames).
    assert paused_at < resumed < paused_at + 40, f"paused at step {paused_at}, resumed at {resumed}"
    assert page.snapshot(canvas) != snapshot


def test_scored_policy_shows_two_bars(page: Page, balancer_html: str):
    page.load(balancer_html)
    (canvas,) = page.canvases()
    page.wait_drawn(canvas)
    page.page.wait_for_function("document.querySelectorAll('.cartpole-show .cp-bars > div').length > 0")
    canvas.click()  # pause: the bars stay those of one step
    bars = page.page.query_selector_all(".cartpole-show .cp-bars > div")
    texts = [b.evaluate("b => b.firstElementChild.textContent") for b in bars]
    assert len(bars) == 2, f"bars: {texts}"
    number = r"(-?\d+\.\d\d)"
    left = re.fullmatch(r"← left " + number, texts[0])
    right = re.fullmatch(r"right → " + number, texts[1])
    assert left and right, f"bar labels {texts}"
    # The balancer's scores are -z and z: opposite numbers, and the bold bar is the larger.
    assert float(left.group(1)) == pytest.approx(-float(right.group(1)), abs=0.011)
    bold = [b.evaluate("b => b.style.fontWeight") for b in bars]
    chosen = 1 if float(right.group(1)) > float(left.group(1)) else 0
    if float(left.group(1)) != float(right.group(1)):
        assert bold[chosen] == "700" and bold[1 - chosen] != "700", f"bold {bold} for {texts}"
    fill = "b => b.querySelector('div[style*=\"position:absolute\"]').style.width"
    widths = [b.evaluate(fill) for b in bars]
    assert all(re.fullmatch(r"[\d.]+%", w) for w in widths), f"bar widths {widths}"


def test_policy_without_scores_has_no_bars(page: Page):
    page.load(cartpole.show(ActOnlyBalancer(), episodes=1)._repr_html_())
    (canvas,) = page.canvases()
    page.wait_drawn(canvas)
    page.wait_step_past(canvas, 0)
    assert page.page.query_selector_all(".cartpole-show .cp-bars > *") == []
    assert page.page.inner_text(".cartpole-show .cp-bars") == ""


def test_loops_over_the_episodes(page: Page):
    animation = cartpole.show(AlwaysLeft(), episodes=2, seed=0)
    assert all(r < 30 for r in animation.returns), animation.returns
    page.load(animation._repr_html_())
    (canvas,) = page.canvases()
    page.wait_drawn(canvas)
    assert page.caption(canvas).startswith("episode 1/2  seed 0")
    page.page.wait_for_function("c => c.dataset.cpCaption.startsWith('episode 2/2  seed 1')", arg=canvas)
    page.page.wait_for_function("c => c.dataset.cpCaption.startsWith('episode 1/2  seed 0')", arg=canvas)


def test_two_outputs_on_one_page(page: Page, balancer_html: str):
    other = cartpole.show(ActOnlyBalancer(), episodes=1, seed=1)._repr_html_()
    page.load(balancer_html + other)
    roots = page.page.query_selector_all(".cartpole-show")
    ids = [r.get_attribute("id") for r in roots]
    assert len(ids) == 2 and len(set(ids)) == 2, f"ids {ids}"
    canvases = page.canvases()
    assert len(canvases) == 2
    for canvas in canvases:
        page.wait_drawn(canvas)
    assert "seed 0" in page.caption(canvases[0]) and "seed 1" in page.caption(canvases[1])
    for canvas in canvases:
        cart, _ = page.colours(canvas, [CART, POLE])["counts"]
        assert cart > 300, f"the cart's colour covers only {cart} pixels"
        before, step = page.snapshot(canvas), page.step(canvas)
        page.wait_step_past(canvas, step)
        assert page.snapshot(canvas) != before
    # Each output has its own bars: the scored one two, the other none.
    assert len(page.page.query_selector_all(f"#{ids[0]} .cp-bars > div")) == 2
    assert page.page.query_selector_all(f"#{ids[1]} .cp-bars > *") == []
    # Pausing one leaves the other playing.
    canvases[0].click()
    paused, step = page.step(canvases[0]), page.step(canvases[1])
    page.wait_step_past(canvases[1], step)
    page.page.wait_for_timeout(200)
    assert page.step(canvases[0]) == paused
    assert page.errors == [], f"JavaScript errors: {page.errors}"


def test_gif_mode_decodes(page: Page):
    animation = cartpole.show(AlwaysLeft(), episodes=1, mode="gif")
    assert animation.mode == "gif" and animation.gif and animation.gif[:6] in (b"GIF87a", b"GIF89a")
    html = animation._repr_html_()
    assert html.startswith("<figure>") and 'src="data:image/gif;base64,' in html
    page.load(html)
    image = page.page.wait_for_selector("figure img", state="attached")
    image.wait_for_element_state("visible")
    page.page.wait_for_function("i => i.complete", arg=image)
    size = image.evaluate("i => [i.naturalWidth, i.naturalHeight]")
    assert size[0] == 300 and size[1] > 0, f"the GIF decoded as {size}"
    assert "returns" in page.page.inner_text("figure figcaption")


class DarkSide:
    """A stub pixel policy: pushes toward the half of its newest frame with more dark pixels."""

    def scores(self, observations: np.ndarray) -> np.ndarray:
        darkness = 255.0 - np.asarray(observations)[:, -1].astype(np.float64)
        return np.stack([darkness[:, :, :50].sum(axis=(1, 2)), darkness[:, :, 50:].sum(axis=(1, 2))], 1) / 1e4

    def act(self, observations: np.ndarray) -> np.ndarray:
        return self.scores(observations).argmax(axis=1)


# The gray levels of the "now" frame of the agent's view, read back from its canvas: frame pixels
# are drawn 3x3 under a 16-pixel label, in the last of 4 cells in a column with 8-pixel gaps.
NOW_FRAME = """(canvas, [width, height]) => {
  const x0 = 0, y0 = 3 * (3 * height + 16 + 8) + 16;
  const pixels = canvas.getContext("2d").getImageData(x0, y0, 3 * width, 3 * height).data;
  const gray = [];
  for (let r = 0; r < height; r++) for (let c = 0; c < width; c++) {
    gray.push(pixels[((3 * r + 1) * 3 * width + 3 * c + 1) * 4]);
  }
  return gray;
}"""


def test_a_pixel_agents_frames_are_drawn_beside_the_scene(page: Page):
    animation = cartpole.show(DarkSide(), "cartpole/CartPolePixels-v1", episodes=1, seed=5)
    page.load(animation._repr_html_())
    (canvas,) = page.canvases()
    page.wait_drawn(canvas)
    assert page.page.is_visible(".cartpole-show .cp-view canvas")
    assert "what the agent sees" in page.page.inner_text(".cartpole-show .cp-view")
    canvas.click()  # pause: the scene and the view stay at one step
    step = page.step(canvas)
    view = page.page.query_selector(".cartpole-show .cp-view canvas")
    drawn = np.array(view.evaluate(NOW_FRAME, [100, 30]), dtype=np.uint8).reshape(30, 100)  # type: ignore[union-attr]
    frames = animation.episodes[0].frames
    assert frames is not None and np.array_equal(drawn, frames[step])
    assert (drawn < 128).sum() > 20  # the cart and pole, dark on the white screen
