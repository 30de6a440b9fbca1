"""The agent file format: one zip, JSON metadata and raw arrays, nothing pickled.

A saved agent is a zip archive with

- ``meta.json``: ``format_version``, the tl_gym version, the agent class, its
  config (hyperparameters), the formula text, the env id and kwargs, the
  observation and action spaces, the history and the RNG state;
- ``arrays.npz``: the learned arrays by name, read with ``allow_pickle=False``;
- any extra members an agent needs (`SB3Agent` embeds stable-baselines3's own zip).

Writing is atomic: the archive goes to a temporary file in the target's folder,
is flushed and fsynced, then `os.replace` moves it over the target, so a crash
mid-save leaves the old file (or none), never a truncated one.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import tempfile
import zipfile
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from tl_gym.errors import IncompatibleSaveError

FORMAT_VERSION = 1
META = "meta.json"
ARRAYS = "arrays.npz"


def write_archive(
    path: str | Path, meta: Mapping[str, Any], arrays: Mapping[str, np.ndarray], files: Mapping[str, bytes]
) -> Path:
    """Atomically write ``meta``, ``arrays`` and extra ``files`` as a zip at ``path``.

    Returns:
        The path written.
    """
    reserved = {META, ARRAYS} & set(files)
    if reserved:
        raise ValueError(f"extra member names {sorted(reserved)} are reserved")
    buffer = io.BytesIO()
    np.savez(buffer, **{k: np.asarray(v) for k, v in arrays.items()})
    archive_bytes = io.BytesIO()
    with zipfile.ZipFile(archive_bytes, "w", compression=zipfile.ZIP_DEFLATED) as archive:
        archive.writestr(META, json.dumps(meta, indent=1, allow_nan=True))
        archive.writestr(ARRAYS, buffer.getvalue())
        for name, data in files.items():
            archive.writestr(name, data)
    return write_atomic(path, archive_bytes.getvalue())


def write_atomic(path: str | Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` all or nothing (the module docstring's way); the path written.

    The one atomic writer of tl_gym (`atomic_path` for a writer that takes a file name): saved agents,
    history CSVs and the benchmark runner's run files. The file gets the permissions a plain
    ``open(path, "w")`` would give.
    """
    with atomic_path(path) as tmp, tmp.open("wb") as handle:
        handle.write(data)
    return Path(path)


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """A temporary file beside ``path`` to write by name; fsynced and moved over ``path`` when the block succeeds.

    For writers that open a path themselves (stable-baselines3's ``save_replay_buffer``), so that a
    large file streams to disk and still lands all or nothing; the temporary file is removed if the
    block raises.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, name = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    os.close(fd)
    tmp = Path(name)
    try:
        os.chmod(tmp, _file_mode(path))
        yield tmp
        with tmp.open("rb+") as handle:
            os.fsync(handle.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def _file_mode(path: Path) -> int:
    """The permissions a plain ``open(path, "w")`` would give (mkstemp's are owner-only)."""
    if path.exists():
        return path.stat().st_mode & 0o777
    umask = os.umask(0)
    os.umask(umask)
    return 0o666 & ~umask


def read_archive(path: str | Path) -> tuple[dict[str, Any], dict[str, np.ndarray], dict[str, bytes]]:
    """Read a saved agent: ``(meta, arrays, extra files)``.

    Raises:
        IncompatibleSaveError: not an agent file, or written by an incompatible format version.
    """
    path = Path(path)
    try:
        with zipfile.ZipFile(path) as archive:
            names = set(archive.namelist())
            if META not in names or ARRAYS not in names:
                raise IncompatibleSaveError(f"{path} is not a tl_gym agent file (no {META} / {ARRAYS})")
            meta = json.loads(archive.read(META))
            with np.load(io.BytesIO(archive.read(ARRAYS)), allow_pickle=False) as npz:
                arrays = {k: npz[k] for k in npz.files}
            files = {n: archive.read(n) for n in names - {META, ARRAYS}}
    except zipfile.BadZipFile as error:
        raise IncompatibleSaveError(f"{path} is not a tl_gym agent file: {error}") from None
    version = meta.get("format_version")
    if version != FORMAT_VERSION:
        raise IncompatibleSaveError(
            f"{path} has format_version {version!r}; this tl_gym reads version {FORMAT_VERSION}"
        )
    return meta, arrays, files


def check_arrays(saved: Mapping[str, np.ndarray], skeleton: Mapping[str, np.ndarray]) -> None:
    """Check that ``saved`` holds exactly the skeleton's arrays with the same shapes and kinds.

    Raises:
        IncompatibleSaveError: naming the missing, extra or mismatched array.
    """
    missing = sorted(set(skeleton) - set(saved))
    extra = sorted(set(saved) - set(skeleton))
    if missing or extra:
        raise IncompatibleSaveError(f"saved arrays do not match the agent: missing {missing}, unexpected {extra}")
    for name, expected in skeleton.items():
        got = saved[name]
        if got.shape != np.shape(expected):
            raise IncompatibleSaveError(
                f"array {name!r} has shape {got.shape} in the file, the agent expects {np.shape(expected)}"
            )
        if np.asarray(expected).dtype.kind != got.dtype.kind:
            raise IncompatibleSaveError(
                f"array {name!r} has dtype {got.dtype} in the file, the agent expects {np.asarray(expected).dtype}"
            )


def describe_space(space: gym.Space) -> dict[str, Any]:
    """A JSON description of a space, enough to check a new env against a saved agent."""
    if isinstance(space, gym.spaces.Box):
        return {"type": "Box", "shape": list(space.shape), "low": space.low.tolist(), "high": space.high.tolist()}
    if isinstance(space, gym.spaces.Discrete):
        return {"type": "Discrete", "n": int(space.n), "start": int(space.start)}
    if isinstance(space, gym.spaces.Dict):
        return {"type": "Dict", "spaces": {k: describe_space(v) for k, v in space.spaces.items()}}
    return {"type": type(space).__name__, "repr": repr(space)}


def to_json(value: Any) -> Any:
    """Convert numpy scalars and arrays (and tuples) in ``value`` to JSON types."""
    if isinstance(value, Mapping):
        return {str(k): to_json(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [to_json(v) for v in value]
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return value


def is_jsonable(value: Any) -> bool:
    """Whether ``value`` survives a JSON round trip unchanged (after `to_json`)."""
    try:
        return json.loads(json.dumps(to_json(value))) == to_json(value)
    except (TypeError, ValueError):
        return False
