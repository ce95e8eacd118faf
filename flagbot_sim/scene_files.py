"""Scene files on disk: the built-in ones, and the one safe reader of a scene file for the CLI and the nodes alike
(a regular UTF-8 file of sane size, never blocking on a FIFO or a device). What the text means is
:mod:`flagbot_sim.scene`'s."""
from __future__ import annotations

import os
import stat
from importlib import resources
from pathlib import Path

from .fields import SceneError, control_character, short

#: a scene file larger than this is refused unread (the built-in ones are ~1 kB)
MAX_FILE_BYTES = 1 << 20


def builtin_scenes() -> list[str]:
    return sorted(p.name[:-5] for p in resources.files("flagbot_sim.scenes").iterdir()
                  if p.name.endswith(".toml"))


def portable_source(source: str | None) -> str | None:
    """A scene's source as written into shared results: a built-in scene as ``flagbot_sim/scenes/<name>.toml``
    (the same on every checkout and install), any other file as given."""
    if not source:
        return source
    p = Path(source)
    builtin = Path(str(resources.files("flagbot_sim.scenes")))
    try:
        return "flagbot_sim/scenes/" + p.resolve().relative_to(builtin.resolve()).as_posix()
    except (ValueError, OSError):
        return source


def resolve_scene_path(name_or_path: str | Path) -> Path:
    """The file a scene name or path means: a built-in scene's name, or an existing regular file (never a
    directory, FIFO or device: reading one would fail or block)."""
    if isinstance(name_or_path, str) and not name_or_path.strip():
        raise SceneError(f"no scene given (an empty name); use a built-in scene ({', '.join(builtin_scenes())}) "
                         "or a .toml path")
    bad = control_character(str(name_or_path))
    if bad:
        raise SceneError(f"scene {short(str(name_or_path))} holds {bad}: a scene is a built-in name or a file "
                         "path, on one line")
    p = Path(name_or_path)
    try:
        st = p.stat()
    except FileNotFoundError:
        st = None
    except (OSError, ValueError) as exc:             # ValueError: a NUL byte in the name
        raise SceneError(f"scene {short(str(p))} cannot be read: {getattr(exc, 'strerror', None) or exc}") \
            from None
    if p.suffix == ".toml" or st is not None:
        if st is None:
            raise SceneError(f"scene file {short(str(p))} does not exist")
        if not stat.S_ISREG(st.st_mode):
            kind = "a directory" if stat.S_ISDIR(st.st_mode) else "not a regular file"
            raise SceneError(f"scene {short(str(p))} is {kind}; give a .toml file or a built-in scene name")
        if not os.access(p, os.R_OK):
            raise SceneError(f"scene file {short(str(p))} is not readable (permission denied)")
        return p
    if "/" not in str(name_or_path) and len(str(name_or_path)) < 256:
        candidate = resources.files("flagbot_sim.scenes") / f"{name_or_path}.toml"
        if candidate.is_file():
            return Path(str(candidate))
    raise SceneError(f"unknown scene {short(str(name_or_path))}: not a file, and not a built-in scene "
                     f"({', '.join(builtin_scenes())})")


def read_scene_text(path: Path) -> str:
    """The text of a scene file: at most MAX_FILE_BYTES, UTF-8 (a leading BOM is dropped), as TOML requires.

    The one reader of scene files, for the CLI and the nodes alike. It never blocks: the file is opened
    non-blocking and must be a regular file (a FIFO, a directory or a device is refused before anything is read,
    even one swapped in after :func:`resolve_scene_path` looked), and a file that grows while it is read is cut
    off at the limit."""
    shown = short(str(path))
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_NOCTTY | os.O_CLOEXEC)
    except (OSError, ValueError) as exc:              # ValueError: a NUL byte in the name
        raise SceneError(f"scene file {shown} cannot be read: {getattr(exc, 'strerror', None) or exc}") from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            kind = ("a directory" if stat.S_ISDIR(st.st_mode) else "a FIFO" if stat.S_ISFIFO(st.st_mode)
                    else "a device or socket")
            raise SceneError(f"scene {shown} is {kind}, not a scene file")
        chunks, size = [], 0
        while size <= MAX_FILE_BYTES:
            chunk = os.read(fd, 65536)
            if not chunk:
                break
            chunks.append(chunk)
            size += len(chunk)
    except OSError as exc:
        raise SceneError(f"scene file {shown} cannot be read: {exc.strerror or exc}") from None
    finally:
        os.close(fd)
    if size > MAX_FILE_BYTES:
        raise SceneError(f"scene file {shown} is larger than {MAX_FILE_BYTES >> 20} MiB; a scene file holds a few "
                         "dozen keys (the built-in ones are ~1 KiB)")
    raw = b"".join(chunks)
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = raw.count(b"\n", 0, exc.start) + 1
        column = exc.start - (raw.rfind(b"\n", 0, exc.start) + 1) + 1
        raise SceneError(f"scene file {shown} is not UTF-8 text (TOML must be): byte "
                         f"0x{raw[exc.start]:02x} at line {line}, column {column}") from None
    return text.removeprefix("\ufeff")
