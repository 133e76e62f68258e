"""This project's earlier argument names, kept as documented aliases of TorchRL's names.

The factories take the names of the TorchRL class they build (``spec``, ``num_cells``,
``value_network_update_interval``...); where this project first used another name, that name
still works, and giving both is refused.
"""

from __future__ import annotations

from typing import TypeVar

__all__ = ["resolve_alias"]

T = TypeVar("T")


def resolve_alias(name: str, value: T | None, alias: str, alias_value: T | None) -> T | None:
    """``value``, or ``alias_value`` when only the alias was given; both given: ``TypeError``."""
    if alias_value is None:
        return value
    if value is not None:
        raise TypeError(f"{alias}= is an alias of {name}=; pass one of them")
    return alias_value
