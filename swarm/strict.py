"""The base of every config model (unknown keys refused, values frozen, numbers numbers),
and the merge of config layers."""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, ConfigDict, model_validator

_NUMBERS = (float, int, float | None, int | None)


class Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    @model_validator(mode="before")
    @classmethod
    def _numbers_are_numbers(cls, data: Any) -> Any:
        """A number field takes a number, not ``true`` (which pydantic reads as 1) or a
        string (``"5"``): a YAML typo must not fly as a different value."""
        if isinstance(data, dict):
            for name, f in cls.model_fields.items():
                v = data.get(name)
                if f.annotation in _NUMBERS and (isinstance(v, bool | str)):
                    raise ValueError(f"{name}: must be a number, got {v!r}")
        return data


def merge(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    """``over`` on top of ``base``: dicts merge key by key, anything else replaces."""
    out = dict(base)
    for k, v in over.items():
        out[k] = merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out
