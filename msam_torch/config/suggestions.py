"""What a config error suggests: for a key of a close spelling, the key meant (pydantic's errors
read against the config schema)."""
from __future__ import annotations

import difflib
import typing
from typing import Annotated, Any

from pydantic import BaseModel


def misspelt(error: dict, errors: list[dict], schema: type[BaseModel]) -> str:
    """For a missing key beside an unknown one of a close spelling (or the reverse): which one; for
    an unknown key alone, the key of the same section it is closest to."""
    other = {"missing": "extra_forbidden", "extra_forbidden": "missing"}.get(error["type"])
    names = [str(e["loc"][-1]) for e in errors if e["type"] == other and e["loc"][:-1] == error["loc"][:-1]]
    close = difflib.get_close_matches(str(error["loc"][-1]), names, n=1)
    if close:
        missing, given = (error["loc"][-1], close[0]) if error["type"] == "missing" else (close[0], error["loc"][-1])
        return f" ({given!r} is given: a misspelling of {missing!r}?)"
    known = difflib.get_close_matches(str(error["loc"][-1]), keys(schema, error["loc"][:-1]), n=1)
    return f" (did you mean {known[0]!r}?)" if error["type"] == "extra_forbidden" and known else ""


def keys(schema: Any, loc: tuple) -> list[str]:
    """The keys of the section of ``schema`` at ``loc`` (list indices and mapping keys passed
    through, optional and list types unwrapped); none where it is not a section."""
    for part in (*loc, None):
        while typing.get_origin(schema) is not None and not isinstance(schema, type):
            args = [a for a in typing.get_args(schema) if a is not type(None)]
            schema = args[0] if typing.get_origin(schema) is Annotated else args[-1] if args else None
        if part is None or not (isinstance(schema, type) and issubclass(schema, BaseModel)):
            break
        if isinstance(part, str):
            field = schema.model_fields.get(part)
            schema = field.annotation if field is not None else None
    return list(schema.model_fields) if isinstance(schema, type) and issubclass(schema, BaseModel) else []
