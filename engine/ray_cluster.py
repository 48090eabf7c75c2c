"""Where a --ray render runs and the connection to it: the --ray address (a new local Ray, an existing cluster),
Ray itself (imported here, lazily: an optional dependency of the command line, never of the extension), and
ray.init / ray.shutdown around the driver's work (engine/distributed.py), with one line instead of minutes of
retries when the cluster cannot be reached.
"""
from __future__ import annotations

import contextlib
import logging
import os
import re
import socket
import sys
import threading
from dataclasses import dataclass

from . import stop_signals
from .batch import EXIT_FAILED, CliError, UsageError
from .frame_save import first_line

RAY_MISSING = "--ray needs Ray: python3 dev.py --blender 5.0 setup --ray"
CONNECT_TIMEOUT_S = 5.0      # an unreachable head node fails after this, not after Ray's own minutes of retries
INIT_TIMEOUT_S = 60.0        # ray.init against a reachable port that does not answer as Ray would


@dataclass(frozen=True)
class Cluster:
    """Where to render: a new local Ray with `workers` slots, or an existing cluster at `address`."""
    address: str          # "local", "auto", "HOST:PORT" or "ray://HOST:PORT"
    workers: int | None   # local:N

    @property
    def local(self) -> bool:
        return self.address == "local"


def require_ray():
    try:
        import ray
    except ImportError:
        raise CliError(RAY_MISSING) from None
    return ray


def parse_cluster(text: str) -> Cluster:
    text = text.strip()
    m = re.fullmatch(r"local(?::(\d+))?", text)
    if m:
        workers = int(m.group(1)) if m.group(1) else None
        if workers is not None and not 1 <= workers <= 4096:
            raise UsageError(f"--ray local:N needs N from 1 to 4096, got {text!r}")
        return Cluster("local", workers)
    if text == "auto" or re.fullmatch(r"(ray://)?[^\s:/]+:\d+", text):
        return Cluster(text, None)
    raise UsageError(f"--ray takes auto, HOST:PORT, ray://HOST:PORT or local[:N], got {text!r}")


def node_count(ray) -> int:
    """The cluster's live nodes with CPUs (at least 1)."""
    return max(1, sum(1 for node in ray.nodes() if node.get("Alive") and node.get("Resources", {}).get("CPU")))


@contextlib.contextmanager
def connected(ray, cluster: Cluster, local_workers: int):
    """ray.init for the cluster (workers' output stays in their logs), ray.shutdown after."""
    quiet = dict(log_to_driver=False, logging_level=logging.ERROR)
    try:
        if cluster.local:
            # A Ray of this machine alone: on the loopback interface. Its processes start with the stop signals
            # held, so that a signal to the process group (a farm's SIGTERM, Ctrl-C) does not end them under
            # this driver (which would abort with Ray's stack dump): the driver stops them in order.
            with stop_signals.held():
                ray.init(address="local", num_cpus=local_workers, include_dashboard=False,
                         _node_ip_address="127.0.0.1", **quiet)
        else:
            _check_reachable(cluster.address)
            with _deadline(INIT_TIMEOUT_S, f"cannot connect to the Ray cluster at {cluster.address}: no answer "
                                           f"in {INIT_TIMEOUT_S:.0f} s (is it a Ray head node, of Ray 2.40.0?)"):
                ray.init(address=cluster.address, **quiet)
    except CliError:
        raise
    except Exception as err:
        raise CliError(f"cannot connect to the Ray cluster at {cluster.address}: {first_line(err)}") from None
    finally:
        stop_signals.take_back()
    try:
        yield
    finally:
        if cluster.local:
            _end_local_ray()
        ray.shutdown()


def _end_local_ray() -> None:
    """Kill the local Ray's processes (this process's descendants: the driver renders nothing itself) before
    ray.shutdown, which would send them SIGTERM, held since their start, and wait a second for each."""
    import psutil  # Ray's own copy (ray/thirdparty_files, on sys.path once Ray is imported)
    processes = psutil.Process().children(recursive=True)
    for process in processes:
        with contextlib.suppress(psutil.Error):
            process.kill()
    psutil.wait_procs(processes, timeout=5.0)


def _check_reachable(address: str) -> None:
    """A TCP connection to HOST:PORT within CONNECT_TIMEOUT_S ("auto" is Ray's own to find). Ray connects to a
    head node at 127.0.0.1 or localhost through the machine's network address: that one is checked."""
    if address == "auto":
        return
    resolved = address
    if not address.startswith("ray://"):
        from ray._private.services import resolve_ip_for_localhost
        resolved = resolve_ip_for_localhost(address)
    host, port = resolved.removeprefix("ray://").rsplit(":", 1)
    try:
        socket.create_connection((host, int(port)), timeout=CONNECT_TIMEOUT_S).close()
    except OSError as err:
        reason = "timed out" if isinstance(err, TimeoutError) else (err.strerror or str(err))
        via = f" (Ray's {resolved})" if resolved != address else ""
        raise CliError(f"cannot reach the Ray cluster at {address}{via}: {reason}") from None


@contextlib.contextmanager
def _deadline(seconds: float, message: str):
    """Past `seconds` inside the block, one line and exit 1: ray.init retries for minutes in native code that
    Python cannot interrupt, and nothing has been started yet that would need cleaning up."""
    def expire():
        print(f"ember: error: {message}", file=sys.stderr, flush=True)
        os._exit(EXIT_FAILED)
    timer = threading.Timer(seconds, expire)
    timer.daemon = True
    timer.start()
    try:
        yield
    finally:
        timer.cancel()
