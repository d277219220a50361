"""Atomic file writing: a killed run never leaves a half-written file that a later run trusts."""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

import numpy as np

from core.errors import InputError


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it over ``path`` if the block succeeds.

    The temporary keeps the final suffix so that writers which pick a format by extension
    (trimesh, PIL, numpy) behave. On error the temporary is removed and ``path`` is untouched.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(
        prefix=f".{path.stem}.", suffix=f".tmp{path.suffix}", dir=path.parent
    )
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        os.chmod(tmp_path, 0o666 & ~_umask())  # mkstemp makes 0600; give the usual mode
        os.replace(tmp_path, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            tmp_path.unlink()
        raise


@contextlib.contextmanager
def atomic_open(path: str | os.PathLike, mode: str = "w", **kwargs: Any) -> Iterator[IO]:
    """``open`` for writing, atomically: the file appears complete or not at all."""
    with atomic_path(path) as tmp, open(tmp, mode, **kwargs) as f:
        yield f
        f.flush()
        os.fsync(f.fileno())


def write_json(path: str | os.PathLike, data: Any) -> None:
    """Write ``data`` as indented JSON, atomically. numpy scalars and arrays are converted."""
    with atomic_open(path, "w", encoding="utf-8") as f:
        json.dump(data, f, indent=2, default=json_default)
        f.write("\n")


def write_npz(path: str | os.PathLike, **arrays: np.ndarray) -> None:
    """``np.savez_compressed``, atomically."""
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        np.savez_compressed(f, **arrays)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def json_default(obj: Any) -> Any:
    """``json.dump``'s ``default``: numpy scalars and arrays, and paths, as plain JSON."""
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


def read_input_bytes(path: str | os.PathLike, kind: str) -> bytes:
    """The whole of an input file, or an :class:`InputError` naming it: missing, a folder,
    unreadable or empty. ``kind`` names what was expected ("a BVH file", "a glTF file")."""
    try:
        with open(path, "rb") as f:
            raw = f.read()
    except FileNotFoundError:
        raise InputError("no such file", path) from None
    except IsADirectoryError:
        raise InputError(f"is a directory, not {kind}", path) from None
    except OSError as exc:
        raise InputError(f"cannot read: {exc.strerror or exc}", path) from None
    if not raw.strip():
        raise InputError("empty file", path)
    return raw


def read_torch_payload(
    path: str | os.PathLike, formats: str | tuple[str, ...], what: str, missing: str | None = None
) -> dict:
    """A dict saved with ``torch.save`` whose ``"format"`` is one of ``formats``, read with
    ``torch.load(weights_only=True)`` onto the CPU; an :class:`InputError` naming the file when
    it is missing (``missing`` or "no WHAT file here"), unreadable or of another format.
    ``what`` names the kind of file ("Joint2Coarse model", "torch bundle")."""
    import torch  # deferred: core imports without torch

    formats = (formats,) if isinstance(formats, str) else tuple(formats)
    path = Path(path)
    if not path.is_file():
        raise InputError(missing or f"no {what} file here", path)
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises many kinds on corrupt files
        raise InputError(f"cannot read {what}: {exc}", path) from None
    if not isinstance(payload, dict) or payload.get("format") not in formats:
        raise InputError(f"not a {what} file (expected format {' or '.join(formats)})", path)
    return payload
