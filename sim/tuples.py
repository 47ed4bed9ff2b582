"""A file's fixed-length lists as the tuples the simulator's models declare (the length checked here:
a wrong one is a ValueError, which the readers report with the field)."""

from __future__ import annotations

from collections.abc import Iterable
from typing import TypeVar

T = TypeVar("T")


def pair(values: Iterable[T]) -> tuple[T, T]:
    first, second = values
    return first, second


def triple(values: Iterable[T]) -> tuple[T, T, T]:
    x, y, z = values
    return x, y, z
