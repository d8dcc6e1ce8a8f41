"""File helpers shared by every reader and writer: atomic single files and folders, special-file
refusal, capped reads, paths that stay inside their folder, names made safe for the file system.

Writers: :func:`atomic_write` (one file: unique temp beside it, fsync, rename) and
:func:`atomic_dir` (a multi-file output built in a temp folder beside the target and swapped in
whole). Temp names carry the writer's process id (``.<name>.<pid>.<random>.tmp``); a writer killed
with SIGKILL leaves its temp behind, and the next writer into the same folder removes the temps of
processes that no longer run (:func:`sweep_stale`).

Readers: :func:`open_regular` / :func:`read_bytes` refuse FIFOs, devices, sockets (also behind
symlinks) before reading and cap the size; :func:`inside` keeps a path named inside a file within
its folder.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import re
import shutil
import stat
import tempfile
from pathlib import Path
from typing import IO, Iterable, Iterator

from ..errors import FormatError

__all__ = ["atomic_write", "atomic_dir", "sweep_stale", "open_regular", "read_bytes", "read_text",
           "inside", "safe_name", "check_overwrite", "load_json", "claim_output", "OutputBusyError",
           "MAX_FILE_BYTES", "MAX_TEXT_BYTES"]

#: Largest file any reader loads into memory whole (point clouds, images, caches read lazily).
MAX_FILE_BYTES = 2 << 30
#: Largest JSON / YAML / text file a reader parses.
MAX_TEXT_BYTES = 256 << 20
_TMP_RE = r"\.{name}\.(\d+)\.[A-Za-z0-9_]+\.(?:tmp|old)$"


def _umask() -> int:
    """The process umask, read without changing it where the OS allows (Linux /proc)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    mask = os.umask(0o022)  # elsewhere: read by setting (briefly) and restoring
    os.umask(mask)
    return mask


def _alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def sweep_stale(parent, name: str) -> int:
    """Remove ``.<name>.<pid>.*.tmp`` / ``.old`` entries in ``parent`` left by writers that were
    killed (their process no longer runs). Returns how many were removed."""
    parent = Path(parent)
    pat = re.compile(_TMP_RE.format(name=re.escape(name)))
    n = 0
    try:
        entries = list(os.scandir(parent))
    except OSError:
        return 0
    for e in entries:
        m = pat.match(e.name)
        if m is None or _alive(int(m.group(1))):
            continue
        try:
            if e.is_dir(follow_symlinks=False):
                shutil.rmtree(e.path, ignore_errors=True)
            else:
                os.unlink(e.path)
            n += 1
        except OSError:
            pass
    return n


def tmp_prefix(name: str) -> str:
    """Prefix of this process's temp entries for output ``name`` (``sweep_stale`` recognises them)."""
    return f".{name}.{os.getpid()}."


def check_overwrite(path, overwrite: bool, what: str = "output") -> None:
    """FileExistsError when ``path`` exists and ``overwrite`` is False."""
    p = Path(path)
    if not overwrite and (p.exists() or p.is_symlink()):
        raise FileExistsError(f"{what} {p} already exists; pass overwrite=True (CLI: --force) to replace it")


def atomic_write(path, payload: Iterable[bytes], *, overwrite: bool = True) -> Path:
    """Write ``payload`` chunks to a unique temporary file beside ``path`` (``mkstemp``: never
    follows a planted symlink), fsync it, then rename it into place: readers never see a
    half-written file and a failed write leaves nothing behind. The file gets the permissions a
    plain ``open(path, "w")`` would give (0o666 minus the umask). ``overwrite=False`` refuses an
    existing ``path`` (FileExistsError)."""
    path = Path(path)
    check_overwrite(path, overwrite)
    path.parent.mkdir(parents=True, exist_ok=True)
    sweep_stale(path.parent, path.name)
    fd, tmp = tempfile.mkstemp(prefix=tmp_prefix(path.name), suffix=".tmp", dir=path.parent)
    try:
        os.fchmod(fd, 0o666 & ~_umask())
        with os.fdopen(fd, "wb") as f:
            for chunk in payload:
                f.write(chunk)
            f.flush()
            os.fsync(f.fileno())
        if not overwrite:
            os.link(tmp, path)  # fails if path appeared meanwhile: no silent overwrite
            os.unlink(tmp)
        else:
            os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
    return path


def _exchange(a: str, b: str) -> bool:
    """Atomically swap two paths (Linux renameat2 RENAME_EXCHANGE); False where unsupported."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        fn = libc.renameat2
    except (OSError, AttributeError):
        return False
    AT_FDCWD, RENAME_EXCHANGE = -100, 2
    rc = fn(AT_FDCWD, os.fsencode(a), AT_FDCWD, os.fsencode(b), RENAME_EXCHANGE)
    return rc == 0


@contextlib.contextmanager
def atomic_dir(path, *, overwrite: bool = False, keep_existing: bool = False,
               drop: Iterable[str] = ()) -> Iterator[Path]:
    """Build a multi-file output in a temporary folder beside ``path`` and swap it in whole.

    Yields the temporary folder; write every file of the output into it. On a clean exit the
    folder replaces ``path`` in one step (Linux: an atomic exchange; elsewhere two renames), so
    readers see the old output or the new one, never a mix. On an exception the temp folder is
    removed and ``path`` is untouched. An existing ``path`` is refused unless ``overwrite``;
    ``keep_existing`` carries over (hard link or copy) the files of the old folder that the new
    output does not write (e.g. other models' weights in a site folder), except the relative
    paths in ``drop`` (files the new output supersedes).
    """
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise FileExistsError(f"{path} exists and is not a folder")
    if path.is_dir() and any(path.iterdir()):  # an existing empty folder is no output to protect
        check_overwrite(path, overwrite or keep_existing, "output folder")
    path.parent.mkdir(parents=True, exist_ok=True)
    sweep_stale(path.parent, path.name)
    tmp = Path(tempfile.mkdtemp(prefix=tmp_prefix(path.name), suffix=".tmp", dir=path.parent))
    try:
        os.chmod(tmp, 0o777 & ~_umask())
        yield tmp
        if keep_existing and path.is_dir():
            _carry_over(path, tmp, set(drop))
        _fsync_tree(tmp)
        if not (overwrite or keep_existing) and (path.is_symlink() or (path.exists() and (
                not path.is_dir() or any(path.iterdir())))):
            # another writer filled it while we computed: never swap its output away
            raise FileExistsError(f"output folder {path} was written by another process while this one ran; "
                                  "nothing replaced (pass overwrite / --force to replace it)")
        if path.is_dir():
            if not _exchange(str(tmp), str(path)):
                old = Path(tempfile.mkdtemp(prefix=tmp_prefix(path.name), suffix=".old", dir=path.parent))
                os.rmdir(old)
                os.replace(path, old)
                os.replace(tmp, path)
                tmp = old
            shutil.rmtree(tmp, ignore_errors=True)  # now the old output
        else:
            os.replace(tmp, path)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


class OutputBusyError(FileExistsError):
    """Another running process has claimed the same output (see :func:`claim_output`)."""


def _lock_path(path: Path) -> Path:
    return path.parent / f".{path.name}.lock"


@contextlib.contextmanager
def claim_output(path, what: str = "output") -> Iterator[Path]:
    """Claim output ``path`` for this process before any work is done: an advisory lock
    (``flock``) on ``.<name>.lock`` beside it. A second claim of the same output while the first
    holder runs raises :class:`OutputBusyError` at once, naming the holder's process id; the lock
    dies with its process (kill -9 included), so nothing stale blocks a later run. Creating the
    lock also proves the parent folder is writable, before hours of computing. Yields the lock
    file's path; it is removed on exit."""
    import fcntl

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    lock = _lock_path(path)
    while True:
        try:
            fd = os.open(lock, os.O_RDWR | os.O_CREAT | getattr(os, "O_NOFOLLOW", 0), 0o644)
        except OSError as exc:
            raise PermissionError(f"cannot write {what} {path}: cannot create {lock} "
                                  f"({exc.strerror or exc})") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            try:
                holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "?"
            finally:
                os.close(fd)
            raise OutputBusyError(f"{what} {path} is being written by another run (process {holder}, lock "
                                  f"{lock}); wait for it to finish or choose another output") from None
        try:  # the lock file we hold must still be the one at that path (a releasing holder unlinks it)
            same = os.path.samestat(os.fstat(fd), os.stat(lock, follow_symlinks=False))
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(fd)
    try:
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        yield lock
    finally:
        with contextlib.suppress(OSError):
            os.unlink(lock)
        os.close(fd)


def _carry_over(old: Path, new: Path, drop: set[str]) -> None:
    for src in old.rglob("*"):
        rel = src.relative_to(old)
        dst = new / rel
        if rel.as_posix() in drop or dst.exists() or dst.is_symlink():
            continue
        if src.is_dir() and not src.is_symlink():
            dst.mkdir(parents=True, exist_ok=True)
            continue
        dst.parent.mkdir(parents=True, exist_ok=True)
        try:
            os.link(src, dst, follow_symlinks=False)
        except OSError:
            shutil.copy2(src, dst, follow_symlinks=False)


def _fsync_tree(root: Path) -> None:
    for dirpath, _, files in os.walk(root):
        for f in files:
            with contextlib.suppress(OSError):
                fd = os.open(os.path.join(dirpath, f), os.O_RDONLY)
                try:
                    os.fsync(fd)
                finally:
                    os.close(fd)


# ---------------------------------------------------------------------------------- reading
def open_regular(path, *, max_bytes: int = MAX_FILE_BYTES, what: str = "file") -> IO[bytes]:
    """Open ``path`` for binary reading if it is a regular file (also behind symlinks) of at most
    ``max_bytes``. FIFOs, devices and sockets are refused before any read (opened non-blocking
    and checked with fstat, so a path swapped after a check cannot block us)."""
    p = Path(path)
    try:
        st = os.stat(p)
    except FileNotFoundError:
        raise FileNotFoundError(f"{what} not found: {p}") from None
    except OSError as exc:
        raise FormatError(p, f"cannot be read ({exc.strerror or exc})") from None
    if stat.S_ISDIR(st.st_mode):
        raise FormatError(p, f"expected a {what}, found a directory")
    _require_regular(p, st, what)
    try:
        fd = os.open(p, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_NOCTTY", 0))
    except OSError as exc:
        raise FormatError(p, f"cannot be opened ({exc.strerror or exc})") from None
    try:
        st = os.fstat(fd)
        _require_regular(p, st, what)
        if st.st_size > max_bytes:
            raise FormatError(p, f"{what} is {st.st_size} bytes; the limit is {max_bytes} bytes")
        if hasattr(os, "set_blocking"):
            os.set_blocking(fd, True)
        return os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise


def _require_regular(p: Path, st: os.stat_result, what: str) -> None:
    if not stat.S_ISREG(st.st_mode):
        kind = ("a FIFO" if stat.S_ISFIFO(st.st_mode) else "a device" if stat.S_ISCHR(st.st_mode)
                or stat.S_ISBLK(st.st_mode) else "a socket" if stat.S_ISSOCK(st.st_mode) else "not a regular file")
        via = " (through a symlink)" if p.is_symlink() else ""
        raise FormatError(p, f"refusing to read {kind}{via}; expected a regular {what}")


def read_bytes(path, *, max_bytes: int = MAX_FILE_BYTES, what: str = "file") -> bytes:
    """The bytes of a regular file of at most ``max_bytes`` (see :func:`open_regular`)."""
    with open_regular(path, max_bytes=max_bytes, what=what) as f:
        data = f.read(max_bytes + 1)
    if len(data) > max_bytes:  # grew while we read it
        raise FormatError(path, f"{what} is larger than the limit of {max_bytes} bytes")
    return data


def read_text(path, *, max_bytes: int = MAX_TEXT_BYTES, what: str = "text file", encoding: str = "utf-8") -> str:
    """A regular text file decoded as ``encoding``; undecodable bytes are a FormatError."""
    data = read_bytes(path, max_bytes=max_bytes, what=what)
    try:
        return data.decode(encoding)
    except UnicodeDecodeError as exc:
        raise FormatError(path, f"not {encoding} text (byte {exc.start}: {exc.reason})") from None


# ------------------------------------------------------------------------------------ paths
def inside(root, rel, *, source=None, field: str | None = None, allow_outside: bool = False) -> Path:
    """``root / rel`` for a path ``rel`` read from a file; an absolute ``rel`` or one that climbs
    out of ``root`` (``..``) is a FormatError naming ``source`` and ``field`` unless
    ``allow_outside``."""
    root = Path(root)
    if not isinstance(rel, (str, os.PathLike)) or not str(rel) or "\x00" in str(rel):
        raise FormatError(source, f"expected a relative file path, got {rel!r:.80}", field)
    rel_s = os.fspath(rel)
    if len(rel_s) > 4096 or any(len(os.fsencode(c)) > 255 for c in Path(rel_s).parts):
        raise FormatError(source, f"path {rel_s[:60]!r}... is too long for a file name", field)
    joined = root / rel_s
    if allow_outside:
        return joined
    norm = os.path.normpath(rel_s)
    if os.path.isabs(rel_s) or norm == ".." or norm.startswith(".." + os.sep) or (os.altsep and norm.startswith(".." + os.altsep)):
        raise FormatError(source, f"path {rel_s!r} points outside {root} (absolute or '..'); "
                                  "paths inside files must stay in their folder (allow_outside=True to permit)", field)
    return joined


_UNSAFE = re.compile(r"[^A-Za-z0-9._+=-]+")


def safe_name(text, *, max_len: int = 120, default: str = "_") -> str:
    """A file-name component derived from data: characters other than letters, digits and
    ``. _ + = -`` become ``_`` (so ``/``, ``\\`` and ``..`` cannot climb out), no leading dot,
    at most ``max_len`` characters."""
    s = _UNSAFE.sub("_", str(text)).lstrip(".")
    s = s[:max_len]
    return s or default


def load_json(path, *, max_bytes: int = MAX_TEXT_BYTES, what: str = "JSON file"):
    """Parse a regular, size-capped UTF-8 JSON file; every parse problem (bad bytes, syntax,
    nesting too deep) is a FormatError naming the file."""
    import json

    text = read_text(path, max_bytes=max_bytes, what=what)
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise FormatError(path, f"not valid JSON ({exc})") from None
    except (RecursionError, ValueError, MemoryError) as exc:
        raise FormatError(path, f"not valid JSON ({type(exc).__name__}: nesting too deep or too large)") from None
