"""The results.json codec: schema name, JSON-number sanitiser, validating field reader.

The types of :mod:`vibro_model.results` turn themselves into the contract's keys
(docs/recording-format.md) with the helpers here; :mod:`vibro_io.results_file` writes and reads the
file (every results.json vibro writes or reads goes through it). A document read back is validated: a
missing key, a wrong type or an unknown plate or direction raises :class:`ResultsError` naming the file
and the key (``flights[3].t_start``).
"""

from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

import numpy as np

from vibro_model.errors import RecordingError

SCHEMA = "vibro.results/1"


class ResultsError(RecordingError):
    """A results document (file or mapping) that does not follow the contract; the message names the key."""


# ---------------------------------------------------------------- JSON numbers
def json_number(x: Any) -> Any:
    """A JSON-safe scalar: numpy scalars to Python, NaN/inf to None (JSON null: unknown), bools kept."""
    if x is None:
        return None
    if isinstance(x, (bool, np.bool_)):
        return bool(x)
    if isinstance(x, (int, np.integer)):
        return int(x)
    x = float(x)
    return x if math.isfinite(x) else None


def json_value(obj: Any) -> Any:
    """Plain JSON types, recursively: mappings (keys to str), sequences and arrays to lists, numbers through
    :func:`json_number`; strings and None as they are."""
    if isinstance(obj, Mapping):
        return {str(k): json_value(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple, np.ndarray)):
        return [json_value(v) for v in obj]
    if obj is None or isinstance(obj, (bool, np.bool_, int, np.integer, float, np.floating)):
        return json_number(obj)
    return obj


def nan_if_none(x: float | None) -> float:
    """None (unknown) as NaN, for float64 message fields."""
    return math.nan if x is None else float(x)


def none_if_nan(x: Any) -> float | None:
    """A finite float, or None for NaN/inf/None."""
    return json_number(None if x is None else float(x))


# ---------------------------------------------------------------- reading with validation
class Fields:
    """Typed access to one mapping of a results document; every error names ``where.key``."""

    def __init__(self, data: Any, where: str):
        if not isinstance(data, Mapping):
            raise ResultsError(f"{where}: expected a mapping, got {type(data).__name__}")
        self.data = data
        self.where = where

    def value(self, key: str, required: bool) -> Any:
        """The raw value of ``key`` (None when absent and not required)."""
        if key not in self.data:
            if required:
                raise ResultsError(f"{self.where}.{key}: missing")
            return None
        return self.data[key]

    def number(self, key: str, required: bool = True, nullable: bool = True) -> float | None:
        """A finite number (int or float, not bool), or None where null is allowed."""
        value = self.value(key, required)
        if value is None:
            if key in self.data and not nullable:
                raise ResultsError(f"{self.where}.{key}: must be a number, got null")
            return None
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise ResultsError(f"{self.where}.{key}: must be a finite number, got {value!r}")
        return float(value)

    def integer(self, key: str, required: bool = True, nullable: bool = False) -> int | None:
        value = self.value(key, required)
        if value is None and (nullable or key not in self.data):
            return None
        if isinstance(value, bool) or not isinstance(value, int):
            raise ResultsError(f"{self.where}.{key}: must be an integer, got {value!r}")
        return int(value)

    def boolean(self, key: str, default: bool) -> bool:
        value = self.value(key, False)
        if value is None:
            return default
        if not isinstance(value, bool):
            raise ResultsError(f"{self.where}.{key}: must be true or false, got {value!r}")
        return value

    def string(self, key: str, required: bool = True, choices: Sequence[str] | None = None,
               default: str | None = None) -> str | None:
        value = self.value(key, required)
        if value is None:
            return default
        if not isinstance(value, str):
            raise ResultsError(f"{self.where}.{key}: must be a string, got {value!r}")
        if choices is not None and value not in choices:
            raise ResultsError(f"{self.where}.{key}: must be one of {', '.join(choices)}, got {value!r}")
        return value

    def mapping(self, key: str, required: bool = True) -> "Fields | None":
        value = self.value(key, required)
        return None if value is None else Fields(value, f"{self.where}.{key}")

    def rows(self, key: str, required: bool = True) -> list["Fields"]:
        """A list of mappings, each as :class:`Fields` named ``where.key[i]``."""
        value = self.value(key, required)
        if value is None:
            return []
        if not isinstance(value, list):
            raise ResultsError(f"{self.where}.{key}: must be a list, got {type(value).__name__}")
        return [Fields(row, f"{self.where}.{key}[{i}]") for i, row in enumerate(value)]

    def numbers_by_name(self, key: str, required: bool = True) -> dict[str, float | None] | None:
        """A mapping name -> number or null (finding parameters)."""
        sub = self.mapping(key, required)
        if sub is None:
            return None
        return {str(k): sub.number(str(k)) for k in sub.data}

    def extras(self, known: Sequence[str]) -> dict[str, Any]:
        """The keys not in ``known``, as written (kept through a read/write round trip)."""
        return {k: v for k, v in self.data.items() if k not in known}
