"""Reading and writing the project's files: one clear error per bad file, nothing half-written."""

from __future__ import annotations

import difflib
import errno
import json
import math
import os
import re
import shutil
import stat
import tempfile
import tomllib
from collections.abc import Sequence
from pathlib import Path
from typing import TypeVar

import pydantic

from hlr_lab.errors import DiskFull, InputError

Model = TypeVar("Model", bound=pydantic.BaseModel)
T = TypeVar("T")


class StrictModel(pydantic.BaseModel):
    """A file or section of one: strict types (a number in quotes is refused), no unknown keys, no NaN
    or infinity (docs/formats.md)."""

    model_config = pydantic.ConfigDict(extra="forbid", allow_inf_nan=False, strict=True)


class OpenModel(pydantic.BaseModel):
    """:class:`StrictModel` that keeps keys it does not know: a newer hlr-lab's, read by an older one —
    unless the key looks like a misspelling of one it knows (``exposure_s`` for ``exposures_s``): a value
    the user meant to set would be silently ignored."""

    model_config = pydantic.ConfigDict(extra="allow", allow_inf_nan=False, strict=True)

    @pydantic.model_validator(mode="after")
    def _no_misspelt_keys(self):
        known = list(type(self).model_fields)
        for key in self.model_extra or {}:
            close = difflib.get_close_matches(key, known, n=1, cutoff=0.8)
            if close and key not in known:
                raise ValueError(f"unknown key {key!r}: did you mean {close[0]!r}?")
        return self


# files get the mode an ordinary open() gives (mkstemp's temporaries are private: 0600); read once, at
# import, because reading the umask means setting it
_UMASK = os.umask(0o022)
os.umask(_UMASK)
FILE_MODE = 0o666 & ~_UMASK


def as_pair(values: Sequence[T]) -> tuple[T, T]:
    """A file's two-element list (its model checked the length) as the 2-tuple the code declares."""
    first, second = values
    return first, second


def as_triple(values: Sequence[T]) -> tuple[T, T, T]:
    """A file's three-element list (its model checked the length) as a 3-tuple."""
    x, y, z = values
    return x, y, z


LINK_REFUSED = (
    "is a symbolic link: hlr-lab neither writes nor reads through links; put the file itself there (or give "
    "its real path)"
)
SPECIAL_REFUSED = "is not a regular file (a FIFO, a socket, a device or a folder): give a regular file"


def open_regular(path: Path, flags: int, mode: int = 0o644) -> int:
    """``os.open(path, flags)`` that neither follows a symbolic link at ``path`` nor blocks on a FIFO, and
    refuses anything but a regular file (an :class:`InputError` naming it); the descriptor is blocking."""
    try:
        fd = os.open(path, flags | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC, mode)
    except OSError as exc:
        if exc.errno == errno.ELOOP:  # O_NOFOLLOW's answer to a link at the name
            raise InputError(LINK_REFUSED, path=path) from None
        if exc.errno == errno.ENXIO:  # a FIFO opened for writing without a reader
            raise InputError(SPECIAL_REFUSED, path=path) from None
        raise
    if not stat.S_ISREG(os.fstat(fd).st_mode):
        os.close(fd)
        raise InputError(SPECIAL_REFUSED, path=path)
    os.set_blocking(fd, True)
    return fd


def require_file(path: Path, what: str = "") -> None:
    """Refuse (:class:`InputError` naming it) an input that is missing or is not a regular file (a FIFO
    would block the reader forever, a device such as /dev/zero never end, a folder is not a file). A
    symbolic link to a regular file is an input like any other (inside a session, links are refused:
    :func:`read_regular`)."""
    try:
        mode = path.stat().st_mode
    except FileNotFoundError:
        raise InputError(f"no such {what + ' ' if what else ''}file; check the path", path=path) from None
    except OSError as exc:
        raise InputError(f"cannot read it ({exc.strerror})", path=path) from exc
    if not stat.S_ISREG(mode):
        raise InputError(SPECIAL_REFUSED, path=path)


def read_regular(path: str | Path) -> bytes:
    """The bytes of the regular file ``path``, not through a symbolic link at its name (a link, a FIFO, a
    device such as /dev/zero or a folder is an :class:`InputError` naming it; a missing file raises
    :class:`FileNotFoundError`)."""
    fd = open_regular(Path(path), os.O_RDONLY)
    with os.fdopen(fd, "rb") as f:
        return f.read()


def atomic_write_text(path: str | Path, text: str) -> None:
    """Write to a temporary file beside ``path``, fsync, then rename over it: a crash leaves the old
    file or the new one, never a mix."""
    if not isinstance(text, str):
        raise TypeError(f"text expected, got {type(text).__name__}")
    atomic_write_bytes(path, text.encode("utf-8"))


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    """:func:`atomic_write_text` for bytes."""
    _write_via_temporary(Path(path), data, os.replace)


def atomic_create_bytes(path: str | Path, data: bytes) -> None:
    """Like :func:`atomic_write_bytes`, but never replaces a file: :class:`FileExistsError` if ``path``
    exists. A hard link publishes the temporary under its final name in one step that fails if taken."""
    _write_via_temporary(Path(path), data, os.link)


def atomic_write_all(files: Sequence[tuple[str | Path, bytes]]) -> None:
    """Write several files all or none: each to a temporary beside it first (fsynced), and only when every
    one is written are they renamed over their names, in order (a file another names goes first: an OBJ's
    .mtl before the OBJ, a scene's meshes before scene.xml). A full disk or a failed write leaves none of
    them changed and no temporary behind."""
    staged: list[tuple[str, Path]] = []
    try:
        for path, data in files:
            staged.append((_temporary(Path(path), data), Path(path)))
        for tmp, path in staged:
            os.replace(tmp, path)
            fsync_directory(path.parent)
    finally:
        for tmp, _ in staged:
            Path(tmp).unlink(missing_ok=True)  # after os.replace it is gone already


_TEMPORARY_NAME_BYTES = 200


def _write_via_temporary(path: Path, data: bytes, publish) -> None:
    tmp = _temporary(path, data)
    try:
        publish(tmp, path)
        fsync_directory(path.parent)
    finally:
        # after os.replace it is gone already; after os.link, it is a second name
        Path(tmp).unlink(missing_ok=True)


def _temporary(path: Path, data: bytes) -> str:
    """A fsynced temporary file beside ``path`` holding ``data``; its name."""
    if path.is_symlink():  # replacing it would break the user's link; writing through it, redirect a write
        raise InputError(LINK_REFUSED, path=path)
    tmp = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        # the name cut short: a legal name of up to NAME_MAX (255) bytes must leave room for ".XXXXXXXX.tmp"
        prefix = "." + path.name.encode()[:_TEMPORARY_NAME_BYTES].decode(errors="ignore") + "."
        fd, tmp = tempfile.mkstemp(prefix=prefix, suffix=".tmp", dir=path.parent)
        with os.fdopen(fd, "wb") as f:
            os.fchmod(f.fileno(), FILE_MODE)
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
    except BaseException as exc:  # nothing half-written is left behind, whatever stopped the write
        if tmp is not None:
            Path(tmp).unlink(missing_ok=True)
        if isinstance(exc, OSError) and exc.errno in (errno.ENOSPC, errno.EDQUOT):
            raise disk_full(path, len(data)) from exc
        raise
    return tmp


def free_bytes(path: Path) -> int:
    """Free bytes for this user on the filesystem holding ``path`` (or its nearest existing parent)."""
    while not path.exists() and path != path.parent:
        path = path.parent
    return shutil.disk_usage(path).free


def disk_full(path: Path, size: int) -> DiskFull:
    """The error for ``path`` (``size`` bytes) not fitting on its filesystem, with what is free there."""
    free = free_bytes(path.parent)
    return DiskFull(
        f"{path}: no space left on the device ({size / 1e6:.1f} MB to write, {free / 1e6:.1f} MB free); "
        "free some space and run the command again"
    )


def fsync_directory(directory: Path) -> None:
    """Make a rename or a new name in ``directory`` survive a power cut."""
    dir_fd = os.open(directory, os.O_RDONLY)
    try:
        os.fsync(dir_fd)
    finally:
        os.close(dir_fd)


_NUMBER_LIST = re.compile(r"\[\s*(-?[\d.eE+-]+(?:,\s*-?[\d.eE+-]+)*)\s*\]")


def dumps(data: object) -> str:
    """JSON indented for people, with lists of numbers kept on one line."""
    text = json.dumps(data, indent=1, ensure_ascii=False)
    return _NUMBER_LIST.sub(lambda m: "[" + ", ".join(x.strip() for x in m.group(1).split(",")) + "]", text)


def model_json(model: pydantic.BaseModel) -> str:
    """``model`` as the JSON text hlr-lab writes (:func:`dumps`, unset optional fields left out)."""
    return dumps(model.model_dump(mode="json", exclude_none=True)) + "\n"


def write_json(path: str | Path, model: pydantic.BaseModel) -> None:
    """Write ``model`` as JSON to ``path`` atomically (a reader sees the old file or the new one)."""
    atomic_write_text(path, model_json(model))


def read_json(path: str | Path) -> object:
    """A JSON file. NaN and ±Infinity (which Python's json accepts) are read as numbers, so that the
    format's model refuses them naming the field (or :func:`non_finite` finds them in a free-form one)."""
    return _parse(Path(path), json.loads, json.JSONDecodeError, "JSON")


def non_finite(data: object, at: str = "") -> str | None:
    """The path (``a.b[2]``) of the first NaN or infinity in parsed JSON ``data``, or None."""
    if isinstance(data, float) and not math.isfinite(data):
        return at or "(the whole file)"
    items = data.items() if isinstance(data, dict) else enumerate(data) if isinstance(data, list) else ()
    for key, value in items:
        found = non_finite(value, f"{at}[{key}]" if isinstance(key, int) else f"{at}.{key}".lstrip("."))
        if found:
            return found
    return None


def read_toml(path: str | Path) -> dict:
    """A TOML file as a table; a missing or malformed file is an :class:`InputError` naming it."""
    return _parse(Path(path), tomllib.loads, tomllib.TOMLDecodeError, "TOML")


def _parse(path: Path, loads, error: type[Exception], kind: str):
    require_file(path)
    try:
        return loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, error) as exc:
        raise InputError(f"not valid {kind} ({exc})", path=path) from exc
    except ValueError as exc:  # Python's int limit: "Exceeds the limit (4300 digits) for integer string …"
        raise InputError(f"not valid {kind} for hlr-lab ({str(exc).split(';')[0]})", path=path) from exc
    except RecursionError as exc:  # Python's parsers recurse once per nesting level
        raise InputError(
            f"not valid {kind} (nested too deeply to be a file of hlr-lab's)", path=path
        ) from exc


def check_header(data: object, path: Path, fmt: str, versions: set[int], header: str | None = None) -> None:
    """Reject a file of another format or an unknown version before validating its body."""
    block = data.get(header, {}) if isinstance(data, dict) and header else data
    if not isinstance(block, dict) or block.get("format") != fmt:
        where = f"{header}.format" if header else "format"
        raise InputError(f"this is not an {fmt} file (expected format = {fmt!r})", path=path, field=where)
    version = block.get("version")
    if type(version) is not int or version not in versions:  # (a list or a table is not a version either)
        raise InputError(
            f"version {version!r} is not one this hlr-lab reads "
            f"({', '.join(map(str, sorted(versions)))}); upgrade hlr-lab or re-create the file",
            path=path,
            field=f"{header}.version" if header else "version",
        )


def validate(model: type[Model], data: object, path: str | Path, at: str = "") -> Model:
    """Validate ``data`` against ``model``; the first problem becomes an InputError naming the field
    (under ``at``, where ``data`` sits in its file: e.g. ``job[2]``)."""
    try:
        return model.model_validate(data)
    except pydantic.ValidationError as exc:
        err = exc.errors()[0]
        field = at + "".join(f"[{p}]" if isinstance(p, int) else f".{p}" for p in err["loc"])
        field = field.lstrip(".")
        more = f" (and {exc.error_count() - 1} more problems)" if exc.error_count() > 1 else ""
        message = err["msg"].removeprefix("Value error, ")  # a validator's own sentence, as it wrote it
        raise InputError(f"{message}{more}", path=path, field=field or None) from exc


def read_format(
    path: str | Path, fmt: str, model: type[Model], versions: frozenset[int] = frozenset({1})
) -> Model:
    """Read a JSON file of one of the project's formats: the header first (format, version), then the body."""
    path = Path(path)
    data = read_json(path)
    check_header(data, path, fmt, set(versions))
    return validate(model, data, path)
