"""Confinement a kernel worker process applies to itself before it reads any untrusted code (Linux).

:func:`confine` is called by :mod:`robot_agent.kernels.worker` once its imports are done; each layer is tried
and reported (``{"layer": "applied" | "unavailable: why"}``), so the agent logs what holds on this machine
(docs/reliability/sandbox.md lists every layer and what it does and does not prevent):

- ``pdeathsig``: ``prctl(PR_SET_PDEATHSIG, SIGKILL)`` (the worker dies with the agent) — applied first, by
  :func:`die_with_parent`;
- ``no_new_privs``: ``prctl(PR_SET_NO_NEW_PRIVS)`` (no setuid gain; needed by the two layers below);
- ``netns``: ``unshare(CLONE_NEWUSER | CLONE_NEWNET | CLONE_NEWNS)``: a network namespace with only a
  downed loopback, and a mount namespace of its own;
- ``scratch``: a private tmpfs (16 MB, 1024 files) mounted on the scratch directory, seen by nobody else;
- ``landlock``: reads only below the Python installation, the system libraries and the agent's packages;
  reads and writes in the scratch directory; no other write, removal, creation or truncation anywhere;
  no TCP bind/connect (ABI >= 4); no abstract UNIX sockets and no signals out of the sandbox (ABI >= 6);
  no ptrace of processes outside it (every ABI);
- ``seccomp``: ``socket()`` fails (EACCES), ``fork``/``vfork``/``clone`` without ``CLONE_THREAD`` fail
  (EPERM: no grandchild outlives the worker), ``clone3`` answers ENOSYS (so threads use ``clone``),
  ``ptrace`` fails; x86-64 and aarch64 only;
- ``rlimits``: address space (RLIMIT_AS) = the footprint now + ``memory_mb``; CPU seconds (RLIMIT_CPU)
  when ``cpu_s`` is given; open files 64; file size 16 MB; no core dumps.

Nothing here needs root; the namespace layer needs unprivileged user namespaces (most distributions).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import platform
import resource
import signal
import struct
import sys
from collections.abc import Sequence
from pathlib import Path

__all__ = [
    "FILE_SIZE_BYTES",
    "OPEN_FILES",
    "SCRATCH_BYTES",
    "address_space_bytes",
    "confine",
    "die_with_parent",
]

#: RLIMIT_NOFILE of a worker.
OPEN_FILES = 64
#: RLIMIT_FSIZE of a worker (bytes): what it may write into its scratch directory per file.
FILE_SIZE_BYTES = 16 * 2**20
#: Size of the worker's private scratch file system (bytes), where mount namespaces are available.
SCRATCH_BYTES = 16 * 2**20

_PR_SET_PDEATHSIG = 1
_PR_SET_NO_NEW_PRIVS = 38
_PR_SET_SECCOMP = 22
_SECCOMP_MODE_FILTER = 2
_CLONE_NEWUSER = 0x10000000
_CLONE_NEWNET = 0x40000000
_CLONE_NEWNS = 0x00020000
_MS_NOSUID, _MS_NODEV = 2, 4
_CLONE_THREAD = 0x00010000

_libc = ctypes.CDLL(ctypes.util.find_library("c") or None, use_errno=True)
_libc.syscall.restype = ctypes.c_long


def _err() -> str:
    return os.strerror(ctypes.get_errno())


def die_with_parent(parent_pid: int) -> None:
    """SIGKILL this process when the thread that started it ends; exit now if that already happened."""
    if _libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0) != 0:
        raise OSError(f"prctl(PR_SET_PDEATHSIG): {_err()}")
    if os.getppid() != parent_pid:  # the parent died before the prctl: nobody would kill us
        os._exit(70)


def address_space_bytes() -> int | None:
    """This process's virtual memory size (``/proc/self/status`` VmSize), or ``None``."""
    try:
        with open("/proc/self/status", encoding="ascii") as status:
            for line in status:
                if line.startswith("VmSize:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError):
        return None
    return None


def _map_ids(uid: int, gid: int) -> None:
    """Keep this process's user and group ids inside its new user namespace (files it creates in its
    scratch need an owner); supplementary groups are dropped for good."""
    for name, text in (("setgroups", "deny"), ("uid_map", f"{uid} {uid} 1"), ("gid_map", f"{gid} {gid} 1")):
        try:
            with open(f"/proc/self/{name}", "w", encoding="ascii") as f:
                f.write(text)
        except OSError:
            return


def _scratch_tmpfs(scratch: Path) -> str:
    """Mount a private tmpfs of :data:`SCRATCH_BYTES` on ``scratch`` (in this process's own mount
    namespace: nobody else sees it) and move into it: the worker's writes are bounded in total."""
    _libc.mount.argtypes = (ctypes.c_char_p,) * 3 + (ctypes.c_ulong, ctypes.c_char_p)
    opts = f"size={SCRATCH_BYTES},mode=0700,nr_inodes=1024".encode()
    if _libc.mount(b"none", str(scratch).encode(), b"tmpfs", _MS_NOSUID | _MS_NODEV, opts) != 0:
        return f"unavailable: mount tmpfs: {_err()}; RLIMIT_FSIZE bounds each file only"
    os.chdir(scratch)
    return f"applied (private tmpfs of {SCRATCH_BYTES // 2**20} MB, 1024 files)"


# ----------------------------------------------------------------------------------------- landlock
_LL_CREATE, _LL_ADD_RULE, _LL_RESTRICT = 444, 445, 446  # the same numbers on every architecture
_FS_EXECUTE, _FS_WRITE_FILE, _FS_READ_FILE, _FS_READ_DIR = 1 << 0, 1 << 1, 1 << 2, 1 << 3
_FS_ALL_V1 = (1 << 13) - 1  # execute .. make_sym
_FS_REFER, _FS_TRUNCATE, _FS_IOCTL_DEV = 1 << 13, 1 << 14, 1 << 15
_NET_BIND_TCP, _NET_CONNECT_TCP = 1 << 0, 1 << 1
_SCOPE_ABSTRACT_UNIX, _SCOPE_SIGNAL = 1 << 0, 1 << 1
_READ = _FS_EXECUTE | _FS_READ_FILE | _FS_READ_DIR


class _PathBeneath(ctypes.Structure):
    _pack_ = 1
    _fields_ = (("allowed_access", ctypes.c_uint64), ("parent_fd", ctypes.c_int32))


def _landlock(readable: Sequence[Path], writable: Sequence[Path]) -> str:
    abi = _libc.syscall(_LL_CREATE, None, 0, 1)  # LANDLOCK_CREATE_RULESET_VERSION
    if abi < 1:
        return f"unavailable: {_err()}"
    fs = _FS_ALL_V1
    if abi >= 2:
        fs |= _FS_REFER
    if abi >= 3:
        fs |= _FS_TRUNCATE
    if abi >= 5:
        fs |= _FS_IOCTL_DEV
    net = _NET_BIND_TCP | _NET_CONNECT_TCP if abi >= 4 else 0
    scoped = _SCOPE_ABSTRACT_UNIX | _SCOPE_SIGNAL if abi >= 6 else 0
    attr = struct.pack("QQQ", fs, net, scoped)[: 8 if abi < 4 else 16 if abi < 6 else 24]
    buf = ctypes.create_string_buffer(attr, len(attr))
    ruleset = _libc.syscall(_LL_CREATE, buf, ctypes.c_size_t(len(attr)), 0)
    if ruleset < 0:
        return f"unavailable: landlock_create_ruleset: {_err()}"
    try:
        file_rights = _FS_EXECUTE | _FS_WRITE_FILE | _FS_READ_FILE | (_FS_TRUNCATE if abi >= 3 else 0)
        rules = [(p, _READ) for p in readable] + [(p, fs) for p in writable]
        for path, access in rules:
            try:
                fd = os.open(path, os.O_PATH | os.O_CLOEXEC)
            except OSError:
                continue  # a path this machine does not have
            try:
                if not path.is_dir():
                    access &= file_rights
                rule = _PathBeneath(access, fd)
                if _libc.syscall(_LL_ADD_RULE, ruleset, 1, ctypes.byref(rule), 0) != 0:
                    return f"unavailable: landlock_add_rule({path}): {_err()}"
            finally:
                os.close(fd)
        if _libc.syscall(_LL_RESTRICT, ruleset, 0) != 0:
            return f"unavailable: landlock_restrict_self: {_err()}"
    finally:
        os.close(ruleset)
    return f"applied (ABI {abi})"


# ------------------------------------------------------------------------------------------ seccomp
_ARCHES = {  # machine -> (AUDIT_ARCH, socket, clone, clone3, ptrace, fork, vfork)
    "x86_64": (0xC000003E, 41, 56, 435, 101, 57, 58),
    "aarch64": (0xC00000B7, 198, 220, 435, 117, None, None),
}
_RET_ALLOW = 0x7FFF0000
_RET_ERRNO = 0x00050000


def _bpf(code: int, jt: int, jf: int, k: int) -> bytes:
    return struct.pack("HBBI", code, jt, jf, k & 0xFFFFFFFF)


def _seccomp() -> str:
    arch = _ARCHES.get(platform.machine())
    if arch is None:
        return f"unavailable: no filter for {platform.machine()}"
    audit, sock, clone, clone3, ptrace, fork, vfork = arch
    ld, jeq, jset, ret = 0x20, 0x15, 0x45, 0x06  # BPF_LD|W|ABS, BPF_JMP|JEQ|K, BPF_JMP|JSET|K, BPF_RET
    denied = [(sock, 13), (ptrace, 1), (fork, 1), (vfork, 1), (clone3, 38)]  # EACCES, EPERM, ENOSYS
    prog = [
        _bpf(ld, 0, 0, 4),  # seccomp_data.arch
        _bpf(jeq, 1, 0, audit),
        _bpf(ret, 0, 0, _RET_ERRNO | 1),  # another ABI (e.g. 32-bit calls): refuse
        _bpf(ld, 0, 0, 0),  # seccomp_data.nr
    ]
    if platform.machine() == "x86_64":  # x32 system calls: refuse
        prog += [_bpf(jset, 0, 1, 0x40000000), _bpf(ret, 0, 0, _RET_ERRNO | 1)]
    for nr, errno in denied:
        if nr is not None:
            prog += [_bpf(jeq, 0, 1, nr), _bpf(ret, 0, 0, _RET_ERRNO | errno)]
    prog += [
        _bpf(jeq, 0, 4, clone),
        _bpf(ld, 0, 0, 16),  # args[0] (low word): the clone flags
        _bpf(jset, 1, 0, _CLONE_THREAD),
        _bpf(ret, 0, 0, _RET_ERRNO | 1),
        _bpf(ret, 0, 0, _RET_ALLOW),
        _bpf(ret, 0, 0, _RET_ALLOW),
    ]
    code = b"".join(prog)
    filt = ctypes.create_string_buffer(code, len(code))

    class _Prog(ctypes.Structure):
        _fields_ = (("len", ctypes.c_ushort), ("filter", ctypes.c_void_p))

    fprog = _Prog(len(prog), ctypes.cast(filt, ctypes.c_void_p))
    if _libc.prctl(_PR_SET_SECCOMP, _SECCOMP_MODE_FILTER, ctypes.byref(fprog), 0, 0) != 0:
        return f"unavailable: prctl(PR_SET_SECCOMP): {_err()}"
    return "applied"


# ------------------------------------------------------------------------------------------- confine
def _readable_roots(packages: Sequence[Path]) -> list[Path]:
    roots = {Path(sys.prefix), Path(sys.base_prefix), Path(sys.exec_prefix)}
    roots |= {Path(p) for p in ("/usr/lib", "/usr/lib64", "/lib", "/lib64", "/usr/local/lib")}
    roots |= set(packages)
    for entry in sys.path:  # site-packages and the standard library, not the working directory
        path = Path(entry or ".").resolve()
        public = any(part in ("site-packages", "dist-packages") for part in path.parts)
        if path.is_dir() and (public or path.name.startswith("python3") or path.name == "lib-dynload"):
            roots.add(path)
    return sorted(roots)


def _rlimit(which: int, value: int) -> None:
    _soft, hard = resource.getrlimit(which)
    value = value if hard == resource.RLIM_INFINITY else min(value, hard)
    resource.setrlimit(which, (value, value))


def confine(scratch: Path, packages: Sequence[Path], memory_mb: float, cpu_s: int | None) -> dict[str, str]:
    """Apply every layer above to this process, for good; what each layer came to (see the module doc).

    ``scratch``: the only writable directory; ``packages``: the agent's package directories (readable);
    ``memory_mb``: address space allowed above the current footprint; ``cpu_s``: CPU seconds for the
    rest of this process's life (None: no CPU limit; the agent's wall-time limit per call still holds).
    """
    report: dict[str, str] = {"pdeathsig": "applied"}
    base = address_space_bytes()  # before Landlock hides /proc
    ok = _libc.prctl(_PR_SET_NO_NEW_PRIVS, 1, 0, 0, 0) == 0
    report["no_new_privs"] = "applied" if ok else f"unavailable: {_err()}"
    uid, gid = os.getuid(), os.getgid()
    if _libc.unshare(_CLONE_NEWUSER | _CLONE_NEWNET | _CLONE_NEWNS) == 0:
        report["netns"] = "applied"
        _map_ids(uid, gid)
        report["scratch"] = _scratch_tmpfs(scratch)
    elif _libc.unshare(_CLONE_NEWUSER | _CLONE_NEWNET) == 0:
        report["netns"] = "applied"
        report["scratch"] = "unavailable: no mount namespace; RLIMIT_FSIZE bounds each file only"
    else:
        report["netns"] = f"unavailable: unshare: {_err()}"
        report["scratch"] = "unavailable: no user namespace; RLIMIT_FSIZE bounds each file only"
    report["landlock"] = _landlock(_readable_roots(packages), [scratch, Path("/dev/null")])
    report["seccomp"] = _seccomp()
    if base is not None:
        limit = base + int(memory_mb * 2**20)
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
    if cpu_s is not None:
        used = resource.getrusage(resource.RUSAGE_SELF)
        _rlimit(resource.RLIMIT_CPU, int(used.ru_utime + used.ru_stime) + cpu_s)
    _rlimit(resource.RLIMIT_NOFILE, OPEN_FILES)
    _rlimit(resource.RLIMIT_FSIZE, FILE_SIZE_BYTES)
    _rlimit(resource.RLIMIT_CORE, 0)
    room = "unknown" if base is None else f"+{memory_mb:g} MB"
    cpu = "unlimited" if cpu_s is None else f"{cpu_s} s"
    report["rlimits"] = (
        f"applied (address space {room}, cpu {cpu}, {OPEN_FILES} files,"
        f" {FILE_SIZE_BYTES // 2**20} MB per file)"
    )
    return report
