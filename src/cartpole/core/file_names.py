"""File and folder names built from what a person gave (an env id, an entry, a preset file), legal on
every OS.

POSIX refuses only ``/`` in a name; Windows also refuses ``< > : " \\ | ? *`` and control characters, a
name that ends in a dot or a space, and its device names (``CON``, ``NUL``, ``COM1``, ...) even with an
extension (``nul.json``). One rule for every OS, so that a runs folder made on Linux can be copied to
Windows and the same input gives the same name everywhere: :func:`portable_name` makes such a name
from any text, :func:`is_portable_name` checks one a person chose (an experiment's, a study's), which
is refused rather than changed so that the person finds it again under the name they gave.
"""

from __future__ import annotations

import re

KEPT = re.compile(r"[A-Za-z0-9._-]+")
"""The characters a name keeps: ASCII letters and digits, ``.``, ``_`` and ``-``. Narrower than what
Windows allows, on purpose: the web app serves only such names, and a shell needs no quotes for them."""
_OTHERS = re.compile(r"[^A-Za-z0-9._-]+")
WINDOWS_DEVICES = frozenset(
    {"CON", "PRN", "AUX", "NUL", *(f"COM{i}" for i in range(1, 10)), *(f"LPT{i}" for i in range(1, 10))}
)
"""Names Windows keeps for devices, in any case, whatever extension follows them."""


def portable_name(text: str) -> str:
    """``text`` as a file or folder name (or a part of one) that every OS accepts: each run of other
    characters than :data:`KEPT`'s becomes one ``-`` (``mypkg:MyEnv-v0`` -> ``mypkg-MyEnv-v0``,
    ``ALE/Pong-v5`` -> ``ALE-Pong-v5``), ``-`` and ``.`` go from both ends (Windows drops a last dot, a
    first one hides a file elsewhere), and a Windows device name gets a ``_`` (``nul.toml`` ->
    ``nul_.toml``). Text with nothing to keep gives ``_``."""
    name = _OTHERS.sub("-", text).strip("-.") or "_"
    stem, dot, rest = name.partition(".")
    if stem.upper() in WINDOWS_DEVICES:
        name = f"{stem}_{dot}{rest}"
    return name


def is_portable_name(name: str) -> bool:
    """Whether ``name``, as it is, is a file or folder name every OS accepts, in :data:`KEPT`'s
    characters: not empty, no last dot, no Windows device name (``.`` and ``..`` are not names)."""
    return (
        KEPT.fullmatch(name) is not None
        and not name.endswith(".")
        and name.partition(".")[0].upper() not in WINDOWS_DEVICES
    )


__all__ = ["KEPT", "WINDOWS_DEVICES", "is_portable_name", "portable_name"]
