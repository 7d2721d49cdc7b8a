"""One typed, checked value of a SPEC: a scenario setting or a parameter a study varies.

A :class:`Setting` turns what YAML gave (``1``, ``'1'``, ``1.0e3``) into the one type
the scenario computes with, or refuses it with a message that names the field::

    Setting(float, 60.0, minimum=0.0, doc='record length [s]').value(x, 'scenario.duration_s')
"""

from dataclasses import dataclass
import math
from typing import Any

REQUIRED = object()     #: default of a setting the SPEC must give


@dataclass(frozen=True)
class Setting:
    """A value of type ``kind`` (float, int, str, bool), with optional bounds or choices."""

    kind: type
    default: Any = None
    choices: tuple = ()
    minimum: float | None = None
    maximum: float | None = None
    doc: str = ''

    def value(self, raw, where: str):
        """Return ``raw`` converted to :attr:`kind`; ValueError naming ``where`` otherwise."""
        if raw is None:
            if self.default is REQUIRED:
                raise ValueError(f'{where}: required ({self.doc or self.kind.__name__})')
            return self.default
        if self.kind is bool:
            if not isinstance(raw, bool):
                raise ValueError(f'{where}: expected true or false, got {raw!r}')
            return raw
        if self.kind in (int, float):
            raw = _yaml_number(raw)
            if isinstance(raw, bool) or not isinstance(raw, (int, float)):
                raise ValueError(f'{where}: expected a number, got {raw!r}')
            if self.kind is int and raw != int(raw):
                raise ValueError(f'{where}: expected an integer, got {raw!r}')
            val = self.kind(raw)
            if not math.isfinite(val):
                raise ValueError(f'{where}: expected a finite number, got {raw!r}')
            if self.minimum is not None and val < self.minimum:
                raise ValueError(f'{where}: {val!r} is below the minimum {self.minimum!r}')
            if self.maximum is not None and val > self.maximum:
                raise ValueError(f'{where}: {val!r} is above the maximum {self.maximum!r}')
        else:
            val = str(raw) if isinstance(raw, (str, int)) and not isinstance(raw, bool) else None
            if val is None:
                raise ValueError(f'{where}: expected text, got {raw!r}')
        if self.choices and val not in self.choices:
            raise ValueError(f'{where}: {val!r} is not one of {", ".join(map(str, self.choices))}')
        return val


def _yaml_number(raw):
    """``'1e6'`` -> 1e6: PyYAML reads an exponent without a dot or sign as text."""
    if isinstance(raw, str):
        try:
            return float(raw)
        except ValueError:
            return raw
    return raw


def check_mapping(raw, known: dict, where: str) -> dict:
    """Check a mapping against ``known`` (name -> Setting); return it complete with defaults."""
    if raw is None:
        raw = {}
    if not isinstance(raw, dict):
        raise ValueError(f'{where}: expected a mapping of name: value, got {type(raw).__name__}')
    unknown = sorted(set(raw) - set(known))
    if unknown:
        raise ValueError(f'{where}.{unknown[0]}: unknown; known: {", ".join(sorted(known))}')
    return {name: setting.value(raw.get(name), f'{where}.{name}')
            for name, setting in known.items()}
