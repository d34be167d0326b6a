"""Run docs/tutorial.ipynb top to bottom in a fresh kernel, as CI does (tests/test_tutorial.py).

    python scripts/tutorial.py            # run it in a temporary folder; report the time and any error
    python scripts/tutorial.py --write    # ... and save its outputs into docs/tutorial.ipynb, and its
                                          # replay GIF as docs/images/tutorial-replay.gif (the README's)

Its run folders go to a temporary folder (the notebook's working directory), never to runs/.
"""

from __future__ import annotations

import argparse
import base64
import re
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

NOTEBOOK = Path(__file__).resolve().parents[1] / "docs" / "tutorial.ipynb"
REPLAY = NOTEBOOK.parent / "images" / "tutorial-replay.gif"
GIF_IN_HTML = re.compile(r"data:image/gif;base64,([A-Za-z0-9+/=]+)")
TIMEOUT_S = 600
"""The most one cell may take."""
MAX_SECONDS = 300
"""The most the whole notebook may take, top to bottom in a fresh kernel: what the README and the
notebook promise ("in under five minutes"), and what ``tests/test_tutorial.py`` checks."""


def execute(path: Path = NOTEBOOK, workdir: Path | None = None) -> Any:
    """The notebook at ``path``, executed in a new kernel with ``workdir`` as its working folder."""
    import nbclient
    import nbformat

    notebook = nbformat.read(path, as_version=4)
    with tempfile.TemporaryDirectory() as tmp:
        where = str(workdir or tmp)
        client = nbclient.NotebookClient(
            notebook, timeout=TIMEOUT_S, kernel_name="python3", resources={"metadata": {"path": where}}
        )
        client.execute()
    return notebook


def first_gif(notebook: Any) -> bytes:
    """The first animated GIF among the notebook's outputs (``show(..., mode="gif")``)."""
    for cell in notebook.cells:
        for output in cell.get("outputs", []):
            found = GIF_IN_HTML.search(output.get("data", {}).get("text/html", ""))
            if found:
                return base64.b64decode(found.group(1))
    raise SystemExit("the notebook shows no GIF: it should (section 8, a replay)")


def main() -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--write", action="store_true", help="save the outputs into the notebook")
    args = parser.parse_args()
    import nbformat

    start = time.perf_counter()
    notebook = execute()
    wall = time.perf_counter() - start
    print(f"{NOTEBOOK.name}: ran top to bottom in {wall:.0f} s (promised: at most {MAX_SECONDS} s)")
    if args.write:
        nbformat.write(notebook, NOTEBOOK)
        print(f"wrote its outputs into {NOTEBOOK}")
        REPLAY.write_bytes(first_gif(notebook))
        print(f"wrote its replay to {REPLAY}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
