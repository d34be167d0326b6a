"""Box2D (the box2d extra, for LunarLander-v3) has wheels for some Pythons only (none for 3.14 yet): where
it cannot be imported, a run on a Box2D env says so in one line, naming this Python when Box2D has no wheel
for it, and exits 2; pyproject.toml's marker on the extra and the lock agree with what the line says."""

from __future__ import annotations

import sys
import tomllib
from pathlib import Path

import pytest
from packaging.requirements import Requirement

from cartpole.cli.main import main
from cartpole.envs import spec
from cartpole.envs.spec import BOX2D_PYTHONS

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture
def without_box2d(monkeypatch: pytest.MonkeyPatch):
    """Box2D cannot be imported, and Gymnasium's Box2D envs are imported afresh, so they find that out."""
    monkeypatch.setitem(sys.modules, "Box2D", None)
    for name in [name for name in sys.modules if name.startswith("gymnasium.envs.box2d")]:
        monkeypatch.delitem(sys.modules, name)
    spec._env_info.cache_clear()  # an env this worker made before, with Box2D, would be read from it
    yield
    spec._env_info.cache_clear()


def train_lunarlander(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    code = main(["train", "ppo", "--env", "LunarLander-v3", "--runs-dir", str(tmp_path / "runs")])
    err = capsys.readouterr().err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "runs").exists() or not any((tmp_path / "runs").iterdir())
    return code, err


@pytest.mark.usefixtures("without_box2d")
def test_on_a_python_without_a_box2d_wheel_lunarlander_names_that_python(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
):
    monkeypatch.setattr(spec, "running_python", lambda: (3, 14))
    code, err = train_lunarlander(tmp_path, capsys)
    assert code == 2
    assert (
        "LunarLander-v3 needs Box2D, which has no wheel for Python 3.14 yet; "
        "use Python 3.11-3.13 for the box2d extra"
    ) in err


@pytest.mark.usefixtures("without_box2d")
def test_on_a_python_with_a_box2d_wheel_lunarlander_says_to_install_the_extra(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
):
    monkeypatch.setattr(spec, "running_python", lambda: (3, 12))
    code, err = train_lunarlander(tmp_path, capsys)
    assert code == 2
    assert "LunarLander-v3 needs Box2D, which is not installed: install the box2d extra" in err
    assert '.[box2d]"' in err and "Python 3.12" not in err


def box2d_requirement(texts: list[str]) -> Requirement:
    (found,) = [Requirement(text) for text in texts if Requirement(text).name == "box2d"]
    return found


@pytest.mark.parametrize("source", ["pyproject.toml", "requirements.lock"])
def test_the_box2d_marker_skips_exactly_the_pythons_without_a_wheel(source: str):
    text = (ROOT / source).read_text()
    if source == "pyproject.toml":
        requirement = box2d_requirement(tomllib.loads(text)["project"]["optional-dependencies"]["box2d"])
    else:
        lines = [line.split("#", 1)[0].strip() for line in text.splitlines()]
        requirement = box2d_requirement([line for line in lines if line])
    assert requirement.marker is not None
    oldest, newest = BOX2D_PYTHONS
    for minor in range(11, 17):
        version = {"python_version": f"3.{minor}", "python_full_version": f"3.{minor}.0"}
        assert requirement.marker.evaluate(version) == (oldest <= (3, minor) <= newest), (source, minor)
