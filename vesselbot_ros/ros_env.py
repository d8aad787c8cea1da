"""Network hygiene for every run and test: own domain, localhost discovery, own logs.

Fast DDS multicasts discovery on every interface by default, and every
process on the machine with the same ROS_DOMAIN_ID joins the same graph.  Our
entry points and test fixtures therefore:

* set ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``;
* give every run and every test its own ``ROS_DOMAIN_ID``, allocated with an
  exclusive lock file so that concurrent runs on one machine never share one;
* put rcl's log files under the run's own folder (``ROS_LOG_DIR``);
* give Fast DDS our participant defaults (:data:`FASTDDS_PROFILE`: every participant re-announces itself every
  250 ms), unless the user's environment names a profiles file of its own.

No rclpy import here: the launcher sets this up before any node starts.
"""

from __future__ import annotations

import fcntl
import os
import random
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

__all__ = ["FASTDDS_PROFILE", "FASTDDS_PROFILE_KEY", "DomainLease", "allocate_domain", "allocate_domain_for_peers", "ros_environment",
           "apply_to_process", "restore_process_env"]

# Linux-safe domain ids are 0..101 (higher ones may collide with ephemeral
# ports).  0 is the default that other programs use: never take it.
DOMAIN_MIN = 1
DOMAIN_MAX = 101

#: The Fast DDS profiles file every process of a run loads (``FASTRTPS_DEFAULT_PROFILES_FILE``, read once per process
#: when its first participant is made): participants re-announce every 250 ms, not every 3 s.  A node's publishers
#: and subscriptions are made in its first second, while its participant is being discovered; made at that moment,
#: about one in two was matched only at a peer's next announcement (measured: 2.2-2.4 s late in 4 of 8 trials, and a
#: lockstep run waited 2-2.5 s for "every node to be wired"); with a peer announcing every 250 ms, 0 of 8 trials.
#: The run's own processes are the peers a user's node meets, so it gains without the file.
#: bench/bench_discovery.py measures both settings side by side.
FASTDDS_PROFILE = Path(__file__).with_name("fastdds_profile.xml")
#: The environment variable Fast DDS reads the profiles file's path from.
FASTDDS_PROFILE_KEY = "FASTRTPS_DEFAULT_PROFILES_FILE"


def _temp_dir() -> Path:
    """The folder ``tempfile.gettempdir()`` picks (``$TMPDIR``, ``$TEMP``, ``$TMP``, ``/tmp``, ...), without its probe.

    gettempdir() writes a test file to choose; on a full disk every write fails and it raises "No usable
    temporary directory" at import, before a command could check (and name) its own output path.
    """
    for name in ("TMPDIR", "TEMP", "TMP"):
        d = os.environ.get(name)
        if d and os.path.isdir(d):
            return Path(d)
    return next((Path(d) for d in ("/tmp", "/var/tmp", "/usr/tmp") if os.path.isdir(d)), Path.cwd())


_LOCK_DIR = _temp_dir() / "vesselbot_domains"


@dataclass
class DomainLease:
    """An exclusively held ROS domain id; release() (or process exit) frees it."""

    domain_id: int
    _fh: IO[str] | None = field(default=None, repr=False)
    _ns_fh: IO[str] | None = field(default=None, repr=False)

    @property
    def fds(self) -> tuple[int, ...]:
        """The locks' file descriptors (for child processes that must hold the lease until they exit)."""
        return tuple(f.fileno() for f in (self._fh, self._ns_fh) if f is not None)

    def release(self) -> None:
        """Give up this process's hold on the domain id (idempotent).

        The lock is on the open file: it is freed once every process holding
        its descriptor (this one, and children started with ``hold_fds=lease.fds``)
        closed it or exited, so a domain whose nodes still run is never leased again.
        """
        for f in (self._fh, self._ns_fh):
            if f is not None:
                f.close()
        self._fh = self._ns_fh = None

    def __enter__(self) -> DomainLease:
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()


def allocate_domain(preferred: int | None = None, namespace: str | None = None) -> DomainLease:
    """Lease a ROS domain id in [1, 101] no other vesselbot run on this machine holds.

    Args:
        preferred: Use this id (e.g. a user's ``--domain-id``); if it is held
            by another run, raise instead of silently picking another.
        namespace: With ``preferred``: the graph's namespace.  Graphs in
            different namespaces may share a chosen domain (``vesselbot run
            --domain-id D --namespace NAME``): the domain is then held shared,
            the namespace in it exclusively.  An automatically chosen domain is
            always held exclusively.

    Raises:
        RuntimeError: if ``preferred`` (or its namespace) is busy or every id is leased.
    """
    _LOCK_DIR.mkdir(parents=True, exist_ok=True)
    if preferred is not None:
        if not DOMAIN_MIN <= preferred <= DOMAIN_MAX and preferred != 0:
            raise RuntimeError(f"ROS domain id {preferred} is outside [{DOMAIN_MIN}, {DOMAIN_MAX}]")
        if namespace is not None:
            return _shared_lease(preferred, namespace)
        candidates = [preferred]
    else:
        candidates = list(range(DOMAIN_MIN, DOMAIN_MAX + 1))
        random.SystemRandom().shuffle(candidates)
    for dom in candidates:
        fh = open(_LOCK_DIR / f"{dom}.lock", "a+")  # noqa: SIM115 - held for the lease's lifetime
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            fh.close()
            continue
        return DomainLease(dom, fh)
    if preferred is not None:
        raise RuntimeError(f"ROS domain id {preferred} is in use by another vesselbot run")
    raise RuntimeError("every ROS domain id in [1, 101] is in use by other vesselbot runs")


def allocate_domain_for_peers() -> DomainLease:
    """Lease a free domain id for your own nodes, that a run started later can join.

    The id is held shared (as ``vesselbot run --domain-id D`` holds it, under
    a name no namespace can take): ``vesselbot run --domain-id D`` then joins it, while no automatically leased run can take it.  Start your
    peer nodes on it before the run, and keep the lease until the run ends.
    (``allocate_domain()`` then ``release()`` would leave a gap in which
    another run may lease the id first.)
    """
    for _ in range(DOMAIN_MAX):
        lease = allocate_domain()
        assert lease._fh is not None
        try:
            # a conversion is not atomic: an exclusive taker may slip in between, then take another id
            fcntl.flock(lease._fh, fcntl.LOCK_SH | fcntl.LOCK_NB)
            ns_fh = open(_LOCK_DIR / f"{lease.domain_id}.ns_peers.{os.getpid()}.lock", "a+")  # noqa: SIM115 - held with the lease
            try:
                fcntl.flock(ns_fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:
                ns_fh.close()
                raise
        except OSError:
            lease.release()
            continue
        lease._ns_fh = ns_fh
        return lease
    raise RuntimeError("every ROS domain id in [1, 101] is in use by other vesselbot runs")


def _shared_lease(domain_id: int, namespace: str) -> DomainLease:
    fh = open(_LOCK_DIR / f"{domain_id}.lock", "a+")  # noqa: SIM115 - held for the lease's lifetime
    try:
        fcntl.flock(fh, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except OSError:
        fh.close()
        raise RuntimeError(f"ROS domain id {domain_id} is in use by another vesselbot run") from None
    tag = namespace.strip("/").replace("/", "_") or "_"
    ns_fh = open(_LOCK_DIR / f"{domain_id}.ns_{tag}.lock", "a+")  # noqa: SIM115
    try:
        fcntl.flock(ns_fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        ns_fh.close()
        fh.close()
        raise RuntimeError(f"ROS domain id {domain_id} already runs a vesselbot graph in namespace {namespace}") from None
    return DomainLease(domain_id, fh, ns_fh)


def ros_environment(domain_id: int, log_dir: str | os.PathLike[str], base: dict[str, str] | None = None) -> dict[str, str]:
    """Environment for a node process (or this process) of one isolated run.

    Args:
        domain_id: The leased ROS domain id.
        log_dir: Folder for rcl log files (created).
        base: Environment to start from (default: ``os.environ``).
    """
    env = dict(os.environ if base is None else base)
    Path(log_dir).mkdir(parents=True, exist_ok=True)
    env["ROS_DOMAIN_ID"] = str(domain_id)
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env.pop("ROS_LOCALHOST_ONLY", None)  # deprecated in Jazzy; would warn
    env["ROS_LOG_DIR"] = str(log_dir)
    env.setdefault("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
    if not env.get(FASTDDS_PROFILE_KEY):  # the user's own profiles file wins
        env[FASTDDS_PROFILE_KEY] = str(FASTDDS_PROFILE)
    env["PYTHONUNBUFFERED"] = "1"
    return env


_PROCESS_KEYS = ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE", "ROS_LOG_DIR", FASTDDS_PROFILE_KEY)


def apply_to_process(env: dict[str, str]) -> dict[str, str | None]:
    """Put a run's ROS settings into this process's ``os.environ``; return what they replaced.

    rcl reads ``ROS_LOG_DIR`` and discovery settings from the process environment, so an
    in-process Context (launcher, test, re-estimation) needs them too.  Undo with
    :func:`restore_process_env`.
    """
    saved = {k: os.environ.get(k) for k in _PROCESS_KEYS}
    os.environ.update({k: env[k] for k in _PROCESS_KEYS})
    return saved


def restore_process_env(saved: dict[str, str | None]) -> None:
    """Undo :func:`apply_to_process`."""
    for k, v in saved.items():
        if v is None:
            os.environ.pop(k, None)
        else:
            os.environ[k] = v
