"""Independent work spread over the host's cores: fitlab gives XLA's CPU backend one device per
core (fitlab/_jax.py), and a computation made of independent pieces (NUTS's chains, each a
long sequential loop) is compiled once with ``jax.shard_map`` so that each device
runs its share of them at the same time. One XLA CPU computation otherwise runs its small
operations on one core; on an accelerator the pieces stay vmapped on the one device."""

from __future__ import annotations

import numpy as np

from fitlab._jax import jax


def host_devices() -> list:
    """The devices work is spread over: the host's CPU devices when JAX computes on the CPU
    (one per core); none on an accelerator."""
    return jax.devices() if jax.default_backend() == "cpu" else []


def over_cores(local, ndevices: int, split: tuple):
    """``local`` compiled to run on the first ``ndevices`` host devices at once: the arguments
    marked in ``split`` shared out along their first axis (a multiple of ``ndevices``), the
    others copied to every device; the results gathered along their first axis. With one
    device, ``local`` jitted as it is."""
    if ndevices <= 1:
        return jax.jit(local)
    spec = jax.sharding.PartitionSpec
    mesh = jax.sharding.Mesh(np.array(host_devices()[:ndevices]), ("core",))
    return jax.jit(jax.shard_map(local, mesh=mesh,
                                 in_specs=tuple(spec("core") if s else spec() for s in split),
                                 out_specs=spec("core"), check_vma=False))


__all__ = ["host_devices", "over_cores"]
