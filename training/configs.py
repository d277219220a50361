"""What the training configs share: a plain-dict form that a ``weights_only`` checkpoint holds."""

from __future__ import annotations

from dataclasses import asdict, fields
from typing import Any

from core.errors import InputError


class PlainConfig:
    """Mixin for frozen config dataclasses: ``to_dict`` / ``from_dict`` with tuples as lists.

    ``kind`` names the stage in messages (set it on the class, outside the dataclass fields).
    """

    kind = "training"

    def to_dict(self) -> dict[str, Any]:
        """Plain types only (tuples as lists): safe inside a ``weights_only`` checkpoint."""
        return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self).items()}

    @classmethod
    def from_dict(cls, data: dict):
        names = {f.name for f in fields(cls)}
        unknown = set(data) - names
        if unknown:
            raise InputError(f"unknown {cls.kind} config keys {sorted(unknown)}")
        return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in data.items()})
