"""Where a sweep's configs run: CPU devices asked for before JAX's backend starts, the processes of a multi-host
sweep (``jax.distributed``), a 1-D mesh over every device, and moving results between processes and the host.

Used by :mod:`gsjax.app.sweep.grid` (which places configs) and ``gsjax sweep`` (which asks for devices and starts the
distributed runtime before anything touches the backend).
"""

from __future__ import annotations

import os
import pickle

import jax
import numpy as np


def maybe_initialize_distributed() -> None:
    """``jax.distributed.initialize()`` when ``GSJAX_DISTRIBUTED=1``. The coordinator, process count and id come from
    ``JAX_COORDINATOR_ADDRESS`` (host:port), ``GSJAX_NUM_PROCESSES`` and ``GSJAX_PROCESS_ID`` where set, else from
    the cluster's environment (e.g. SLURM, Open MPI) as JAX detects it."""
    if os.environ.get("GSJAX_DISTRIBUTED") != "1":
        return
    given = {name: os.environ.get(f"GSJAX_{name.upper()}") for name in ("num_processes", "process_id")}
    try:
        jax.distributed.initialize(**{name: int(value) for name, value in given.items() if value is not None})
    except ValueError as err:
        raise ValueError(f"GSJAX_DISTRIBUTED=1: cannot start the distributed runtime: {err}") from None


def available_cores() -> int:
    """CPU cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def default_cpu_devices(configs: int) -> int:
    """CPU devices for ``configs`` configs run at once: one per two cores, at most one per config.

    One SLAM program already keeps about 1.3 cores busy (its ops and its compilation are multi-threaded), and
    XLA:CPU compiles a program once per device (the device is part of its persistent-cache key): measured on 2
    cores, 2 devices ran 4 configs 9 % faster than 1 with a warm cache, and compiled twice with a cold one."""
    return max(1, min(available_cores() // 2, configs))


def request_cpu_devices(count: int) -> int:
    """Ask JAX for ``count`` CPU devices before its backend starts, so that single-config programs placed on
    different devices run at the same time. Returns the count asked for, or 0 when it could not be changed:
    ``XLA_FLAGS`` already forces a count, or the backend is already up (an in-process caller keeps the devices it
    has). Accelerator runs are unaffected (their devices form the mesh)."""
    if count < 1 or "xla_force_host_platform_device_count" in os.environ.get("XLA_FLAGS", ""):
        return 0
    try:
        jax.config.update("jax_num_cpu_devices", count)
    except RuntimeError:  # the backend is initialised already
        return 0
    return count


def batch_mesh():
    """A 1-D mesh named ``batch`` over every device (all processes)."""
    return jax.sharding.Mesh(np.asarray(jax.devices()), ("batch",))


def place_batch(tree, mesh):
    """A batched tree laid out along its leading axis over ``mesh`` (each process fills its own shards)."""
    sharding = jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec("batch"))

    def put(x):
        x = np.asarray(x)
        return jax.make_array_from_callback(x.shape, sharding, lambda index: x[index])

    return jax.tree_util.tree_map(put, tree)


def to_host(tree):
    """A tree as numpy; an array sharded over several processes is gathered to every process (each must call)."""
    from jax.experimental import multihost_utils

    def get(x):
        if isinstance(x, jax.Array) and not x.is_fully_addressable:
            return np.asarray(multihost_utils.process_allgather(x, tiled=True))
        return jax.device_get(x)

    return jax.tree_util.tree_map(get, tree)


# How long a process waits at a batch's end for the others to finish theirs (their shares of a batch may differ by
# a whole config's run; hours on a CPU).
RESULTS_BARRIER_MS = 12 * 3600 * 1000


def share_results(per_config: list, name: str = "results") -> list:
    """Every process's entries of ``per_config`` (None where another process ran the config) on every process, as
    numpy: each process pickles its own and all-gathers the bytes. One process: returned as given.

    The processes first meet at a coordination-service barrier named ``name`` (unique per call): the collectives'
    own rendezvous gives up after 30 s, less than one process can be ahead of another."""
    if jax.process_count() == 1:
        return per_config
    from jax._src import distributed
    from jax.experimental import multihost_utils

    distributed.global_state.client.wait_at_barrier(f"gsjax_share_{name}", RESULTS_BARRIER_MS)

    mine = {i: jax.device_get(entry) for i, entry in enumerate(per_config) if entry is not None}
    blob = np.frombuffer(pickle.dumps(mine), np.uint8)
    sizes = np.asarray(multihost_utils.process_allgather(np.array([blob.size], np.int64))).reshape(-1)
    padded = np.zeros(int(sizes.max()), np.uint8)
    padded[:blob.size] = blob
    blobs = np.asarray(multihost_utils.process_allgather(padded))
    shared = list(per_config)
    for process, size in enumerate(sizes):
        for i, entry in pickle.loads(blobs[process, :size].tobytes()).items():
            shared[i] = shared[i] if shared[i] is not None else entry
    return shared
