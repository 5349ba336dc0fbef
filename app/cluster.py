"""Reaching Ray (informative): a local Ray instance or an existing cluster, with errors that name
the address. One way for every program that runs work on Ray (lghcc-batch's sweeps, lghcc-enc
--ray's tiles)."""

from __future__ import annotations

import socket

from ..common.errors import LghccError


class ClusterError(LghccError):
    """The Ray cluster cannot be reached or started."""


def one_line(e: BaseException) -> str:
    """An exception as one line: its type and the last line of its message (a Ray task error
    carries the remote traceback; its last line is the cause)."""
    text = str(e).strip()
    last = text.splitlines()[-1].strip() if text else ""
    name = type(e).__name__
    return last if name in last or name.startswith("RayTaskError") else f"{name}: {last}" if last else name


def parse_address(address: str) -> tuple[str, int] | None:
    """(host, port) of a Ray address 'host:port' or 'ray://host:port'; None for 'auto' or
    'local' (Ray finds those itself)."""
    a = address.strip()
    if a in ("auto", "local"):
        return None
    if a.startswith("ray://"):
        a = a[len("ray://"):]
    host, sep, port = a.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise ClusterError(f"--address {address!r}: expected host:port (the head node's GCS address, as "
                           "`ray start --head` prints it, default port 6379), ray://host:port, or auto")
    return host.strip("[]"), int(port)


def check_reachable(address: str, timeout_s: float) -> None:
    """Fail fast and clearly when nothing listens at the address (Ray itself retries for long)."""
    hp = parse_address(address)
    if hp is None:
        return
    host, port = hp
    try:
        with socket.create_connection((host, port), timeout=timeout_s):
            pass
    except socket.timeout:
        raise ClusterError(f"cannot reach the Ray cluster at {address}: no answer within {timeout_s:g} s "
                           "(is the head node up and the port open? `ray start --head` on it)") from None
    except OSError as e:
        raise ClusterError(f"cannot reach the Ray cluster at {address}: {e.strerror or e} "
                           "(is `ray start --head` running there?)") from None


def init_ray(address: str | None, num_cpus: int | None, timeout_s: float,
             missing: str = "pip install 'lghcc[batch]' (or run with --local)"):
    """ray.init: a local Ray (address None) or an existing cluster; ClusterError naming the
    address when it fails (``missing``: what to do when Ray is not installed). Workers get
    OMP_WAIT_POLICY=PASSIVE (torch threads do not spin)."""
    if address:
        check_reachable(address, timeout_s)
    try:
        import ray
    except ImportError:
        raise ClusterError(f"Ray is not installed: {missing}") from None
    env = {"env_vars": {"OMP_WAIT_POLICY": "PASSIVE"}}
    kw = dict(include_dashboard=False, log_to_driver=False, runtime_env=env, logging_level="WARNING")
    try:
        if address:
            ray.init(address=address, **kw)
        else:
            ray.init(num_cpus=num_cpus, **kw)
    except Exception as e:  # noqa: BLE001 - Ray raises ConnectionError, RuntimeError, ...
        where = f"the Ray cluster at {address}" if address else "a local Ray instance"
        raise ClusterError(f"cannot connect to {where}: {one_line(e)}") from None
    return ray
