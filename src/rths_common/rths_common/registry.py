"""Registries: one table per extension point, from the name a user writes to what it does.

A lab extends rths at a few points: a specimen, a ground-motion record format, a
compensator scheme, an adaptive method, a bridge backend.  Each point is one
:class:`Registry`, owned by the lowest package that uses its names
(``rths_numerical.specimens.SPECIMENS``, ``rths_numerical.ground_motion.FORMATS``,
``rths_compensator.schemes.SCHEMES``, ``rths_compensator.adaptive.METHODS``,
``rths_actuator_bridge.bridge.BACKENDS``).  An entry is an object carrying the
behaviour (a class, a function, a dataclass of physics) and a one-line ``summary``.

Code chooses behaviour by looking a name up (:meth:`Registry.entry`), never by
comparing the name to a string; the parameter schema's allowed values
(:class:`rths_common.params.Spec` ``choices``), argparse ``choices=``, the YAML
comments and the docs tables are all made from :meth:`Registry.names`, and
``rths_bringup/test/test_registries.py`` fails when any of them drifts.
docs/extending.md shows how to add an entry.
"""

from collections.abc import Iterator, Mapping


class Registry(Mapping):
    """Names -> entries of one extension point, in the order they were added.

    ``what`` names the point in errors (``'specimen'``); ``key`` is the
    parameter or option the user writes the name in (``'specimen'``), for the fix.
    """

    def __init__(self, what: str, key: str, entries: dict | None = None):
        """Start the table of ``what`` (chosen by ``key``) with ``entries``."""
        self.what = what
        self.key = key
        self._entries: dict = {}
        for name, entry in (entries or {}).items():
            self.add(name, entry)

    def add(self, name: str, entry):
        """Add ``entry`` under ``name`` (ValueError if the name is taken); return ``entry``."""
        if not isinstance(name, str) or not name:
            raise ValueError(f'{self.what} registry: a name must be a non-empty string, '
                             f'got {name!r}')
        if name in self._entries:
            raise ValueError(f'{self.what} registry: {name!r} is already registered')
        if not str(getattr(entry, 'summary', '') or '').strip():
            raise ValueError(f'{self.what} registry: entry {name!r} needs a one-line summary')
        self._entries[name] = entry
        return entry

    def __getitem__(self, name):
        """Return the entry of ``name`` (KeyError if unknown; :meth:`entry` explains)."""
        return self._entries[name]

    def __contains__(self, name) -> bool:
        """Return True if ``name`` is registered (False for any other value, a list too)."""
        try:
            return name in self._entries
        except TypeError:                     # unhashable: a YAML list or mapping
            return False

    def __iter__(self) -> Iterator[str]:
        """Iterate over the names in registration order."""
        return iter(self._entries)

    def __len__(self) -> int:
        """Return the number of entries."""
        return len(self._entries)

    def names(self) -> tuple:
        """Return the names, in registration order (the allowed values of :attr:`key`)."""
        return tuple(self._entries)

    def entry(self, name, where: str = ''):
        """Return the entry of ``name``; ValueError naming the choices if it is unknown."""
        try:
            return self._entries[name]
        except (KeyError, TypeError):
            prefix = f'{where}: ' if where else ''
            raise ValueError(f'{prefix}{self.key} = {name!r} is an unknown {self.what}; use '
                             f'one of {", ".join(self._entries)}') from None

    def text(self, sep: str = ' | ') -> str:
        """Return the names joined by ``sep`` (a YAML comment, a help text)."""
        return sep.join(self._entries)

    def summaries(self) -> dict:
        """Return ``{name: summary}``."""
        return {name: str(e.summary) for name, e in self._entries.items()}

    def markdown(self) -> str:
        """Return the docs table of this registry: one row per name with its summary."""
        rows = [f'| `{self.key}` | what it is |', '|---|---|']
        rows += [f'| `{name}` | {summary} |' for name, summary in self.summaries().items()]
        return '\n'.join(rows) + '\n'
