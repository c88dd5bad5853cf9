"""Typed, validated access to YAML spec mappings, shared by every spec kind of the simulator.

Errors name the file and the dotted key path and say what was expected, one line, as ``SpecError``
(exit code 2 in the CLI). Unknown keys are errors: a typo must not silently fall back to a default.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import yaml

from vdm_aero.errors import SpecError


def parse_yaml(text: str, origin: str) -> Any:
    """YAML text → data, or one SpecError naming the origin and the line."""
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f" at line {mark.line + 1}" if mark is not None else ""
        raise SpecError(f"{origin}: YAML syntax error{where}") from None


def read_yaml_file(path: Path, what: str = "spec") -> Any:
    """Read and parse a YAML file, with one-line errors naming the file."""
    try:
        text = path.read_text()
    except OSError as e:
        raise SpecError(f"{path}: cannot read {what}: {e.strerror or e}") from None
    return parse_yaml(text, str(path))


class SpecReader:
    """Typed access to one mapping of the spec with errors that name the file and the key path."""

    def __init__(self, data: Any, origin: str, path: str) -> None:
        if not isinstance(data, Mapping):
            raise SpecError(f"{origin}: {path or 'spec'}: expected a mapping, got {type(data).__name__}")
        self.data = data
        self.origin = origin
        self.path = path
        self.used: set[str] = set()

    def key(self, k: str) -> str:
        return f"{self.path}.{k}" if self.path else k

    def fail(self, k: str, msg: str) -> SpecError:
        return SpecError(f"{self.origin}: {self.key(k)}: {msg}")

    def raw(self, k: str, default: Any = ...) -> Any:
        self.used.add(k)
        if k not in self.data:
            if default is ...:
                raise self.fail(k, "missing required key")
            return default
        return self.data[k]

    def sub(self, k: str, default: Any = ...) -> SpecReader:
        return SpecReader(self.raw(k, default), self.origin, self.key(k))

    def num(
        self, k: str, default: Any = ..., *, positive: bool = False, lo: float | None = None, hi: float | None = None
    ) -> float:
        return spec_number(self, k, self.raw(k, default), positive=positive, lo=lo, hi=hi)

    def integer(self, k: str, default: Any = ..., *, lo: int = 0, hi: int | None = None) -> int:
        v = self.raw(k, default)
        if isinstance(v, bool) or not isinstance(v, int):
            raise self.fail(k, f"expected an integer, got {v!r}")
        if v < lo or (hi is not None and v > hi):
            raise self.fail(k, f"must be in [{lo}, {hi if hi is not None else '∞'}], got {v}")
        return int(v)

    def text(self, k: str, default: Any = ...) -> str:
        v = self.raw(k, default)
        if not isinstance(v, str):
            raise self.fail(k, f"expected a string, got {v!r}")
        return v

    def seq(self, k: str, default: Any = ...) -> Sequence[Any]:
        v = self.raw(k, default)
        if not isinstance(v, list | tuple):
            raise self.fail(k, f"expected a list, got {v!r}")
        return v

    def numbers(self, k: str, default: Any = ..., *, n: int | None = None) -> tuple[float, ...]:
        vals = self.seq(k, default)
        if n is not None and len(vals) != n:
            raise self.fail(k, f"expected {n} numbers, got {len(vals)}")
        return tuple(spec_number(self, k, v) for v in vals)

    def finish(self) -> None:
        unknown = sorted(set(self.data) - self.used, key=str)
        if unknown:
            raise self.fail(str(unknown[0]), f"unknown key (allowed: {', '.join(sorted(self.used))})")


def spec_number(
    r: SpecReader, k: str, v: Any, *, positive: bool = False, lo: float | None = None, hi: float | None = None
) -> float:
    if isinstance(v, str):  # YAML 1.1 reads 1e-3 as a string
        try:
            v = float(v)
        except ValueError:
            raise r.fail(k, f"expected a number, got {v!r}") from None
    if isinstance(v, bool) or not isinstance(v, int | float):
        raise r.fail(k, f"expected a number, got {v!r}")
    x = float(v)
    if not math.isfinite(x):
        raise r.fail(k, f"must be finite, got {v!r}")
    if positive and x <= 0:
        raise r.fail(k, f"must be > 0, got {v!r}")
    if (lo is not None and x < lo) or (hi is not None and x > hi):
        raise r.fail(k, f"must be in [{lo}, {hi}], got {v!r}")
    return x


# ------------------------------------------------------------------------------------------- design
