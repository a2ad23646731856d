"""The config reference (``docs/config-keys.md``) is generated from the schema and holds every key:
a key added to the schema without regenerating the page, or a page that lost one, fails here."""
import typing
from pathlib import Path

from pydantic import BaseModel

from msam_torch.config.keys import markdown, rows
from msam_torch.config.schema import Config

PAGE = Path(__file__).resolve().parents[2] / "docs" / "config-keys.md"


def keys(model: type[BaseModel], prefix: str = "") -> list[str]:
    """Every key of a config, from the pydantic models' fields (not from the JSON schema the page is built from)."""
    out = []
    for name, field in model.model_fields.items():
        key = f"{prefix}{name}"
        out.append(key)
        for inner, suffix in _nested(field.annotation):
            out += keys(inner, f"{key}{suffix}.")
    return out


def _nested(annotation) -> list[tuple[type[BaseModel], str]]:
    """The models a field's value holds, with how their keys are reached ('' , '[]' or '.<name>')."""
    origin, args = typing.get_origin(annotation), typing.get_args(annotation)
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return [(annotation, "")]
    if origin is typing.Annotated:
        return _nested(args[0])
    if origin is list:
        return [(m, "[]" + s) for m, s in _nested(args[0])]
    if origin is dict:
        return [(m, ".<name>" + s) for m, s in _nested(args[1])]
    return [n for a in args for n in _nested(a)]  # Optional, Union


def test_the_published_reference_is_the_generated_one():
    """``python -m msam_torch.config.keys > docs/config-keys.md`` after a change of the schema."""
    assert PAGE.read_text() == markdown()


def test_every_key_of_the_schema_is_in_the_reference():
    page = PAGE.read_text()
    expected = keys(Config)
    assert {"model.quantities", "model.quantities.<name>.quantity", "adaptation.simulation.input_hold",
            "model.equations[].components[].theta", "data.train.start"} <= set(expected)
    missing = [k for k in expected if f"| `{k}` |" not in page]
    assert missing == []
    assert [k for k, *_ in rows()] == expected  # the same keys, in the same order
    assert all(meaning for *_, meaning in rows())  # every key says what it means
