"""Named plugins: a name -> class or factory table, filled by explicit registration or by entry point.

The region plugins (entry-point group ``lidar_weather_sim.regions``), the ray casting backends
and weather_filter's filter methods are each one :class:`Registry`.
"""

from __future__ import annotations

from importlib.metadata import EntryPoint, entry_points
from typing import Generic, TypeVar

T = TypeVar("T")


class Registry(Generic[T]):
    """Objects by name: :meth:`register` ones first, then those of the entry-point ``group`` (if any),
    loaded when asked for.

    ``kind`` names what the registry holds in its errors ("region", "filter method"); ``error`` is the
    exception type :meth:`get` raises for an unknown name (the one the callers catch).
    """

    def __init__(self, kind: str, group: str | None = None, error: type[Exception] = ValueError) -> None:
        self.kind = kind
        self.group = group
        self.error = error
        self._registered: dict[str, T] = {}
        self._entry_points: dict[str, EntryPoint] | None = None

    def register(self, name: str, obj: T) -> None:
        """Add ``name`` (or replace it); it shadows an entry point of the same name."""
        self._registered[name] = obj

    def names(self) -> list[str]:
        """Without an entry-point group: the registered names in registration order. With one: the
        registered and entry-point names, sorted (entry points come in no defined order)."""
        if self.group is None:
            return list(self._registered)
        return sorted(set(self._registered) | set(self._installed()))

    def _installed(self) -> dict[str, EntryPoint]:
        """The group's entry points by name, read once: scanning the installed packages' metadata costs
        ~20 ms, and a gap search builds its regions hundreds of times."""
        if self._entry_points is None:
            self._entry_points = {ep.name: ep for ep in entry_points(group=self.group)} if self.group else {}
        return self._entry_points

    def get(self, name: str) -> T:
        """The object registered as ``name``, else the entry point ``name`` loaded; an unknown name raises
        ``error`` naming the kind and listing the known names."""
        if name in self._registered:
            return self._registered[name]
        if name in self._installed():
            return self._installed()[name].load()
        raise self.error(f"unknown {self.kind} '{name}' (available: {', '.join(self.names()) or 'none'})")
