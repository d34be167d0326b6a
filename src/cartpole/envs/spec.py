"""What we need to know about an environment, read from Gymnasium's registry and the env as configured.

The "solved" threshold and the episode limit are never written in our code: they come from
``gymnasium.spec(env_id)``, so CartPole-v0 (195 over 200 steps) and CartPole-v1 (475 over 500)
each get their own rule.

An env is its id as Gymnasium takes it (``CartPole-v1``, or ``module:Id-vN``, whose module is
imported first: it registers the id), the keyword arguments ``gymnasium.make`` passes to its
constructor, and the wrappers put around it (each ``module:Class``, with its own keyword arguments).
:func:`env_info` reads spaces, threshold and episode limit from the env made that way, so what it says
is keyed by all three; :func:`make_env` makes one of it. A CartPole id with kwargs that only our
simulator takes (its physics constants, ``gravity=5.0``: Gymnasium's CartPole refuses them) is made
on our simulator, and its :attr:`EnvInfo.simulator_only` names them.
"""

from __future__ import annotations

import importlib
import inspect
import json
import math
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from functools import cache
from typing import Any

import gymnasium as gym
import numpy as np

from cartpole.core.errors import InputError
from cartpole.envs.params import PHYSICS_KWARGS
from cartpole.envs.registration import PIXEL_REFERENCE_IDS, REFERENCE_IDS, fast_env_id


class UnsupportedEnvError(InputError, ValueError):
    """The env id is unknown, or its spaces are not a Box observation (flat or image) and Discrete
    actions."""


# The Pythons, oldest and newest, that Box2D (the box2d extra's box2d 2.3.10, for LunarLander) has wheels
# for. pyproject.toml's box2d extra carries the same bound as its marker (python_version < '3.14'), so on a
# newer Python the extra installs nothing; tests/test_box2d_python.py checks that the two agree.
BOX2D_PYTHONS = ((3, 11), (3, 13))


def running_python() -> tuple[int, int]:
    """This interpreter's (major, minor), as :func:`box2d_missing` names it."""
    return sys.version_info.major, sys.version_info.minor


def box2d_missing(env_id: str) -> str:
    """The one line for ``env_id``, an env that needs Box2D, where Box2D cannot be imported: on a
    Python that Box2D has no wheel for, that Python and the ones to use; elsewhere, how to install it."""
    python = running_python()
    (oldest, newest), version = BOX2D_PYTHONS, ".".join(map(str, python))
    if not oldest <= python <= newest:
        return (
            f"{env_id} needs Box2D, which has no wheel for Python {version} yet; use Python "
            f"{oldest[0]}.{oldest[1]}-{newest[0]}.{newest[1]} for the box2d extra"
        )
    return (
        f"{env_id} needs Box2D, which is not installed: install the box2d extra "
        '(pip install -c requirements.lock -e ".[box2d]")'
    )


def _needs_box2d(err: BaseException) -> bool:
    """Whether ``err``, raised making an env, says that Box2D cannot be imported: Gymnasium's
    DependencyNotInstalled for its Box2D envs, or an ImportError of the module ``Box2D`` itself."""
    seen: set[int] = set()
    found: BaseException | None = err
    while found is not None and id(found) not in seen:
        seen.add(id(found))
        if isinstance(found, ImportError) and (found.name or "").partition(".")[0] == "Box2D":
            return True
        if isinstance(found, gym.error.DependencyNotInstalled) and "Box2D" in str(found):
            return True
        found = found.__cause__ or found.__context__
    return False


@dataclass(frozen=True)
class WrapperSpec:
    """A Gymnasium wrapper to put around an env: ``name`` is its import path ``module:Class``."""

    name: str
    kwargs: dict[str, Any] = field(default_factory=dict, hash=False)

    def to_dict(self) -> dict[str, Any]:
        """As a preset file and config.json write it: ``{"name": ..., "kwargs": {...}}``."""
        return {"name": self.name, "kwargs": dict(self.kwargs)}

    @property
    def label(self) -> str:
        """``module:Class`` with its arguments, as a verdict line names it."""
        return self.name + (f"({describe_kwargs(self.kwargs)})" if self.kwargs else "")

    def load(self) -> type[gym.Wrapper[Any, Any, Any, Any]]:
        """The wrapper class; UnsupportedEnvError when it cannot be imported."""
        module_name, _, class_name = self.name.partition(":")
        try:
            found = getattr(importlib.import_module(module_name), class_name)
        except (ImportError, AttributeError) as err:
            raise UnsupportedEnvError(f"cannot import wrapper {self.name!r}: {err}") from None
        if not (isinstance(found, type) and issubclass(found, gym.Wrapper)):
            raise UnsupportedEnvError(f"wrapper {self.name!r} is not a gymnasium.Wrapper class")
        return found

    def wrap(self, env: gym.Env[Any, Any]) -> gym.Wrapper[Any, Any, Any, Any]:
        """``env`` inside this wrapper; UnsupportedEnvError when the wrapper refuses its arguments."""
        wrapper = self.load()
        try:
            return wrapper(env, **self.kwargs)
        except Exception as err:  # the wrapper's own code: anything it raises means it cannot wrap
            args = f" with kwargs {describe_kwargs(self.kwargs)}" if self.kwargs else ""
            raise UnsupportedEnvError(
                f"wrapper {self.name}{args} cannot wrap {env.spec.id if env.spec else env}: "
                f"{type(err).__name__}: {err}"
            ) from None


def check_wrappers(value: Any, setting: str = "wrappers") -> tuple[WrapperSpec, ...]:
    """Wrappers as a preset file lists them, each ``"module:Class"`` or ``{name = "module:Class",
    kwargs = {...}}`` (or already WrapperSpecs); ConfigError naming ``setting`` otherwise. The
    classes are not imported here."""
    if not isinstance(value, list | tuple):
        raise UnsupportedEnvError(f"{setting} must be a list of wrappers, got {value!r}")
    specs = []
    for item in value:
        if isinstance(item, WrapperSpec):
            specs.append(item)
            continue
        if isinstance(item, str):
            item = {"name": item}
        if not isinstance(item, Mapping) or set(item) - {"name", "kwargs"} or "name" not in item:
            raise UnsupportedEnvError(
                f'{setting}: each wrapper is "module:Class" or {{name = "module:Class", kwargs = {{...}}}}, '
                f"got {item!r}"
            )
        name, kwargs = item["name"], item.get("kwargs", {})
        if not isinstance(name, str) or ":" not in name.strip(":"):
            raise UnsupportedEnvError(
                f"{setting}: a wrapper's name is an import path module:Class, got {name!r}"
            )
        specs.append(WrapperSpec(name, dict(check_kwargs(kwargs, f"{setting}: {name}'s kwargs"))))
    return tuple(specs)


def check_kwargs(value: Any, setting: str = "env_kwargs") -> dict[str, Any]:
    """Keyword arguments as plain data (a table of names to values); UnsupportedEnvError otherwise."""
    if not isinstance(value, Mapping) or not all(isinstance(k, str) and k.isidentifier() for k in value):
        raise UnsupportedEnvError(f"{setting} must be a table of keyword names to values, got {value!r}")
    return dict(value)


def describe_kwargs(kwargs: Mapping[str, Any]) -> str:
    """``key=value, ...`` in the order given, values as JSON writes them."""
    return ", ".join(f"{k}={json.dumps(v)}" for k, v in kwargs.items())


MAKE_ARGUMENTS = frozenset(
    name for name in inspect.signature(gym.make).parameters if name not in ("id", "kwargs")
)
"""``gymnasium.make``'s own arguments (``max_episode_steps``, ``autoreset``, ``disable_env_checker``,
...): in ``--env-kwargs`` they change how the env is made, not the env. Training takes them; a
verdict leaves them out (:func:`judged_env`), so that the registry's time limit judges."""


@dataclass(frozen=True)
class EnvInfo:
    """Spaces and limits of one Gymnasium environment as configured (its id, kwargs and wrappers)."""

    env_id: str
    obs_dim: int
    """Numbers in one observation (of a flat one, its length; of an image, channels x height x width)."""
    n_actions: int
    reward_threshold: float | None
    max_episode_steps: int | None
    obs_low: tuple[float, ...]
    obs_high: tuple[float, ...]
    """Bounds of each number of a flat observation (of an image: its one pixel range, 0 and 255)."""
    obs_shape: tuple[int, ...] = ()
    """Shape of one observation: ``(obs_dim,)`` flat, ``(channels, height, width)`` for images, as
    agents choose their network by it."""
    kwargs: dict[str, Any] = field(default_factory=dict, hash=False)
    """What ``gymnasium.make`` passes to the env's constructor (``--env-kwargs``)."""
    wrappers: tuple[WrapperSpec, ...] = ()
    """Put around the env in this order (a preset's ``wrappers``)."""
    simulator_only: tuple[str, ...] = ()
    """The kwargs that Gymnasium's own env does not take and our simulator does (CartPole's physics
    constants): every env of this one, training's and the verdict's, is our simulator's."""

    def __post_init__(self) -> None:
        if not self.obs_shape:
            object.__setattr__(self, "obs_shape", (self.obs_dim,))

    @property
    def training_only(self) -> tuple[str, ...]:
        """The kwargs that are ``gymnasium.make``'s own arguments (:data:`MAKE_ARGUMENTS`), which a
        verdict leaves out."""
        return tuple(name for name in self.kwargs if name in MAKE_ARGUMENTS)

    @property
    def made_id(self) -> str:
        """The id ``gymnasium.make`` is given: ours (``cartpole/...``) where :attr:`simulator_only`."""
        return fast_env_id(self.env_id) if self.simulator_only else self.env_id

    @property
    def configured(self) -> bool:
        """True when the env is not its id's plain env: kwargs or wrappers change it."""
        return bool(self.kwargs or self.wrappers)

    @property
    def label(self) -> str:
        """The id with its kwargs and wrappers, as verdict lines name the env:
        ``CartPole-v1 (sutton_barto_reward=true; wrappers: mypkg:Scale)``."""
        parts = [describe_kwargs(self.kwargs)] if self.kwargs else []
        if self.wrappers:
            parts.append("wrappers: " + ", ".join(w.label for w in self.wrappers))
        return self.env_id + (f" ({'; '.join(parts)})" if parts else "")

    @property
    def is_image(self) -> bool:
        """True for image observations ``[channels, height, width]`` (a convolutional network's)."""
        return len(self.obs_shape) == 3

    @property
    def is_cartpole(self) -> bool:
        """True for Gymnasium's CartPole ids (our fast simulator can stand in for them)."""
        return self.env_id.removeprefix("cartpole/") in ("CartPole-v0", "CartPole-v1")

    @property
    def pixels_of(self) -> str | None:
        """For our pixel envs, the Gymnasium CartPole id they show (their verdicts are played on it,
        seen through :class:`~cartpole.envs.pixels.GymnasiumPixels`); else None."""
        return PIXEL_REFERENCE_IDS.get("cartpole/" + self.env_id.removeprefix("cartpole/"))


def env_info(env_id: str, kwargs: Mapping[str, Any] | None = None, wrappers: Sequence[Any] = ()) -> EnvInfo:
    """Read spaces, threshold and episode limit of ``env_id`` made with ``kwargs`` inside
    ``wrappers`` (see :func:`check_wrappers`); UnsupportedEnvError (one line) if it is unusable."""
    checked = check_wrappers(list(wrappers))
    key = json.dumps(
        {"kwargs": check_kwargs(kwargs or {}), "wrappers": [w.to_dict() for w in checked]}, sort_keys=True
    )
    return _env_info(env_id, key)


def as_env_info(env: str | EnvInfo) -> EnvInfo:
    """``env`` itself, or the plain env of the id ``env``."""
    return env if isinstance(env, EnvInfo) else env_info(env)


def registered_spec(env_id: str) -> gym.envs.registration.EnvSpec:
    """Gymnasium's spec of ``env_id``, importing the module of a ``module:Id-vN`` id first (it
    registers the id, as ``gymnasium.make`` does it); UnsupportedEnvError otherwise."""
    module, _, name = env_id.rpartition(":")
    if module:
        try:
            importlib.import_module(module)
        except Exception as err:  # the user's module: anything it raises means it cannot be used
            raise UnsupportedEnvError(
                f"cannot import {module!r} for environment {env_id!r}: {type(err).__name__}: {err} "
                "(is its package installed, or on PYTHONPATH?)"
            ) from None
    try:
        return gym.spec(name)
    except Exception as err:  # gymnasium raises several error types for unknown ids
        if module:
            raise UnsupportedEnvError(
                f"unknown environment {env_id!r}: importing {module} registers no {name!r}"
            ) from err
        raise UnsupportedEnvError(
            f"unknown environment {env_id!r}: use a registered Gymnasium id such as CartPole-v1, "
            "CartPole-v0 or Acrobot-v1, or module:Id-vN for an env that a module registers"
        ) from err


def make_env(env: EnvInfo, **make_args: Any) -> gym.Env[Any, Any]:
    """One env of ``env`` as configured: ``gymnasium.make`` of its id with its kwargs (and
    ``make_args``, e.g. ``render_mode``), inside its wrappers; on our simulator where
    :attr:`EnvInfo.simulator_only`."""
    return _make(env.made_id, env.kwargs, env.wrappers, **make_args)


def judged_env(env: EnvInfo) -> EnvInfo:
    """The env a verdict plays: ``env`` as configured but for its :attr:`~EnvInfo.training_only`
    kwargs (``max_episode_steps=1000`` trains on 1000-step episodes; the verdict keeps the
    registry's limit, and says so)."""
    if not env.training_only:
        return env
    kept = {name: value for name, value in env.kwargs.items() if name not in MAKE_ARGUMENTS}
    return env_info(env.env_id, kept, env.wrappers)


def _make(
    env_id: str, kwargs: Mapping[str, Any], wrappers: Sequence[WrapperSpec], **make_args: Any
) -> gym.Env[Any, Any]:
    made = gym.make(registered_spec(env_id), **make_args, **kwargs)
    for wrapper in wrappers:
        made = wrapper.wrap(made)
    return made


@cache
def _env_info(env_id: str, key: str) -> EnvInfo:
    configuration = json.loads(key)
    kwargs = configuration["kwargs"]
    wrappers = check_wrappers(configuration["wrappers"])
    spec = registered_spec(env_id)
    simulator_only = _simulator_only(env_id, kwargs)
    try:
        env = _make(fast_env_id(env_id) if simulator_only else env_id, kwargs, wrappers)
    except UnsupportedEnvError:
        raise
    except TypeError as err:
        reason = str(err).split(" was raised from the environment creator")[0]  # gymnasium adds the kwargs
        raise UnsupportedEnvError(
            f"{env_id} does not take env kwargs {describe_kwargs(kwargs)}: {reason}"
        ) from None
    except ValueError as err:
        raise UnsupportedEnvError(f"{env_id} refuses env kwargs {describe_kwargs(kwargs)}: {err}") from None
    except Exception as err:
        if _needs_box2d(err):
            raise UnsupportedEnvError(box2d_missing(env_id)) from None
        raise UnsupportedEnvError(
            f"cannot create environment {env_id!r}: {err} (is its extra installed?)"
        ) from err
    try:
        obs_space, act_space = env.observation_space, env.action_space
        limit = env.spec.max_episode_steps if env.spec is not None else spec.max_episode_steps
    finally:
        env.close()
    if not isinstance(obs_space, gym.spaces.Box) or len(obs_space.shape) not in (1, 3):
        raise UnsupportedEnvError(
            f"{env_id} has a {type(obs_space).__name__}{getattr(obs_space, 'shape', '')} "
            "observation; supported: a flat Box observation, or images [channels, height, width], "
            "with Discrete actions"
        )
    if not isinstance(act_space, gym.spaces.Discrete):
        raise UnsupportedEnvError(
            f"{env_id} has {type(act_space).__name__} actions; supported: Discrete actions "
            "with a flat Box observation"
        )
    shape = tuple(int(n) for n in obs_space.shape)
    low, high = np.asarray(obs_space.low), np.asarray(obs_space.high)
    if len(shape) == 3:  # one range for every pixel, not one per pixel
        low, high = np.asarray([low.min()]), np.asarray([high.max()])
    return EnvInfo(
        env_id=env_id,
        obs_dim=math.prod(shape),
        n_actions=int(act_space.n),
        reward_threshold=spec.reward_threshold,
        max_episode_steps=limit,
        obs_low=tuple(float(v) for v in low),
        obs_high=tuple(float(v) for v in high),
        obs_shape=shape,
        kwargs=kwargs,
        wrappers=wrappers,
        simulator_only=simulator_only,
    )


def _simulator_only(env_id: str, kwargs: Mapping[str, Any]) -> tuple[str, ...]:
    """The physics constants among ``kwargs`` of a CartPole id that Gymnasium's own CartPole refuses
    (all of them, today: asked of Gymnasium, not assumed); () when there are none."""
    reference = env_id.removeprefix(fast_env_id(""))
    physics = {k: v for k, v in kwargs.items() if k in PHYSICS_KWARGS}
    if reference not in REFERENCE_IDS or not physics:
        return ()
    try:
        gym.make(reference, **physics).close()
    except TypeError:
        return tuple(physics)
    return ()
