"""What every answer of the web app keeps to: it names no path of this machine, and every refusal
(each 4xx) has one shape, ``{"detail": "<one line>", "field": "<the input it is about, or null>"}``.

:func:`shown_paths` is the one way an answer shows a path: inside the runs folder relative to it (the
runs folder itself as the pages show it, :func:`shown_root`), anywhere else by its last part only.
:func:`refusal` is the one shape of a refusal; :func:`install_handlers` gives FastAPI's own refusals
(its list of schema errors, ``HTTPException``, a pydantic error inside a handler) that shape, and a
WebSocket whose query does not validate a one-line close reason.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from fastapi import FastAPI, Request, WebSocket
from fastapi.exceptions import RequestValidationError, WebSocketRequestValidationError
from fastapi.responses import JSONResponse, Response
from pydantic import BaseModel, Field, ValidationError
from starlette.exceptions import HTTPException

POLICY_VIOLATION = 1008
"""The WebSocket close code for a request the app refuses (its reason says why, in one line)."""
MAX_CLOSE_REASON = 123
"""Bytes a WebSocket close reason may have."""

ABSOLUTE_PATH = re.compile(r"(?<![\w.:/\\])(?:/|[A-Za-z]:[\\/])(?:[^\s/\\:'\"]+[\\/])*([^\s/\\:'\"]+)")
"""An absolute path in text (POSIX, or Windows' ``C:\\...``), its last part the group: not a relative
path's inner slashes (``runs/x``, ``cartpole/CartPole-v1``), nor a URL's (``http://...``)."""


class Refusal(BaseModel):
    """Every refusal of the app (each 4xx answer)."""

    detail: str = Field(
        description="what is wrong, in one line (for a training's input: as `cartpole train` says it)"
    )
    field: str | None = Field(
        description="the input it is about (agent, env_id, preset, seeds, budget, a setting's name, a query "
        "parameter), or null"
    )


class Refused(HTTPException):
    """An HTTPException that names the input it is about (``field``), for :func:`refusal`."""

    def __init__(self, status_code: int, detail: str, field: str | None = None, **kwargs: Any):
        super().__init__(status_code, detail, **kwargs)
        self.field = field


def one_line(text: object) -> str:
    return " ".join(str(text).split())


def refusal(
    status: int, detail: object, field: str | None = None, headers: Mapping[str, str] | None = None
) -> JSONResponse:
    """The answer of a refusal: ``{"detail", "field"}``, ``detail`` in one line."""
    body = {"detail": one_line(detail), "field": field}
    return JSONResponse(body, status_code=status, headers=dict(headers) if headers else None)


# ---------------------------------------------------------------------------------------------------
# No path of this machine
# ---------------------------------------------------------------------------------------------------


def shown_root(root: Path) -> str:
    """The runs folder as the pages show it: as given when relative, else only its name (where it is
    on this machine is nobody else's business)."""
    return root.name if root.is_absolute() else str(root)


def shown_paths(value: Any, root: Path) -> Any:
    """``value`` (text, or lists and dicts of it) as an answer shows it: every path inside the runs
    folder ``root`` relative to it, the runs folder itself as :func:`shown_root`, and any other
    absolute path by its last part (a preset file given by its full path shows as ``best.toml``)."""
    if isinstance(value, str):
        return _shown_text(value, root)
    if isinstance(value, list | tuple):
        return [shown_paths(v, root) for v in value]
    if isinstance(value, dict):
        return {k: shown_paths(v, root) for k, v in value.items()}
    return value


def _shown_text(text: str, root: Path) -> str:
    for spelling in _spellings(root):
        for separator in {"/", os.sep}:
            text = text.replace(spelling + separator, "")
        text = text.replace(spelling, shown_root(root))
    return ABSOLUTE_PATH.sub(lambda match: match.group(1), text)


def _spellings(root: Path) -> list[str]:
    """The runs folder's absolute path as written (resolved and not), longest first."""
    names = {str(root.absolute())}
    with contextlib.suppress(OSError):
        names.add(str(root.resolve()))
    return sorted((n for n in names if n.strip("/\\")), key=len, reverse=True)


# ---------------------------------------------------------------------------------------------------
# Schema errors in one line
# ---------------------------------------------------------------------------------------------------

SOURCES = ("body", "query", "path", "header", "cookie")
"""Where FastAPI says an input came from: the first part of an error's location."""
SETTINGS = "settings"
"""The body field whose keys are settings: an error inside it is about that setting."""


def shown_value(value: Any, limit: int = 40) -> str:
    """A value a request gave, as a refusal quotes it: JSON (``"1"``, ``1.0``, ``true``), an object
    or a list by its kind (``an object``, ``a list of 5000 items``)."""
    if isinstance(value, dict):
        return "an object"
    if isinstance(value, list | tuple):
        return f"a list of {len(value)} items" if len(value) > 3 else _json(list(value), limit)
    return _json(value, limit)


def _json(value: Any, limit: int) -> str:
    try:
        text = json.dumps(value)
    except (TypeError, ValueError):
        text = repr(value)
    return text if len(text) <= limit else text[: limit - 1] + "\u2026"


def error_line(errors: Sequence[Any]) -> tuple[str, str | None]:
    """(one line, the input it is about) for FastAPI's or pydantic's list of errors: the first of them,
    e.g. ``seeds: at most 4096 seeds, got 5000``, ``settings.lr must be ..., got an object``,
    ``seed must be >= 0, got -5`` (as ``cartpole train`` words its refusals),
    ``unknown field "foo"``."""
    if not errors:
        return "the request is not valid", None
    error = dict(errors[0])
    loc = [part for part in error.get("loc", ()) if part is not None]
    source = loc.pop(0) if loc and loc[0] in SOURCES else None
    where = _where(loc)
    kind, value, ctx = error.get("type", ""), error.get("input"), error.get("ctx") or {}
    quoted = source in (None, "body")  # a query's, a path's values are text: shown as given
    got = shown_value(value) if quoted else one_line(value)[:40]
    if kind == "extra_forbidden":
        return f"unknown field {json.dumps(where)}", None
    if kind == "json_invalid":
        return f"the body is not JSON: {ctx.get('error', error.get('msg', ''))}", None
    if "got" in ctx:  # a message of the app's own, complete (a setting's value)
        return f"{where} {one_line(error.get('msg', ''))}", _field(loc)
    if kind == "missing":
        return f"{where or 'the body'}: required", _field(loc)
    if kind in ("too_long", "too_short") and isinstance(value, list | tuple):
        bound = "at most" if kind == "too_long" else "at least"
        items = where if where == "seeds" else "items"
        limit = ctx.get("max_length" if kind == "too_long" else "min_length")
        return f"{where}: {bound} {limit} {items}, got {len(value)}", _field(loc)
    if kind in ("string_too_long", "string_too_short", "too_long", "too_short"):
        bound = "at most" if kind.endswith("long") else "at least"
        limit = ctx.get("max_length" if kind.endswith("long") else "min_length")
        size = len(value) if isinstance(value, str | list | tuple) else "more"
        return f"{where}: {bound} {limit} characters, got {size}", _field(loc)
    return f"{where or 'the body'} {_rule(kind, ctx, error.get('msg', 'not valid'))}, got {got}", _field(loc)


def _where(loc: Sequence[Any]) -> str:
    """An input's place as a path: ``seeds[0]``, ``settings.lr``."""
    text = ""
    for part in loc:
        text += f"[{part}]" if isinstance(part, int) else (f".{part}" if text else str(part))
    return text


def _field(loc: Sequence[Any]) -> str | None:
    """The input an error at ``loc`` is about: a setting's name inside ``settings``, else the field."""
    names = [part for part in loc if isinstance(part, str)]
    if not names:
        return None
    if names[0] == SETTINGS and len(names) > 1:
        return names[1]
    return names[0]


RULES = {
    "int_type": "must be an integer",
    "int_parsing": "must be an integer",
    "int_from_float": "must be an integer",
    "float_type": "must be a number",
    "float_parsing": "must be a number",
    "finite_number": "must be a finite number",
    "bool_type": "must be true or false",
    "bool_parsing": "must be true or false",
    "string_type": "must be text",
    "list_type": "must be a list",
    "dict_type": "must be an object",
    "model_type": "must be an object",
    "model_attributes_type": "must be an object",
}
BOUNDS = {"greater_than_equal": ">=", "greater_than": ">", "less_than_equal": "<=", "less_than": "<"}


def _rule(kind: str, ctx: Mapping[str, Any], message: str) -> str:
    if kind in RULES:
        return RULES[kind]
    if kind in BOUNDS:
        limit = next(iter(ctx.values()), "its limit")
        return f"must be {BOUNDS[kind]} {limit}"
    text = one_line(message).removeprefix("Value error, ")
    return text[:1].lower() + text[1:]


# ---------------------------------------------------------------------------------------------------
# FastAPI's refusals in the app's shape
# ---------------------------------------------------------------------------------------------------


def install_handlers(app: FastAPI) -> None:
    """Give every refusal FastAPI makes itself the app's one shape, with no machine path."""
    app.add_exception_handler(HTTPException, _http_error)
    app.add_exception_handler(RequestValidationError, _schema_error)
    app.add_exception_handler(ValidationError, _schema_error)
    app.add_exception_handler(WebSocketRequestValidationError, _websocket_schema_error)


def _root(request: Request | WebSocket) -> Path:
    return request.app.state.runs.root


async def _http_error(request: Request, exc: Exception) -> Response:
    assert isinstance(exc, HTTPException)
    if exc.status_code in (204, 304) or exc.status_code < 200:  # answers without a body
        return Response(status_code=exc.status_code, headers=exc.headers)
    detail = shown_paths(one_line(exc.detail), _root(request))
    return refusal(exc.status_code, detail, getattr(exc, "field", None), exc.headers)


async def _schema_error(request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, RequestValidationError | ValidationError)
    detail, field = error_line(exc.errors())
    return refusal(422, shown_paths(detail, _root(request)), field)


async def _websocket_schema_error(websocket: WebSocket, exc: Exception) -> None:
    assert isinstance(exc, WebSocketRequestValidationError)
    detail, _ = error_line(exc.errors())
    await websocket.close(code=POLICY_VIOLATION, reason=close_reason(detail))


def close_reason(text: str) -> str:
    """``text`` in one line cut to what a WebSocket close reason may hold."""
    return one_line(text).encode()[:MAX_CLOSE_REASON].decode(errors="ignore")


__all__ = [
    "POLICY_VIOLATION",
    "Refusal",
    "Refused",
    "close_reason",
    "error_line",
    "install_handlers",
    "one_line",
    "refusal",
    "shown_paths",
    "shown_root",
    "shown_value",
]
