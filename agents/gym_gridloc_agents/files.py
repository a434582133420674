"""Files: atomic writes, model metadata, and loading stable-baselines3 models safely.

A model ``X.zip`` has its metadata beside it in ``X.json`` (config, seed, versions, evaluations).
Writes go to a temporary file in the same directory, named so a person recognises it
(``.X.zip.gridloc-tmp-<random>``), and are renamed into place: a crash never leaves half a file,
and :func:`clean_stale_temporaries` removes what a killed process left behind.

Model zip files are pickles: load only files from a trusted source.
"""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
import time
from pathlib import Path
from typing import Any

#: Marks the temporary files of atomic writes (``.<name>.gridloc-tmp-<random>``).
TMP_MARK = ".gridloc-tmp-"


class OutputError(OSError):
    """An output cannot be written (checked before a long run starts), or a final write failed
    (the message says where the work was saved instead)."""


class OutputExists(OutputError, FileExistsError):
    """An output exists (a file of the kind the command writes) and the command was not told to
    replace it (``--force``/``--update``)."""


def writable_directory(directory: Path, what: str) -> None:
    """Create ``directory`` if needed and prove a file can be written there, or raise
    :class:`OutputError` naming it and why."""
    try:
        directory.mkdir(parents=True, exist_ok=True)
        tempfile.NamedTemporaryFile(dir=directory, prefix=f".gridloc-probe{TMP_MARK}", delete=True).close()
    except OSError as exc:
        blocker = next((p for p in [directory, *directory.parents] if p.exists() and not p.is_dir()), None)
        reason = exc.strerror or str(exc) if blocker is None else f"{blocker} is a file, not a directory"
        raise OutputError(f"cannot write to the {what} {directory}: {reason}") from None


def writable_file(path: str | Path, what: str) -> Path:
    """``path`` can be written (its directory is created and probed; it is not a directory), or
    :class:`OutputError` naming it."""
    path = Path(path)
    if path.is_dir():
        raise OutputError(f"the {what} {path} is a directory; give a file name")
    writable_directory(path.parent, f"directory of the {what}")
    return path


#: Kinds of files the commands write, as :func:`file_kind` names them.
FIGURE, MODEL, MODEL_METADATA, BENCH_RESULTS, BOUND, TABLE, MARKDOWN, CURVES = (
    "figure", "model", "model metadata", "bench results", "bound", "bench table", "markdown table", "learning curves")
#: Kinds that may be replaced by an output of the same kind without --force (derived, redrawable).
REDRAWABLE = (FIGURE, TABLE, MARKDOWN, CURVES)


def file_kind(path: str | Path) -> str | None:
    """What an existing file holds, judged by its content: :data:`FIGURE` (PNG/GIF), :data:`MODEL`
    (a zip), :data:`MODEL_METADATA` (a JSON object beside a model, or with ``algo``/``env_id``),
    :data:`BENCH_RESULTS` (a JSON list of benchmark rows), :data:`TABLE` (the public table of
    ``bench --all``), :data:`BOUND` (``gridloc bound``'s JSON), :data:`MARKDOWN` (a ``.md`` file
    that starts with a table row, as ``bench --markdown`` writes); ``"other"`` for anything else,
    ``None`` if there is no file (or an empty one: nothing to lose)."""
    path = Path(path)
    if not path.is_file() or path.stat().st_size == 0:
        return None
    try:
        with open(path, "rb") as fh:
            head = fh.read(8)
    except OSError:
        return "other"
    if head.startswith(b"\x89PNG") or head[:4] == b"GIF8":
        return FIGURE
    if head[:2] == b"PK":
        return MODEL
    if path.with_suffix(".zip").is_file() and path.suffix == ".json":
        return MODEL_METADATA
    if path.suffix == ".md" and head.startswith(b"| "):
        return MARKDOWN
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError, RecursionError):
        return "other"
    if isinstance(data, dict):
        if "bound" in data:
            return BOUND
        if "curves" in data and "baselines" in data:
            return CURVES
        if "algo" in data or "env_id" in data or "num_timesteps" in data:
            return MODEL_METADATA
    if isinstance(data, list) and data and all(isinstance(r, dict) and "env" in r and "policy" in r for r in data):
        return TABLE if all("localised_curve" not in r for r in data) else BENCH_RESULTS
    return "other"


def check_outputs(outputs, *, inputs=(), replace: bool = False, flag: str = "--force") -> None:
    """Refuse, before any work, outputs that would lose finished work.  ``outputs``: ``(path, kind,
    what)`` triples of one run (``path`` None: not written).  Refused (:class:`OutputError` naming
    the path): two outputs of the run on one path, an output that is one of ``inputs``, a
    directory, an existing file of another kind (a model, its metadata -- also a JSON beside a
    model ``X.zip`` --, results, a file this project does not write), and an existing file of the
    same kind unless ``replace`` (the command's ``--update``/``--force``) or the kind is
    :data:`REDRAWABLE` (:class:`OutputExists`, also a ``FileExistsError``).  Then every output's
    directory is created and probed."""
    seen: dict[Path, str] = {}
    ins = {Path(p).expanduser().resolve(): str(p) for p in inputs if p}
    for path, kind, what in outputs:
        if not path:
            continue
        path = Path(path)
        key = path.expanduser().resolve()
        if key in seen:
            raise OutputError(f"the {what} {path} is also the {seen[key]}: give each output its own file")
        seen[key] = what
        if key in ins:
            raise OutputError(f"the {what} {path} is an input of this command ({ins[key]}): writing it would replace it")
        if (problem := foreign(path, kind, what)) is not None:
            raise OutputError(problem)
        found = file_kind(path)
        if found is not None and not replace and kind not in REDRAWABLE:
            raise OutputExists(f"the {what} {path} exists ({kind}); pass {flag} to replace it, or choose another name")
        writable_directory(path.parent, f"directory of the {what}")


def foreign(path: Path, kind: str | None, what: str) -> str | None:
    """Why writing ``path`` (an output of ``kind``) would replace what is not the command's to
    replace -- a directory, a path that is not a regular file (a device, a pipe, a socket), a
    model's metadata (``X.json`` beside ``X.zip``), an existing file of another kind -- or None.
    :func:`check_outputs` asks before any work, :func:`atomic_path` again at the replace."""
    if path.is_dir():
        return f"the {what} {path} is a directory; give a file name"
    if path.exists() and not path.is_file():
        return f"the {what} {path} exists and is not a regular file (a device, a pipe or a socket): give a file name"
    if kind is None:
        return None
    if kind not in (MODEL, MODEL_METADATA) and path.suffix == ".json" and path.with_suffix(".zip").is_file():
        return (f"the {what} {path} is the metadata file of the model {path.with_suffix('.zip')}: "
                "writing it would replace that model's metadata; choose another name")
    found = file_kind(path)
    if found is not None and found != kind:
        return (f"the {what} {path} exists and holds {'a file of another kind' if found == 'other' else found}, "
                f"not {kind}: it would be replaced; choose another name")
    return None


@contextlib.contextmanager
def locked(path: str | Path, *, wait: bool = True, what: str = "file", directory: bool | None = None,
           name: str = ".gridloc-lock"):
    """An exclusive ``fcntl.flock`` for the block: on ``<dir>/<name>`` for a directory (another
    ``name``: another lock on the same directory), for a file on a lock file named by the hash of
    its full path in the system's temporary directory (no lock files beside results or models).
    ``wait=False``: :class:`OutputError` if another process holds it."""
    import hashlib

    path = Path(path)
    if path.is_dir() if directory is None else directory:
        path.mkdir(parents=True, exist_ok=True)
        lock = path / name
    else:
        digest = hashlib.sha1(str(path.expanduser().resolve()).encode()).hexdigest()[:16]
        lock = Path(tempfile.gettempdir()) / "gridloc-locks" / f"{path.name[:40]}-{digest}.lock"
    lock.parent.mkdir(parents=True, exist_ok=True)
    try:
        import fcntl
    except ImportError:  # pragma: no cover - not POSIX
        yield
        return
    with open(lock, "a+") as fh:
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | (0 if wait else fcntl.LOCK_NB))
        except BlockingIOError:
            raise OutputError(f"another process is writing the {what} {path} (it holds {lock}); "
                              "wait for it to finish or choose another output") from None
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


def rescue_write(write, path: Path, what: str, *, places: tuple[Path, ...] = (), problem: str | None = None) -> None:
    """Call ``write(target)`` for ``path`` (unless ``problem`` already says why not); if that
    fails, for ``<stem>-rescued-<time><suffix>`` in each of ``places``, then the working
    directory, then the system's temporary directory, and raise :class:`OutputError` saying where
    the work went (or that it could not be saved)."""
    if problem is None:
        try:
            write(path)
            return
        except OSError as exc:
            problem = f"cannot write the {what} {path}: {exc.strerror or exc}"
    stamp = f"{time.strftime('%Y%m%d-%H%M%S')}-{os.getpid()}"  # two processes in one second: two names
    for directory in (*places, Path.cwd(), Path(tempfile.gettempdir())):
        target = directory / f"{path.stem}-rescued-{stamp}{path.suffix}"
        n = 1
        while target.exists() or target.with_suffix(".json").exists():  # never over another rescue
            target, n = directory / f"{path.stem}-rescued-{stamp}-{n}{path.suffix}", n + 1
        try:
            write(target)
        except OSError:
            continue
        raise OutputError(f"{problem}; written to {target} instead")
    raise OutputError(f"{problem}; writing it elsewhere failed too")


#: The algorithms a model file may hold: their modules and classes.
def _umask_mode() -> int:
    old = os.umask(0)
    os.umask(old)
    return 0o666 & ~old


def clean_stale_temporaries(directory: str | Path, name: str | None = None) -> list[Path]:
    """Remove the temporary files an interrupted atomic write left in ``directory`` (for the
    file ``name`` only, if given); returns what was removed."""
    d = Path(directory)
    if not d.is_dir():
        return []
    pattern = f".{name}{TMP_MARK}*" if name else f".*{TMP_MARK}*"
    removed = []
    for p in d.glob(pattern):
        if _in_use(p):  # another process's live temporary (it holds a lock on it while writing)
            continue
        with contextlib.suppress(OSError):
            p.unlink()
            removed.append(p)
    return removed


def _in_use(path: Path) -> bool:
    """Whether a process holds the ``flock`` :func:`atomic_path` keeps on its temporary."""
    try:
        import fcntl
    except ImportError:  # pragma: no cover - not POSIX
        return False
    try:
        with open(path, "rb") as fh:
            try:
                fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                return True
            fcntl.flock(fh, fcntl.LOCK_UN)
    except OSError:
        return False
    return False


@contextlib.contextmanager
def atomic_path(path: str | Path, kind: str | None = None):
    """Yield a temporary path beside ``path`` (with ``path``'s suffix, so that libraries that
    add a suffix do not); on success give it the usual file mode and rename it onto ``path``, on
    any error remove it and leave ``path`` as it was.  At the rename, ``path`` is judged again
    (:func:`foreign`; with ``kind``, the kind of output written): what appeared there meanwhile and
    is not the command's to replace is kept, and :class:`OutputError` says so."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    clean_stale_temporaries(path.parent, path.name)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}{TMP_MARK}", suffix=path.suffix, dir=path.parent)
    try:  # held while the temporary lives: another process's clean_stale_temporaries leaves it alone
        import fcntl

        fcntl.flock(fd, fcntl.LOCK_EX)
    except ImportError:  # pragma: no cover - not POSIX
        pass
    try:
        yield tmp
        os.chmod(tmp, _umask_mode())
        if (problem := foreign(path, kind, "output")) is not None:
            raise OutputError(f"{problem} (it changed while the command ran)")
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
    finally:
        os.close(fd)


def atomic_write_text(path: str | Path, text: str, kind: str | None = None) -> None:
    """Write ``text`` to ``path`` via a temporary file in the same directory and a rename
    (:func:`atomic_path`: ``kind``, the kind of output, is checked again at the rename)."""
    with atomic_path(path, kind) as tmp, open(tmp, "w", encoding="utf-8") as fh:
        fh.write(text)
        fh.flush()
        os.fsync(fh.fileno())


def atomic_write_json(path: str | Path, data: Any, kind: str | None = None) -> None:
    atomic_write_text(path, json.dumps(data, indent=2, sort_keys=False) + "\n", kind)


def atomic_save_model(model, path: str | Path) -> None:
    """``model.save`` to a temporary ``.zip`` beside ``path``, then rename."""
    with atomic_path(path) as tmp:
        model.save(tmp)


def metadata_path(model_path: str | Path) -> Path:
    """Where the metadata of a model file lives: the same name with ``.json``."""
    return Path(model_path).with_suffix(".json")


#: The types of the metadata entries commands read (an entry may be missing; None only where listed).
METADATA_TYPES = {"seed": (int, type(None)), "env_id": str, "algo": str, "method": str, "env_kwargs": dict,
                  "wrapper": dict, "config": dict, "num_timesteps": int, "total_timesteps": int, "evaluations": list,
                  "wall_time_seconds": (int, float, type(None)), "pretrain": (dict, type(None))}
#: The numbers of one held-out evaluation (``num_timesteps`` always; the others where recorded).
EVALUATION_NUMBERS = ("mean_steps", "accuracy", "argmax_accuracy", "wall_time_seconds", "cpu_seconds")


def read_metadata(model_path: str | Path) -> dict[str, Any]:
    """The metadata JSON beside a model (``{}`` if there is none); a one-line ``ValueError``
    naming the file and the entry if it is not a JSON object, nests deeper than
    :data:`MAX_METADATA_DEPTH`, or holds an entry of another type than :data:`METADATA_TYPES`
    says (an evaluation: an object whose ``num_timesteps`` is a whole number, its scores numbers)."""
    meta = metadata_path(model_path)
    if not meta.exists():
        return {}
    try:
        text = meta.read_text(encoding="utf-8")
        if _nesting(text) > MAX_METADATA_DEPTH:
            raise ValueError(f"nested more than {MAX_METADATA_DEPTH} levels deep")
        data = json.loads(text)
    except (OSError, UnicodeDecodeError, ValueError, RecursionError) as exc:
        raise ValueError(f"{meta}: the model's metadata is not readable JSON ({' '.join(str(exc).split())[:200]})") from None
    if not isinstance(data, dict):
        raise ValueError(f"{meta}: the model's metadata must be a JSON object, got {type(data).__name__}")

    def wrong(key: str, value: Any, allowed: str) -> ValueError:
        return ValueError(f"{meta}: the model's metadata has {key} = {json.dumps(value)[:80]}, not {allowed}")

    from gym_gridloc.core.validation import is_int

    for key, types in METADATA_TYPES.items():
        types = types if isinstance(types, tuple) else (types,)
        if key in data and not any(is_int(data[key]) if t is int else isinstance(data[key], t) and not isinstance(data[key], bool)
                                   for t in types):  # (a bool is no number here)
            names = {"NoneType": "null", "dict": "an object", "list": "a list", "int": "a whole number", "str": "a string"}
            raise wrong(key, data[key], " or ".join(names.get(t.__name__, t.__name__) for t in types))
    for i, entry in enumerate(data.get("evaluations") or []):
        if not isinstance(entry, dict):
            raise wrong(f"evaluations[{i}]", entry, "an object")
        steps = entry.get("num_timesteps")
        if "num_timesteps" in entry and (not is_int(steps) or steps < 0):
            raise wrong(f"evaluations[{i}].num_timesteps", steps, "a whole number >= 0")
        for key in EVALUATION_NUMBERS:
            value = entry.get(key)
            if value is not None and (isinstance(value, bool) or not isinstance(value, (int, float))):
                raise wrong(f"evaluations[{i}].{key}", value, "a number")
    return data


#: How deep a model's metadata may nest (a real one nests four or five levels).
MAX_METADATA_DEPTH = 50


def _nesting(text: str) -> int:
    """The deepest nesting of brackets in a JSON text (an upper bound of its objects' and lists' depth)."""
    depth = level = 0
    for ch in text:
        level += (ch in "[{") - (ch in "]}")
        depth = max(depth, level)
    return depth
