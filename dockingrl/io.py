"""Writing results whole or not at all, and the files dockingrl reads back: written with a
format version and a sha256 of their bytes, read back checked and without running code."""

from __future__ import annotations

import hashlib
import io
import json
import math
import os
import pickle
import re
import tempfile
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from typing import Any

import torch

#: the command that converts files of an older format
UPGRADE_COMMAND = "dockingrl upgrade"
#: the ZIP comment that ends an artefact: this prefix, then the sha256 of the bytes before it
_HASH_PREFIX = b"dockingrl-sha256:"
_HASH_RE = re.compile(rb"dockingrl-sha256:([0-9a-f]{64})\Z")
_ZIP_END = b"PK\x05\x06"
_ZIP_END_SIZE = 22
_ZIP_START = b"PK\x03\x04"


class ArtifactError(ValueError):
    """A file dockingrl reads back that is missing, damaged, of another kind or of an older
    format; the message is one line naming the file and what is wrong."""


def atomic_write(path: str | Path, write: Callable[[Path], None]) -> Path:
    """Call ``write(tmp_path)`` then move the file onto ``path`` in one rename, so that a crash
    leaves either the old file or the new one, never half of one. The file gets the mode a
    plain ``open`` would give it (``0o666`` less the umask)."""
    path = Path(path)
    blocker = file_in_the_way(path.parent)
    if blocker is not None:
        raise NotADirectoryError(f"{path}: cannot be written ({blocker} is a file)")
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=path.suffix, dir=path.parent)
    try:
        os.fchmod(fd, 0o666 & ~_umask())
        os.close(fd)
        write(Path(tmp))
        fsync_path(tmp)  # the bytes on disk before the name points at them (a power cut)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    fsync_path(path.parent)
    return path


def sync_tree(folder: str | Path) -> None:
    """Flush every file under ``folder``, and the folders, to disk: what a folder written and
    then renamed into place needs before anything points at it."""
    folder = Path(folder)
    for path in sorted(folder.rglob("*"), reverse=True):
        fsync_path(path)
    fsync_path(folder)


def fsync_path(path: str | Path) -> None:
    """``fsync`` a file or a folder; a file system that cannot sync a folder is let be."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    except OSError:
        if not os.path.isdir(path):
            raise
    finally:
        os.close(fd)


def _umask() -> int:
    """The process's umask, read without changing it where Linux shows it."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    except OSError:
        pass
    mask = os.umask(0o077)
    os.umask(mask)
    return mask


def write_json(path: str | Path, data: Any) -> Path:
    """Atomically write ``data`` as indented JSON."""
    text = json.dumps(data, indent=2, sort_keys=False, default=_jsonable)
    return atomic_write(path, lambda tmp: tmp.write_text(text + "\n"))


def file_in_the_way(folder: str | Path) -> Path | None:
    """The file that stops ``folder`` from being made or written into: ``folder`` itself, or
    the nearest existing path above it, when that is not a folder; ``None`` otherwise."""
    path = Path(folder)
    found = next((p for p in (path, *path.parents) if p.exists()), None)
    return found if found is not None and not found.is_dir() else None


def _jsonable(value: Any) -> Any:
    if hasattr(value, "tolist"):
        return value.tolist()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"cannot write {type(value).__name__} as JSON")


# -- artefacts -------------------------------------------------------------------------------


def artifact_bytes(payload: Mapping) -> bytes:
    """The bytes of an artefact holding ``payload`` (a dict with a ``"format"``, of tensors,
    numbers, strings, lists and dicts): PyTorch's file of it (``torch.load(...,
    weights_only=True)`` reads it), whose ZIP comment is the sha256 of all the bytes before
    the comment. Raises ``TypeError`` for a payload that would not load weights-only."""
    if not isinstance(payload, Mapping) or not isinstance(payload.get("format"), str):
        raise TypeError("an artefact's payload is a dict with a 'format' string")
    buffer = io.BytesIO()
    torch.save(dict(payload), buffer)
    data = bytearray(buffer.getvalue())
    end = len(data) - _ZIP_END_SIZE
    if data[end : end + 4] != _ZIP_END or data[-2:] != b"\x00\x00":
        raise RuntimeError("torch.save wrote a file without a plain ZIP end record")
    try:
        torch.load(io.BytesIO(bytes(data)), map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as exc:
        raise TypeError(f"the payload would not load weights-only: {first_line(exc)}") from None
    comment_size = len(_HASH_PREFIX) + 64
    data[-2:] = comment_size.to_bytes(2, "little")
    return bytes(data) + _HASH_PREFIX + hashlib.sha256(data).hexdigest().encode()


def save_artifact(path: str | Path, payload: Mapping) -> Path:
    """Write :func:`artifact_bytes` of ``payload`` to ``path`` atomically."""
    data = artifact_bytes(payload)
    return atomic_write(path, lambda tmp: tmp.write_bytes(data))


def read_artifact(path: str | Path, what: str, format: str, old: Iterable[str] = ()) -> dict:
    """The payload of the artefact at ``path`` written by :func:`save_artifact` in ``format``,
    its hash checked and loaded weights-only. ``what`` names the kind of file in messages
    (``"dockingrl policy file"``); a file of a format in ``old`` is refused with the command
    that converts it. Raises :class:`ArtifactError`."""
    path = Path(path)
    data = _read_file(path, what)
    digest = _stored_hash(data)
    if digest is None:
        found = _unpickle(path, data, what).get("format")
        if found == format:
            raise ArtifactError(
                f"{path}: {what} with no content hash at its end: damaged (truncated, or "
                "rewritten by another program)"
            )
        raise _format_error(path, found, what, format, old)
    _check_hash(path, data, digest)
    payload = _unpickle(path, data, what)
    if payload.get("format") != format:
        raise _format_error(path, payload.get("format"), what, format, old)
    return payload


def read_old_artifact(path: str | Path, what: str) -> dict:
    """The payload of the file at ``path`` whatever its format, loaded weights-only (its hash
    checked where it has one), for the command that converts older formats."""
    path = Path(path)
    data = _read_file(path, what)
    digest = _stored_hash(data)
    if digest is not None:
        _check_hash(path, data, digest)
    return _unpickle(path, data, what)


def read_to_upgrade(path: str | Path, what: str, format: str, old: Iterable[str]) -> dict | None:
    """The payload of the ``what`` at ``path`` (:func:`read_old_artifact`) when its format is
    one of the older ``old``, to convert; ``None`` when it is ``format`` already. Raises
    :class:`ArtifactError` for any other format."""
    payload = read_old_artifact(path, what)
    found = payload.get("format")
    if found == format:
        return None
    if found not in tuple(old):
        raise ArtifactError(f"{path}: not a {what}: its format is {found!r}")
    return payload


def upgrade_message(path: str | Path, what: str, found: str) -> str:
    """The one line refusing ``path``, a ``what`` of the older format ``found``."""
    return (
        f"{path}: {what} of the older format {found}; convert it once with: "
        f"{UPGRADE_COMMAND} {path}"
    )


def _format_error(
    path: Path, found: Any, what: str, format: str, old: Iterable[str]
) -> ArtifactError:
    if found in tuple(old):
        return ArtifactError(upgrade_message(path, what, found))
    shown = repr(found) if isinstance(found, str) else "none"
    return ArtifactError(f"{path}: not a {what}: its format is {shown}, expected {format}")


def _check_hash(path: Path, data: bytes, digest: str) -> None:
    if hashlib.sha256(data[: -len(_HASH_PREFIX) - 64]).hexdigest() != digest:
        raise ArtifactError(
            f"{path}: content hash mismatch: the file was damaged or changed after dockingrl "
            "wrote it"
        )


def _read_file(path: Path, what: str) -> bytes:
    if not path.exists():
        raise ArtifactError(f"{path}: no such file (expected a {what})")
    if path.is_dir():
        raise ArtifactError(f"{path}: is a directory, not a {what}")
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise ArtifactError(f"{path}: cannot be read: {exc.strerror}") from None
    if not data:
        raise ArtifactError(f"{path}: is empty, not a {what}")
    if not data.startswith(_ZIP_START):
        kind = "a text file" if _is_text(data) else "not a PyTorch file"
        raise ArtifactError(f"{path}: not a {what} ({kind})")
    return data


def _is_text(data: bytes) -> bool:
    try:
        data[:4096].decode("utf-8")
    except UnicodeDecodeError:
        return False
    return True


def _stored_hash(data: bytes) -> str | None:
    """The sha256 stored in ``data``'s ZIP comment, ``None`` where it ends without one, or
    ``""`` (which no hash equals) where the ZIP end record before the comment is damaged."""
    match = _HASH_RE.search(data[-len(_HASH_PREFIX) - 64 :])
    if match is None:
        return None
    comment_size = len(_HASH_PREFIX) + 64
    end = len(data) - comment_size - _ZIP_END_SIZE
    record = data[end : end + _ZIP_END_SIZE]
    if record[:4] != _ZIP_END or int.from_bytes(record[-2:], "little") != comment_size:
        return ""
    return match.group(1).decode()


def _unpickle(path: Path, data: bytes, what: str) -> dict:
    try:
        payload = torch.load(io.BytesIO(data), map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as exc:
        if "weights only" in str(exc).lower():
            raise ArtifactError(
                f"{path}: refused: it holds Python objects other than tensors, numbers, "
                f"strings, lists and dicts, which could run code when loaded ({what} expected)"
            ) from None
        raise ArtifactError(f"{path}: damaged {what}: {first_line(exc)}") from None
    except Exception:  # a damaged ZIP or pickle fails in many ways
        raise ArtifactError(f"{path}: damaged or truncated, not a readable {what}") from None
    if not isinstance(payload, dict):
        raise ArtifactError(f"{path}: not a {what}: it holds a {type(payload).__name__}")
    return payload


def first_line(exc: BaseException) -> str:
    """``exc``'s message on one line: its first line, and the next where the first ends with
    a colon (torch's ``Error(s) in loading state_dict for X:`` then what differs), at most 200
    characters."""
    text = [line.strip() for line in str(exc).strip().splitlines() if line.strip()]
    line = text[0] if text else type(exc).__name__
    if line.endswith(":") and len(text) > 1:
        line += " " + text[1]
    return line if len(line) <= 200 else line[:197] + "..."


def require_keys(path: str | Path, payload: Mapping, what: str, keys: Iterable[str]) -> None:
    """Raise :class:`ArtifactError` naming the ``keys`` that ``payload`` lacks."""
    missing = [k for k in keys if k not in payload]
    if missing:
        raise ArtifactError(f"{path}: {what} without {', '.join(missing)}")


def require_finite(path: str | Path, name: str, tree: Any) -> None:
    """Raise :class:`ArtifactError` where the tensors of ``tree`` (a tensor, or dicts and lists
    of them) hold a NaN or an infinity: a whole file of dockingrl's can still hold the
    numbers of a run that diverged, or edited ones."""
    bad = [
        key for key, t in _tensors(name, tree) if t.is_floating_point() and not t.isfinite().all()
    ]
    if bad:
        raise ArtifactError(f"{path}: non-finite numbers in {', '.join(bad[:3])}")


def is_count(value: Any, least: int = 0) -> bool:
    """Whether ``value`` read back from a file is an integer >= ``least`` (a bool is not)."""
    return isinstance(value, int) and not isinstance(value, bool) and value >= least


def is_finite_number(value: Any) -> bool:
    """Whether ``value`` read back from a file is a finite number (a bool is not)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


#: a field of a file read back: what it must be, in words, and the test of a value
FieldRule = tuple[str, Callable[[Any], bool]]


def first_bad_field(rules: Mapping[str, FieldRule], values: Mapping) -> str:
    """The first of ``values``'s fields that ``rules`` name and that fails its rule, as
    ``"frames must be an integer >= 0 (got 'abc')"`` (the value cut at 80 characters); ""
    if none. A field ``values`` lacks is not checked here (:func:`require_keys`)."""
    for key, (what, ok) in rules.items():
        if key in values and not ok(values[key]):
            return f"{key} must be {what} (got {values[key]!r:.80})"
    return ""


def _tensors(key: str, tree: Any):
    if isinstance(tree, torch.Tensor):
        yield key, tree
    elif isinstance(tree, Mapping):
        for k, v in tree.items():
            yield from _tensors(f"{key}.{k}", v)
    elif isinstance(tree, (list, tuple)):
        for i, v in enumerate(tree):
            yield from _tensors(f"{key}[{i}]", v)


# -- folders written by other libraries --------------------------------------------------------


def folder_manifest(folder: str | Path) -> dict[str, str]:
    """The sha256 of each file under ``folder``, by its path relative to it (``/``-separated).
    Raises :class:`ArtifactError` for a link or anything but a plain file or folder."""
    folder = Path(folder)
    manifest = {}
    for path in sorted(folder.rglob("*")):
        name = path.relative_to(folder).as_posix()
        if path.is_symlink() or not (path.is_file() or path.is_dir()):
            raise ArtifactError(f"{path}: a link or special file in {folder}")
        if path.is_file():
            manifest[name] = _sha256_file(path)
    return manifest


def check_folder(
    folder: str | Path, manifest: Any, suffixes: tuple[str, ...], source: str | Path
) -> None:
    """Check that ``folder`` holds exactly the files of ``manifest`` (from
    :func:`folder_manifest`, recorded in ``source``) with their hashes, and only files ending
    in ``suffixes``. Raises :class:`ArtifactError`."""
    folder = Path(folder)
    if not isinstance(manifest, dict) or not all(
        isinstance(k, str) and isinstance(v, str) for k, v in manifest.items()
    ):
        raise ArtifactError(f"{source}: its manifest of {folder.name}/ is not a dict of hashes")
    if not folder.is_dir():
        raise ArtifactError(f"{folder}: missing (listed in {source})")
    for name in manifest:
        if not name.endswith(suffixes) or ".." in name.split("/") or name.startswith("/"):
            raise ArtifactError(
                f"{source}: lists {name!r} in {folder.name}/, which holds only "
                f"{' and '.join(suffixes)} files"
            )
    found = folder_manifest(folder)
    extra = sorted(set(found) - set(manifest))
    missing = sorted(set(manifest) - set(found))
    if extra or missing:
        parts = ([f"unlisted {', '.join(extra)}"] if extra else []) + (
            [f"missing {', '.join(missing)}"] if missing else []
        )
        raise ArtifactError(f"{folder}: does not match {source}: {'; '.join(parts)}")
    changed = sorted(k for k in manifest if manifest[k] != found[k])
    if changed:
        raise ArtifactError(
            f"{folder}: content hash mismatch of {', '.join(changed)}: damaged or changed "
            "after dockingrl wrote it"
        )


def _sha256_file(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()
