"""A sweep folder's chunk store: verified chunks, claims for concurrent writers, the manifest.

Layout of a sweep folder:
  chunk_000007.npz     the records of chunk 7 (columnar npz).
  manifest.json        the sweep's description and `chunks`: {"chunk_000007.npz": {sha256,
                       rows}} for every chunk written completely. A chunk counts as done only
                       when the file exists AND matches its manifest entry; anything else
                       (missing, truncated, corrupted, or written but never recorded because
                       the writer was killed) is recomputed.
  .claims/chunk_000007.claim   held while a process computes chunk 7.
  .lock                the flock serialising claim recovery and manifest read-modify-write.

Write protocol for one chunk (every step survives a SIGKILL at any moment):
  1. claim: create .claims/chunk_i.claim exclusively (link(2) of a complete temporary file,
     which like O_CREAT|O_EXCL fails when the name exists), holding {pid, host, start, time}.
     Exclusive create is atomic, so of two writers exactly one gets the chunk.
  2. write the npz to a temporary name private to this process, fsync, os.replace onto
     chunk_i.npz (a reader sees the old file or the new one, never half of one).
  3. under .lock: read the manifest, set chunks[chunk_i.npz] = {sha256, rows}, write it to a
     temporary name, os.replace. The entry comes after the rename, so an entry always
     describes a complete file.
  4. delete the claim.
A claim is stale, and is taken over, when its process is gone: same host and the pid is not
alive (or is alive but started at another time: a reused pid), or, for a claim from another
host, older than CLAIM_STALE_S (default 6 h; TKUJAX_CLAIM_STALE_S overrides it), since a pid
on another host cannot be checked. Stale claims are removed under .lock, so two writers can
never both take one over.

Fault injection: TKUJAX_TEST_SLOW_WRITE=S makes step 2 sleep S/2 s with half of the bytes
written, and sleep S/2 s between steps 2 and 3, so that a SIGKILL at a random moment lands
mid-write often (tests/test_records.py). Never set it otherwise.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import io
import json
import os
import socket
import time
import zipfile
from pathlib import Path

import numpy as np

MANIFEST = "manifest.json"
CLAIMS = ".claims"
LOCK = ".lock"
CLAIM_STALE_S = 6 * 3600.0


class ChunkError(ValueError):
    """A chunk on disk does not match the manifest; the message names the file."""


def chunk_name(i: int) -> str:
    return f"chunk_{i:06d}.npz"


def _proc_start(pid: int) -> str | None:
    """The process start time (clock ticks since boot, /proc/PID/stat field 22): pid + start
    identifies a process even when pids are reused. None where /proc is absent."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
        return stat.rsplit(")", 1)[1].split()[19]
    except (OSError, IndexError):
        return None


def _alive(pid: int, start: str | None) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        pass                                   # alive, another user's process
    return start is None or _proc_start(pid) in (None, start)


def _me() -> dict:
    return dict(pid=os.getpid(), host=socket.gethostname(), start=_proc_start(os.getpid()))


@contextlib.contextmanager
def locked(out: Path):
    """An exclusive flock on out/.lock (released by the kernel if the holder is killed)."""
    with open(out / LOCK, "a+") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


def _write_temporary(path: Path, data: bytes, slow_s: float = 0.0) -> Path:
    """`data` written and fsynced to a temporary name beside `path` (private to this process);
    removed again when anything (an OS error, Ctrl-C) interrupts the write."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        with open(tmp, "wb") as fh:
            if slow_s > 0:                       # fault injection: a window with half a file
                fh.write(data[:len(data) // 2])
                fh.flush()
                time.sleep(slow_s)
                fh.write(data[len(data) // 2:])
            else:
                fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise
    return tmp


def _atomic_write(path: Path, data: bytes, slow_s: float = 0.0) -> None:
    tmp = _write_temporary(path, data, slow_s)
    try:
        os.replace(tmp, path)
    finally:
        with contextlib.suppress(OSError):
            tmp.unlink()


def read_manifest(out: Path) -> dict:
    path = Path(out) / MANIFEST
    if not path.exists():
        return {}
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError as err:   # written atomically: only an outside edit does this
        raise ChunkError(f"{path}: not valid JSON ({err})") from err


def update_manifest(out: Path, change) -> dict:
    """Read-modify-write of the manifest under the lock: `change(manifest) -> manifest`."""
    with locked(out):
        manifest = change(read_manifest(out))
        _atomic_write(out / MANIFEST, json.dumps(manifest, indent=1, default=str).encode())
    return manifest


def sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


# {path: (size, mtime_ns, inode, sha256)} of chunk files this process hashed or wrote: a file
# whose size, mtime and inode are unchanged is not hashed again (`check_chunk`), so the checks
# at the end of a run and while waiting for other writers cost a stat per chunk
# (tests/test_hostile_records.py::test_a_noop_rerun_hashes_each_chunk_once).
_VERIFIED: dict[str, tuple[int, int, int, str]] = {}


def _stat_key(st: os.stat_result) -> tuple[int, int, int]:
    return st.st_size, st.st_mtime_ns, st.st_ino


def forget_verified() -> None:
    """Hash every chunk file again at its next check (the verified-file cache emptied)."""
    _VERIFIED.clear()


def check_chunk(out: Path, i: int, entry: dict | None) -> str | None:
    """Why chunk i is not done (None when it is): missing file or entry, or a mismatch."""
    path = Path(out) / chunk_name(i)
    try:
        st = path.stat()
    except FileNotFoundError:
        return f"{path} is missing"
    if not entry:
        return f"{path} is not recorded in the manifest (its writer was interrupted)"
    if st.st_size != entry.get("bytes", st.st_size):
        return (f"{path} is truncated or padded ({st.st_size} bytes, "
                f"expected {entry['bytes']})")
    known = _VERIFIED.get(str(path))
    if known is not None and known[:3] == _stat_key(st) and known[3] == entry["sha256"]:
        return None
    digest = sha256(path)
    _VERIFIED[str(path)] = (*_stat_key(st), digest)
    if digest != entry["sha256"]:
        return f"{path} is corrupted (sha256 differs from the manifest)"
    return None


def done_chunks(out: Path, n_chunks: int) -> set[int]:
    """Chunks whose file matches its manifest entry (a file is hashed once per process while
    its size, mtime and inode stay the same)."""
    entries = read_manifest(out).get("chunks", {})
    return {i for i in range(n_chunks) if check_chunk(out, i, entries.get(chunk_name(i))) is None}


def try_claim(out: Path, i: int) -> bool:
    """Claim chunk i for this process (exclusive create); take over a stale claim."""
    claims = Path(out) / CLAIMS
    claims.mkdir(exist_ok=True)
    path = claims / f"{chunk_name(i)[:-4]}.claim"
    me = _me()
    # The claim's content is written first and hard-linked into place: link(2), like
    # O_CREAT|O_EXCL, fails when the name exists, and a claim is never seen half-written.
    tmp = claims / f".{path.name}.{me['pid']}.tmp"
    try:
        tmp.write_text(json.dumps(dict(me, time=time.time())))
        for _ in range(2):
            try:
                os.link(tmp, path)
                return True
            except FileExistsError:
                with locked(out):   # judge and remove under the lock: one writer takes it over
                    if not _stale_or_mine(path, me):
                        return False
                    with contextlib.suppress(FileNotFoundError):
                        path.unlink()
        return False
    finally:
        with contextlib.suppress(OSError):
            tmp.unlink()


def _stale_or_mine(path: Path, me: dict) -> bool:
    try:
        claim = json.loads(path.read_text())
        pid, host, start, t = claim["pid"], claim["host"], claim.get("start"), claim["time"]
    except FileNotFoundError:
        return True
    except (OSError, ValueError, KeyError, TypeError):
        # Unreadable: a writer killed between create and write. Judge it by its age.
        try:
            return time.time() - path.stat().st_mtime > 60.0
        except FileNotFoundError:
            return True
    if host == me["host"]:
        # Ours (e.g. an earlier run_sweep in this process that raised) or a dead process.
        return (pid == me["pid"] and start == me["start"]) or not _alive(pid, start)
    stale_s = float(os.environ.get("TKUJAX_CLAIM_STALE_S", CLAIM_STALE_S))
    return time.time() - t > stale_s


def release(out: Path, i: int) -> None:
    with contextlib.suppress(FileNotFoundError):
        (Path(out) / CLAIMS / f"{chunk_name(i)[:-4]}.claim").unlink()


class ForeignFolderError(ValueError):
    """The folder's manifest names another sweep than the writer's (see `owner_check`)."""


def owner_check(out: Path, spec_hash: str | None) -> None:
    """Under the lock: refuse to write into `out` unless its manifest is this sweep's."""
    if spec_hash is None:
        return
    held = read_manifest(out).get("spec_hash")
    if held != spec_hash:
        raise ForeignFolderError(f"{out}: the folder now holds another sweep (spec hash {held}, "
                                 f"this one {spec_hash}); nothing was written")


def write_chunk(out: Path, i: int, record: dict[str, np.ndarray], extra: dict | None = None,
                spec_hash: str | None = None) -> dict:
    """Write chunk i atomically, then record {sha256, rows, bytes, n_diverged} (and `extra`,
    e.g. who wrote it) in the manifest. With `spec_hash`, the rename and the entry happen only
    while the folder's manifest is that sweep's (checked under the lock)."""
    out = Path(out)
    slow = float(os.environ.get("TKUJAX_TEST_SLOW_WRITE", 0) or 0)
    buf = io.BytesIO()
    np.savez(buf, **record)
    data = buf.getvalue()
    path = out / chunk_name(i)
    tmp = _write_temporary(path, data, slow / 2)
    try:
        with locked(out):
            owner_check(out, spec_hash)
            os.replace(tmp, path)
    finally:
        with contextlib.suppress(OSError):
            tmp.unlink()
    digest = hashlib.sha256(data).hexdigest()
    with contextlib.suppress(OSError):
        _VERIFIED[str(path)] = (*_stat_key(path.stat()), digest)
    if slow > 0:
        time.sleep(slow / 2)                  # fault injection: renamed, not yet recorded
    rows = len(next(iter(record.values())))
    entry = dict(sha256=digest, rows=rows, bytes=len(data),
                 n_diverged=int(np.sum(record["diverged"])) if "diverged" in record else 0,
                 **(extra or {}))

    def add(manifest: dict) -> dict:
        owner_check(out, spec_hash)
        manifest.setdefault("chunks", {})[chunk_name(i)] = entry
        return manifest

    update_manifest(out, add)
    return entry


def clean_temporaries(out: Path) -> None:
    """Remove temporary files of writers that are gone (pid in the name, this host)."""
    for tmp in [*Path(out).glob(".*.tmp"), *Path(out).glob(f"{CLAIMS}/.*.tmp")]:
        with contextlib.suppress(ValueError, IndexError, FileNotFoundError):
            pid = int(tmp.name.rsplit(".", 2)[1])
            if pid != os.getpid() and not _alive(pid, None):
                tmp.unlink()


def read_chunks(out: Path, manifest: dict) -> list[dict[str, np.ndarray]]:
    """The verified chunks recorded in the manifest, in order; ChunkError names a bad file.

    Sweeps written before the manifest held checksums: every chunk file, unverified, with a
    bad file still named."""
    out = Path(out)
    entries = manifest.get("chunks")
    if entries is None:
        names = sorted(p.name for p in out.glob("chunk_*.npz"))
    else:
        names = sorted(entries)
        for name in names:
            why = check_chunk(out, int(name[6:12]), entries[name])
            if why:
                raise ChunkError(f"{why}; rerun the sweep command to recompute it")
    parts = []
    for name in names:
        try:
            with np.load(out / name) as z:
                parts.append({k: z[k] for k in z.files})
        except (zipfile.BadZipFile, OSError, ValueError, EOFError) as err:
            raise ChunkError(f"{out / name} cannot be read ({type(err).__name__}: {err}); "
                             "rerun the sweep command to recompute it") from err
        if entries is not None and len(next(iter(parts[-1].values()))) != entries[name]["rows"]:
            raise ChunkError(f"{out / name} has {len(next(iter(parts[-1].values())))} rows, "
                             f"the manifest says {entries[name]['rows']}")
    return parts


class Claims:
    """This process's pending chunks, claimed one at a time (`next`): a chunk another writer
    holds is retried once the others are tried, until it is done or its claim goes stale
    (bounded by `deadline`, time.monotonic); at most `max_chunks` (None: all) are claimed.
    The caller writes a claimed chunk and releases it (`release`)."""

    def __init__(self, out: Path, pending: list[int], n_chunks: int, max_chunks: int | None,
                 deadline: float):
        self.out, self.n_chunks, self.max_chunks = out, n_chunks, max_chunks
        self.deadline = deadline
        self.queue, self.waiting, self.claimed = list(pending), [], 0

    def next(self, wait: bool = True) -> int | None:
        """The next chunk claimed here that is not done yet; None when none is left, or, with
        wait=False, when only chunks another writer holds are left (nothing slept)."""
        while self.max_chunks is None or self.claimed < self.max_chunks:
            while self.queue:
                i = self.queue.pop(0)
                if not try_claim(self.out, i):
                    self.waiting.append(i)
                    continue
                entries = read_manifest(self.out).get("chunks", {})
                if check_chunk(self.out, i, entries.get(chunk_name(i))) is None:
                    release(self.out, i)          # another writer finished it meanwhile
                    continue
                self.claimed += 1
                return i
            if not wait or not self.waiting:
                return None
            done = done_chunks(self.out, self.n_chunks)
            self.waiting = [i for i in self.waiting if i not in done]
            if not self.waiting or time.monotonic() > self.deadline:
                return None
            time.sleep(0.5)
            self.queue, self.waiting = self.waiting, []
        return None
